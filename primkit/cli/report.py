"""``primkit report FOLDER --model MODEL -o report/``: the whole chain (abstract, segment, embed,
deform) on a collection, into a static HTML page (:func:`primkit.report.build_report`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import (add_abstraction_options, add_force, add_output, check_outputs, collect, err, input_paths, model_file,
                      output_names, report_errors, settings_from_args)

__all__ = ["register"]


def _run(args) -> int:
    from ..model.abstraction import load_model
    from ..report import build_report

    files = collect(args.inputs)
    if args.limit:
        files = files[: args.limit]
    if not files:
        err("no shape files found in " + " ".join(map(str, args.inputs)))
        return 2
    model = load_model(args.model)
    out = Path(args.output)
    output_names(files)  # says which inputs shared a name
    images = [out / "images" / f"{i:03d}.{kind}.png" for i in range(len(files)) for kind in ("mesh", "cuboids", "segmentation")]
    check_outputs(args, [out / "index.html", out / "report.json", out / "images" / "similarity.png",
                         out / "images" / "deformation.png", *images], input_paths(files, model_file(args.model)))
    report, errors = build_report(files, model, args.output, refine=args.refine,
                                  settings=settings_from_args(args, model.settings), model_label=args.model,
                                  align=args.align, up=args.up, front=args.front, overwrite=args.force,
                                  cache_dir=args.cache, workers=args.workers, adapt=args.adapt)
    for note in report.notes.values():
        print(f"primkit: note: {note}")
    print(f"wrote {report.path} ({report.shapes} shapes)")
    return report_errors(errors)


def register(subparsers) -> None:
    p = subparsers.add_parser("report", help="a static HTML report of a collection: thumbnails, segmentation, "
                              "similarity map, deformation, metrics, interactive 3D scene",
        description="Run the whole chain (abstract, segment, embed, deform) on a collection and write one static HTML page that opens offline: thumbnails, co-segmentation, the similarity map, a deformation, a metrics table and a 3D scene.",
        epilog="examples:\n  primkit report chairs/ --model chair -o report/\n", formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+", help="folders or files of shapes")
    add_abstraction_options(p)
    add_output(p, "output folder (index.html, report.json, images/)")
    p.add_argument("--limit", type=int, default=0, help="at most this many shapes (0: all)")
    add_force(p)
    p.set_defaults(func=_run)

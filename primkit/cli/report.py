"""``primkit report FOLDER --model MODEL -o report/``: the whole chain (abstract, segment, embed,
deform) on a collection, into a static HTML page (:func:`primkit.report.build_report`)."""

from __future__ import annotations

from ._common import collect, err, report_errors, settings_from_args

__all__ = ["register"]


def _run(args) -> int:
    from ..model.abstractor import Abstractor
    from ..report import build_report

    files = collect(args.inputs)
    if args.limit:
        files = files[: args.limit]
    if not files:
        err("no shape files found in " + " ".join(map(str, args.inputs)))
        return 2
    model = Abstractor.load(args.model)
    report, errors = build_report(files, model, args.output, refine=args.refine,
                                  settings=settings_from_args(args, model.settings), model_label=args.model,
                                  align=None if args.align == "none" else args.align, overwrite=args.force,
                                  cache_dir=args.cache, workers=args.workers)
    for note in report.notes.values():
        print(f"primkit: note: {note}")
    print(f"wrote {report.path} ({report.shapes} shapes)")
    return report_errors(errors)


def register(subparsers) -> None:
    p = subparsers.add_parser("report", help="a static HTML report of a collection: thumbnails, segmentation, "
                              "similarity map, deformation, metrics, interactive 3D scene")
    p.add_argument("inputs", nargs="+", help="folders or files of shapes")
    p.add_argument("--model", required=True, help="a model file, or a bundled model's name")
    p.add_argument("-o", "--output", required=True, help="output folder (index.html, report.json, images/)")
    p.add_argument("--limit", type=int, default=0, help="at most this many shapes (0: all)")
    p.add_argument("--refine", type=int, default=0, metavar="N")
    p.add_argument("--align", choices=["none", "auto"], default="none")
    p.add_argument("--up", default=None, help="the inputs' up axis (default +y)")
    p.add_argument("--front", default=None, help="the inputs' front axis (default +x; COSEG chairs: +z)")
    p.add_argument("--cache", default=None)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--force", action="store_true", help="replace an existing report")
    p.set_defaults(func=_run)

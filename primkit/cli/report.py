"""``primkit report FOLDER --model MODEL -o report/``: the whole chain (abstract, segment, embed,
deform) on a collection, into a static HTML page (:func:`primkit.report.build_report`)."""

from __future__ import annotations


from ._common import add_command
from ._common import add_abstraction_options, add_force, add_output, model_file, progress_of, report_errors, settings_from_args

__all__ = ["register"]


def _run(args) -> int:
    from ..data import plan_run
    from ..model.abstraction import load_model
    from ..report import build_report
    from ..segmentation.labeller import read_labeller

    model = load_model(args.model)
    plan = plan_run(args.inputs, limit=args.limit, reads=[model_file(args.model)])
    report, errors = build_report(plan, model, args.output, refine=args.refine,
                                  settings=settings_from_args(args, model.settings), model_label=args.model,
                                  align=args.align, up=args.up, front=args.front, overwrite=args.force,
                                  cache_dir=args.cache, workers=args.workers, adapt=args.adapt,
                                  progress=progress_of(args), labeller=read_labeller(model_file(args.model)),
                                  images=args.images)
    for note in report.notes.values():
        print(f"primkit: note: {note}")
    print(f"wrote {report.path} ({report.shapes} shapes)")
    return report_errors(errors)


def register(subparsers) -> None:
    p = add_command(subparsers, "report", help="a static HTML report of a collection: thumbnails, segmentation, "
                              "similarity map, deformation, metrics, interactive 3D scene",
        description="Run the whole chain (abstract, segment, embed, deform) on a collection and write one static, self-contained HTML page that opens offline: a card per shape (co-segmentation, cuboids, mesh, names), the similarity map, a deformation, the metrics defined and tabulated, and a 3D scene.",
        examples=["primkit report chairs/ --model chair -o report/"])
    p.add_argument("inputs", nargs="+", help="folders or files of shapes")
    add_abstraction_options(p)
    add_output(p, "output folder: index.html (one self-contained page, pictures inlined) and report.json")
    p.add_argument("--images", action="store_true", help="also write each picture as a PNG into OUTPUT/images/ "
                   "(the page needs none of them)")
    p.add_argument("--limit", type=int, default=0, help="at most this many shapes (0: all)")
    add_force(p)
    p.set_defaults(func=_run)

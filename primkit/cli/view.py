"""``primkit view ...``: open one of the interactive viewers of ``apps/`` (pyvista windows).

    primkit view abstraction SHAPE --model chair
    primkit view collection FOLDER --model chair [--mode segmentation]
    primkit view embedding FOLDER --model chair
    primkit view deformation SOURCE TARGET --model chair

``--png PATH`` draws the viewer's first frame off screen into a PNG instead of opening a window
(no display needed); with ``--window`` as well, the picture is taken from a real window (under X,
e.g. ``xvfb-run -a``) which then closes.

The viewers live in ``apps/`` of a source checkout (they sit above the library and are not
installed with it); :func:`load_app` finds them beside the package.
"""

from __future__ import annotations

import importlib
import os

from ._common import err, report_errors

__all__ = ["register", "load_app", "show"]

def load_app(name: str):
    """Import the viewer module ``primkit.viewers.<name>``."""
    return importlib.import_module(f"primkit.viewers.{name}")


def show(plotter, png=None, window: bool = False) -> None:
    """Open the plotter's window; or write its first frame to ``png`` (off screen, or from a real
    window that then closes when ``window``)."""
    from ..io import atomic_output

    if png is None:
        plotter.show()
        return
    if window:
        plotter.show(interactive=False, auto_close=False)
        print(f"opened a window on X display {os.environ.get('DISPLAY', '?')}")
    plotter.render()
    with atomic_output(png, overwrite=True) as tmp:
        plotter.screenshot(str(tmp))
    plotter.close()
    print(f"wrote {png}")


def _common(p, model_required=True):
    p.add_argument("--model", required=model_required, help="a model file, or a bundled model's name")
    p.add_argument("--refine", type=int, default=0, metavar="N", help="N gradient steps per shape (0: off)")
    p.add_argument("--align", choices=["none", "auto"], default="none")
    p.add_argument("--png", default=None, help="write the viewer's first frame to this PNG instead of opening it")
    p.add_argument("--window", action="store_true", help="with --png: take the picture from a real window (needs X)")
    p.add_argument("--size", default="1280x900", help="window size WxH (default 1280x900)")
    p.add_argument("--force", action="store_true", help="replace an existing --png file")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must be WxH, e.g. 1280x900, got {text!r}") from None
    return w, h


def _run(args) -> int:
    from ..io import refuse_existing

    refuse_existing(args.png, args.force)
    align = None if args.align == "none" else args.align
    off = args.png is not None and not args.window
    size = _size(args.size)
    common = load_app("common")
    if args.viewer == "abstraction":
        app = load_app("abstraction_viewer")
        shapes, model, errors = common.abstract_shapes([args.shape], args.model, refine=args.refine, align=align,
                                                       progress=False)
        if not shapes:
            err(errors[0] if errors else f"{args.shape}: not usable")
            return 2
        s = shapes[0]
        viewer = app.abstraction_viewer(s.vertices, s.faces, s.cuboids, model.part_names, title=s.name,
                                        off_screen=off, window_size=size)
        if args.select is not None:
            viewer.select(args.select)
        elif viewer.part_actors:
            viewer.select(max(viewer.part_actors, key=lambda k: s.cuboids.volumes[k]))
        show(viewer.plotter, args.png, args.window)
        return 0
    if args.viewer == "collection":
        from ._common import collect

        app = load_app("collection_browser")
        files = collect(args.folder)
        if args.limit:
            files = files[: args.limit]
        shapes, model, errors = common.abstract_shapes(files, args.model, refine=args.refine, align=align)
        if not shapes:
            report_errors(errors)
            err("no usable shapes")
            return 2
        browser = app.collection_browser(shapes, model.part_names, mode=args.mode, off_screen=off, window_size=size,
                                         title=" ".join(args.folder))
        show(browser.plotter, args.png, args.window)
        return report_errors(errors)
    if args.viewer == "embedding":
        app = load_app("embedding_explorer")
        return app.run(args, off_screen=off, window_size=size, show=show)
    if args.viewer == "deformation":
        app = load_app("deformation_viewer")
        return app.run(args, off_screen=off, window_size=size, show=show)
    err(f"unknown viewer {args.viewer}")
    return 2


def register(subparsers) -> None:
    p = subparsers.add_parser("view", help="interactive viewers (pyvista windows): abstraction, collection, embedding, "
                              "deformation")
    sub = p.add_subparsers(dest="viewer", required=True)
    q = sub.add_parser("abstraction", help="one shape and its cuboids: toggle parts, opacity, click a cuboid")
    q.add_argument("shape")
    q.add_argument("--select", type=int, default=None, help="part index selected at start (default: the largest)")
    _common(q)
    q = sub.add_parser("collection", help="a grid of shapes, parts coloured alike; mesh / cuboids / segmentation")
    q.add_argument("folder", nargs="+")
    q.add_argument("--mode", choices=["mesh", "cuboids", "segmentation"], default="cuboids")
    q.add_argument("--limit", type=int, default=0, help="at most this many shapes (0: all)")
    _common(q)
    q = sub.add_parser("embedding", help="the t-SNE map of a collection; click a shape for its nearest neighbours")
    q.add_argument("folder", nargs="+")
    q.add_argument("--parts", default="all", help="parts the similarity looks at (names or indices, e.g. back,seat)")
    q.add_argument("--neighbors", type=int, default=4, help="neighbours shown beside the chosen shape")
    q.add_argument("--select", type=int, default=0, help="shape chosen at start (its position in the collection)")
    q.add_argument("--limit", type=int, default=0)
    _common(q)
    q = sub.add_parser("deformation", help="source, target and result; blend slider; move, scale, turn a part")
    q.add_argument("source")
    q.add_argument("target")
    q.add_argument("--part", default=None, help="part edited by the widgets (name or index; default: the largest)")
    _common(q)
    p.set_defaults(func=_run)

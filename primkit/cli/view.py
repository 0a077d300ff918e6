"""``primkit view ...``: one of the interactive viewers of :mod:`primkit.viewers` (pyvista windows).

    primkit view abstraction SHAPE --model chair
    primkit view collection FOLDER --model chair [--mode segmentation]
    primkit view embedding FOLDER --model chair
    primkit view deformation SOURCE TARGET --model chair
    primkit view open3d SHAPE --model chair             # Open3D's own window (a mesh or a point cloud)

``--png PATH`` draws the viewer's first frame off screen into a PNG instead of opening a window
(no display needed); with ``--window`` as well, the picture is taken from a real window (under X,
e.g. ``xvfb-run -a``) which then closes. The viewers are part of the installed package.
"""

from __future__ import annotations

import os
from pathlib import Path

from ._common import add_command
from ._common import (
    abstraction_options,
    progress_of,
    add_abstraction_options,
    add_force,
    add_png,
    check_command_outputs,
    collect,
    err,
    input_paths,
    model_file,
    report_errors,
)

__all__ = ["register", "show"]


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


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must be WxH, e.g. 1280x900, got {text!r}") from None
    return w, h


def _meshes(args, inputs, progress: bool = True):
    """The inputs abstracted (:func:`primkit.model.abstraction.abstract_shapes`), as the viewers
    draw them: ``(shapes, model, errors)``; meshes, and point clouds as points
    (:func:`primkit.viewers.common.drawable`); a voxel grid is reported as an error."""
    from ..model.abstraction import abstract_shapes
    from ..viewers.common import drawable

    out = abstract_shapes(inputs, args.model, **dict(abstraction_options(args), progress=progress and progress_of(args)))
    shapes, errors = [], list(out.errors)
    for a in out:
        try:
            shapes.append(drawable(a))
        except ValueError as exc:
            errors.append(str(exc))
    return shapes, out.model, errors


def _labeller(args):
    """The model's labeller (:func:`primkit.segmentation.labeller.read_labeller`), None without one."""
    from ..segmentation.labeller import read_labeller

    path = model_file(args.model)
    return None if path is None else read_labeller(path)


def _files(args):
    files = collect(args.folder)
    return files[: args.limit] if args.limit else files


def _view_abstraction(args, off, size) -> int:
    from ..viewers.abstraction_viewer import abstraction_viewer

    shapes, model, errors = _meshes(args, [args.shape], progress=False)
    if not shapes:
        err(errors[0] if errors else f"{args.shape}: not usable")
        return 2
    s = shapes[0]
    label_to = getattr(args, "label_to", None)
    if (getattr(args, "label_from", None) is not None or getattr(args, "label_guess", False)) and label_to is None:
        err("--label-from and --label-guess start a labelling: give --label-to as well")
        return 2
    guess = named = None
    labeller = _labeller(args)
    for flag, asked in (("--label-guess", getattr(args, "label_guess", False)), ("--semantic", args.semantic)):
        if asked and labeller is None:
            err(f"{flag}: the model {args.model} has no labeller (primkit name-parts learns one)")
            return 2
    if labeller is not None:  # each face's (point's) name: the "by name" checkbox, or the guess to start from
        from ..segmentation.bylabel import labelled_surface

        named = (labelled_surface(labeller, s.vertices, s.faces, s.result), list(labeller.names))
    if getattr(args, "label_guess", False):
        if args.label_from is not None:
            err("--label-from or --label-guess: one start, not both")
            return 2
        guess = named
    if label_to is not None:
        from ..segmentation.handlabels import label_suffix

        want = ".seg" if len(s.faces) else ".labels.npy"
        if label_suffix(label_to) != want:
            err(f"{label_to}: {args.shape} is a {'mesh' if len(s.faces) else 'point cloud'}: its labels go to "
                f"<stem>{want}")
            return 2
    viewer = abstraction_viewer(s.vertices, s.faces, s.cuboids, model.part_names, title=s.name, off_screen=off,
                                window_size=size, label_to=label_to, overwrite=args.force, source=args.shape,
                                opacity=0.6 if label_to is None and not args.semantic else 0.35,  # the names show through
                                label_from=getattr(args, "label_from", None), label_guess=guess, named=named,
                                by_name=args.semantic)
    if args.select is not None:
        viewer.select(args.select)
    elif viewer.part_actors:
        viewer.select(max(viewer.part_actors, key=lambda k: s.cuboids.volumes[k]))
    show(viewer.plotter, args.png, args.window)
    hand = viewer.labelling
    if hand is not None and args.png is None and not hand.saved and hand.labels.changed:
        err(f"closed without saving: nothing written to {label_to}")
        return 1
    return 0


def _view_collection(args, off, size) -> int:
    from ..viewers.collection_browser import collection_browser

    shapes, model, errors = _meshes(args, _files(args))
    if not shapes:
        report_errors(errors)
        err("no usable shapes")
        return 2
    labeller = _labeller(args) if args.mode == "names" else None
    if args.mode == "names" and labeller is None:
        err(f"--mode names: the model {args.model} has no labeller (primkit name-parts learns one)")
        return 2
    browser = collection_browser(shapes, model.part_names, mode=args.mode, off_screen=off, window_size=size,
                                 title=" ".join(args.folder), labeller=labeller)
    show(browser.plotter, args.png, args.window)
    return report_errors(errors)


def _view_embedding(args, off, size) -> int:
    from ..viewers.embedding_explorer import embedding_explorer

    shapes, model, errors = _meshes(args, _files(args))
    if len(shapes) < 3:
        report_errors(errors)
        err(f"the map needs at least 3 usable shapes, got {len(shapes)}")
        return 2
    explorer = embedding_explorer(shapes, model.part_names, parts=args.parts, neighbors=args.neighbors,
                                  off_screen=off, window_size=size, title=" ".join(args.folder),
                                  labeller=_labeller(args))
    explorer.select(min(max(args.select, 0), len(shapes) - 1))
    show(explorer.plotter, args.png, args.window)
    return report_errors(errors)


def _view_deformation(args, off, size) -> int:
    from ..model.parts import resolve_parts
    from ..viewers.deformation_viewer import deformation_viewer

    shapes, model, errors = _meshes(args, [args.source, args.target], progress=False)
    if len(shapes) != 2:
        report_errors(errors)
        err("deformation needs a usable source and target")
        return 2
    part = None
    if args.part is not None:
        chosen = resolve_parts(args.part, model.part_names)
        if len(chosen) != 1:
            err(f"--part must name one part, got {args.part!r}")
            return 2
        part = int(chosen[0])
    viewer = deformation_viewer(shapes[0], shapes[1], model.part_names, part=part, off_screen=off, window_size=size)
    show(viewer.plotter, args.png, args.window)
    return 0


def _view_open3d(args, off, size) -> int:
    from ..io import Mesh, PointCloud, read_shape
    from ..viewers.open3d_viewer import open3d_viewer

    shape = read_shape(args.shape)
    if isinstance(shape, Mesh):
        given = (shape.vertices, shape.faces)
    elif isinstance(shape, PointCloud):
        given = shape.points
    else:
        err(f"{args.shape}: a voxel grid; the Open3D viewer shows meshes and point clouds")
        return 2
    if args.png is not None and args.window and not os.environ.get("DISPLAY"):
        err("view open3d --png --window takes the picture from Open3D's window and needs a display: run it under X "
            "or xvfb-run -a (without --window it draws off screen)")
        return 2
    options = {k: v for k, v in abstraction_options(args).items() if k not in ("cache", "workers", "progress")}
    if args.semantic and _labeller(args) is None:
        err(f"--semantic: the model {args.model} has no labeller (primkit name-parts learns one)")
        return 2
    viewer = open3d_viewer(given, args.model, name=Path(args.shape).stem, refine_step=args.refine_step,
                           export_folder=args.export, names=args.semantic, **options)
    if args.png is not None:
        # --png: Open3D's OffscreenRenderer, no display; with --window: the window's own frame (X)
        viewer.picture(args.png, width=size[0], height=size[1], overwrite=True, offscreen=not args.window)
        print(f"wrote {args.png}")
    else:
        viewer.show(width=size[0], height=size[1])
    return 0


_VIEWERS = {"abstraction": _view_abstraction, "collection": _view_collection, "embedding": _view_embedding,
            "deformation": _view_deformation, "open3d": _view_open3d}


def _run(args) -> int:
    from ..io import check_suffix

    given = [getattr(args, k) for k in ("shape", "source", "target") if getattr(args, k, None)]
    given += list(getattr(args, "folder", None) or [])
    outputs = [] if args.png is None else [check_suffix(args.png, ".png", "a picture")]
    if getattr(args, "label_to", None) is not None:  # the label file and its names file
        from ..segmentation.handlabels import names_path

        outputs += [Path(args.label_to), names_path(args.label_to)]
    if outputs:  # before any work: outputs that can be written and are none of the inputs
        check_command_outputs(args, outputs, input_paths([f for g in given for f in collect([g])], model_file(args.model)))
    off = args.png is not None and not args.window
    return _VIEWERS[args.viewer](args, off, _size(args.size))


def _options(p) -> None:
    add_abstraction_options(p)
    add_png(p)
    p.add_argument("--window", action="store_true", help="with --png: take the picture from a real window (needs X)")
    p.add_argument("--size", default="1280x900", help="window size WxH (default 1280x900)")
    add_force(p)


def register(subparsers) -> None:
    p = add_command(subparsers, "view", help="interactive viewers: abstraction, collection, embedding, deformation "
                              "(pyvista windows) and open3d (Open3D's window); --png: the first frame into a PNG",
        description="Interactive viewers: pyvista windows (abstraction, collection, embedding, deformation) and Open3D's window (open3d). --png PATH draws the first frame into a picture instead of opening a window.",
        examples=["primkit view abstraction chair.off --model chair", "primkit view collection chairs/ --model chair --png grid.png"])
    sub = p.add_subparsers(dest="viewer", required=True)
    q = add_command(sub, "abstraction", help="one shape and its cuboids: toggle parts, opacity, click a cuboid",
        description="One shape and its cuboids: a toggle per part, the mesh's opacity, click a cuboid to select it.",
        examples=["primkit view abstraction chair.off --model chair", "primkit view abstraction chair.off --model chair --png view.png",
                  "primkit view abstraction chair.off --model chair --label-to chair.seg"])
    q.add_argument("shape", help="a mesh, point cloud or voxel file")
    q.add_argument("--select", type=int, default=None, help="part index selected at start (default: the largest)")
    q.add_argument("--label-to", default=None, metavar="PATH",
                   help="label by hand (docs/labeller.md): click a cuboid, type a name, Enter; Tab paints with a brush; "
                   "Ctrl+Z undoes, Ctrl+S writes PATH (a mesh: <stem>.seg, a point cloud: <stem>.labels.npy) and "
                   "<stem>.names.json beside it, which name-parts reads")
    q.add_argument("--label-from", default=None, metavar="PATH",
                   help="with --label-to: start from this label file (and its <stem>.names.json), e.g. to go on "
                   "with an earlier labelling (--label-to the same file needs --force)")
    q.add_argument("--label-guess", action="store_true",
                   help="with --label-to: start from the model's labeller's labels, to correct them")
    q.add_argument("--semantic", action="store_true",
                   help="colour the shape by the model's labeller's names, with a legend (the 'by name' checkbox)")
    _options(q)
    q = add_command(sub, "collection", help="a grid of shapes, parts coloured alike; mesh / cuboids / segmentation",
        description="A grid of shapes with parts coloured alike on every shape; switch between the mesh, the cuboids and the segmentation.",
        examples=["primkit view collection chairs/ --model chair --mode segmentation"])
    q.add_argument("folder", nargs="+", help="folders or files of shapes")
    q.add_argument("--mode", choices=["mesh", "cuboids", "segmentation", "names"], default="cuboids",
                   help="what each shape shows at start (default cuboids; names: each face coloured by the model's "
                   "labeller's name, with a legend)")
    q.add_argument("--limit", type=int, default=0, help="at most this many shapes (0: all)")
    _options(q)
    q = add_command(sub, "embedding", help="the t-SNE map of a collection; click a shape for its nearest neighbours",
        description="The t-SNE map of a collection by the chosen parts; click a shape to see its nearest neighbours.",
        examples=["primkit view embedding chairs/ --model chair --parts back,seat"])
    q.add_argument("folder", nargs="+", help="folders or files of shapes")
    q.add_argument("--parts", default="all", help="parts the similarity looks at (names or indices, e.g. back,seat); "
                   "with a model labeller, names it knows (arms) are each shape's labelled regions, as embed --parts")
    q.add_argument("--neighbors", type=int, default=4, help="neighbours shown beside the chosen shape")
    q.add_argument("--select", type=int, default=0, help="shape chosen at start (its position in the collection)")
    q.add_argument("--limit", type=int, default=0, help="at most this many shapes (0: all)")
    _options(q)
    q = add_command(sub, "deformation", help="source, target and result; blend slider; move, scale, turn a part",
        description="Source, target and the deformed result side by side; a slider blends source to target, widgets move, scale and turn a part live.",
        examples=["primkit view deformation src.off tgt.off --model chair"])
    q.add_argument("source", help="the shape to deform")
    q.add_argument("target", help="the shape whose part configuration it takes")
    q.add_argument("--part", default=None, help="part edited by the widgets (name or index; default: the largest)")
    _options(q)
    q = add_command(sub, "open3d", help="one mesh or point cloud in Open3D's window: toggle parts, refine, export",
        description="One mesh or point cloud in Open3D's window, part by part: toggle parts, the surface and the cuboids, refine, export (never over an existing file).",
        examples=["primkit view open3d chair.ply --model chair", "primkit view open3d cloud.xyz --model chair --export out/"])
    q.add_argument("shape", help="a mesh or point cloud file")
    q.add_argument("--export", default="primkit-export", help="folder the export button writes into (default "
                   "primkit-export; nothing is overwritten)")
    q.add_argument("--refine-step", type=int, default=100, help="gradient steps the refine button adds (default 100)")
    q.add_argument("--semantic", action="store_true",
                   help="colour the surface by the model's labeller's names (a 'colour by name' button switches)")
    _options(q)
    p.set_defaults(func=_run)

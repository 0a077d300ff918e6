"""``primkit deform`` (a source mesh or point cloud takes a target's part configuration) and ``primkit edit``
(scale, turn and move named parts of one mesh): thin wrappers over :mod:`primkit.deformation`.

Both abstract their inputs with ``--model``, work in the canonical frame of the source (so shapes
of any size or placement compare alike), and write the result back in the source's own frame, with
its faces and vertex order (and, when the output has the source's format, the attributes trimesh
keeps, such as vertex colours), a PNG and a JSON file of quality measures beside it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..model.parts import resolve_parts
from ._common import add_command
from ._common import (abstraction_options, add_abstraction_options, add_force, add_output, add_png, check_command_outputs, err,
                      input_paths, model_file, report_errors)

__all__ = ["register", "parse_edit"]

#: the one frame every distance deform reports is measured in (its JSON says so)
FRAME = ("canonical frame of each shape, as its cuboids are: bounding box centred, longest side 1, turned as the "
         "model's orientation search chose (--align)")


def parse_edit(text: str, names, *, kind: str) -> dict[int, float | np.ndarray]:
    """``"legs=1.3"`` / ``"back=15"`` / ``"seat=0,0.05,0"`` -> {slot: value} for every slot the
    part name or index selects (:func:`primkit.model.parts.resolve_parts`). ``kind`` is ``"scale"``
    (1 or 3 numbers), ``"rotate"`` (1 number), ``"move"`` (3 numbers) or ``"lengthen"`` (1
    number, ``"legs=1.3"``)."""
    if "=" not in text:
        raise ValueError(f"--{kind} {text!r}: expected PART=VALUE, e.g. legs=1.3")
    spec, value = text.split("=", 1)
    try:
        numbers = [float(x) for x in value.split(",")]
    except ValueError:
        raise ValueError(f"--{kind} {text!r}: {value!r} is not a number or a comma-separated list of numbers") from None
    allowed = {"scale": (1, 3), "rotate": (1,), "move": (3,), "lengthen": (1,)}[kind]
    if len(numbers) not in allowed:
        raise ValueError(f"--{kind} {text!r}: expected {' or '.join(map(str, allowed))} number(s), got {len(numbers)}")
    if not all(np.isfinite(numbers)):
        raise ValueError(f"--{kind} {text!r}: values must be finite")
    val = numbers[0] if len(numbers) == 1 else np.array(numbers)
    return {int(k): val for k in resolve_parts(spec, names)}


def _outputs(args, inputs, *, points: bool = False) -> tuple[Path, Path | None, Path]:
    """The deformed mesh (or points), the picture and the JSON, checked before any work against
    the ``inputs`` (the shapes read, the model): writable, the right suffixes, nothing replaced
    without ``--force``."""
    from ..io import MESH_WRITE_SUFFIXES, check_suffix

    if points:
        out = check_suffix(args.output, (".xyz", ".npy", ".ply"), "a deformed point cloud")
    else:
        out = check_suffix(args.output, MESH_WRITE_SUFFIXES, "a deformed mesh")
    png = check_suffix(args.png, ".png", "a picture") if args.png else None
    js = check_suffix(args.json, ".json", "the quality measures") if args.json else out.with_suffix(".json")
    check_command_outputs(args, (out, png, js), input_paths([Path(p) for p in inputs if Path(p).is_file()], model_file(args.model)))
    return out, png, js


def _abstract(args, paths, model=None):
    """(model, [(prepared shape, result)] in the order of ``paths``, errors): the inputs through
    :func:`primkit.model.abstraction.abstract_shapes`. Each prepared shape is in the frame of its
    result's cuboids (turned as the orientation search chose: :meth:`Abstraction.canonical_shape`),
    so that its samples, its frame and its cuboids agree, and every distance is measured there."""
    from ..model.abstraction import abstract_shapes

    out = abstract_shapes(paths, model or args.model, **abstraction_options(args))
    if out.errors:
        return out.model, None, out.errors
    return out.model, [(a.canonical_shape(), a.result) for a in out], []


def _labeller(model):
    """The model file's labeller (:mod:`primkit.segmentation.labeller`), or None."""
    from ..model.bundled import resolve_model
    from ..segmentation.labeller import read_labeller

    return read_labeller(resolve_model(model))


def _labelled_names(labeller, mesh, frame, canonical, fallback) -> list:
    """Each part index's name on this mesh: the labeller's label of most of its faces."""
    from .. import primitives
    from ..segmentation.labeller import label_elements, mesh_elements, names_by_index

    elements = mesh_elements(mesh.vertices, mesh.faces, frame)
    codes = label_elements(labeller, elements, canonical)
    return names_by_index(codes, primitives.assign_points(elements.points, canonical), canonical.count,
                          labeller.names, fallback)


def _check_label_held(text: str, names, labeller, shape: str, kind: str) -> None:
    """A label the labeller knows but no cuboid of this shape holds mostly (arms spread over the
    legs' and the seat's cuboids): one line saying so, instead of "unknown part"."""
    from ..segmentation.bylabel import by_label

    missing = [n for n in by_label(text.split("=", 1)[0], labeller.names) or [] if n not in names]
    if missing:
        raise ValueError(f"--{kind} {text!r}: no cuboid of {shape} holds mostly {', '.join(missing)} (each cuboid "
                         f"takes the label the model's labeller gives most of its faces on this shape)")


def _source_mesh(path, *, points: bool = False):
    """The source as read: a Mesh, or with ``points`` also a PointCloud (deformed point by point)."""
    from ..io import Mesh, PointCloud, ShapeFileError, read_shape

    shape = read_shape(path)
    if isinstance(shape, Mesh) or (points and isinstance(shape, PointCloud)):
        return shape
    what = "a triangle mesh or a point cloud" if points else "a triangle mesh (a point cloud has no surface to edit)"
    raise ShapeFileError(path, f"the source must be {what}, not a voxel grid")


def _parts_tile(title, vertices, faces, face_parts, cuboids, count=None):
    """A picture tile: the mesh coloured by part, under translucent ``cuboids``; ``count`` is the
    number of part colours (default ``cuboids.count``)."""
    from ..viz.render import Tile, cuboid_layer, segmentation_layer

    count = cuboids.count if count is None else count
    return Tile(title, [segmentation_layer(vertices, faces, face_parts, count), cuboid_layer(cuboids, opacity=0.25)])


def _target_layer(shape):
    from ..io import Mesh, read_shape
    from ..viz.render import mesh_layer, points_layer

    try:
        target = read_shape(shape.source)
    except Exception:  # noqa: BLE001 - drawn from its samples instead
        target = None
    if isinstance(target, Mesh):
        return mesh_layer(shape.frame.to_canonical(target.vertices), target.faces)
    return points_layer(shape.points, point_size=2.0)


def _summary_line(q) -> str:
    d = q["distortion"]["all"]
    return (f"flipped triangles {100 * q['flipped']:.3f}% (against the parts' own turns {100 * q['flipped_vs_parts']:.3f}%); "
            f"edge-length distortion inside parts (vs each part's map): median {d['median']:.4f}, 99th pct {d['p99']:.4f}")


def _named(q, names):
    """Quality dict with part slots named ``<name>[<k>]`` for the JSON."""
    out = dict(q)
    for key in ("distortion", "stretch"):
        out[key] = {(k if k == "all" else f"{names[k]}[{k}]"): v for k, v in q[key].items()}
    return out


def _cmd_deform(args) -> int:
    from .. import deformation, io
    from ..segmentation import face_labels
    from ..io import atomic_output
    from ..viz.camera import CANONICAL_RADIUS
    from ..viz.render import Tile, cuboid_layer, write_png

    src, tgt = Path(args.source), Path(args.target)
    mesh = _source_mesh(src, points=True)  # read first: a point cloud is written as points
    out, png, js = _outputs(args, [args.source, args.target], points=isinstance(mesh, io.PointCloud))
    abstractor, pairs, errors = _abstract(args, [src, tgt])
    if errors:
        return report_errors(errors)
    (ss, rs), (ts, rt) = pairs
    if isinstance(mesh, io.PointCloud):
        return _deform_points(args, mesh, src, tgt, out, png, js, abstractor, ss, rs, ts, rt)
    v = rs.frame.to_canonical(mesh.vertices)
    d = deformation.deform(v, rs.canonical, rt.canonical, falloff=args.falloff, faces=mesh.faces, unfold=True)
    q = d.quality(mesh.faces, target_points=ts.points, source_points=ss.points).to_dict()
    names = abstractor.part_names
    _print_transfer(d.transfer, names)
    print(f"Chamfer-L1 to the target (canonical frames, 10000+10000 samples): source {q['chamfer_source_target']:.4f} "
          f"-> result {q['chamfer_result_target']:.4f}")
    print(_summary_line(q) + f"; blending distance {d.binding.falloff:.4f}")
    io.write_like(src, out, rs.frame.from_canonical(d.vertices), mesh.faces, overwrite=args.force)
    report = {"source": str(src), "target": str(tgt), "model": str(args.model), "output": str(out),
              "frame": FRAME,
              "chamfer": "Chamfer-L1 = (mean_A min_B |a-b| + mean_B min_A |b-a|) / 2, unsquared",
              "falloff": d.binding.falloff, "parts": {**d.transfer.to_dict(), "names": names}, "quality": _named(q, names)}
    with atomic_output(js, overwrite=args.force) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1))
    if png is not None:
        flab = face_labels(v, mesh.faces, rs.canonical)  # the co-segmentation rule, drawn on both
        tiles = [_parts_tile(f"source {ss.name}", v, mesh.faces, flab, rs.canonical),
                 Tile(f"target {ts.name}", [_target_layer(ts), cuboid_layer(rt.canonical, opacity=0.25)]),
                 _parts_tile("result", d.vertices, mesh.faces, flab, rt.canonical, rs.canonical.count)]
        write_png(png, tiles, overwrite=args.force, columns=3, radius=CANONICAL_RADIUS)
    print(f"-> {out}, {js}" + (f", {png}" if png else ""))
    return 0


def _print_transfer(tr, names) -> None:
    label = lambda ks: ", ".join(f"{names[k]}[{k}]" for k in ks) or "none"  # noqa: E731
    print(f"parts moved onto the target's: {label(tr.paired)}")
    for k, j in tr.source_only.items():
        why = "too different in size" if k in tr.mismatched else "absent in the target"
        what = f"follows {names[j]}[{j}]" if j is not None else "stays put"
        print(f"  {names[k]}[{k}] ({why}) {what}")
    if tr.target_only:
        print(f"  only in the target (not represented): {label(tr.target_only)}")


def _deform_points(args, cloud, src, tgt, out, png, js, abstractor, ss, rs, ts, rt) -> int:
    """``deform`` of a point cloud: every point follows the blended maps of the parts near it
    (the mesh rule without faces: no unfolding, no triangle measures); written as points."""
    from .. import deformation, io
    from ..io import atomic_output
    from ..metrics import chamfer_distance
    from ..segmentation import point_labels
    from ..viz.camera import CANONICAL_RADIUS
    from ..viz.render import Tile, cuboid_layer, point_segmentation_layer, write_png

    v = rs.frame.to_canonical(cloud.points)
    d = deformation.deform(v, rs.canonical, rt.canonical, falloff=args.falloff)
    names = abstractor.part_names
    _print_transfer(d.transfer, names)
    q = {"chamfer_source_target": chamfer_distance(v, ts.points), "chamfer_result_target": chamfer_distance(d.vertices, ts.points)}
    print(f"Chamfer-L1 to the target (canonical frames, the {len(v)} points against {len(ts.points)} target samples): "
          f"source {q['chamfer_source_target']:.4f} -> result {q['chamfer_result_target']:.4f}; "
          f"blending distance {d.binding.falloff:.4f}")
    io.write_points(out, rs.frame.from_canonical(d.vertices), overwrite=args.force)
    report = {"source": str(src), "target": str(tgt), "model": str(args.model), "output": str(out), "kind": "points",
              "frame": FRAME,
              "chamfer": "Chamfer-L1 = (mean_A min_B |a-b| + mean_B min_A |b-a|) / 2, unsquared",
              "falloff": d.binding.falloff, "parts": {**d.transfer.to_dict(), "names": names}, "quality": q}
    with atomic_output(js, overwrite=args.force) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1))
    if png is not None:
        labels = point_labels(v, rs.canonical)
        tiles = [Tile(f"source {ss.name}", [point_segmentation_layer(v, labels, rs.canonical.count, point_size=2.0),
                                            cuboid_layer(rs.canonical, opacity=0.25)]),
                 Tile(f"target {ts.name}", [_target_layer(ts), cuboid_layer(rt.canonical, opacity=0.25)]),
                 Tile("result", [point_segmentation_layer(d.vertices, labels, rs.canonical.count, point_size=2.0),
                                 cuboid_layer(rt.canonical, opacity=0.25)])]
        write_png(png, tiles, overwrite=args.force, columns=3, radius=CANONICAL_RADIUS)
    print(f"-> {out}, {js}" + (f", {png}" if png else ""))
    return 0


def _cmd_edit(args) -> int:
    from .. import deformation, io
    from ..io import atomic_output
    from ..model.abstraction import load_model

    out, png, js = _outputs(args, [args.mesh])
    src = Path(args.mesh)
    abstractor = load_model(args.model)
    names = abstractor.part_names
    labeller = _labeller(args.model)
    edits = {"scale": {}, "rotate": {}, "move": {}, "lengthen": {}}
    if not any(getattr(args, kind) for kind in edits):
        err("nothing to edit: give --scale, --rotate, --move or --lengthen")
        return 2
    if labeller is None:  # checked before any shape is read (with a labeller: once the shape is labelled)
        for kind in edits:
            for text in getattr(args, kind) or []:
                edits[kind].update(parse_edit(text, names, kind=kind))
    abstractor, pairs, errors = _abstract(args, [src], abstractor)
    if errors:
        return report_errors(errors)
    (shape, res), = pairs
    if labeller is not None:  # a name selects the cuboids whose faces the labeller mostly gives it
        names = _labelled_names(labeller, _source_mesh(src), shape.frame, res.canonical, names)
        for kind in edits:
            for text in getattr(args, kind) or []:
                _check_label_held(text, names, labeller, shape.name, kind)
                edits[kind].update(parse_edit(text, names, kind=kind))
    present = set(res.canonical.present.tolist())
    for kind, chosen in edits.items():
        missing = [k for k in chosen if k not in present]
        if missing and len(missing) == len(chosen):
            raise ValueError(f"--{kind}: {', '.join(f'{names[k]}[{k}]' for k in missing)} not present in {shape.name}'s abstraction")
        for k in missing:  # a name covering several slots (legs) edits the present ones
            del chosen[k]
    mesh = _source_mesh(src)
    v = shape.frame.to_canonical(mesh.vertices)
    d = deformation.edit(v, res.canonical, **edits, falloff=args.falloff, faces=mesh.faces, unfold=True)
    q = d.quality(mesh.faces).to_dict()
    e = d.edit
    h0, h1 = _print_edit(d, q, v, names)
    io.write_like(src, out, shape.frame.from_canonical(d.vertices), mesh.faces, overwrite=args.force)
    report = {"source": str(src), "model": str(args.model), "output": str(out),
              "edits": {kind: {f"{names[k]}[{k}]": np.atleast_1d(val).tolist() for k, val in chosen.items()}
                        for kind, chosen in edits.items()},
              "frame": "canonical frame of the shape (+Y up, +X front, longest side 1); edits in each part's "
                       "(front, up, side) axes about the centre of its bottom face",
              "edited": [int(k) for k in e.edited], "carried": {str(j): [int(k) for k in b] for j, b in e.carried.items()},
              "height_before": float(h0), "height_after": float(h1), "falloff": d.binding.falloff,
              "quality": _named(q, names)}
    with atomic_output(js, overwrite=args.force) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1))
    if png is not None:
        _draw_edit(png, shape.name, v, mesh.faces, res.canonical, d, args.force)
    print(f"-> {out}, {js}" + (f", {png}" if png else ""))
    return 0


def _print_edit(d, q, v, names) -> tuple:
    """What the edit did, printed: the parts edited and carried, the height, the lengthening, the
    quality; returns the heights before and after."""
    e = d.edit
    print("edited: " + ", ".join(f"{names[k]}[{k}]" for k in e.edited))
    for j, below in e.carried.items():
        print(f"  {names[j]}[{j}] carried along (rests on {', '.join(f'{names[k]}[{k}]' for k in below)})")
    h0, h1 = np.ptp(v[:, 1]), np.ptp(d.vertices[:, 1])
    print(f"height (canonical units, longest side 1): {h0:.4f} -> {h1:.4f} ({100 * (h1 / h0 - 1):+.1f}%)")
    if e.lengthening is not None:
        L = e.lengthening
        held = "given" if L.support is None else f"underside of {names[L.support]}[{L.support}]"
        print(f"lengthened between the floor at {L.floor:.4f} and the cut plane at {L.cut:.4f} ({held}); "
              f"expected rise {max(L.rise(k) for k in L.factors):.4f}")
    print(_summary_line(q) + f"; blending distance {d.binding.falloff:.4f}")
    return h0, h1


def _draw_edit(png, name, v, faces, canonical, d, force) -> None:
    """The shape before and after, coloured by part (the co-segmentation rule, drawn on both)."""
    from ..segmentation import face_labels
    from ..viz.camera import CANONICAL_RADIUS
    from ..viz.render import write_png

    flab = face_labels(v, faces, canonical)
    tiles = [_parts_tile(f"before {name}", v, faces, flab, canonical),
             _parts_tile("after", d.vertices, faces, flab, d.edit.cuboids, canonical.count)]
    write_png(png, tiles, overwrite=force, columns=2, radius=CANONICAL_RADIUS)


def _common_options(p) -> None:
    add_abstraction_options(p)
    add_output(p, "the deformed mesh (.ply, .obj, .off, .glb, .stl), or points (.xyz, .npy, .ply)")
    p.add_argument("--falloff", type=float, default=None,
                   help="blending distance at seams, canonical units (default: 3%% of the shape's size, widened to 3 "
                   "times where two parts' maps disagree at a seam, at most 25%%)")
    add_png(p)
    p.add_argument("--json", default=None, help="quality measures (default OUTPUT with .json)")
    add_force(p)


def register(subparsers) -> None:
    p = add_command(subparsers, "deform", help="deform a source mesh or point cloud into a target shape's part configuration",
        description="Deform a source mesh or point cloud into a target shape's part configuration: both are abstracted, each source vertex is bound to its cuboid and follows the target's cuboid of the same index. Writes the result, a JSON of quality measures and, with --png, a picture.",
        examples=["primkit deform src.off tgt.off --model chair -o out.off", "primkit deform src.xyz tgt.off --model chair -o out.xyz"])
    p.add_argument("source", help="the mesh (or point cloud) to deform")
    p.add_argument("target", help="the shape whose configuration it takes (mesh, points or voxels)")
    _common_options(p)
    p.set_defaults(func=_cmd_deform)

    p = add_command(subparsers, "edit", help="scale, turn or move parts of a mesh (by part name or index)",
        description="Edit a mesh part by part: scale, turn, move or lengthen parts named by the model (or by index), in each part's own frame.",
        examples=["primkit edit chair.off --model chair --lengthen legs=1.3 -o taller.off", "primkit edit chair.off --model chair --scale seat=1.2,1,1.2 --rotate back=15 -o edited.off"])
    p.add_argument("mesh", help="the mesh to edit (never modified; the result goes to -o)")
    p.add_argument("--scale", action="append", metavar="PART=S|F,U,S",
                   help="scale a part: one factor (uniform) or three along its front, up, side axes (legs=1,1.3,1)")
    p.add_argument("--rotate", action="append", metavar="PART=DEG",
                   help="turn a part about its side axis through its bottom face (positive tips it backwards)")
    p.add_argument("--move", action="append", metavar="PART=F,U,S",
                   help="move a part along its front, up, side axes (canonical units, longest side 1)")
    p.add_argument("--lengthen", action="append", metavar="PART=F",
                   help="lengthen parts below the underside of what they hold up (legs=1.3: the legs' length "
                        "below the seat grows 30%%, the feet stay, the seat and all above rise rigidly)")
    _common_options(p)
    p.set_defaults(func=_cmd_edit)

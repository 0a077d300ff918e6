"""``primkit segment`` (co-segmentation of a collection, optionally evaluated against ground truth)
and ``primkit name-parts`` (name a model's part indices from a few labelled shapes)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ._common import add_command
from ._common import (add_abstraction_options, add_force, add_output, add_png, add_scale_out, check_command_outputs, collect, err,
                      input_paths, progress_of, report_errors)

__all__ = ["register"]


def _print_evaluation(report) -> None:
    shapes = list(next(iter(report.protocols.values())).shapes) if report.protocols else []
    labels = report.labels
    print(f"\nground-truth labels: {', '.join(labels)}; accuracy by faces and by surface area (face-area weighted)")
    protocols = report.protocols
    header = f"{'shape':24s}" + "".join(f"  {p:>19s}" for p in protocols)
    print(header + "\n" + f"{'':24s}" + "".join(f"  {'faces     area':>19s}" for _ in protocols))
    for name in shapes:
        row = f"{name[:24]:24s}"
        for entry in protocols.values():
            acc = entry.shapes[name]
            row += f"  {acc.faces:8.3f} {acc.area:8.3f} "
        print(row)
    row = f"{'mean':24s}"
    for entry in protocols.values():
        row += f"  {entry.mean_faces:8.3f} {entry.mean_area:8.3f} "
    print(row)
    for protocol, entry in protocols.items():
        ious = ", ".join(f"{k} {v:.3f}" for k, v in entry.iou.items())
        print(f"\n{protocol}: {entry.description}.\n  per-label IoU (area): {ious}; mean {entry.mean_iou:.3f}")
        if entry.mapping is not None:
            used = {k: v for k, v in entry.mapping.items() if v is not None}
            print("  mapping (index -> label): " + ", ".join(f"{k}->{v}" for k, v in used.items()))


def _print_voxel_evaluation(report) -> None:
    print(f"\nvoxel ground truth: {', '.join(report.labels)}; {report.shapes_evaluated} shapes, every occupied "
          f"voxel to its nearest present cuboid; IoU {report.iou_rule}")
    for protocol, entry in report.protocols.items():
        ious = ", ".join(f"{k} {v:.3f}" for k, v in entry.iou.items())
        print(f"\n{protocol}: {entry.description}.\n  per-label IoU: {ious}; mean over "
              f"{', '.join(report.mean_over)} {entry.mean_iou:.3f}; voxel accuracy {entry.accuracy:.3f}")
        detection = []
        for label, d in entry.detection.items():
            if d.shapes_without and d.shapes_with:
                detection.append(f"{label} F1 {d.f1:.3f} (precision {d.precision:.2f}, recall {d.recall:.2f}; "
                                 f"absent from {d.shapes_without} shapes, predicted absent on "
                                 f"{d.absent_kept_absent:.0%} of them)")
        if detection:
            print("  detection (a label is present when one voxel carries it): " + "; ".join(detection))
        used = {k: v for k, v in entry.mapping.items() if v is not None}
        print("  mapping (index -> label): " + ", ".join(f"{k}->{v}" for k, v in used.items()))


def _cmd_segment(args) -> int:
    from ..segmentation import Segmenter

    segmenter = Segmenter(args.model, up=args.up, front=args.front, align=args.align, refine=args.refine,
                          adapt=getattr(args, "adapt", None), labelling=_labelling(args),
                          labeller="auto" if args.semantic else None)
    # with --shard, this shard's outputs only, named as one run over all the inputs names them
    run = segmenter.run(args.inputs, args.output, shard=args.shard, skip_done=args.skip_done, semantic=args.semantic,
                        ground_truth=args.gt, ground_truth_names=args.gt_names, picture=args.png,
                        overwrite=args.force, mean_over=_mean_over(args), cache_dir=args.cache, workers=args.workers,
                        executor=args.executor, progress=progress_of(args))
    plan = run.plan
    if not plan.todo and not plan.done and not plan.refused:
        print(f"shard {plan.shard[0]}/{plan.shard[1]}: none of the {len(plan.files)} inputs is in it (nothing to do)")
        return 0
    if not plan.todo:
        print("nothing to do: every input's outputs are there" + (" but those it cannot write" if plan.refused else ""))
        return report_errors(run.errors)
    if run.mismatch:  # the model-card warning on one line (and again in the summary)
        print(f"primkit: warning: {run.mismatch}", file=sys.stderr)
    for s in run.segmentations:
        print(_segmentation_line(s, run.written[s.name]))
    if not run.segmentations:
        report_errors(run.errors)
        err("no shape could be segmented")
        return 2
    shard = plan.shard
    print(("summary" if shard is None else f"summary of shard {shard[0]}/{shard[1]}") + ": "
          + ", ".join(map(str, run.summaries)) + (f"; picture: {args.png}" if args.png else "")
          + (f"; warning: {run.mismatch}" if run.mismatch else ""))
    if run.evaluation is not None:
        _print_evaluation(run.evaluation)
        print(f"\nevaluation written to {run.evaluation_path}")
    if run.voxel_evaluation is not None:
        _print_voxel_evaluation(run.voxel_evaluation)
        print(f"\nvoxel evaluation written to {run.voxel_evaluation_path}")
    if run.unevaluated_clouds:
        print(f"\n{run.unevaluated_clouds} point clouds not evaluated: --gt holds labels of faces (.seg) or voxels, "
              "not of points")
    return report_errors(run.errors)


def _mean_over(args):
    return [t.strip() for t in args.mean_over.split(",")] if args.mean_over else None


def _segmentation_line(s, paths) -> str:
    """One line per shape segmented: its elements, the parts present, its labels file."""
    from ..segmentation import PointSegmentation, VoxelSegmentation

    if isinstance(s, VoxelSegmentation):
        present = len(np.unique(s.labels[s.labels >= 0]))
        return f"{s.name}: {int((s.labels >= 0).sum())} voxels in {present} parts -> {paths.labels}"
    if isinstance(s, PointSegmentation):
        present = len(np.unique(s.labels[s.labels >= 0]))
        return f"{s.name}: {len(s.points)} points in {present} parts -> {paths.labels}, {paths.mesh}"
    line = f"{s.name}: {len(s.faces)} faces in {len(set(s.face_labels.tolist()))} parts -> {paths.labels}"
    if s.polygons is not None:
        line += f" (triangulated: the file's {s.polygons} faces are polygons; a label per triangle)"
    return line


def _cmd_name_parts(args) -> int:
    from ..model.modelfile import claim_output

    with claim_output(args.output, args.force):  # a second run into the same -o is refused before any work
        return _name_parts_claimed(args)


def _name_parts_claimed(args) -> int:
    from ..io import check_suffix
    from ..model.modelfile import update_metadata
    from ..model.parts import names_from_labels
    from ..segmentation import Segmenter
    from ..segmentation.evaluation import POINT_LABELS, labelled_shapes, parse_label_names
    from ..segmentation.labeller import write_labeller
    from ..segmentation.post import resolve_post
    from ..segmentation.segmenter import fit_labeller

    out = Path(args.output)
    if args.names is not None:
        parse_label_names(args.names)  # empty or malformed: one line before any work
    try:
        post = resolve_post(args.post)  # an unknown step or parameter: one line before any work
    except ValueError as exc:
        err(f"--post: {exc}")
        return 2
    segmenter = Segmenter(args.model, up=args.up, front=args.front, align=args.align, refine=args.refine,
                          adapt=getattr(args, "adapt", None), labeller=None)
    files = [f for f in collect(args.inputs) if not f.name.endswith(POINT_LABELS)]  # a cloud's labels, not a cloud
    check_command_outputs(args, [check_suffix(out, ".safetensors", "a model file")],
                  input_paths(files, _model_path(args.model), args.labels))
    results, errors = segmenter.abstract_files(files, cache_dir=args.cache, workers=args.workers,
                                               progress=progress_of(args))
    segs, errors = segmenter.segment_results(results, workers=args.workers, errors=errors, progress=progress_of(args))
    shapes = labelled_shapes(segs, results, args.labels, args.names)
    failed = list(errors) + shapes.errors
    if not shapes.used:
        report_errors(failed)
        err("no labelled shape to learn names from")
        return 2
    part_names, table = names_from_labels(shapes.assignments, shapes.labels, shapes.weights, shapes.names,
                                          segmenter.abstractor.parts)
    unit = "voxels" if all(w is None for w in shapes.weights) else "area"
    _print_part_names(part_names, table, unit, len(shapes.used))
    naming = {"labels": shapes.names, "shapes": len(shapes.used), "inputs": [str(p) for p in args.inputs],
              "rule": f"each index takes the ground-truth label holding most of its {'voxels' if unit == 'voxels' else 'surface area'}",
              "area_by_label" if unit == "area" else "voxels_by_label": np.round(table, 6).tolist()}
    if shapes.archives:
        naming["labels_from"] = shapes.archives
    changes = {"part_names": part_names, "part_naming": naming}
    if args.index_names_only:
        update_metadata(_model_path(args.model), out, changes, overwrite=args.force)
        print(f"wrote {out} with part names")
        return report_errors(failed)
    try:
        if args.unlabelled or args.mirror:  # more to learn from: the mirrors, unlabelled shapes (docs/labeller.md)
            from ..segmentation.selftrain import learn_labeller

            pool, found = [], []
            if args.unlabelled:  # abstracted and segmented as the labelled shapes
                found, pool_errors = segmenter.abstract_files(collect(args.unlabelled), cache_dir=args.cache,
                                                              workers=args.workers, progress=progress_of(args))
                pool, pool_errors = segmenter.segment_results(found, workers=args.workers, errors=pool_errors,
                                                              progress=progress_of(args))
                failed += list(pool_errors)
            by_name = {r.name: r for r in found}
            labeller = learn_labeller(shapes.learned, shapes.names, segmenter.abstractor.parts,
                                      unlabelled=[(s, by_name[s.name]) for s in pool], mirror=args.mirror,
                                      segmenter=segmenter, seed=args.seed, progress=progress_of(args), post=post)
        else:
            labeller = fit_labeller(shapes.learned, shapes.names, segmenter.abstractor.parts, seed=args.seed,
                                    post=post)
    except ValueError as exc:
        err(f"cannot learn a labeller: {exc}")
        return 2
    write_labeller(_model_path(args.model), out, labeller, changes, overwrite=args.force)
    print(f"labeller: {', '.join(labeller.names)} learned from {labeller.info['shapes']} shapes "
          f"({labeller.info['elements']} elements); {len(labeller.ensemble.feature)} tree nodes")
    if labeller.post:
        print(f"after the decision: {'; '.join(step.describe() for step in labeller.post)} (docs/labeller.md)")
    dropped = [step.STEP for step in post if step not in labeller.post]
    if dropped:
        print(f"post-steps not kept: {', '.join(dropped)} (a label they read was not learned, or the labelled "
              "shapes contradict them)")
    print(f"wrote {out} with part names and a labeller")
    return report_errors(failed)


def _print_part_names(part_names, table, unit: str, shapes: int) -> None:
    total = table.sum(axis=1)
    for k, name in enumerate(part_names):
        if total[k] > 0:
            share = table[k].max() / total[k]
            print(f"part {k:2d}: {name:12s} ({share:.0%} of its {unit} on {shapes} labelled shapes)")
        else:
            print(f"part {k:2d}: {name:12s} (never used on the labelled shapes)")


def _model_path(model):
    from ..model.bundled import resolve_model

    return resolve_model(model)


def _labelling(args):
    """The --labelling/--smoothness pair as a graphcut.Labelling (None: the library's default)."""
    from ..segmentation.graphcut import Labelling

    method = getattr(args, "labelling", None)
    smoothness = getattr(args, "smoothness", None)
    if method is None and smoothness is None:
        return None
    return Labelling(method or "graphcut", smoothness)


def register(sub) -> None:
    p = add_command(sub, 
        "segment", help="co-segment a collection: each face to its primitive, the same part index on every shape",
        description="Co-segment a collection: each face (voxel, point) to its primitive, the same part index on every "
        "shape. With --shard K/N (job arrays) a shard writes its shapes' outputs, named as one run over all the inputs "
        "names them, and its own summary (summary.shard-K-of-N.csv, its shapes' rows: the shards' rows together are "
        "one run's); labels.csv (--semantic) is the same for every shard. --gt and --png need the whole collection "
        "(the paper's mapping is fitted over every shape) and are refused with --shard: run once over all the inputs "
        "for them. A shard killed half-way keeps each output it wrote whole; run it again with --skip-done to do only "
        "what it left, or with --force to redo it all.",
        examples=["primkit segment chairs/ --model chair -o seg/ --refine 200 --png seg.png", "primkit segment clouds/ --model chair -o seg/ --semantic", "primkit segment CHAIRS --model chair -o seg/ --gt PARTNET_VOXLABELS/"])
    p.add_argument("inputs", nargs="+", help="mesh, voxel (.binvox) or point-cloud (.xyz, .npy, .ply) files, or folders")
    add_output(p, "output folder")
    add_abstraction_options(p)
    add_png(p)
    add_scale_out(p)
    p.add_argument("--skip-done", action="store_true",
                   help="leave out the inputs whose outputs are there (its three files, and its row in the summary "
                   "this run writes), e.g. when rerunning a shard after a lost worker or a killed job; the rest is "
                   "redone (what a cut run left of it replaced) and the summary rewritten with every row")
    p.add_argument("--semantic", action="store_true", help="write the codes of part names (labels.csv) instead of indices: each element named by the model's "
                   "labeller when it has one (primkit name-parts), else by its part index's name")
    p.add_argument("--labelling", choices=("nearest", "graphcut"), default=None,
                   help="how faces (voxels, points) get their index: each to its nearest cuboid, or a graph cut over "
                   "the shape's adjacency that follows creases (docs/surface-labels.md; default: graphcut)")
    p.add_argument("--smoothness", type=float, default=None, metavar="W",
                   help="graph cut: weight of label changes against cuboid distances (default: 1e-4 for meshes and "
                   "point clouds, 3e-4 for voxel grids, chosen on validation data)")
    p.add_argument("--gt", action="append", metavar="PATH",
                   help="ground truth: a folder of .seg files for meshes (same stems), or for voxel grids a per-voxel "
                   "label archive (an .npz keyed by shape name, or a folder holding voxlabels.npz, as PartNet's "
                   "voxel labels come); repeatable")
    p.add_argument("--gt-names", action="append", metavar="NAMES",
                   help="what the ground-truth values mean: 'back,seat,legs' names values 1,2,3 ('0=back,1=seat' also); "
                   "'legs/base' accepts either model name; once, or once per --gt (voxel archives default to PartNet's "
                   "0=back,1=seat,2=legs/leg/base,3=arms/arm)")
    p.add_argument("--mean-over", default=None, metavar="LABELS",
                   help="voxel evaluation: the labels averaged into the mean IoU, e.g. back,seat,legs (default: all)")
    add_force(p)
    p.set_defaults(func=_cmd_segment)

    p = add_command(sub, "name-parts", help="name a model's part indices from labelled shapes; writes a copy of the model",
        description="Name a model's parts from labelled shapes: learn a labeller that names each face, voxel or point from where it sits in the shape's cuboids (stored in the model file, no code), and name each part index by the label holding most of its area (or voxels). Writes a copy of the model; the input model is never modified.",
        examples=["primkit name-parts labelled/ --model chair -o chair-named.safetensors", "primkit name-parts CHAIRS --model chair --labels PARTNET_VOXLABELS/ -o named.safetensors"])
    p.add_argument("inputs", nargs="+", help="labelled mesh, voxel (.binvox) or point-cloud files, or folders (a "
                   "cloud's labels: <stem>.labels.npy beside it, one integer per point)")
    add_output(p, "model file to write (the input model is never modified)")
    add_abstraction_options(p)
    p.add_argument("--labels", default=None, help="folder of .seg files (default: the .seg beside each mesh), or for voxel "
                   "grids a per-voxel label archive (.npz, or a folder holding voxlabels.npz)")
    p.add_argument("--names", default=None,
                   help="what the label values mean ('back,seat,legs' for values 1,2,3); default: the .json beside "
                   "procedural shapes (primkit generate), else the values")
    p.add_argument("--index-names-only", action="store_true",
                   help="only name the part indices (one name each); by default a labeller is learned as well, "
                   "naming each face, voxel or point on its own (segment --semantic uses it)")
    p.add_argument("--seed", type=int, default=0, help="the labeller's random state")
    p.add_argument("--unlabelled", nargs="+", default=None, metavar="PATH",
                   help="unlabelled shapes (files or folders) of the same kind: the labeller names them, learns again "
                   "from the elements it is sure of (self-training, docs/labeller.md); their labels are never read")
    p.add_argument("--mirror", action="store_true",
                   help="learn from each labelled shape's left-right mirror too (abstracted again; docs/labeller.md)")
    p.add_argument("--post", action="append", default=None, metavar="STEP",
                   help="a rule to run after the labeller's decision, stored in the model file (repeatable; "
                   "default: none): 'chair' (a chair's arms read from what rises beside the seat, and its seat/legs "
                   "cut at one height on voxel grids), or one step with the labels it reads, e.g. "
                   "'chair.arms_from_side_region:label=armrest' or 'chair.seat_layer_cut:upper=Seat,lower=legs'; "
                   "a step is kept when its labels were learned and the labelled shapes agree with it "
                   "(docs/labeller.md)")
    add_force(p)
    p.set_defaults(func=_cmd_name_parts)

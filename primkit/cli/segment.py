"""``primkit segment`` (co-segmentation of a collection, optionally evaluated against ground truth)
and ``primkit name-parts`` (name a model's part indices from a few labelled shapes)."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

from ._common import (add_abstraction_options, add_force, add_output, add_png, add_scale_out, check_outputs, collect, err,
                      input_paths, output_names, parse_shard_option, report_errors, shard_of)

__all__ = ["register"]


def _ground_truth_files(args):
    """``[(folder, label names or None)]`` from the repeated ``--gt`` / ``--gt-names`` options."""
    folders = args.gt or []
    names = args.gt_names or []
    if names and len(names) not in (1, len(folders)):
        raise ValueError(f"--gt-names given {len(names)} times for {len(folders)} --gt folders (give it once, or once per --gt)")
    if len(names) == 1:
        names = names * len(folders)
    return list(zip(folders, names or [None] * len(folders)))


def _find_truth(seg, sources):
    """The ``.seg`` file of a segmented shape in the ``--gt`` folders (same stem): (path, names) or None."""
    stem = Path(seg.source).stem
    for folder, names in sources:
        for candidate in (Path(folder) / f"{stem}.seg", Path(folder) / f"{seg.name}.seg"):
            if candidate.is_file() and candidate.resolve() != Path(seg.source).resolve():
                return candidate, names
    return None


def _print_evaluation(report, shapes) -> None:
    labels = report["labels"]
    print(f"\nground-truth labels: {', '.join(labels)}; accuracy by faces and by surface area (face-area weighted)")
    protocols = report["protocols"]
    header = f"{'shape':24s}" + "".join(f"  {p:>19s}" for p in protocols)
    print(header + "\n" + f"{'':24s}" + "".join(f"  {'faces     area':>19s}" for _ in protocols))
    for name in shapes:
        row = f"{name[:24]:24s}"
        for entry in protocols.values():
            acc = entry["shapes"][name]
            row += f"  {acc['faces']:8.3f} {acc['area']:8.3f} "
        print(row)
    row = f"{'mean':24s}"
    for entry in protocols.values():
        row += f"  {entry['mean_faces']:8.3f} {entry['mean_area']:8.3f} "
    print(row)
    for protocol, entry in protocols.items():
        ious = ", ".join(f"{k} {v:.3f}" for k, v in entry["iou"].items())
        print(f"\n{protocol}: {entry['description']}.\n  per-label IoU (area): {ious}; mean {entry['mean_iou']:.3f}")
        if "mapping" in entry:
            used = {k: v for k, v in entry["mapping"].items() if v is not None}
            print("  mapping (index -> label): " + ", ".join(f"{k}->{v}" for k, v in used.items()))


def _print_voxel_evaluation(report) -> None:
    print(f"\nvoxel ground truth: {', '.join(report['labels'])}; {report['shapes_evaluated']} shapes, every occupied "
          f"voxel to its nearest present cuboid; IoU {report['iou_rule']}")
    for protocol, entry in report["protocols"].items():
        ious = ", ".join(f"{k} {v:.3f}" for k, v in entry["iou"].items())
        print(f"\n{protocol}: {entry['description']}.\n  per-label IoU: {ious}; mean over "
              f"{', '.join(report['mean_over'])} {entry['mean_iou']:.3f}; voxel accuracy {entry['accuracy']:.3f}")
        detection = []
        for label, d in entry["detection"].items():
            if d["shapes_without"] and d["shapes_with"]:
                detection.append(f"{label} F1 {d['f1']:.3f} (precision {d['precision']:.2f}, recall {d['recall']:.2f}; "
                                 f"absent from {d['shapes_without']} shapes, predicted absent on "
                                 f"{d['absent_kept_absent']:.0%} of them)")
        if detection:
            print("  detection (a label is present when one voxel carries it): " + "; ".join(detection))
        used = {k: v for k, v in entry["mapping"].items() if v is not None}
        print("  mapping (index -> label): " + ", ".join(f"{k}->{v}" for k, v in used.items()))


def _picture(segs, path, limit: int = 16) -> None:
    """Each shape beside its co-segmentation (a point cloud as points, coloured by part)."""
    from ..segmentation import PointSegmentation, VoxelSegmentation
    from ..viz.palette import part_colors
    from ..viz.render import Tile, mesh_layer, point_segmentation_layer, points_layer, write_png

    tiles = []
    for s in segs[:limit]:
        if isinstance(s, PointSegmentation):
            plain = points_layer(s.points, point_size=2.0)
            tiles += [Tile(s.name, [plain]), Tile("", [point_segmentation_layer(s.points, s.labels, s.cuboids.count,
                                                                                 point_size=2.0)], frame=plain.bounds())]
            continue
        v, f, labels = s.boundary_mesh() if isinstance(s, VoxelSegmentation) else (s.vertices, s.faces, s.face_labels)
        plain = mesh_layer(v, f)
        tiles += [Tile(s.name, [plain]), Tile("", [mesh_layer(v, f, part_colors(s.cuboids.count)[labels])],
                                              frame=plain.bounds())]
    write_png(path, tiles, columns=2 * min(4, max(1, len(tiles) // 2)), tile=260, overwrite=True)


def _voxel_archives(sources):
    """The ``--gt`` sources that are voxel label archives (an ``.npz``, or a folder holding
    ``voxlabels.npz``): ``[VoxelLabelArchive]``."""
    from ..segmentation import VoxelLabelArchive, parse_label_names

    archives = []
    for folder, names in sources:
        path = Path(folder)
        if path.suffix == ".npz" or (path / "voxlabels.npz").is_file():
            archives.append(VoxelLabelArchive(path, parse_label_names(names) if names else None))
    return archives


def _voxel_truth(seg, archives):
    """The ground truth of a voxel segmentation in the archives (by shape name), or None."""
    for archive in archives:
        if seg.name in archive:
            return archive.get(seg.name, seg.labels.shape)
    return None


_SUMMARIES = {"mesh": "summary.csv", "voxels": "summary-voxels.csv", "points": "summary-points.csv"}


def _summary_name(kind: str, shard) -> str:
    """The summary file of a kind of shape; a shard's own (``summary.shard-2-of-8.csv``: its shapes' rows)."""
    name = _SUMMARIES[kind]
    return name if shard is None else name.replace(".csv", f".shard-{shard[0]}-of-{shard[1]}.csv")


def _kind(path: Path) -> str:
    """``"mesh"``, ``"voxels"`` or ``"points"`` for a shape file, from its suffix (and for a PLY, from
    its header: a PLY without faces is a point cloud), without reading its geometry."""
    from ..io import VOXEL_SUFFIXES

    suffix = path.suffix.lower()
    if suffix in VOXEL_SUFFIXES:
        return "voxels"
    if suffix in (".xyz", ".npy"):
        return "points"
    if suffix == ".ply":
        try:
            with open(path, "rb") as fh:
                for line in fh.read(1 << 16).split(b"\n"):
                    words = line.split()
                    if words[:2] == [b"element", b"face"] and len(words) > 2:
                        return "mesh" if words[2] != b"0" else "points"
                    if line.strip() == b"end_header":
                        return "points"
        except OSError:
            pass  # reported when it is read
    return "mesh"


def _label_codes_text(segmenter) -> str:
    """``labels.csv``: the 1-based code of each of the model's part names (``--semantic``): its
    labeller's names when it has one, else the names of its part indices."""
    from ..model.parts import label_codes

    names = list(segmenter.labeller.names) if segmenter.labeller is not None else label_codes(segmenter.part_names)[0]
    return "code,name\n" + "".join(f"{i + 1},{n}\n" for i, n in enumerate(names))


def _written_before(path: Path, codes: str, expected: bool, force: bool) -> bool:
    """Whether ``labels.csv`` is there with these very codes, written by another shard of the run or
    by the run that ``--skip-done`` goes on with (``expected``: they are the model's, the same for
    every shard: not a clash). Never otherwise, nor with ``--force``."""
    if not expected or force:
        return False
    try:
        return path.read_text() == codes
    except (OSError, UnicodeDecodeError):
        return False


_LABEL_SUFFIXES = {"mesh": ".seg", "voxels": ".voxlabels.npy", "points": ".parts.npy"}


def _shape_outputs(out: Path, name: str, kind: str) -> list[Path]:
    """A shape's three files, in the order they are written (its ``.cuboids.json`` last)."""
    return [out / f"{name}{_LABEL_SUFFIXES[kind]}", out / f"{name}.parts.ply", out / f"{name}.cuboids.json"]


def _not_done(files, names, out: Path, shard, part_names):
    """``--skip-done``: this shard's inputs still to do, and the summary rows of those that are done.

    Done means its three files exist and its row is in this shard's summary of its kind, written
    by the same model (same columns): a run is cut after the shapes' labels and meshes, before the
    summaries, or before the cuboids. An input that is not done has what it left removed, and is
    redone. Returns the positions to do and, per kind, the summary rows to keep (``{kind: {name: row}}``)."""
    from ..parallel import shard_indices
    from ..segmentation import read_summary, summary_header

    keep = shard_indices(len(files), shard)
    kinds = {i: _kind(files[i]) for i in keep}
    summaries = {}
    for kind in set(kinds.values()):
        header, rows = read_summary(out / _summary_name(kind, shard))
        summaries[kind] = rows if header == summary_header(kind, part_names) else {}
    todo = [i for i in keep if not (all(p.is_file() for p in _shape_outputs(out, names[i], kinds[i]))
                                    and names[i] in summaries[kinds[i]])]
    print(f"--skip-done: {len(keep) - len(todo)} of {len(keep)} input(s) already done", file=sys.stderr)
    for i in todo:
        for path in _shape_outputs(out, names[i], kinds[i]):
            if path.is_file():  # what a cut run left of it: redone
                path.unlink()
    done = set(keep) - set(todo)
    kept = {kind: {names[i]: rows[names[i]] for i in sorted(done) if kinds[i] == kind} for kind, rows in summaries.items()}
    return todo, kept


def _segment_outputs(args, files, names, out: Path, evaluations: dict, sources, shard, codes) -> list:
    """Every file ``segment`` writes (checked before any work): per shape of ``files`` (named
    ``names``) its labels (``.seg``; ``.voxlabels.npy`` for a voxel grid, ``.parts.npy`` for a point
    cloud), ``.parts.ply`` and ``.cuboids.json``; the summaries, the label codes (``codes``: None
    when not written), the evaluations and the picture."""
    from ..io import check_suffix

    kinds = [_kind(f) for f in files]
    outputs = []
    for name, kind in zip(names, kinds):
        outputs += _shape_outputs(out, name, kind)
    # with --skip-done a summary is rewritten with the rows it keeps: not checked here
    outputs += [out / _summary_name(kind, shard) if kind in kinds and not args.skip_done else None for kind in _SUMMARIES]
    outputs += [out / "labels.csv" if codes is not None else None]
    outputs += list(evaluations.values()) if sources else []
    return outputs + [None if args.png is None else check_suffix(args.png, ".png", "a picture")]


def _cmd_segment(args) -> int:
    from ..io import atomic_output
    from ..parallel import executor_from
    from ..model.abstraction import CardMismatchWarning
    from ..segmentation import (PointSegmentation, Segmenter, VoxelSegmentation, evaluate, evaluate_voxels,
                                read_ground_truth, write_summary)

    out = Path(args.output)
    sources = _ground_truth_files(args)
    shard = parse_shard_option(args)
    if shard is not None and sources:
        err("--gt evaluates the whole collection (the paper's mapping is fitted over every shape): not with --shard")
        return 2
    if shard is not None and args.png:
        err("--png draws the whole collection: not with --shard")
        return 2
    if args.skip_done and (sources or args.png):
        err(f"{'--gt evaluates' if sources else '--png draws'} the whole collection: not with --skip-done")
        return 2
    archives = _voxel_archives(sources)
    evaluations = {"meshes": out / "evaluation.json", "voxels": out / "evaluation-voxels.json"}
    segmenter = Segmenter(args.model, up=args.up, front=args.front, align=args.align, refine=args.refine,
                          adapt=getattr(args, "adapt", None), labelling=_labelling(args),
                          labeller="auto" if args.semantic else None)
    files = collect(args.inputs)
    # with --shard, this shard's outputs only, named as one run over all the inputs names them
    mine, names = shard_of(args, files), shard_of(args, output_names(files))
    if not mine:
        print(f"shard {shard[0]}/{shard[1]}: none of the {len(files)} inputs is in it (nothing to do)")
        return 0
    order, kept, selection = names, {}, shard
    if args.skip_done:
        from ..parallel import Selection

        every = output_names(files)
        todo, kept = _not_done(files, every, out, shard, segmenter.part_names)
        if not todo:
            print("nothing to do: every input's outputs are there")
            return 0
        # the rest goes where the shard went, named as one run over all the inputs names them
        mine, names, selection = [files[i] for i in todo], [every[i] for i in todo], Selection(todo)
    codes = _label_codes_text(segmenter) if args.semantic else None
    if codes is not None and _written_before(out / "labels.csv", codes, shard is not None or args.skip_done, args.force):
        codes = None
    # before any work: nothing written over an input (the shapes' own .seg labels, the --gt files)
    check_outputs(args, _segment_outputs(args, mine, names, out, evaluations, sources, shard, codes),
                  input_paths(files, _model_path(args.model), *(folder for folder, _ in sources)))
    with executor_from(args.executor) as pool, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CardMismatchWarning)
        segs, errors = segmenter.segment_files(files, cache_dir=args.cache, workers=args.workers, executor=pool,
                                               shard=selection)
    mismatch = None
    for w in caught:  # the model-card warning on one line (and again in the summary); the others as they came
        if issubclass(w.category, CardMismatchWarning):
            mismatch = str(w.message)
            print(f"primkit: warning: {mismatch}", file=sys.stderr)
        else:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    failed = list(errors)
    written = []
    for s in segs:
        paths = s.save(out, semantic=args.semantic, overwrite=args.force)
        written.append(s)
        if isinstance(s, VoxelSegmentation):
            present = len(np.unique(s.labels[s.labels >= 0]))
            print(f"{s.name}: {int((s.labels >= 0).sum())} voxels in {present} parts -> {paths['labels']}")
        elif isinstance(s, PointSegmentation):
            present = len(np.unique(s.labels[s.labels >= 0]))
            print(f"{s.name}: {len(s.points)} points in {present} parts -> {paths['labels']}, {paths['mesh']}")
        else:
            present = len(set(s.face_labels.tolist()))
            print(f"{s.name}: {len(s.faces)} faces in {present} parts -> {paths['labels']}")
    if not segs:
        report_errors(failed)
        err("no shape could be segmented")
        return 2
    grids = [s for s in segs if isinstance(s, VoxelSegmentation)]
    clouds = [s for s in segs if isinstance(s, PointSegmentation)]
    meshes = [s for s in segs if not isinstance(s, (VoxelSegmentation, PointSegmentation))]
    kinds = {"mesh": meshes, "voxels": grids, "points": clouds}
    summaries = [out / _summary_name(k, shard) for k, group in kinds.items() if group]
    for kind, path in zip([k for k, g in kinds.items() if g], summaries):
        write_summary(kinds[kind], path, overwrite=args.force or args.skip_done, keep=kept.get(kind), order=order)
    if codes is not None and not _written_before(out / "labels.csv", codes, shard is not None, args.force):  # meanwhile
        with atomic_output(out / "labels.csv", overwrite=args.force) as tmp:
            Path(tmp).write_text(codes)
    from ..model.cuboids_file import write_cuboids_file

    for s in written:  # the schema of every <name>.cuboids.json (its canonical_frame not known here)
        write_cuboids_file(out / f"{s.name}.cuboids.json", s.cuboids, name=s.name, source=s.source,
                           model=segmenter.abstractor.model or None, part_names=s.part_names or None, overwrite=args.force)
    if args.png:
        _picture(segs, args.png)
    print(("summary" if shard is None else f"summary of shard {shard[0]}/{shard[1]}") + ": "
          + ", ".join(map(str, summaries)) + (f"; picture: {args.png}" if args.png else "")
          + (f"; warning: {mismatch}" if mismatch else ""))

    if sources and meshes:
        pairs, names = [], []
        for s in meshes:
            found = _find_truth(s, sources)
            if found is None:
                failed.append(f"{s.source}: no ground-truth .seg named {Path(s.source).stem}.seg in the --gt folders")
                continue
            try:
                pairs.append((s, read_ground_truth(found[0], len(s.faces), found[1], names)))
            except (ValueError, OSError) as exc:
                failed.append(str(exc).splitlines()[0])
        if pairs:
            report = evaluate([p[0] for p in pairs], [p[1] for p in pairs], part_names=segmenter.part_names)
            _print_evaluation(report, [p[0].name for p in pairs])
            with atomic_output(evaluations["meshes"], overwrite=args.force) as tmp:
                Path(tmp).write_text(json.dumps(report, indent=1))
            print(f"\nevaluation written to {evaluations['meshes']}")
    if sources and grids:
        pairs = []
        for s in grids:
            truth = _voxel_truth(s, archives)
            if truth is None:
                failed.append(f"{s.source}: no voxel labels for {s.name} in the --gt archives")
            else:
                pairs.append((s, truth))
        if pairs:
            mean_over = [t.strip() for t in args.mean_over.split(",")] if args.mean_over else None
            report = evaluate_voxels([p[0].labels for p in pairs], [p[1] for p in pairs], segmenter.abstractor.parts,
                                     part_names=segmenter.part_names, names=[p[0].name for p in pairs],
                                     mean_over=mean_over)
            if segmenter.labeller is not None:  # each voxel named by the labeller: its names are the "parts"
                names = list(segmenter.labeller.names)
                by_label = evaluate_voxels([p[0].named for p in pairs], [p[1] for p in pairs], len(names),
                                           part_names=names, names=[p[0].name for p in pairs], mean_over=mean_over)
                if "model-names" in by_label["protocols"]:
                    report["protocols"]["labeller"] = {
                        **by_label["protocols"]["model-names"],
                        "description": "each voxel named by the model's labeller (learned on other shapes)"}
            _print_voxel_evaluation(report)
            with atomic_output(evaluations["voxels"], overwrite=args.force) as tmp:
                Path(tmp).write_text(json.dumps(report, indent=1))
            print(f"\nvoxel evaluation written to {evaluations['voxels']}")
    if sources and clouds:
        print(f"\n{len(clouds)} point clouds not evaluated: --gt holds labels of faces (.seg) or voxels, not of points")
    return report_errors(failed)


def _cmd_name_parts(args) -> int:
    import numpy as np

    from ..io import check_suffix
    from ..model.modelfile import update_metadata
    from ..model.parts import names_from_labels
    from ..segmentation import PointSegmentation, Segmenter, VoxelSegmentation, read_ground_truth
    from ..segmentation.labeller import write_labeller
    from ..segmentation.segmenter import fit_labeller

    out = Path(args.output)
    sources = [(args.labels, args.names)] if args.labels else []
    archives = _voxel_archives(sources)
    segmenter = Segmenter(args.model, up=args.up, front=args.front, align=args.align, refine=args.refine,
                          adapt=getattr(args, "adapt", None), labeller=None)
    files = [f for f in collect(args.inputs) if not f.name.endswith(_POINT_LABELS)]  # a cloud's labels, not a cloud
    check_outputs(args, [check_suffix(out, ".safetensors", "a model file")],
                  input_paths(files, _model_path(args.model), args.labels))
    results, errors = segmenter.abstract_files(files, cache_dir=args.cache, workers=args.workers)
    segs, errors = segmenter.segment_results(results, workers=args.workers, errors=errors)
    by_name = {r.name: r for r in results}
    failed = list(errors)
    names, assignments, labels, weights, used, learned = [], [], [], [], [], []
    for s in segs:
        if isinstance(s, VoxelSegmentation):
            truth = _voxel_truth(s, archives)
            if truth is None:
                failed.append(f"{s.source}: no voxel labels for {s.name} (give --labels a voxel label archive)")
                continue
            short = [str(n).split("/")[0] for n in truth.names]
            for n in short:
                if n not in names:
                    names.append(n)
            occupied = s.labels >= 0
            assignments.append(s.labels[occupied])
            labels.append(np.array([names.index(short[c]) if c >= 0 else -1 for c in range(len(short))] + [-1])[truth.labels[occupied]])
            weights.append(None)  # one voxel, one vote
            used.append(s.name)
            learned.append((s, by_name[s.name], labels[-1]))
            continue
        if isinstance(s, PointSegmentation):
            beside = Path(s.source).with_name(Path(s.source).stem + _POINT_LABELS)
            try:
                codes = _point_truth(beside, len(s.points), args.names, names)
            except ValueError as exc:
                failed.append(str(exc).splitlines()[0])
                continue
            assignments.append(s.labels)
            labels.append(codes)
            weights.append(None)  # one point, one vote
            used.append(s.name)
            learned.append((s, by_name[s.name], codes))
            continue
        found = _find_truth(s, sources) if sources and not archives else None
        if found is None:
            beside = Path(s.source).with_suffix(".seg")
            found = (beside, args.names) if beside.is_file() else None
        if found is None:
            failed.append(f"{s.source}: no label file ({Path(s.source).stem}.seg) found")
            continue
        try:
            truth = read_ground_truth(found[0], len(s.faces), found[1], names)
        except (ValueError, OSError) as exc:
            failed.append(str(exc).splitlines()[0])
            continue
        assignments.append(s.face_labels)
        labels.append(truth.labels)
        weights.append(s.face_areas)
        used.append(s.name)
        learned.append((s, by_name[s.name], truth.labels))
    if not used:
        report_errors(failed)
        err("no labelled shape to learn names from")
        return 2
    part_names, table = names_from_labels(assignments, labels, weights, names, segmenter.abstractor.parts)
    unit = "voxels" if all(w is None for w in weights) else "area"
    total = table.sum(axis=1)
    for k, name in enumerate(part_names):
        if total[k] > 0:
            share = table[k].max() / total[k]
            print(f"part {k:2d}: {name:12s} ({share:.0%} of its {unit} on {len(used)} labelled shapes)")
        else:
            print(f"part {k:2d}: {name:12s} (never used on the labelled shapes)")
    naming = {"labels": names, "shapes": len(used), "inputs": [str(p) for p in args.inputs],
              "rule": f"each index takes the ground-truth label holding most of its {'voxels' if unit == 'voxels' else 'surface area'}",
              "area_by_label" if unit == "area" else "voxels_by_label": np.round(table, 6).tolist()}
    if archives:
        naming["labels_from"] = [str(a.path) for a in archives]
    changes = {"part_names": part_names, "part_naming": naming}
    if args.index_names_only:
        update_metadata(_model_path(args.model), out, changes, overwrite=args.force)
        print(f"wrote {out} with part names")
        return report_errors(failed)
    try:
        labeller = fit_labeller(learned, names, segmenter.abstractor.parts, seed=args.seed)
    except ValueError as exc:
        err(f"cannot learn a labeller: {exc}")
        return 2
    write_labeller(_model_path(args.model), out, labeller, changes, overwrite=args.force)
    print(f"labeller: {', '.join(labeller.names)} learned from {labeller.info['shapes']} shapes "
          f"({labeller.info['elements']} elements); {len(labeller.ensemble.feature)} tree nodes")
    print(f"wrote {out} with part names and a labeller")
    return report_errors(failed)


#: the per-point labels of a point cloud ``<stem>.xyz`` (or ``.ply``, ``.npy``): ``<stem>.labels.npy``
_POINT_LABELS = ".labels.npy"


def _point_truth(path: Path, count: int, label_names, names: list) -> np.ndarray:
    """A point cloud's labels (``(count,)`` integers in a ``.npy``, read without pickles) as codes
    into the collection-wide ``names`` (extended); values named by ``label_names`` ('back,seat'
    for 1, 2) or by themselves; a value with no name is unlabelled (-1)."""
    from ..segmentation import parse_label_names

    if not path.is_file():
        raise ValueError(f"{path}: no per-point label file beside the cloud")
    try:
        raw = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a NumPy label array ({exc})") from None
    if raw.shape != (count,) or raw.dtype.kind not in "iu":
        raise ValueError(f"{path}: expected ({count},) integers, one per point, got {raw.dtype} {raw.shape}")
    meaning = parse_label_names(label_names) if label_names else None
    codes = np.full(count, -1, np.int64)
    for value in np.unique(raw):
        name = str(value) if meaning is None else meaning.get(int(value))
        if name is None:
            continue
        if name not in names:
            names.append(name)
        codes[raw == value] = names.index(name)
    return codes


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
    p = sub.add_parser(
        "segment", help="co-segment a collection: each face to its primitive, the same part index on every shape",
        description="Co-segment a collection: each face (voxel, point) to its primitive, the same part index on every "
        "shape. With --shard K/N (job arrays) a shard writes its shapes' outputs, named as one run over all the inputs "
        "names them, and its own summary (summary.shard-K-of-N.csv, its shapes' rows: the shards' rows together are "
        "one run's); labels.csv (--semantic) is the same for every shard. --gt and --png need the whole collection "
        "(the paper's mapping is fitted over every shape) and are refused with --shard: run once over all the inputs "
        "for them. A shard killed half-way keeps each output it wrote whole; run it again with --skip-done to do only "
        "what it left, or with --force to redo it all.",
        epilog="examples:\n  primkit segment chairs/ --model chair -o seg/ --refine 200 --png seg.png\n  primkit segment clouds/ --model chair -o seg/ --semantic\n  primkit segment CHAIRS --model chair -o seg/ --gt ../shared/data/partnet_chair_boxes\n", formatter_class=argparse.RawDescriptionHelpFormatter)
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
                   help="graph cut: weight of label changes against cuboid distances (default: chosen on validation data)")
    p.add_argument("--gt", action="append", metavar="PATH",
                   help="ground truth: a folder of .seg files for meshes (same stems), or for voxel grids a per-voxel "
                   "label archive (an .npz keyed by shape name, or a folder holding voxlabels.npz, e.g. "
                   "../shared/data/partnet_chair_boxes); repeatable")
    p.add_argument("--gt-names", action="append", metavar="NAMES",
                   help="what the ground-truth values mean: 'back,seat,legs' names values 1,2,3 ('0=back,1=seat' also); "
                   "'legs/base' accepts either model name; once, or once per --gt (voxel archives default to PartNet's "
                   "0=back,1=seat,2=legs/leg/base,3=arms/arm)")
    p.add_argument("--mean-over", default=None, metavar="LABELS",
                   help="voxel evaluation: the labels averaged into the mean IoU, e.g. back,seat,legs (default: all)")
    add_force(p)
    p.set_defaults(func=_cmd_segment)

    p = sub.add_parser("name-parts", help="name a model's part indices from labelled shapes; writes a copy of the model",
        description="Name a model's parts from labelled shapes: learn a labeller that names each face, voxel or point from where it sits in the shape's cuboids (stored in the model file, no code), and name each part index by the label holding most of its area (or voxels). Writes a copy of the model; the input model is never modified.",
        epilog="examples:\n  primkit name-parts labelled/ --model chair -o chair-named.safetensors\n  primkit name-parts CHAIRS --model chair --labels ../shared/data/partnet_chair_boxes -o named.safetensors\n", formatter_class=argparse.RawDescriptionHelpFormatter)
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
    add_force(p)
    p.set_defaults(func=_cmd_name_parts)

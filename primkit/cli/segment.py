"""``primkit segment`` (co-segmentation of a collection, optionally evaluated against ground truth)
and ``primkit name-parts`` (name a model's part indices from a few labelled shapes)."""

from __future__ import annotations

import json
from pathlib import Path

from ._common import add_abstraction_options, add_force, add_output, add_png, collect, err, report_errors

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


def _picture(segs, path, limit: int = 16) -> None:
    from ..viz.palette import part_colors
    from ..viz.render import render_pairs

    items = []
    for s in segs[:limit]:
        colors = part_colors(s.cuboids.count)
        items.append((s.name, (s.vertices, s.faces), (s.vertices, s.faces, colors[s.face_labels])))
    render_pairs(items, path)


def _cmd_segment(args) -> int:
    from ..segmentation import Segmenter, evaluate, read_ground_truth, write_summary

    from ..io import atomic_output, refuse_existing

    out = Path(args.output)
    sources = _ground_truth_files(args)
    refuse_existing([args.png] + ([out / "evaluation.json"] if sources else []), args.force)
    segmenter = Segmenter(args.model, up=args.up, front=args.front, align=args.align, refine=args.refine)
    segs, errors = segmenter.segment_files(collect(args.inputs), cache_dir=args.cache, workers=args.workers)
    failed = list(errors)
    written = []
    for s in segs:
        try:
            s.save(out, semantic=args.semantic, overwrite=args.force)
        except FileExistsError as exc:
            failed.append(str(exc))
            continue
        written.append(s)
        present = len(set(s.face_labels.tolist()))
        print(f"{s.name}: {len(s.faces)} faces in {present} parts -> {out / (s.name + '.seg')}")
    if not segs:
        report_errors(failed)
        err("no shape could be segmented")
        return 2
    try:
        write_summary(segs, out / "summary.csv", overwrite=args.force)
        if args.semantic:
            from ..model.parts import label_codes

            names, _ = label_codes(segmenter.part_names)
            (out / "labels.csv").write_text("code,name\n" + "".join(f"{i + 1},{n}\n" for i, n in enumerate(names)))
        for s in written:
            s.cuboids.save_json(out / f"{s.name}.cuboids.json", overwrite=True)
        if args.png:
            _picture(segs, args.png)
    except FileExistsError as exc:
        failed.append(str(exc))
    print(f"summary: {out / 'summary.csv'}" + (f"; picture: {args.png}" if args.png else ""))

    if sources:
        pairs, names = [], []
        for s in segs:
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
            with atomic_output(out / "evaluation.json", overwrite=args.force) as tmp:
                Path(tmp).write_text(json.dumps(report, indent=1))
            print(f"\nevaluation written to {out / 'evaluation.json'}")
    return report_errors(failed)


def _cmd_name_parts(args) -> int:
    import numpy as np

    from ..io import refuse_existing
    from ..model.modelfile import update_metadata
    from ..model.parts import names_from_labels
    from ..segmentation import Segmenter, read_ground_truth

    out = Path(args.output)
    refuse_existing(out, args.force)
    segmenter = Segmenter(args.model, up=args.up, front=args.front, align=args.align, refine=args.refine)
    segs, errors = segmenter.segment_files(collect(args.inputs), cache_dir=args.cache, workers=args.workers)
    failed = list(errors)
    sources = [(args.labels, args.names)] if args.labels else []
    names, assignments, labels, weights, used = [], [], [], [], []
    for s in segs:
        found = _find_truth(s, sources) if sources else None
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
    if not used:
        report_errors(failed)
        err("no labelled shape to learn names from")
        return 2
    part_names, table = names_from_labels(assignments, labels, weights, names, segmenter.abstractor.parts)
    total = table.sum(axis=1)
    for k, name in enumerate(part_names):
        if total[k] > 0:
            share = table[k].max() / total[k]
            print(f"part {k:2d}: {name:12s} ({share:.0%} of its area on {len(used)} labelled shapes)")
        else:
            print(f"part {k:2d}: {name:12s} (never used on the labelled shapes)")
    naming = {"labels": names, "shapes": len(used), "inputs": [str(p) for p in args.inputs],
              "rule": "each index takes the ground-truth label holding most of its surface area",
              "area_by_label": np.round(table, 6).tolist()}
    update_metadata(_model_path(args.model), out,
                    {"part_names": part_names, "part_naming": naming}, overwrite=args.force)
    print(f"wrote {out} with part names")
    return report_errors(failed)


def _model_path(model):
    from ..model.bundled import resolve_model

    return resolve_model(model)


def register(sub) -> None:
    p = sub.add_parser("segment", help="co-segment a collection: each face to its primitive, the same part index on every shape")
    p.add_argument("inputs", nargs="+", help="mesh files or folders")
    add_output(p, "output folder")
    add_abstraction_options(p)
    add_png(p)
    p.add_argument("--semantic", action="store_true", help="write the model's part names' codes (labels.csv) instead of indices")
    p.add_argument("--gt", action="append", metavar="FOLDER", help="folder of ground-truth .seg files (same stems); repeatable")
    p.add_argument("--gt-names", action="append", metavar="NAMES",
                   help="what the ground-truth values mean: 'back,seat,legs' names values 1,2,3 ('1=back,2=seat' also); "
                   "'legs/base' accepts either model name; once, or once per --gt")
    add_force(p)
    p.set_defaults(func=_cmd_segment)

    p = sub.add_parser("name-parts", help="name a model's part indices from labelled shapes; writes a copy of the model")
    p.add_argument("inputs", nargs="+", help="labelled mesh files or folders")
    add_output(p, "model file to write (the input model is never modified)")
    add_abstraction_options(p)
    p.add_argument("--labels", default=None, help="folder of .seg files (default: the .seg beside each mesh)")
    p.add_argument("--names", default=None,
                   help="what the label values mean ('back,seat,legs' for values 1,2,3); default: the .json beside "
                   "procedural shapes (primkit generate), else the values")
    add_force(p)
    p.set_defaults(func=_cmd_name_parts)

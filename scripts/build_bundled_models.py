"""Evaluate trained models and ship them as bundled models with their model cards.

Usage (after ``primkit train ... --preset NAME -o RUNS/NAME.safetensors`` for each preset, and
``scripts/name_bundled_models.sh RUNS`` to name their parts)::

    python scripts/build_bundled_models.py --runs RUNS [--names chair table airplane]
        [--limit 200] [--refine 200] [--pictures docs/images] [--partnet validation test]

For each model: its held-out shapes (the preset's rule applied to the training folder recorded in
the model) are abstracted without and with ``--refine``. The chair model is also evaluated with
default flags (no axes declared) on the PartNet chairs (``scripts/partnet_chairs.py``: the
validation part by default; the test part only when asked, once, for the model that ships), on the
COSEG chairs in ``../shared/data/coseg_chairs`` (faces labelled right, the same index across
chairs, copies turned into random axis-aligned orientations) and by ``primkit deform`` on their
ordered pairs. The figures go into the model card (metadata key ``card``), and the model file with
its card is written to ``primkit/model/bundled/NAME.safetensors``. Pictures of the abstractions go
to ``--pictures``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from primkit import data, geometry, io, segmentation  # noqa: E402
from primkit.model import modelfile, orientation  # noqa: E402
from primkit.model.abstraction import abstract_shapes  # noqa: E402
from primkit.model.abstractor import Abstractor  # noqa: E402
from primkit.metrics import ChamferConvention, part_label_agreement, score, summarize  # noqa: E402
from primkit.model.presets import get_preset  # noqa: E402
from primkit.viz.render import render_abstractions  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
CONV = ChamferConvention()
CONV_DIAGONAL = ChamferConvention(unit="diagonal")


def _brief(summary) -> dict:
    return {
        "shapes": summary.count,
        "chamfer_l1": round(summary.chamfer.mean, 5),
        "iou": round(summary.iou.mean, 4),
        "parts": round(summary.parts.mean, 2),
    }


def evaluate(abstractor, shapes, **kwargs):
    t0 = time.perf_counter()
    results = abstractor.predict(shapes, **kwargs)
    seconds = (time.perf_counter() - t0) / max(1, len(shapes))
    scores = [score(r.canonical, r.canonical_shape(s), CONV) for r, s in zip(results, shapes)]
    out = _brief(summarize(scores))
    diagonal = [score(r.canonical, r.canonical_shape(s), CONV_DIAGONAL) for r, s in zip(results, shapes)]
    out["chamfer_l1_diagonal"] = round(summarize(diagonal).chamfer.mean, 5)
    out["seconds_per_shape"] = round(seconds, 4)
    return out, results


def picture(results, shapes, path, title_extra=""):
    """Results beside their shapes, drawn in the canonical frame (voxel inputs as their boundary)."""
    meshes = []
    for s in shapes:
        shape = io.read_shape(Path(s.source))
        if isinstance(shape, io.Mesh):
            meshes.append((shape.vertices, shape.faces))
        else:
            v, f = geometry.voxel_boundary_mesh(s.solid)
            meshes.append((s.frame.from_canonical(v), f))  # in the input frame, like a mesh
    render_abstractions(results, meshes, path, canonical=True, note=title_extra)
    print(f"  picture: {path}", file=sys.stderr)


def _coseg_truths(segs, names):
    truths = []
    for s in segs:
        p = Path(s.source)
        conv = "back,seat,legs/base" if p.parent.parent.name == "large_chairs" else "legs/base,seat,back"
        truths.append(segmentation.read_ground_truth(p.parent.parent / "gt" / f"{p.stem}.seg", len(s.faces), conv, names))
    return truths


def coseg_chairs(abstractor, refine: int, pictures: Path | None, cache) -> dict:
    """The COSEG chairs with default flags (no axes declared): fidelity in both units, the share of
    faces labelled right under the paper's protocol and the stored names, the same index across
    chairs, and random axis-aligned turns of each chair."""
    folder = SHARED / "coseg_chairs"
    files = sorted(folder.glob("*/shapes/*.off"))
    out = {"shapes": len(files), "frame": "default flags: no axes declared (+Y up unless lying down, front searched)"}
    for key, steps in (("as_given", 0), ("refined", refine)):
        abstractions = abstract_shapes(files, abstractor, refine=steps, cache=cache, progress=False)
        results = abstractions.results
        shapes = [a.prepared for a in abstractions]
        segs, errors = segmentation.Segmenter(abstractor).segment_results(results, progress=False)
        names: list = []
        report = segmentation.evaluate(segs, _coseg_truths(segs, names), part_names=abstractor.part_names)
        r = _brief(summarize([score(x.canonical, x.canonical_shape(s), CONV) for x, s in zip(results, shapes)]))
        r["chamfer_l1_diagonal"] = round(summarize([score(x.canonical, x.canonical_shape(s), CONV_DIAGONAL)
                                                    for x, s in zip(results, shapes)]).chamfer.mean, 5)
        r["steps"] = steps
        for protocol, e in report.protocols.items():
            r[f"faces_right_{protocol}"] = round(e.mean_faces, 4)
            r[f"area_right_{protocol}"] = round(e.mean_area, 4)
        r["per_shape_faces_right"] = {n: round(v.faces, 4) for n, v in
                                      report.protocols["collection-majority"].shapes.items()}
        r["part_index_agreement"] = dict(part_label_agreement(
            [x.canonical for x in results], [s.points for s in shapes],
            [_point_labels(s, p) for s, p in zip(shapes, files)], ["back", "seat", "legs"]).to_dict()["per_label"])
        out[key] = r
        if pictures:
            picture(results, shapes, pictures / ("chair-coseg.png" if steps == 0 else "chair-coseg-refined.png"),
                    "" if steps == 0 else " (refined)")

    # turned copies: each chair in a random axis-aligned orientation, no axes given
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        truth = []
        turned_files = []
        for p in files:
            mesh = io.read_mesh(p)
            a = orientation.AXIS_ROTATIONS[rng.integers(1, 24)]
            dst = Path(tmp) / f"{p.parent.parent.name}-{p.stem}.ply"
            io.write_mesh(dst, mesh.vertices @ a.T, mesh.faces)
            truth.append(a)
            turned_files.append(dst)
        tcoll = data.prepare_collection(turned_files, data.PrepareSettings(), cache_dir=cache, progress=False)
        tshapes = list(tcoll)
        res_al, results_al = evaluate(abstractor, tshapes, align="auto")
        recovered_up = 0
        from primkit.geometry import axis_rotation

        want = axis_rotation("+y", "+z")
        for r, a in zip(results_al, truth):
            total = r.frame.rotation  # canonical = total @ x for the turned input x = a @ original
            recovered_up += bool(np.allclose(total[1], (want @ a.T)[1]))
        res_al["up_recovered"] = f"{recovered_up}/{len(results_al)}"
        out["turned_align_auto"] = res_al
    return out


def _point_labels(shape, path: Path) -> np.ndarray:
    semantic = {"large_chairs": {1: 0, 2: 1, 3: 2}, "chairs_101-120": {3: 0, 2: 1, 1: 2}}
    lut = semantic[path.parent.parent.name]
    return np.array([lut.get(int(v), -1) for v in shape.point_labels])


def coseg_deform(model_path: Path, limit: int = 0) -> dict:
    """``primkit deform`` with default flags on the ordered pairs of COSEG chairs: is the result
    closer to the target than the source? Chamfer-L1 with each mesh in its own frame (bounding box
    centred, diagonal 1: the files use different units), 10k + 10k area-uniform samples."""
    import contextlib
    import io as text_io

    import trimesh

    from primkit.cli import main as cli
    from primkit.metrics import chamfer_distance

    files = sorted((SHARED / "coseg_chairs").glob("*/shapes/*.off"))

    def unit_points(path, seed):
        m = io.read_mesh(path)
        p, _ = trimesh.sample.sample_surface(trimesh.Trimesh(m.vertices, m.faces, process=False), 10000, seed=seed)
        lo, hi = m.vertices.min(0), m.vertices.max(0)
        return (p - (lo + hi) / 2) / np.linalg.norm(hi - lo)

    pairs = [(a, b) for a in files for b in files if a != b][: limit or None]
    closer, failed, before, after = 0, 0, [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (a, b) in enumerate(pairs):
            dst = Path(tmp) / f"{k}.off"
            with contextlib.redirect_stdout(text_io.StringIO()):
                code = cli(["deform", str(a), str(b), "--model", str(model_path), "-o", str(dst), "--workers", "1"])
            if code != 0:
                failed += 1
                continue
            tgt = unit_points(b, 1)
            before.append(chamfer_distance(unit_points(a, 2), tgt))
            after.append(chamfer_distance(unit_points(dst, 3), tgt))
            closer += after[-1] < before[-1]
    return {"pairs": len(pairs), "closer": int(closer), "failed": failed,
            "chamfer_source_target": round(float(np.mean(before)), 5) if before else None,
            "chamfer_result_target": round(float(np.mean(after)), 5) if after else None,
            "convention": "Chamfer-L1 (two-way mean, unsquared), each mesh centred with bounding-box diagonal 1, "
                          "10k + 10k samples; default flags of primkit deform"}


def _finite(value):
    """NaN (an undefined rate, e.g. no chair without that label) as None: model metadata is strict JSON."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return None if isinstance(value, float) and value != value else value


def partnet(model_path: Path, parts: list[str]) -> dict:
    """The chair model on the PartNet validation (and, once, test) chairs with default flags."""
    import partnet_chairs

    validation, test, archive = partnet_chairs.split()
    out = {}
    for part in parts:
        files = validation if part == "validation" else test
        report = partnet_chairs.evaluate(model_path, files, archive)
        for line in partnet_chairs.summary_lines(report):
            print(f"  PartNet {part}: {line}", file=sys.stderr)
        keep = {k: report[k] for k in ("iou_rule", "mean_over", "shapes_evaluated", "frames", "parts_histogram",
                                       "parts_mean", "distinct_index_sets")}
        keep["protocols"] = {p: {k: e[k] for k in ("iou", "mean_iou", "accuracy", "mapping")}
                             | {"arm_detection": e["detection"]["arms"],
                                "absent_kept_absent": {n: d["absent_kept_absent"] for n, d in e["detection"].items()}}
                             for p, e in report["protocols"].items()}
        out[part] = _finite(keep)
    return out


def held_out(abstractor, meta, limit: int, refine: int, pictures: Path | None, name: str, cache) -> dict:
    d = meta["training"]["data"]
    files = []
    for inp in d["inputs"]:
        files += data.find_shape_files(inp)
    _, held = data.split_files(files, abstractor.hold_out_every)
    total = len(held)
    if limit and len(held) > limit:
        held = held[:: int(np.ceil(len(held) / limit))]
    coll = data.prepare_collection(held, abstractor.settings, cache_dir=cache, progress=False)
    shapes = list(coll)
    plain, results = evaluate(abstractor, shapes)
    refined, _ = evaluate(abstractor, shapes, refine=refine)
    refined["steps"] = refine
    if pictures:
        picture(results[:8], shapes[:8], pictures / f"{name}-heldout.png")
    return {"held_out_total": total, "evaluated": len(shapes), "network": plain, "refined": refined}


#: The animal model's names for the procedural animals' eight parts (scripts/name_bundled_models.sh).
ANIMAL_NAMES = "0=body,1=head,2=neck,3=legs,4=legs,5=legs,6=legs,7=tail"


def procedural_named(model_path: Path, category: str, label_names: str, count: int = 20, seed: int = 9) -> dict:
    """``primkit segment --semantic`` (default flags) on ``count`` procedural shapes of ``seed`` (never
    used for naming, which used seed 7): the share of each shape's surface named right, area-weighted."""
    from primkit import synthetic
    from primkit.cli import main as cli
    from primkit.segmentation.evaluation import read_ground_truth

    with tempfile.TemporaryDirectory() as tmp:
        files = synthetic.write_collection(Path(tmp) / "in", category, count, seed=seed)
        out = Path(tmp) / "seg"
        if cli(["segment", str(Path(tmp) / "in"), "--model", str(model_path), "-o", str(out), "--semantic", "-q"]) != 0:
            raise RuntimeError("segment failed")
        codes = dict(line.split(",") for line in (out / "labels.csv").read_text().splitlines()[1:])
        right, names = [], []
        for f in files:
            mesh = io.read_mesh(f)
            truth = read_ground_truth(f.with_suffix(".seg"), len(mesh.faces), label_names=label_names, names=names)
            got = io.read_labels(out / f"{f.stem}.seg", len(mesh.faces))
            got = np.array([truth.names.index(codes[str(c)]) if str(c) in codes and codes[str(c)] in truth.names else -1
                            for c in got])
            area, ok = mesh.face_areas(), truth.labels >= 0
            right.append(float(area[ok & (got == truth.labels)].sum() / area[ok].sum()))
    return {"shapes": count, "seed": seed, "area_right": round(float(np.mean(right)), 4),
            "worst": round(float(np.min(right)), 4)}


def card_text(name: str, card: dict) -> str:
    m = card["metrics"]
    lines = [f"# primkit bundled model: {name}", "", card["summary"], "",
             f"- Data: {card['data']}", f"- Terms: {card['terms']}", f"- Reproduce: `{card['command']}`",
             f"- Schedule: {card['schedule']}", f"- Training time: {card['training_time']}",
             f"- Part names: {card['part_names']}",
             f"- Metric convention: {m['convention']} (\"diagonal\": the same in units of the shape's bounding-box diagonal)", ""]
    h = m["held_out"]
    lines.append(f"Held-out shapes ({h['evaluated']} of {h['held_out_total']} never trained on):")
    for key in ("network", "refined"):
        r = h[key]
        lines.append(f"- {key}: Chamfer-L1 {r['chamfer_l1']:.4f} (diagonal {r['chamfer_l1_diagonal']:.4f}), IoU {r['iou']:.3f}, "
                     f"parts {r['parts']:.1f}, {r['seconds_per_shape'] * 1000:.0f} ms/shape")
    if "partnet_chairs" in m:
        lines.append("")
        lines.append("PartNet chairs (held-out ShapeNetVox32 chairs with PartNet's part boxes as voxel labels, "
                     "default flags, no refinement; scripts/partnet_chairs.py; per-shape IoU, 1 when a label is absent from both):")
        for part, rep in m["partnet_chairs"].items():
            for protocol, e in rep["protocols"].items():
                arm = e["arm_detection"]
                lines.append(f"- {part} ({rep['shapes_evaluated']} chairs), {protocol}: " + ", ".join(
                    f"{k} {v:.3f}" for k, v in e["iou"].items()) + f"; mean over back, seat, legs {e['mean_iou']:.3f}; "
                    f"arm detection F1 {arm['f1']:.3f}")
            hist = ", ".join(f"{n}: {c}" for n, c in rep["parts_histogram"].items())
            lines.append(f"  parts per chair (mean {rep['parts_mean']:.1f}): {hist}")
    if "coseg_chairs" in m:
        c = m["coseg_chairs"]
        lines.append("")
        lines.append(f"COSEG chairs ({c['shapes']} real meshes, another source than ShapeNet; {c['frame']}):")
        for key in ("as_given", "refined"):
            r = c[key]
            agree = ", ".join(f"{k} {v['agreement']:.0%} (#{v['index']})" for k, v in r["part_index_agreement"].items())
            lines.append(f"- {key} (refine {r['steps']}): faces labelled right {r['faces_right_collection-majority']:.1%} "
                         f"(paper's protocol), {r.get('faces_right_model-names', float('nan')):.1%} (stored names); "
                         f"Chamfer-L1 {r['chamfer_l1']:.4f} (diagonal {r['chamfer_l1_diagonal']:.4f}), parts {r['parts']:.1f}; "
                         f"same index across chairs: {agree}")
        r = c["turned_align_auto"]
        lines.append(f"- each chair turned at random (axis-aligned): up recovered {r['up_recovered']}")
    if "procedural_named" in m:
        p = m["procedural_named"]
        lines.append("")
        lines.append(f"Procedural animals ({p['shapes']} of primkit.synthetic's, seed {p['seed']}, never named from), "
                     f"segment --semantic with default flags: {p['area_right']:.1%} of the surface named right "
                     f"(worst shape {p['worst']:.1%}).")
    if "coseg_deform" in m:
        d = m["coseg_deform"]
        lines.append(f"- primkit deform on {d['pairs']} ordered pairs: {d['closer']} end closer to the target than the "
                     f"source (mean Chamfer {d['chamfer_source_target']:.4f} -> {d['chamfer_result_target']:.4f}, "
                     "unit-diagonal frames)")
    return "\n".join(lines) + "\n"


def _naming(meta: dict) -> str:
    n = meta.get("part_naming")
    if not n:
        return "none stored"
    where = ", ".join(n.get("labels_from") or n.get("inputs") or [])
    return f"learned by primkit name-parts from {n['shapes']} labelled shapes ({where}); {n['rule']}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", required=True, type=Path, help="folder with NAME.safetensors from primkit train --preset NAME")
    ap.add_argument("--names", nargs="+", default=["chair", "table", "airplane", "animal"])
    ap.add_argument("--limit", type=int, default=200, help="held-out shapes evaluated per model (evenly spaced)")
    ap.add_argument("--refine", type=int, default=200)
    ap.add_argument("--pictures", type=Path, default=None)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--dest", type=Path, default=ROOT / "primkit" / "model" / "bundled")
    ap.add_argument("--partnet", nargs="*", default=["validation"], choices=["validation", "test"],
                    help="chair: the PartNet parts to evaluate (test: once, for the model that ships)")
    ap.add_argument("--deform-pairs", type=int, default=0, help="chair: COSEG pairs for primkit deform (0: all 90)")
    ap.add_argument("--training-note", default=None,
                    help="how the training ran, when not alone on the machine (e.g. '1 torch thread, beside a second run')")
    args = ap.parse_args(argv)
    if args.pictures:
        args.pictures.mkdir(parents=True, exist_ok=True)
    for name in args.names:
        src = args.runs / f"{name}.safetensors"
        if not src.is_file():
            print(f"{src}: missing, skipped", file=sys.stderr)
            continue
        print(f"== {name}", file=sys.stderr)
        preset = get_preset(name)
        weights, meta = modelfile.load_model_file(src)
        abstractor = Abstractor.load(src)
        metrics = {"convention": CONV.describe(), "held_out": held_out(abstractor, meta, args.limit, args.refine, args.pictures, name, args.cache)}
        if name == "chair" and (SHARED / "partnet_chair_boxes").is_dir() and args.partnet:
            metrics["partnet_chairs"] = partnet(src, args.partnet)
        if name == "chair" and (SHARED / "coseg_chairs").is_dir():
            metrics["coseg_chairs"] = coseg_chairs(abstractor, args.refine, args.pictures, args.cache)
            metrics["coseg_deform"] = coseg_deform(src, args.deform_pairs)
        if name == "animal":
            metrics["procedural_named"] = procedural_named(src, "animal", ANIMAL_NAMES)
        t = meta["training"]
        cfg = t["config"]
        card = {
            "summary": f"{preset.category} abstractor: {cfg['parts']} cuboid slots, {t['shapes']} training shapes.",
            "data": preset.data,
            "terms": preset.terms,
            "command": preset.command,
            "schedule": f"{cfg['stage1_iterations']} + {cfg['stage2_iterations']} iterations (stage 1 all parts on, stage 2 "
                        f"existence learned), batch {cfg['batch_size']}, Adam {cfg['learning_rate']}, "
                        f"{cfg['points_per_shape']} points per shape, {cfg['samples_per_cuboid']} samples per cuboid, "
                        f"existence by {cfg.get('existence_gradient', 'reinforce')} gradient, "
                        f"parsimony {cfg['parsimony']}, seed {cfg['seed']}",
            "part_names": _naming(meta),
            "training_time": f"{t['seconds'] / 60:.1f} min on {t['device']} ({os.cpu_count()} cores, {platform.processor() or platform.machine()}), torch {t['torch']}"
                             + (f"; {args.training_note}" if args.training_note else ""),
            "metrics": metrics,
        }
        card["text"] = card_text(name, card)
        meta["card"] = card
        meta["metrics"] = metrics
        args.dest.mkdir(parents=True, exist_ok=True)
        (args.dest / f"{name}.card.json").write_text(json.dumps(card, indent=1))  # kept if the save fails
        dst = modelfile.save_model(args.dest / f"{name}.safetensors", weights, meta, overwrite=True)
        print(card["text"])
        print(f"wrote {dst} ({dst.stat().st_size / 1024:.0f} KiB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

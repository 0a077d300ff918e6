"""Evaluate trained models and ship them as bundled models with their model cards.

Usage (after ``primkit train ... --preset NAME -o RUNS/NAME.safetensors`` for each preset)::

    python scripts/build_bundled_models.py --runs RUNS [--names chair table airplane animal]
        [--limit 200] [--refine 200] [--pictures docs/images]

For each model: its held-out shapes (the preset's rule applied to the training folder recorded in
the model) are abstracted without and with ``--refine``; the chair model is also run on the COSEG
chairs in ``../shared/data/coseg_chairs`` (+Y up, front +Z) as given with the front named, with
``--align auto`` on copies turned into random axis-aligned orientations, and the seat's primitive
index is checked across chairs. The figures go into the model card (metadata key ``card``), and the
model file with its card is written to ``primkit/model/bundled/NAME.safetensors``. Pictures of the
abstractions go to ``--pictures``.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from primkit import data, geometry, io  # noqa: E402
from primkit.model import modelfile, orientation  # noqa: E402
from primkit.model.abstractor import Abstractor  # noqa: E402
from primkit.metrics import ChamferConvention, part_label_agreement, score, summarize  # noqa: E402
from primkit.model.presets import get_preset  # noqa: E402
from primkit.viz.render import render_abstractions  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
CONV = ChamferConvention()


def _brief(summary: dict) -> dict:
    return {
        "shapes": summary["count"],
        "chamfer_l1": round(summary["chamfer"]["mean"], 5),
        "iou": round(summary["iou"]["mean"], 4),
        "parts": round(summary["parts"]["mean"], 2),
    }


def evaluate(abstractor, shapes, **kwargs):
    t0 = time.perf_counter()
    results = abstractor.predict(shapes, **kwargs)
    seconds = (time.perf_counter() - t0) / max(1, len(shapes))
    scores = [score(r.canonical, r.canonical_shape(s), CONV) for r, s in zip(results, shapes)]
    out = _brief(summarize(scores))
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


def coseg_chairs(abstractor, refine: int, pictures: Path | None, cache) -> dict:
    folder = SHARED / "coseg_chairs"
    files = sorted(folder.glob("*/shapes/*.off"))
    # label values differ between the two subsets (see the data's README); map them to names
    semantic = {"large_chairs": {1: 0, 2: 1, 3: 2}, "chairs_101-120": {3: 0, 2: 1, 1: 2}}
    names = ["back", "seat", "legs"]
    settings = data.PrepareSettings(up="+y", front="+z")
    coll = data.prepare_collection(files, settings, cache_dir=cache, progress=False)
    shapes = list(coll)
    labels = []
    for p, s in zip(coll.paths, shapes):
        lut = semantic[p.parent.parent.name]
        labels.append(np.array([lut.get(int(v), -1) for v in s.point_labels]))
    out = {"shapes": len(shapes), "frame": "+Y up, front +Z (given to the model)"}
    res_plain, results = evaluate(abstractor, shapes)
    out["as_given"] = res_plain
    out["as_given"]["part_index_agreement"] = {
        k: v for k, v in part_label_agreement([r.canonical for r in results], [s.points for s in shapes], labels, names)["per_label"].items()
    }
    if pictures:
        picture(results, shapes, pictures / "chair-coseg.png")
    res_ref, results_ref = evaluate(abstractor, shapes, refine=refine)
    out["refined"] = res_ref
    out["refined"]["steps"] = refine
    out["refined"]["part_index_agreement"] = {
        k: v for k, v in part_label_agreement([r.canonical for r in results_ref], [s.points for s in shapes], labels, names)["per_label"].items()
    }
    if pictures:
        picture(results_ref, shapes, pictures / "chair-coseg-refined.png", " (refined)")

    # turned copies: each chair in a random axis-aligned orientation, no axes given, --align auto
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        truth = []
        turned_files = []
        for p in files:
            mesh = io.read_mesh(p)
            a = orientation.AXIS_ROTATIONS[rng.integers(1, 24)]
            dst = Path(tmp) / f"{p.parent.parent.name}-{p.stem}.ply"
            io.write_mesh(dst, mesh.vertices @ a.T, mesh.faces)
            # the rotation that the frame must apply to the turned copy: the given frame's after a.T
            truth.append(a)
            turned_files.append(dst)
        tcoll = data.prepare_collection(turned_files, data.PrepareSettings(), cache_dir=cache, progress=False)
        tshapes = list(tcoll)
        res_al, results_al = evaluate(abstractor, tshapes, align="auto")
        recovered_up = recovered_both = 0
        from primkit.geometry import axis_rotation

        want = axis_rotation("+y", "+z")
        for r, a in zip(results_al, truth):
            total = r.frame.rotation  # canonical = total @ x for the turned input x = a @ original
            expected = want @ a.T
            recovered_up += bool(np.allclose(total[1], expected[1]))
            recovered_both += bool(np.allclose(total, expected))
        res_al["up_recovered"] = f"{recovered_up}/{len(results_al)}"
        res_al["up_and_front_recovered"] = f"{recovered_both}/{len(results_al)}"
        out["turned_align_auto"] = res_al
        if pictures:
            picture(results_al, tshapes, pictures / "chair-coseg-turned-align.png", " (align auto)")
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


def card_text(name: str, card: dict) -> str:
    m = card["metrics"]
    lines = [f"# primkit bundled model: {name}", "", card["summary"], "",
             f"- Data: {card['data']}", f"- Terms: {card['terms']}", f"- Reproduce: `{card['command']}`",
             f"- Schedule: {card['schedule']}", f"- Training time: {card['training_time']}",
             f"- Metric convention: {m['convention']}", ""]
    h = m["held_out"]
    lines.append(f"Held-out shapes ({h['evaluated']} of {h['held_out_total']} never trained on):")
    for key in ("network", "refined"):
        r = h[key]
        lines.append(f"- {key}: Chamfer-L1 {r['chamfer_l1']:.4f}, IoU {r['iou']:.3f}, parts {r['parts']:.1f}, "
                     f"{r['seconds_per_shape'] * 1000:.0f} ms/shape")
    if "coseg_chairs" in m:
        c = m["coseg_chairs"]
        lines.append("")
        lines.append(f"COSEG chairs ({c['shapes']} real meshes, another source than ShapeNet):")
        for key in ("as_given", "refined", "turned_align_auto"):
            r = c[key]
            extra = ""
            if "part_index_agreement" in r:
                extra = "; same index across chairs: " + ", ".join(f"{k} {v['agreement']:.0%} (#{v['index']})" for k, v in r["part_index_agreement"].items())
            if "up_recovered" in r:
                extra = f"; up recovered {r['up_recovered']}, up and front {r['up_and_front_recovered']}"
            lines.append(f"- {key}: Chamfer-L1 {r['chamfer_l1']:.4f}, IoU {r['iou']:.3f}, parts {r['parts']:.1f}{extra}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", required=True, type=Path, help="folder with NAME.safetensors from primkit train --preset NAME")
    ap.add_argument("--names", nargs="+", default=["chair", "table", "airplane", "animal"])
    ap.add_argument("--limit", type=int, default=200, help="held-out shapes evaluated per model (evenly spaced)")
    ap.add_argument("--refine", type=int, default=200)
    ap.add_argument("--pictures", type=Path, default=None)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--dest", type=Path, default=ROOT / "primkit" / "model" / "bundled")
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
        weights, meta = modelfile.load_model(src)
        abstractor = Abstractor.load(src)
        metrics = {"convention": CONV.describe(), "held_out": held_out(abstractor, meta, args.limit, args.refine, args.pictures, name, args.cache)}
        if name == "chair" and (SHARED / "coseg_chairs").is_dir():
            metrics["coseg_chairs"] = coseg_chairs(abstractor, args.refine, args.pictures, args.cache)
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
                        f"parsimony {cfg['parsimony']}, seed {cfg['seed']}",
            "training_time": f"{t['seconds'] / 60:.1f} min on {t['device']} ({os.cpu_count()} cores, {platform.processor() or platform.machine()}), torch {t['torch']}",
            "metrics": metrics,
        }
        card["text"] = card_text(name, card)
        meta["card"] = card
        meta["metrics"] = metrics
        args.dest.mkdir(parents=True, exist_ok=True)
        dst = modelfile.save_model(args.dest / f"{name}.safetensors", weights, meta, overwrite=True)
        print(card["text"])
        print(f"wrote {dst} ({dst.stat().st_size / 1024:.0f} KiB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

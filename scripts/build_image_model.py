"""Build the bundled chair image model: render views, distil the chair volume model, evaluate.

    python scripts/build_image_model.py render                  # views of training and held-out chairs
    python scripts/build_image_model.py train --minutes 20      # distil (a stage; --resume FILE continues one)
    python scripts/build_image_model.py eval --eval-limit 200   # held-out chairs; writes the bundled file

The bundled file's recipe is :data:`RECIPE` (also in its card): five stages against the chair model
bundled until 2026-12-02 (``--teacher`` names that file), then two against today's chair model,
whose part indices differ, continuing from the fifth stage's network. Stages differ in learning
rate, colour shuffling, background swapping and the geometric term (``--geometric``).

``all`` runs render, train and eval in one go with the options given.

Data: ShapeNetVox32 chairs in ../shared/data/shapenetvox32/03001627, prepared through the cache
``--cache`` (default /work/runs/cache), split with the teacher's own hold-out rule
(:func:`primkit.data.split_files`, every 10th sorted file held out), so the image model never sees
a chair the teacher held out. Views, teacher outputs and checkpoints go to ``--work`` (default
/work/runs/image). The finished model is written to primkit/model/bundled/chair-image.safetensors.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from primkit import data  # noqa: E402
from primkit import image as views  # noqa: E402
from primkit.model.abstractor import Abstractor, RawCuboids  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "shapenetvox32" / "03001627"
_OLD = "--teacher /work/runs/chair-ab37adb.safetensors --threads 1"
#: how the bundled file was built: stages 1-5 against the chair model bundled until 2026-12-02, then
#: stages 6-7 against today's (whose part indices differ), continuing from stage 5's network
RECIPE = (
    "git show ab37adb:primkit/model/bundled/chair.safetensors > /work/runs/chair-ab37adb.safetensors; "
    f"python scripts/build_image_model.py render {_OLD}; "
    f"python scripts/build_image_model.py train --minutes 20 {_OLD}; "
    "cp /work/runs/image/chair-image.safetensors /work/runs/image/stage1.safetensors; "
    f"python scripts/build_image_model.py train --resume /work/runs/image/stage1.safetensors --minutes 6 --lr 3e-4 --colour-shuffle {_OLD}; "
    "cp /work/runs/image/chair-image.safetensors /work/runs/image/stage2.safetensors; "
    f"python scripts/build_image_model.py train --resume /work/runs/image/stage2.safetensors --iterations 10000 --minutes 20 "
    f"--lr 5e-4 --colour-shuffle --swap-backgrounds 0.75 {_OLD}; "
    "cp /work/runs/image/chair-image.safetensors /work/runs/image/stage3.safetensors; "
    f"python scripts/build_image_model.py train --resume /work/runs/image/stage3.safetensors --iterations 8000 --minutes 15 "
    f"--lr 3e-4 --colour-shuffle --swap-backgrounds 0.9 {_OLD}; "
    "cp /work/runs/image/chair-image.safetensors /work/runs/image/stage4.safetensors; "
    f"python scripts/build_image_model.py train --resume /work/runs/image/stage4.safetensors --iterations 6000 --minutes 28 "
    f"--lr 3e-4 --colour-shuffle --swap-backgrounds 0.9 --geometric 5 {_OLD}; "
    "cp /work/runs/image/chair-image.safetensors /work/runs/image/stage5.safetensors "
    "(stage 5's network is also git 2081a9f:primkit/model/bundled/chair-image.safetensors); "
    "python scripts/build_image_model.py train --resume /work/runs/image/stage5.safetensors --iterations 10000 --minutes 25 "
    "--lr 5e-4 --colour-shuffle --swap-backgrounds 0.9 --threads 1; "
    "cp /work/runs/image/chair-image.safetensors /work/runs/image/stage6.safetensors; "
    "python scripts/build_image_model.py train --resume /work/runs/image/stage6.safetensors --iterations 6000 --minutes 25 "
    "--lr 3e-4 --colour-shuffle --swap-backgrounds 0.9 --geometric 5 --threads 1; "
    "python scripts/build_image_model.py eval --eval-limit 200"
)
CHUNK = 500


def _split(teacher):
    files = sorted(DATA.glob("*/model.binvox"))
    return data.split_files(files, teacher.hold_out_every)


def _collection(files, cache):
    coll = data.prepare_collection(files, data.PrepareSettings(), cache_dir=cache, progress=True)
    if coll.errors:
        print(f"{len(coll.errors)} files unusable, e.g. {coll.errors[0]}", file=sys.stderr)
    return coll


def render_split(coll, work: Path, tag: str, views_per_shape: int, palette: str, seed: int, settings, limit=None,
                 reverse=False, keep_foreground=False):
    """Render in chunks of CHUNK shapes (each chunk a cache file) and return the joined views
    (``reverse``: render the chunks last first, so that a second process can share the work)."""
    n = len(coll) if limit is None else min(limit, len(coll))
    parts = []
    starts = list(range(0, n, CHUNK))
    with views.ViewRenderer(settings) as renderer:
        for start in starts[::-1] if reverse else starts:
            idx = range(start, min(n, start + CHUNK))
            path = work / f"views-{tag}-{start:05d}.npz"
            names = [data.shape_name(coll.paths[i]) for i in idx]
            if path.is_file():
                cached = views.load_views(path)
                if cached.names == names and (cached.foreground is not None or not keep_foreground):
                    parts.append(cached)
                    continue
            t = time.time()
            v = views.render_views((coll[i].occupancy for i in idx), views_per_shape, settings=settings,
                                   palette=palette, seed=seed, names=names, renderer=renderer,
                                   progress=True, first_index=start, keep_foreground=keep_foreground)
            v.save(path)
            parts.append(v)
            print(f"{tag} {start}: {len(v)} views in {time.time() - t:.0f} s", flush=True)
    if reverse:
        parts = parts[::-1]
    offsets = np.cumsum([0] + [len(p.names) for p in parts])
    fg = ((np.concatenate([p.foreground for p in parts]), np.concatenate([p.alpha for p in parts]))
          if keep_foreground else (None, None))
    return views.RenderedViews(
        np.concatenate([p.images for p in parts]),
        np.concatenate([p.shape_index + o for p, o in zip(parts, offsets)]),
        np.concatenate([p.cameras for p in parts]),
        sum((p.names for p in parts), []), settings, palette, seed, *fg)


def teacher_targets(teacher, coll, path: Path, limit=None):
    """The teacher's raw outputs for the first ``limit`` shapes, cached in ``path``."""
    n = len(coll) if limit is None else min(limit, len(coll))
    if path.is_file():
        z = RawCuboids(**dict(np.load(path)))
        if len(z.existence) == n:
            return z
    occ = np.stack([coll[i].occupancy for i in range(n)])
    raw = teacher.predict_canonical(occ)
    np.savez(path, **raw.arrays())
    return raw


def teacher_record(teacher, name) -> dict:
    """What a training run distilled: the teacher's card summary and the SHA-256 of its file."""
    import hashlib

    from primkit.model.bundled import resolve_model

    return {"summary": teacher.metadata["card"]["summary"], "model": str(name),
            "sha256": hashlib.sha256(Path(resolve_model(name)).read_bytes()).hexdigest()}


def teacher_cache(work: Path, split: str, args) -> Path:
    """Where the teacher's outputs on ``split`` are cached: per teacher file, so that a stage against
    another teacher never reuses them."""
    return work / f"teacher-{split}-{args.teacher_tag}.npz"


def model_history(path):
    """The training record of the model a run continued from (None for a fresh run)."""
    if not path:
        return None
    from primkit.model.modelfile import read_metadata

    t = read_metadata(path)["training"]
    return {k: t[k] for k in ("config", "seconds", "final", "resumed_from", "views", "teacher") if k in t}


def train(teacher, train_coll, work: Path, settings, args) -> None:
    import torch

    from primkit import image as im

    torch.set_num_threads(args.threads)
    views_train = render_split(train_coll, work, "train-seen", args.views, "seen", 0, settings, args.limit,
                               keep_foreground=True)
    targets = teacher_targets(teacher, train_coll, teacher_cache(work, "train", args), args.limit)
    config = im.ImageTrainConfig(iterations=args.iterations, time_limit_s=60 * args.minutes,
                                 learning_rate=args.lr, colour_shuffle=args.colour_shuffle,
                                 swap_backgrounds=args.swap_backgrounds, geometric=args.geometric)
    geometry = {}
    if args.geometric:
        points, closest = [], []
        for i in range(len(targets.existence)):  # one shape in memory at a time; 2,000 points each suffice
            shape = train_coll[i]
            points.append(shape.points[:2000])
            closest.append(shape.closest)
        geometry = {"surface_points": np.stack(points), "closest": np.stack(closest)}
    start = im.ImageAbstractor.load(args.resume).network if args.resume else None
    net_config = im.ImageNetConfig(size=settings.size)
    print(f"distilling on {len(views_train)} views of {len(views_train.names)} chairs", flush=True)
    result = im.train_image_model(views_train.images, views_train.shape_index, views_train.cameras, targets,
                                  net_config, config, progress=True, network=start, foreground=views_train.foreground,
                                  alpha=views_train.alpha, **geometry)
    model = im.ImageAbstractor(result.network, {})
    meta = {
        "teacher": "chair",
        "part_names": teacher.metadata.get("part_names"),
        "views": settings.to_dict(),
        "training": {"config": config.to_dict(), "views": len(views_train), "shapes": len(views_train.names),
                     "teacher": args.teacher_record,
                     "views_per_shape": args.views, "palette": "seen", "seed": 0, "seconds": round(result.seconds, 1),
                     "device": "cpu", "threads": args.threads, "torch": torch.__version__,
                     "final": result.history[-1], "resumed_from": model_history(args.resume), "history": result.history[:: max(1, len(result.history) // 60)]},
    }
    model.save(work / "chair-image.safetensors", meta, overwrite=True)
    print(f"trained in {result.seconds / 60:.1f} min; final {result.history[-1]}", flush=True)


def _param_errors(student: dict, target: dict) -> dict:
    """Mean errors of the student's raw parts against the teacher's, over the parts the teacher uses."""
    used = target["existence"] > 0.5
    dot = np.abs((student["quaternions"] * target["quaternions"]).sum(-1)).clip(max=1.0)
    return {
        "existence_agreement": float(((student["existence"] > 0.5) == used).mean()),
        "half_extent_l1": float(np.abs(student["half_extents"] - target["half_extents"])[used].mean()),
        "translation_l1": float(np.abs(student["translations"] - target["translations"])[used].mean()),
        "rotation_deg": float(np.degrees(2 * np.arccos(dot))[used].mean()),
        "parts_compared": int(used.sum()),
    }


def _summary(scores, seconds_per_item) -> dict:
    from primkit.metrics import summarize

    s = summarize(scores)
    return {"chamfer_l1": round(s.chamfer.mean, 5), "iou": round(s.iou.mean, 4),
            "parts": round(s.parts.mean, 2), "shapes": len(scores), "seconds_per_item": round(seconds_per_item, 4)}


def evaluate(teacher, held_coll, work: Path, settings, args) -> dict:
    from PIL import Image

    from primkit import image as im
    from primkit.metrics import ChamferConvention, score
    from primkit.model.abstractor import AbstractionResult
    from primkit.viz.render import render_abstractions

    model = im.ImageAbstractor.load(work / "chair-image.safetensors")
    n = len(held_coll) if args.eval_limit is None else min(args.eval_limit, len(held_coll))
    shapes = [held_coll[i] for i in range(n)]
    t = time.time()
    teacher_results = teacher.predict(shapes)
    teacher_seconds = (time.time() - t) / len(shapes)
    teacher_scores = [score(r.canonical, s) for r, s in zip(teacher_results, shapes)]
    targets = teacher_targets(teacher, held_coll, teacher_cache(work, "held", args), n)
    report = {"convention": ChamferConvention().describe(), "held_out_total": len(held_coll),
              "teacher_on_grids": _summary(teacher_scores, teacher_seconds)}
    print("teacher (32^3 grids):", report["teacher_on_grids"], flush=True)
    for tag, palette, seed in (("unseen_backgrounds", "unseen", 1), ("seen_backgrounds", "seen", 2)):
        v = render_split(held_coll, work, f"held-{palette}", 1, palette, seed, settings, n)
        t = time.time()
        raw = model.predict_raw(v.images)
        results = model.predict(v.images, names=[v.names[i] for i in v.shape_index])
        seconds = (time.time() - t) / len(v)
        scores = [score(r.cuboids, shapes[i]) for r, i in zip(results, v.shape_index)]
        errors = _param_errors(raw.arrays(), targets.rows(v.shape_index).arrays())
        az_err = np.abs((np.array([r.azimuth_deg for r in results]) - v.cameras[:, 0] + 180) % 360 - 180)
        report[tag] = {**_summary(scores, seconds), "against_teacher": errors,
                       "azimuth_error_deg_median": round(float(np.median(az_err)), 1)}
        print(tag, report[tag], flush=True)
        if palette == "unseen":
            pics = work / "pictures"
            pics.mkdir(exist_ok=True)
            tiles = []
            for r in results[:24]:
                path = pics / f"{r.name}.png"
                im.draw_over_image(r, path, distance=float(np.mean(settings.distance)),
                                   view_angle_deg=settings.view_angle_deg)
                tiles.append(Image.open(path).convert("RGB"))
            w, h = tiles[0].size
            sheet = Image.new("RGB", (w * 3, h * 8), (255, 255, 255))
            for i, tile in enumerate(tiles):
                sheet.paste(tile, ((i % 3) * w, (i // 3) * h))
            sheet.save(work / "overlay-unseen.png")
            sel = list(range(8))
            held = [shapes[v.shape_index[i]] for i in sel]
            student = [AbstractionResult(results[i].name, results[i].cuboids, results[i].cuboids, h.frame)
                       for i, h in zip(sel, held)]
            meshes = []
            for h in held:  # the surface the pictures show, in the input's frame as render_abstractions wants
                sv, sf = views.shape_surface(h.occupancy)
                meshes.append((h.frame.from_canonical(sv), sf))
            render_abstractions(student, meshes, work / "student-3d.png", canonical=True, note=" image")
            render_abstractions([teacher_results[v.shape_index[i]] for i in sel], meshes, work / "teacher-3d.png",
                                canonical=True, note=" volume")
    (work / "eval.json").write_text(json.dumps(report, indent=1))
    write_bundled(teacher, model, report, work)
    return report


def _line(label: str, m: dict) -> str:
    return f"- {label}: Chamfer-L1 {m['chamfer_l1']:.4f}, IoU {m['iou']:.3f}, parts {m['parts']:.1f}, " \
           f"{m['seconds_per_item'] * 1e3:.1f} ms/item"


def write_bundled(teacher, model, report: dict, work: Path) -> Path:
    """The evaluated model with its card, into primkit/model/bundled/chair-image.safetensors."""
    from primkit.model.modelfile import update_metadata

    tcard = teacher.metadata["card"]
    tr = model.metadata["training"]
    unseen, seen, tnet = report["unseen_backgrounds"], report["seen_backgrounds"], report["teacher_on_grids"]
    ratio = unseen["chamfer_l1"] / tnet["chamfer_l1"]
    data_line = (f"{tr['views']} rendered views ({tr['views_per_shape']} per chair, 64x64, random azimuth, elevation "
                 "0-40 deg, random lights, object colours and backgrounds of the 'seen' palette) of the "
                 f"{tr['shapes']} ShapeNetVox32 chairs the chair model trained on (the voxel grids' contour surface); "
                 "targets: the teacher's cuboids on the same chairs (each stage's teacher in the schedule)")
    stages = []  # oldest first
    t = tr
    while t:
        stages.insert(0, t)
        t = t.get("resumed_from")

    def describe(t: dict) -> str:
        c = t["config"]
        done = t["final"]["iteration"] + 1
        text = (f"{done} iterations" + (f" (of {c['iterations']} planned; stopped by a {c['time_limit_s'] / 60:.0f}-minute limit)"
                                        if done < c["iterations"] else "")
                + f", batch {c['batch_size']}, AdamW {c['learning_rate']} with warm-up and cosine decay, weight decay "
                f"{c['weight_decay']}, shifts of up to {c['shift_pixels']} px and brightness/contrast jitter")
        if c.get("colour_shuffle"):
            text += ", colour channels permuted and their gains jittered"
        if c.get("swap_backgrounds"):
            text += (f", {c['swap_backgrounds']:.0%} of each batch laid over fresh training backgrounds "
                     "(seen-palette kinds and hues plus soft discs; primkit.image.backgrounds.training_backgrounds)")
        if c.get("geometric"):
            text += (f", plus {c['geometric']:g} x the method's coverage + consistency losses of the student's cuboids "
                     "against the true chair")
        who = t.get("teacher")
        text += (f"; teacher: {who['summary']} (sha256 {who['sha256'][:12]})" if who else
                 "; teacher: the chair model bundled before 2026-12-02 (git ab37adb; not recorded in the file)")
        return text

    schedule = "; ".join(f"stage {i + 1}{' (continued)' if i else ''}: {describe(t)}" for i, t in enumerate(stages))
    schedule += "; seed 0"
    seconds = sum(t["seconds"] for t in stages)
    training_time = f"{seconds / 60:.1f} min on cpu ({tr['threads']} threads), torch {tr['torch']}"
    metrics = {
        "convention": report["convention"],
        "held_out": {"evaluated": unseen["shapes"], "held_out_total": report["held_out_total"],
                     "views": "one per held-out chair, backgrounds of the 'unseen' palette (kinds and hues never in training)",
                     "network": unseen, "seen_backgrounds": seen, "teacher_on_grids": tnet,
                     "chamfer_ratio_to_teacher": round(ratio, 3)},
    }
    summary = ("chair image abstractor: 20 cuboid slots (the chair model's indices) from one 64x64 picture, "
               "distilled from the bundled chair model.")
    text = "\n".join([
        "# primkit bundled model: chair-image", "", summary, "",
        f"- Teacher: the bundled chair model ({tcard['summary']})",
        f"- Data: {data_line}",
        f"- Terms: {tcard['terms']}",
        f"- Reproduce: `{RECIPE}`",
        f"- Schedule: {schedule}",
        f"- Training time: {training_time}",
        f"- Metric convention: {report['convention']}",
        "",
        f"Held-out chairs ({unseen['shapes']} the teacher never trained on), one picture each, canonical frame:",
        _line("image model, unseen backgrounds", unseen),
        _line("image model, seen backgrounds", seen),
        _line("chair volume model on the 32^3 grids", tnet),
        f"- image / volume Chamfer: {ratio:.3f}; against the teacher's parts (unseen backgrounds): "
        f"translation L1 {unseen['against_teacher']['translation_l1']:.3f}, half-extent L1 "
        f"{unseen['against_teacher']['half_extent_l1']:.3f}, rotation {unseen['against_teacher']['rotation_deg']:.1f} deg, "
        f"existence agreement {unseen['against_teacher']['existence_agreement']:.3f}; median azimuth error "
        f"{unseen['azimuth_error_deg_median']:.0f} deg",
        "",
    ])
    card = {"summary": summary, "data": data_line, "terms": tcard["terms"], "command": RECIPE, "schedule": schedule,
            "training_time": training_time, "metrics": metrics, "teacher": "chair", "text": text}
    out = ROOT / "primkit" / "model" / "bundled" / "chair-image.safetensors"
    changes = {"card": card, "metrics": metrics, "teacher_card": {k: tcard[k] for k in ("summary", "data", "terms", "command")}}
    model.metadata["training"]["data"] = {"source": "ShapeNetVox32 chairs, synset 03001627", "hold_out_every": 10,
                                         "terms": tcard["terms"]}
    changes["training"] = model.metadata["training"]
    update_metadata(work / "chair-image.safetensors", out, changes, overwrite=True)
    print(text)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stage", choices=["render", "train", "eval", "all"])
    ap.add_argument("--work", default="/work/runs/image")
    ap.add_argument("--cache", default="/work/runs/cache")
    ap.add_argument("--views", type=int, default=2, help="views per training shape")
    ap.add_argument("--limit", type=int, default=None, help="only the first N training shapes")
    ap.add_argument("--reverse", action="store_true", help="render the training chunks last first (a second process)")
    ap.add_argument("--eval-limit", type=int, default=None, help="evaluate on the first N held-out chairs only")
    ap.add_argument("--iterations", type=int, default=9000)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--colour-shuffle", action="store_true", help="permute colour channels and jitter their gains")
    ap.add_argument("--swap-backgrounds", type=float, default=0.0,
                    help="fraction of each batch laid over fresh training backgrounds (0 to 1)")
    ap.add_argument("--geometric", type=float, default=0.0,
                    help="weight of coverage + consistency against the true shape (0: distillation only)")
    ap.add_argument("--resume", default=None, help="continue from this image model file")
    ap.add_argument("--minutes", type=float, default=0, help="stop training after this many minutes (0: no limit)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--teacher", default="chair",
                    help="the volume model distilled (default the bundled chair; a file, e.g. the previous chair "
                         "model from git, to run the earlier stages of the recipe as they were run)")
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    teacher = Abstractor.load(args.teacher)
    args.teacher_record = teacher_record(teacher, args.teacher)
    args.teacher_tag = args.teacher_record["sha256"][:12]
    train_files, held_files = _split(teacher)
    train_coll, held_coll = _collection(train_files, args.cache), _collection(held_files, args.cache)
    settings = views.ViewSettings()
    if args.stage in ("render", "all"):
        teacher_targets(teacher, train_coll, teacher_cache(work, "train", args), args.limit)
        teacher_targets(teacher, held_coll, teacher_cache(work, "held", args))
        if not args.reverse:
            render_split(held_coll, work, "held-unseen", 1, "unseen", 1, settings)
            render_split(held_coll, work, "held-seen", 1, "seen", 2, settings)
        render_split(train_coll, work, "train-seen", args.views, "seen", 0, settings, args.limit, args.reverse,
                     keep_foreground=True)
    if args.stage in ("train", "all"):
        train(teacher, train_coll, work, settings, args)
    if args.stage in ("eval", "all"):
        evaluate(teacher, held_coll, work, settings, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The main job (``primkit demo``): the whole pipeline on procedural chairs, in a few minutes.

0. the bundled chair model (trained on ShapeNet chairs) abstracts the held-out procedural chairs,
   some of them turned into other orientations and found again by ``align="auto"``, and refined
   (``OUT/bundled.png``, ``OUT/bundled.json``); skipped when no bundled model is installed;
1. generate part-labelled procedural chairs (training and held-out sets) into ``OUT/shapes``;
2. prepare them (grids, samples, distances) and train an abstractor (``OUT/chair-demo.safetensors``,
   with the training plot ``OUT/chair-demo.training.png``);
3. abstract the held-out chairs (``OUT/abstractions/*.cuboids.json`` and coloured ``.ply``);
4. score them (Chamfer, IoU, parts, and how consistently each labelled part gets the same
   primitive index) into ``OUT/report.json``, and draw ``OUT/abstractions.png``;
5. run the applications on the held-out chairs with the bundled chair model (abstract, segment,
   embed, deform) into one static page, ``OUT/report/index.html`` (:mod:`primkit.report`).
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path
from . import data, io, synthetic
from .model import orientation
from .model.abstraction import abstract_shapes, load_model
from .metrics import ChamferConvention, part_label_agreement, score, summarize
from .model.bundled import bundled_models
from .viz.render import render_abstractions
from .model.training import ShapeTensors, train, TrainConfig
from .report import build_report


__all__ = ["run_demo"]

_logger = logging.getLogger(__name__)


def _bundled_step(out: Path, folder: Path, cache: Path, quick: bool, progress: bool) -> None:
    """Abstract ``folder``'s chairs with the bundled chair model: as given, turned + align auto, refined."""
    import numpy as np

    if "chair" not in bundled_models():
        _logger.info("[bundled] no bundled chair model installed; skipped")
        return
    _logger.info("[bundled] the bundled chair model on the held-out chairs: as given, turned (align auto), refined")
    model = load_model("chair")
    given = abstract_shapes(folder, model, cache=cache, progress=progress)
    shapes = [a.prepared for a in given]
    turns = [orientation.AXIS_ROTATIONS[(7 * i + 5) % 23 + 1] for i in range(len(shapes))]
    turned = [orientation.rotate_prepared(s, a) for s, a in zip(shapes, turns)]
    steps = 50 if quick else 200
    runs = {  # name: (results, the shapes they were computed from)
        "as given": (given.results, shapes),
        "turned, align auto": (model.predict(turned, align="auto"), turned),  # prepared shapes turned: predict them
        "refined": (abstract_shapes(folder, model, refine=steps, cache=cache, progress=progress).results, shapes),
    }
    conv = ChamferConvention()
    report = {"convention": conv.describe(), "refine_steps": steps}
    for key, (results, inputs) in runs.items():
        scores = [score(r.canonical, r.canonical_shape(s), conv) for r, s in zip(results, inputs)]
        summ = summarize(scores)
        report[key] = {"parts": summ.parts.mean, "iou": summ.iou.mean, "chamfer": summ.chamfer.mean}
        _logger.info("  %-20s: parts %.1f, IoU %.3f, Chamfer %.4f", key, summ.parts.mean, summ.iou.mean,
                     summ.chamfer.mean)
    undone = [bool(np.allclose(r.frame.rotation, s.frame.rotation)) for r, s in zip(runs["turned, align auto"][0], shapes)]
    report["turned, align auto"]["orientation_recovered"] = f"{sum(undone)}/{len(undone)}"
    _logger.info("  turned chairs whose orientation align auto recovered: %d/%d", sum(undone), len(undone))
    with io.atomic_output(out / "bundled.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1))
    meshes = [(a.vertices, a.faces) for a in given]
    render_abstractions(runs["refined"][0], meshes, out / "bundled.png", note=f" (refined {steps})")


def _demo_outputs(out: Path, train_count: int, test_count: int) -> list:
    """The files the demo writes into ``out``."""
    from .model.training import training_outputs

    shapes = [out / "shapes" / kind / f"chair_{i:04d}{ext}" for kind, n in (("train", train_count), ("heldout", test_count))
              for i in range(n) for ext in (".ply", ".seg", ".json")]
    abstractions = [out / "abstractions" / f"chair_{i:04d}.cuboids{ext}" for i in range(test_count) for ext in (".json", ".ply")]
    fixed = [out / name for name in ("bundled.json", "bundled.png", "report.json", "abstractions.png",
                                     "report/index.html", "report/report.json")]
    return [*training_outputs(out / "chair-demo.safetensors").paths(), *fixed, *shapes, *abstractions]


def run_demo(output="primkit-demo", *, quick: bool = False, force: bool = False, train_count: int = 96,
             test_count: int = 8, iterations: int = 2400, progress: bool = False) -> int:
    """Run the demo into ``output`` (the steps in the module notes); 0 when done, 2 when an output
    cannot be written or exists (without ``force``). The steps and the scores are logged (the module logger
    ``primkit.demo``, level INFO); ``progress`` draws tqdm bars on stderr."""
    out = Path(output)
    model_path = out / "chair-demo.safetensors"
    if quick:
        train_count, test_count, iterations = 16, 4, 60
    try:  # before any work: everything the demo writes can be written, and replaces nothing without --force
        io.check_outputs(_demo_outputs(out, train_count, test_count), overwrite=force)
    except (OSError, ValueError) as exc:
        _logger.error("primkit: error: %s", exc)
        return 2
    _logger.info("[1/4] generating %d training and %d held-out procedural chairs", train_count, test_count)
    train_dir, test_dir = out / "shapes" / "train", out / "shapes" / "heldout"
    synthetic.write_collection(train_dir, "chair", train_count, seed=0, overwrite=force)
    synthetic.write_collection(test_dir, "chair", test_count, seed=10_000, overwrite=force)

    cache = out / "cache"
    _bundled_step(out, test_dir, cache, quick, progress)

    _logger.info("[2/4] preparing and training")
    train_set = data.prepare_collection(train_dir, cache_dir=cache, progress=progress)
    s1 = int(iterations * 0.4)
    config = TrainConfig(stage1_iterations=s1, stage2_iterations=iterations - s1, batch_size=16 if quick else 32)
    train(ShapeTensors(train_set), model_path, config, overwrite=True, progress=progress,
          description={"inputs": "procedural chairs made by primkit.synthetic (seed 0)", "terms": "generated by primkit; no restrictions"})

    _logger.info("[3/4] abstracting held-out chairs")
    test_set = abstract_shapes(test_dir, model_path, cache=cache, progress=progress)
    shapes = [a.prepared for a in test_set]
    results = test_set.results
    for r in results:
        r.save(out / "abstractions", overwrite=True)

    _logger.info("[4/4] scoring and drawing")
    conv = ChamferConvention()
    scores = [score(r.canonical, s, conv) for r, s in zip(results, shapes)]
    _, meta = synthetic.read_collection_labels(test_set[0].source)
    agreement = part_label_agreement([r.canonical for r in results], [s.points for s in shapes],
                                     [s.point_labels for s in shapes], names=meta["part_names"])
    summ = summarize(scores)
    report = {"convention": conv.describe(), "summary": summ.to_dict(), "part_index_agreement": agreement.to_dict()}
    with io.atomic_output(out / "report.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1))
    render_abstractions(results, [(a.vertices, a.faces) for a in test_set], out / "abstractions.png")
    _logger.info("held-out chairs: %d; parts %.1f; IoU %.3f; Chamfer %.4f (%s)", len(scores), summ.parts.mean,
                 summ.iou.mean, summ.chamfer.mean, conv.describe())
    _logger.info("part -> primitive index agreement across held-out chairs: %s",
                 ", ".join(f"{k} {v.agreement:.0%} (#{v.index})" for k, v in agreement.per_label.items()))
    report_dir = _chain_step(out, test_dir, cache, progress)
    _logger.info("wrote %s/bundled.png, %s/abstractions.png, %s/report.json, %s/abstractions/, %s%s", out, out, out, out,
                 model_path, f"; open {report_dir}/index.html" if report_dir else "")
    return 0


def _chain_step(out: Path, folder: Path, cache: Path, progress: bool):
    """The applications on the held-out chairs with the bundled chair model, into one HTML page:
    abstraction, co-segmentation, similarity map and a deformation transfer (:mod:`primkit.report`)."""
    if "chair" not in bundled_models():
        _logger.info("[report] no bundled chair model installed; skipped")
        return None
    _logger.info("[report] abstract, segment, embed and deform the held-out chairs with the bundled chair model")
    target = out / "report"
    _, errors = build_report(folder, "chair", target, refine=50, overwrite=True, model_label="chair (bundled)",
                             cache_dir=cache, progress=progress)
    for e in errors:
        warnings.warn(f"skipped {e}", stacklevel=2)
    return target

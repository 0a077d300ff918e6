"""Part counts before and after the rule that present parts have a size, on the PartNet chairs.

Usage (from the repository root, primkit importable)::

    python scripts/partnet_part_counts.py [MODEL] [--part validation|test] [--limit N] [--json F]

The chairs are the fixed split of ``scripts/partnet_chairs.py`` (validation by default). Each chair
is abstracted twice with the default flags of ``primkit segment``: once with ``min_extent=None``
(every part the network and the covered-part pruning keep: the behaviour before the rule) and once
with the default (:func:`primkit.model.abstractor.drop_unsized_parts`). For each it prints the
histogram of present parts per chair, how many present parts have a longest side under the
threshold or are the nearest part of none of the chair's surface samples (counted here from the
cuboids, independently of the rule), and the voxel segmentation scores under the paper's protocol
(:func:`primkit.segmentation.evaluate_voxels`, as ``scripts/partnet_chairs.py`` reports them).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from partnet_chairs import MEAN_OVER, split  # this script's own folder is on sys.path when run
from primkit import io
from primkit.model.abstraction import abstract_shapes, load_model
from primkit.model.abstractor import MIN_EXTENT
from primkit.segmentation import evaluate_voxels, label_voxels


def unsized(canonical, points, min_extent: float) -> tuple[int, int]:
    """``(small, empty)``: present parts whose longest side is under ``min_extent``, and present
    parts that are the nearest present part (by a plain per-part distance loop) of no point."""
    present = canonical.present
    longest = 2.0 * canonical.half_extents[present].max(axis=1)
    dist = np.empty((len(points), len(present)))
    for j, k in enumerate(present):  # distance to box k in its own frame: the norm of the excess
        local = (points - canonical.translations[k]) @ canonical.rotations[k]
        dist[:, j] = np.linalg.norm(np.maximum(np.abs(local) - canonical.half_extents[k], 0.0), axis=1)
    owned = np.zeros(len(present), bool)
    owned[np.argmin(dist, axis=1)] = True  # ties aside (measure zero on these shapes), the nearest part
    return int((longest < min_extent).sum()), int((~owned).sum())


def measure(model, files, archive, min_extent) -> dict:
    t0 = time.perf_counter()
    out = abstract_shapes(files, model, min_extent=min_extent, workers=1, progress=False)
    seconds = time.perf_counter() - t0
    counts, small, empty, labels, truths, names = [], 0, 0, [], [], []
    for a in out:
        c = a.canonical
        counts.append(int(c.existence.sum()))
        s, e = unsized(c, a.canonical_shape().points, MIN_EXTENT)
        small, empty = small + s, empty + e
        grid = io.read_voxels(a.source)
        labels.append(label_voxels(grid, a.cuboids))
        truths.append(archive.get(a.name, grid.occupancy.shape))
        names.append(a.name)
    report = evaluate_voxels(labels, truths, out.model.parts, part_names=out.model.part_names, names=names,
                             mean_over=MEAN_OVER)
    counts = np.array(counts)
    return {
        "min_extent": min_extent,
        "shapes": len(counts),
        "seconds": round(seconds, 1),
        "parts_mean": float(counts.mean()),
        "parts_histogram": {str(n): int(k) for n, k in zip(*np.unique(counts, return_counts=True))},
        "present_parts": int(counts.sum()),
        f"present_longest_side_under_{MIN_EXTENT}": small,
        "present_nearest_to_no_surface_sample": empty,
        "protocols": {p: {"mean_iou": e.mean_iou, "accuracy": e.accuracy, "iou": e.iou,
                          "arm_f1": e.detection["arms"].f1} for p, e in report.protocols.items()},
        "errors": list(out.errors),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default="chair", help="a model file or a bundled model's name")
    ap.add_argument("--part", choices=["validation", "test"], default="validation")
    ap.add_argument("--limit", type=int, default=0, help="the first N chairs of the part")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    validation, test, archive = split()
    files = validation if args.part == "validation" else test
    files = files[: args.limit] if args.limit else files
    model = load_model(args.model)
    rows = [measure(model, files, archive, m) for m in (None, MIN_EXTENT)]
    for r in rows:
        print(f"min_extent {r['min_extent']}: {r['shapes']} PartNet {args.part} chairs ({r['seconds']:.0f} s)")
        print(f"  parts per chair (mean {r['parts_mean']:.2f}): "
              + ", ".join(f"{n}: {k}" for n, k in r["parts_histogram"].items()))
        print(f"  {r['present_parts']} present parts; longest side under {MIN_EXTENT}: "
              f"{r[f'present_longest_side_under_{MIN_EXTENT}']}; nearest to no surface sample: "
              f"{r['present_nearest_to_no_surface_sample']}")
        for p, e in r["protocols"].items():
            print(f"  {p:20s} mean(back, seat, legs) IoU {e['mean_iou']:.4f} | accuracy {e['accuracy']:.4f} | "
                  + " ".join(f"{k} {v:.3f}" for k, v in e["iou"].items()) + f" | arm F1 {e['arm_f1']:.3f}")
    for e in rows[-1]["errors"]:
        print(e, file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 1 if rows[-1]["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())

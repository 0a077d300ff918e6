"""A chair model on real semantic labels: PartNet's part boxes as per-voxel labels of the
ShapeNetVox32 chairs (``../shared/data/partnet_chair_boxes``), with the default flags of
``primkit segment`` (no frame declared, no refinement unless ``--refine``).

Usage::

    python scripts/partnet_chairs.py MODEL --part validation|test [--refine N] [--limit N] [--json F]

The split, fixed before any model was chosen: the chair preset's held-out files (rank
``r % 10 == 9`` of the sorted ``shapenetvox32/03001627`` paths, never trained on) that have PartNet
labels, sorted by shape id; even positions are the **validation** part (recipes and part names are
chosen on it), odd positions the **test** part (reported once, for the shipped model and the
baseline). Scores (:func:`primkit.segmentation.evaluate_voxels`): each occupied voxel labelled as
``primkit segment`` does (the graph cut by default; ``--labelling nearest``: its nearest present
cuboid); per-label IoU per shape, 1 when a label is absent from both, averaged over shapes; the
paper's collection-majority mapping and the model's stored names; arm detection F1 over chairs
with and without arms; the histogram of part counts; how often an absent label's index is absent.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from primkit import data  # noqa: E402
from primkit.segmentation import Segmenter, VoxelLabelArchive, evaluate_voxels  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
CHAIRS = SHARED / "shapenetvox32" / "03001627"
PARTNET = SHARED / "partnet_chair_boxes"
MEAN_OVER = ["back", "seat", "legs"]


def split(chairs=CHAIRS, labels=PARTNET, hold_out_every: int = 10):
    """``(validation, test, archive)``: the labelled held-out chair files of each part, and the labels."""
    _, held = data.split_files(data.find_shape_files(chairs), hold_out_every)
    archive = VoxelLabelArchive(labels)
    labelled = sorted((p for p in held if data.shape_name(p) in archive), key=data.shape_name)
    return labelled[0::2], labelled[1::2], archive


@dataclass
class ChairRun:
    """One segmentation run over labelled chair files: the segmentations (input order, files that
    failed left out), their ground truths, the errors, the seconds it took and the segmenter."""

    segmentations: list
    truths: list
    errors: list
    seconds: float
    segmenter: Segmenter
    refine: int = 0


def segment_chairs(model, files, archive, *, refine: int = 0, workers=None, progress: bool = False, labelling=None,
                   adapt=None) -> ChairRun:
    """Segment ``files`` with ``model`` (default flags; ``adapt``: adapted to ``files`` first, without
    labels, as ``primkit segment --adapt``) and look up their labels in ``archive``."""
    segmenter = Segmenter(model, refine=refine, labelling=labelling, adapt=adapt)
    t0 = time.perf_counter()
    segs, errors = segmenter.segment_files(files, workers=workers, progress=progress)
    seconds = time.perf_counter() - t0
    truths = [archive.get(s.name, s.grid.occupancy.shape) for s in segs]
    return ChairRun(segs, truths, errors, seconds, segmenter, refine)


def score(run: ChairRun) -> dict:
    """The report of a :class:`ChairRun` (see the module notes)."""
    segs = run.segmentations
    report = evaluate_voxels([s.labels for s in segs], run.truths, run.segmenter.abstractor.parts,
                             part_names=run.segmenter.part_names, names=[s.name for s in segs],
                             mean_over=MEAN_OVER).to_dict()  # extended below with the run's figures
    present = np.array([s.cuboids.existence for s in segs], bool)
    counts = present.sum(axis=1)
    index_sets: dict = {}
    for row in present:
        key = tuple(int(k) for k in np.flatnonzero(row))
        index_sets[key] = index_sets.get(key, 0) + 1
    report.update({
        "errors": run.errors,
        "seconds": round(run.seconds, 1),
        "refine": run.refine,
        "frames": "default flags: no axes declared (+Y up unless the collection lies on a side, front searched)",
        "parts_histogram": {str(n): int(c) for n, c in zip(*np.unique(counts, return_counts=True))},
        "parts_mean": float(counts.mean()),
        "presence_per_index": [round(float(p), 3) for p in present.mean(axis=0)],
        "distinct_index_sets": len(index_sets),
        "most_common_index_sets": [[list(k), v] for k, v in sorted(index_sets.items(), key=lambda kv: -kv[1])[:3]],
    })
    return report


def evaluate(model, files, archive, *, refine: int = 0, workers=None, progress: bool = False, labelling=None,
             adapt=None) -> dict:
    """Segment ``files`` with ``model`` (default flags) and score them against ``archive``."""
    return score(segment_chairs(model, files, archive, refine=refine, workers=workers, progress=progress,
                                labelling=labelling, adapt=adapt))


def summary_lines(report: dict) -> list[str]:
    lines = []
    for protocol, e in report["protocols"].items():
        arm = e["detection"]["arms"]
        lines.append(f"{protocol:20s} " + " ".join(f"{k} {v:.3f}" for k, v in e["iou"].items())
                     + f" | mean(back, seat, legs) {e['mean_iou']:.3f} | accuracy {e['accuracy']:.3f}"
                     + f" | arm F1 {arm['f1']:.3f} (P {arm['precision']:.2f} R {arm['recall']:.2f})")
        lines.append("    absent label, index absent too: " + ", ".join(
            f"{k} {d['absent_kept_absent']:.2f} ({d['shapes_without']} chairs without)"
            for k, d in e["detection"].items() if d["shapes_without"]))
    hist = ", ".join(f"{n}: {c}" for n, c in report["parts_histogram"].items())
    lines.append(f"parts per chair (mean {report['parts_mean']:.2f}): {hist}; {report['distinct_index_sets']} distinct index sets")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="a model file or a bundled model's name")
    ap.add_argument("--part", choices=["validation", "test"], default="validation")
    ap.add_argument("--refine", type=int, default=0)
    ap.add_argument("--limit", type=int, default=0, help="the first N chairs of the part")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--labelling", choices=("nearest", "graphcut"), default=None, help="default: primkit segment's")
    args = ap.parse_args(argv)
    validation, test, archive = split()
    files = validation if args.part == "validation" else test
    if args.limit:
        files = files[: args.limit]
    report = evaluate(args.model, files, archive, refine=args.refine, workers=args.workers, progress=True,
                      labelling=args.labelling)
    print(f"{args.model} on {report['shapes_evaluated']} PartNet {args.part} chairs, refine {args.refine}, "
          f"{report['frames']} ({report['seconds']:.0f} s)")
    for line in summary_lines(report):
        print("  " + line)
    for e in report["errors"]:
        print(e, file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))
    return 1 if report["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())

"""Which chairs have arms, by label against by index: what ``embed --parts arms`` reads of each shape.

Usage::

    python -m scripts.arms_by_label procedural [--count 40]     # procedural chairs, has_arms known
    python -m scripts.arms_by_label partnet                     # PartNet validation chairs 100-218

For each chair, the arms' presence as the descriptor's presence block holds it: **by label**, the
bundled chair labeller's arms on at least 1% of the chair's canonical voxels and 4
(:func:`primkit.embedding.label_boxes` of :func:`primkit.segmentation.bylabel.labelled_voxels`);
**by index**, any of the cuboids the model names ``arms`` present (:class:`PartDescriptor`,
``parts="arms"``). Truth: a procedural chair's ``has_arms``; a PartNet chair has arms when at least
2% of its voxels are arm (the rule of ``scripts/partnet_chairs.py``). The PartNet chairs are the
validation part's 100-218 (those the bundled labeller and index names were not learned from).
Prints accuracy, precision, recall and F1 of each, and the labelling's time per chair.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from primkit import data, io, synthetic  # noqa: E402
from primkit.embedding import PartDescriptor, label_boxes  # noqa: E402
from primkit.model.abstraction import abstract_shapes  # noqa: E402
from primkit.model.bundled import resolve_model  # noqa: E402
from primkit.segmentation.bylabel import labelled_voxels  # noqa: E402
from primkit.segmentation.labeller import read_labeller  # noqa: E402


def scores(pred, truth) -> str:
    pred, truth = np.asarray(pred, bool), np.asarray(truth, bool)
    tp, fp, fn = (pred & truth).sum(), (pred & ~truth).sum(), (~pred & truth).sum()
    p = tp / max(tp + fp, 1)
    r = tp / max(tp + fn, 1)
    f1 = 2 * p * r / max(p + r, 1e-12)
    return f"accuracy {(pred == truth).mean():.3f}  precision {p:.3f}  recall {r:.3f}  F1 {f1:.3f}"


def presence(paths):
    """(by label, by index, seconds of labelling per chair) for the chairs at ``paths``."""
    out = abstract_shapes(paths, "chair")
    labeller = read_labeller(resolve_model("chair"))
    t0 = time.perf_counter()
    found = [labelled_voxels(labeller, a.canonical_shape().occupancy, a.result.canonical) for a in out]
    seconds = (time.perf_counter() - t0) / len(found)
    table = label_boxes([f[0] for f in found], [f[1] for f in found], labeller.names)
    arm = labeller.names.index("arms")
    by_label = table.values.reshape(len(found), -1, 11)[:, arm, 10] > 0.5
    by_index = (PartDescriptor("arms", "presence", part_names=out.model.part_names)
                .fit(out.results).transform(out.results) > 0).any(axis=1)
    return [a.name for a in out], by_label, by_index, seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", choices=["procedural", "partnet"])
    ap.add_argument("--count", type=int, default=40, help="procedural chairs (half drawn with arms)")
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args(argv)
    if args.data == "procedural":
        folder = Path(tempfile.mkdtemp(prefix="arms-by-label-"))
        paths = sorted(synthetic.write_collection(folder, "chair", args.count, seed=args.seed, rates={"has_arms": 0.5}))
        truth = {p.stem: bool(json.loads(p.with_suffix(".json").read_text())["attributes"]["has_arms"]) for p in paths}
    else:
        from scripts.partnet_chairs import split

        validation, _, archive = split()
        paths = validation[100:]
        truth = {}
        for p in paths:
            grid = io.read_voxels(p)
            g = archive.get(data.shape_name(p), grid.occupancy.shape)
            occupied = g.labels[grid.occupancy]
            arm = [i for i, n in enumerate(g.names) if n.split("/")[0] == "arms"][0]
            truth[data.shape_name(p)] = (occupied == arm).mean() >= 0.02
    names, by_label, by_index, seconds = presence(paths)
    has = np.array([truth[n] for n in names])
    print(f"{len(names)} {args.data} chairs, {has.sum()} with arms")
    print(f"by label (labeller's arms, 1% of voxels): {scores(by_label, has)}")
    print(f"by index (cuboids named arms present):    {scores(by_index, has)}")
    print(f"labelling: {1000 * seconds:.0f} ms a chair")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Face accuracy on the COSEG chairs in ``../shared`` before and after adapting the chair model to them.

Usage (from the repository root, primkit importable)::

    python scripts/coseg_adaptation.py [SETTING ...]

Each SETTING is a comma-separated list of :class:`primkit.model.adaptation.AdaptConfig` fields,
e.g. ``pull=0`` or ``steps=2000,learning_rate=3e-4`` (none: the defaults). The 10 chairs
(``coseg_chairs/chairs_101-120`` and ``coseg_chairs/large_chairs``) are adapted to all together,
without their labels; each folder is then scored against its own ``gt/*.seg`` under the paper's
protocol (collection-majority mapping, :func:`primkit.segmentation.evaluation.evaluate`), with the
default flags of ``primkit segment``. Printed per setting: the mean face accuracy over the 10, each
chair's, the seconds the adaptation took and :func:`primkit.model.adaptation.index_agreement`.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from primkit import data
from primkit.model.abstraction import load_model
from primkit.model.adaptation import AdaptConfig, adapt, index_agreement
from primkit.segmentation import Segmenter
from primkit.segmentation.evaluation import evaluate, read_ground_truth

COSEG = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "coseg_chairs"
FOLDERS = ("chairs_101-120", "large_chairs")


def parse_setting(text: str) -> AdaptConfig:
    fields = {f.name: f.type for f in dataclasses.fields(AdaptConfig)}
    values = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        key, _, value = item.partition("=")
        if key not in fields:
            raise ValueError(f"{key!r} is not a setting of AdaptConfig ({', '.join(fields)})")
        kind = {"int": int, "float": float, "str": str}[str(fields[key]).split(" | ")[0]]
        values[key] = kind(value)
    return AdaptConfig(**values)


def face_accuracy(model) -> dict:
    """``{chair: face accuracy}`` under the paper's protocol, each folder mapped on its own."""
    segmenter = Segmenter(model)
    out = {}
    for folder in FOLDERS:
        files = sorted((COSEG / folder / "shapes").glob("*.off"))
        segs, errors = segmenter.segment_files(files, workers=1, progress=False)
        if errors:
            raise RuntimeError("; ".join(errors))
        truths = [read_ground_truth(COSEG / folder / "gt" / f"{s.name}.seg", len(s.faces)) for s in segs]
        shapes = evaluate(segs, truths).protocols["collection-majority"].shapes
        out.update({s.name: shapes[s.name].faces for s in segs})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("settings", nargs="*", help="AdaptConfig fields, e.g. pull=0 (default: the defaults)")
    args = ap.parse_args(argv)
    parent = load_model("chair")
    files = [f for folder in FOLDERS for f in sorted((COSEG / folder / "shapes").glob("*.off"))]
    coll = data.prepare_collection(files, parent.settings, workers=1, progress=False)
    shapes = [coll[i] for i in range(len(coll))]
    base = face_accuracy(parent)
    print(f"parent: mean {np.mean(list(base.values())):.4f} " + " ".join(f"{k} {v:.3f}" for k, v in base.items()))
    before = parent.predict(shapes, align="auto")
    for text in args.settings or [""]:
        config = parse_setting(text)
        t0 = time.perf_counter()
        child = adapt(parent, shapes, config, parent_name="chair")
        seconds = time.perf_counter() - t0
        acc = face_accuracy(child)
        worst = min(acc[k] - base[k] for k in acc)
        agreement = index_agreement(before, child.predict(shapes, align="auto"), shapes)
        print(f"{text or 'defaults'}: mean {np.mean(list(acc.values())):.4f} (largest drop {-worst:+.3f}) "
              + " ".join(f"{k} {v:.3f}" for k, v in acc.items())
              + f" | {seconds:.0f} s | index agreement {agreement:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What ``--align auto`` and ``--refine N`` cost and buy, with the bundled chair model.

On procedural chairs (made here, never seen by the model, which was trained on ShapeNet):

* network only (with pruning), per shape;
* ``align="auto"`` on copies turned into random axis-aligned orientations: how often the original
  orientation comes back, and its cost, against the straightforward way (each of the 24
  orientations sent through the network and scored as its own call);
* ``refine=N``: Chamfer-L1 and IoU before and after, and its cost with all shapes refined as one
  batch against one shape at a time.

Usage: ``python benchmarks/bench_inference_options.py [--shapes 16] [--steps 200] [--quick]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np


from benchmarks._common import table  # noqa: E402
from primkit import data, io, synthetic  # noqa: E402
from primkit.model import orientation  # noqa: E402
from primkit.model.abstractor import Abstractor  # noqa: E402
from primkit.model.fitting import fit_losses  # noqa: E402
from primkit.metrics import ChamferConvention, score, summarize  # noqa: E402


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def align_one_call_per_orientation(model, shape):
    """The straightforward alignment: 24 separate network calls and 24 separate scorings."""
    best, best_loss = None, np.inf
    for a in orientation.AXIS_ROTATIONS:
        turned = orientation.rotate_prepared(shape, a)
        (r,) = model.predict([turned], prune_threshold=None)
        loss = fit_losses([r.canonical], [turned]).total[0]
        if loss < best_loss:
            best, best_loss = turned, loss
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", type=int, default=16)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--quick", action="store_true", help="4 shapes, 50 steps")
    args = ap.parse_args(argv)
    if args.quick:
        args.shapes, args.steps = 4, 50
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} cores)")
    model = Abstractor.load("chair")
    gen = synthetic.generate("chair", args.shapes, seed=2024)
    shapes = [data.prepare(io.Mesh(s.vertices, s.faces), name=f"chair{i}") for i, s in enumerate(gen)]
    conv = ChamferConvention()
    n = len(shapes)

    def summary(results, on):
        s = summarize([score(r.canonical, r.canonical_shape(x), conv) for r, x in zip(results, on)])
        return s.chamfer.mean, s.iou.mean, s.parts.mean

    plain, t_plain = _timed(lambda: model.predict(shapes))
    rows = [["network + pruning", f"{1000 * t_plain / n:.1f}", *(f"{v:.4f}" for v in summary(plain, shapes)), "-"]]

    rng = np.random.default_rng(0)
    turns = [orientation.AXIS_ROTATIONS[rng.integers(1, 24)] for _ in shapes]
    turned = [orientation.rotate_prepared(s, a) for s, a in zip(shapes, turns)]
    aligned, t_align = _timed(lambda: model.predict(turned, align="auto"))
    back = sum(bool(np.allclose(r.frame.rotation, s.frame.rotation)) for r, s in zip(aligned, shapes))
    rows.append(["turned, align auto (24 in one batch)", f"{1000 * t_align / n:.1f}", *(f"{v:.4f}" for v in summary(aligned, turned)),
                 f"{back}/{n}"])
    simple, t_simple = _timed(lambda: [align_one_call_per_orientation(model, s) for s in turned])
    back_simple = sum(bool(np.allclose(x.frame.rotation, s.frame.rotation)) for x, s in zip(simple, shapes))
    rows.append(["turned, 24 calls per shape (straightforward)", f"{1000 * t_simple / n:.1f}", "", "", "", f"{back_simple}/{n}"])
    unaligned = model.predict(turned)
    rows.append(["turned, no alignment", "", *(f"{v:.4f}" for v in summary(unaligned, turned)), f"0/{n}"])

    refined, t_ref = _timed(lambda: model.predict(shapes, refine=args.steps))
    rows.append([f"refine {args.steps} steps, all shapes in one batch", f"{1000 * t_ref / n:.1f}", *(f"{v:.4f}" for v in summary(refined, shapes)), "-"])
    k = min(4, n)
    _, t_one = _timed(lambda: [model.predict([s], refine=args.steps) for s in shapes[:k]])
    rows.append([f"refine {args.steps} steps, one shape at a time", f"{1000 * t_one / k:.1f}", "", "", "", "-"])
    table(f"bundled chair model on {n} procedural chairs (ms per shape include pruning; {conv.describe()})",
          ["method", "ms/shape", "Chamfer-L1", "IoU", "parts", "orientation recovered"], rows)
    print(f"\nload average at end: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

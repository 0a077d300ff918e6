"""The plugins on a collection: a pyvista ``MultiBlock`` segmented in one batch
(``blocks.primkit.segment``) against a loop of ``block.primkit.segment`` over its blocks, and the
VTK filter re-run in a pipeline (model loaded once) against a fresh filter per update; the labels
are checked equal.

    python benchmarks/bench_plugins.py [--shapes 16]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from _common import table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shapes", type=int, default=16)
    args = ap.parse_args(argv)
    import numpy as np
    import pyvista as pv
    import torch

    torch.set_num_threads(1)
    from primkit import synthetic
    from primkit.model.abstraction import load_model
    from primkit.plugins.vtk_filter import PrimkitSegmentation

    print(f"load average at start: {os.getloadavg()[0]:.1f}")
    model = load_model("chair")
    with tempfile.TemporaryDirectory() as tmp:
        paths = synthetic.write_collection(Path(tmp), "chair", args.shapes, seed=3)
        blocks = pv.MultiBlock({p.stem: pv.read(p) for p in paths})
        blocks[0].primkit.segment(model=model)  # warm up (imports, first inference)
        rows, same = [], True
        for label, options in (("frames found (default)", {}), ("axes given (+y up, +x front)", {"up": "+y", "front": "+x"})):
            t = time.perf_counter()
            batch = blocks.primkit.segment(model=model, **options)
            t_batch = time.perf_counter() - t
            t = time.perf_counter()
            loop = [b.primkit.segment(model=model, **options) for b in blocks]
            t_loop = time.perf_counter() - t
            same &= all(np.array_equal(a["part"], b["part"]) for a, b in zip(batch, loop))
            rows += [[f"{label}: blocks.primkit.segment (one batch)", f"{t_batch:.2f}", f"{t_batch / args.shapes * 1000:.0f} ms"],
                     [f"{label}: loop of block.primkit.segment", f"{t_loop:.2f}", f"{t_loop / args.shapes * 1000:.0f} ms"]]

        reader = pv.read(paths[0])
        f = PrimkitSegmentation(Model="chair")
        f.SetInputDataObject(0, reader)
        f.Update()
        t = time.perf_counter()
        for i in range(5):
            reader.points[:, 0] += 0.01  # the input changes: the filter runs again
            reader.Modified()
            f.Update()
        t_rerun = (time.perf_counter() - t) / 5
        t = time.perf_counter()
        for i in range(5):
            g = PrimkitSegmentation(Model="chair")
            g.SetInputDataObject(0, reader)
            g.Update()
        t_fresh = (time.perf_counter() - t) / 5
    table(f"pyvista accessor on a MultiBlock of {args.shapes} procedural chairs (bundled chair model)",
          ["way", "seconds", "per shape"], rows,
          note=f"same labels batch and loop: {same} (with frames found, a batch decides the up axis once for the "
               "collection: every shape in all 24 turns)")
    table("VTK filter, one update after its input changed", ["way", "seconds per update"],
          [["the same filter (model kept)", f"{t_rerun:.3f}"], ["a new filter each time (model loaded)", f"{t_fresh:.3f}"]])
    print(f"load average at end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

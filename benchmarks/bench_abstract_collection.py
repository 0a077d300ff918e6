"""Benchmark: ``primkit abstract`` over a collection of ShapeNetVox32 chairs from a cold cache.

    python benchmarks/bench_abstract_collection.py [--shapes 847] [--workers W] [--quick] [--before REV]

Each way in a fresh process, from an empty cache, the bundled chair model, in one run:

* today's: binvox grids prepared from the grid itself (``primkit.geometry.voxels``), pruning of
  all shapes of a batch at once (``primitives.prune_covered_many``);
* the first way: the same command with the grids prepared through their boundary mesh (the
  mesh machinery: BVH closest points, voxeliser, triangle samples; what ``prepare`` did before)
  and pruning one shape at a time (``primitives.prune_covered``).

* with ``--before REV``: the command of primkit as it was at git revision ``REV`` (``git archive``
  into a temporary folder, run in a fresh process with this interpreter, its own bundled model).

Shapes per second of the whole command (``abstract_shapes`` + writing each shape's JSON and PLY),
and the part of it spent preparing. Nothing here asserts a time: it prints and exits 0.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from _common import load_line, run_at_revision, run_isolated, table  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "shapenetvox32" / "03001627"


def _first_way() -> None:
    """Patch preparation and pruning back to the first way (inherited by forked workers)."""
    from primkit import data, geometry, primitives

    def prepare_voxels(grid, settings, name, source):
        occ, frame = data.preparation._canonical_voxels(grid, settings)
        v, f = geometry.voxel_boundary_mesh(occ)
        solid = geometry.occupancy_grid(v, f, settings.resolution)
        surface = geometry.surface_voxels(v, f, settings.resolution) & solid
        return data.preparation._from_surface(v, f, solid, surface, settings, frame, name=name, source=source, kind="voxels")

    def prune_many(boxes_list, *args, **kwargs):
        return [primitives.prune_covered(b, *args, **kwargs) for b in boxes_list]

    data.preparation._prepare_voxels = prepare_voxels
    primitives.prune_covered_many = prune_many  # the abstractor calls it through the module


def run_abstract(files: list, workers, first: bool) -> dict:
    import torch

    if first:
        _first_way()
    from primkit.cli import main

    tmp = Path(tempfile.mkdtemp(prefix="bench_abstract."))
    args = ["abstract", *files, "--model", "chair", "-o", str(tmp / "out"), "--cache", str(tmp / "cache"),
            "--up", "+y", "--front", "+x"]
    if workers:
        args += ["--workers", str(workers)]
    import contextlib
    import io

    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(args)
    seconds = time.perf_counter() - t0
    t1 = time.perf_counter()
    from primkit import data

    data.prepare_collection(files, cache_dir=tmp / "cache", workers=1, progress=False)  # all cached now
    lookup = time.perf_counter() - t1
    written = len(list((tmp / "out").glob("*.json")))
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)
    return {"code": code, "seconds": seconds, "written": written, "lookup": lookup, "threads": torch.get_num_threads()}


_AT_REVISION = """
import contextlib, io, json, sys, tempfile, time
from pathlib import Path
from primkit.cli import main
files, workers = json.loads(sys.argv[1]), sys.argv[2]
tmp = Path(tempfile.mkdtemp(prefix="bench_abstract_rev."))
args = ["abstract", *files, "--model", "chair", "-o", str(tmp / "out"), "--cache", str(tmp / "cache")]
if workers != "0":
    args += ["--workers", workers]
t0 = time.perf_counter()
with contextlib.redirect_stdout(io.StringIO()):
    code = main(args)
print(json.dumps({"code": code, "seconds": time.perf_counter() - t0, "written": len(list((tmp / "out").glob("*.json")))}))
"""


def abstract_at_revision(rev: str, files: list, workers) -> dict | None:
    """``primkit abstract`` of primkit at git revision ``rev``, cold cache, in a fresh process."""
    import json

    out, why = run_at_revision(rev, _AT_REVISION, json.dumps(files), str(workers or 0))
    if out is None:
        print(f"  (--before {rev}: {why})")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shapes", type=int, default=847)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--quick", action="store_true", help="60 shapes")
    ap.add_argument("--before", default=None, metavar="REV", help="also run primkit abstract as it was at this git revision")
    args = ap.parse_args(argv)
    if args.quick:
        args.shapes = 60
    if not DATA.is_dir():
        print(f"no ShapeNetVox32 chairs at {DATA}: nothing to measure")
        return 0
    from primkit import data

    files = [str(p) for p in data.find_shape_files(DATA)[: args.shapes]]
    print(f"{len(files)} ShapeNetVox32 chairs, cold cache, bundled chair model; {load_line()}")
    rows, rates = [], {}
    for label, first in (("first way: boundary mesh, pruning per shape", True), ("today's", False)):
        r = run_isolated(run_abstract, files, args.workers, first)
        rates[label] = r["written"] / r["seconds"]
        rows.append([label, r["code"], r["written"], f"{r['seconds']:.1f}", f"{rates[label]:.1f}"])
        print(f"  {label}: {r['seconds']:.1f} s; {load_line()}", flush=True)
    note = f"today's / first: {rates[rows[1][0]] / rates[rows[0][0]]:.2f}x shapes per second"
    if args.before:
        r = abstract_at_revision(args.before, files, args.workers)
        if r is not None:
            label = f"primkit at {args.before}"
            rates[label] = r["written"] / r["seconds"]
            rows.append([label, r["code"], r["written"], f"{r['seconds']:.1f}", f"{rates[label]:.1f}"])
            print(f"  {label}: {r['seconds']:.1f} s; {load_line()}", flush=True)
            note += f"; today's / primkit at {args.before}: {rates[rows[1][0]] / rates[label]:.2f}x"
    table("primkit abstract, cold cache", ["way", "exit", "shapes", "seconds", "shapes/s"], rows, note=f"{note}; {load_line()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

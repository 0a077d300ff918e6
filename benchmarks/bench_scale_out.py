"""Benchmark: ``primkit segment`` over a collection, on this machine's process pool against the
scale-out ways (a Dask cluster, a Ray instance, two job-array shards).

    python benchmarks/bench_scale_out.py [--shapes 24] [--quick]

Each way in a fresh process, from an empty cache, over the same procedural chairs (meshes), the
bundled chair model, ``--semantic`` outputs:

* local: ``--workers 2`` (the process pool, the straightforward way on one machine);
* dask: ``--executor ADDRESS`` of a ``distributed.LocalCluster`` of 2 worker processes started
  before the clock (as a cluster would be);
* ray: ``--executor ray`` on a Ray instance of 2 CPUs started before the clock;
* shards: ``--shard 1/2`` then ``--shard 2/2`` (``--workers 2`` each) into one folder, each in a
  fresh process of its own, one after the other (a job array runs them side by side on two
  machines: the slower shard is its wall time).

Seconds of the whole command, shapes per second, and whether the per-shape outputs equal the local
run's (labels and coloured meshes byte for byte). On one machine the engines cannot be faster than
its own pool; what this measures is what they cost on top of the work. Nothing here asserts a
time: it prints and exits 0.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
import time
from pathlib import Path

from _common import load_line, run_isolated, table  # noqa: E402


def _digests(folder: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())
            if p.name.endswith((".seg", ".parts.ply"))}


def run_way(way: str, inputs: str, folder: str, shard: str | None = None) -> dict:
    """One way in this (fresh) process: seconds of the command, digests of the outputs so far."""
    import contextlib
    import io

    import torch

    torch.set_num_threads(1)
    from primkit.cli import main

    tmp = Path(folder)
    argv = ["segment", inputs, "--model", "chair", "-o", str(tmp / "out"), "--cache", str(tmp / "cache"), "--semantic"]
    with contextlib.ExitStack() as stack:
        if way == "dask":
            import distributed

            cluster = stack.enter_context(distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                                   dashboard_address=None))
            argv += ["--executor", cluster.scheduler_address]
        elif way == "ray":
            import ray

            ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
            stack.callback(ray.shutdown)
            argv += ["--executor", "ray"]
        else:
            argv += ["--workers", "2"] + (["--shard", shard] if shard else [])
        start = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
        seconds = time.perf_counter() - start
    if code != 0:
        raise RuntimeError(f"primkit {' '.join(argv)} exited {code}")
    return {"seconds": [seconds], "digests": _digests(tmp / "out")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", type=int, default=24)
    parser.add_argument("--quick", action="store_true", help="8 shapes")
    args = parser.parse_args()
    count = 8 if args.quick else args.shapes

    from primkit import synthetic

    root = Path(tempfile.mkdtemp(prefix="bench_scale_out."))
    synthetic.write_collection(root / "in", "chair", count, seed=3)
    print(f"primkit segment over {count} procedural chairs (meshes), cold cache each way; {load_line()}")
    ways = ["local", "dask", "ray", "shards"]
    results, rows = {}, []
    for way in ways:
        if way in ("dask", "ray"):
            try:
                __import__("distributed" if way == "dask" else "ray")
            except ImportError:
                rows.append([way, "not installed", "", "", ""])
                continue
        folder = tempfile.mkdtemp(prefix=f"bench_scale_out.{way}.")
        if way == "shards":  # each shard in a fresh process of its own, as a job array's tasks
            runs = [run_isolated(run_way, way, str(root / "in"), folder, f"{k}/2") for k in (1, 2)]
            results[way] = {"seconds": [r["seconds"][0] for r in runs], "digests": runs[-1]["digests"]}
        else:
            results[way] = run_isolated(run_way, way, str(root / "in"), folder)
    local = results["local"]
    for way, r in results.items():
        wall = max(r["seconds"]) if way == "shards" else sum(r["seconds"])
        detail = " + ".join(f"{s:.1f}" for s in r["seconds"])
        same = "yes" if r["digests"] == local["digests"] else \
            f"{sum(r['digests'].get(k) == v for k, v in local['digests'].items())}/{len(local['digests'])} files"
        rows.append([way, f"{wall:.1f} ({detail})", f"{count / wall:.2f}", f"{sum(local['seconds']) / wall:.2f}x", same])
    table("primkit segment: seconds, shapes per second, against the local process pool",
          ["way", "seconds", "shapes/s", "vs local", "outputs = local's"], rows,
          note="shards: the slower shard's seconds (a job array runs them side by side); both are shown")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: the preparation cache, its bytes per shape and how fast training starts from it.

    python benchmarks/bench_cache.py [--quick] [--shapes N] [--batches B]

In one run, on the same prepared ShapeNetVox32 chairs (procedural chairs without ``../shared``):

1. Bytes per shape: the cache of today (``primkit.data.CACHE_FORMAT`` 2: segments of compact
   codes, the default, or of float32 arrays, ``PRIMKIT_CACHE_CODES=exact``) against the first
   format, one ``.npz`` of float32 arrays per shape (``PreparedShape.save``, what the cache held
   before), written from the same shapes.
2. Training's start on N shapes, each in a fresh process: the first format's way (load every
   entry, stack them into ``ShapeTensors``) against today's (``prepare_collection`` finding every
   shape in the cache, checksums checked, and ``ShapeTensors`` over the collection, which loads
   nothing); then B random batches of 32 from each. Peak resident memory (``ru_maxrss``, which
   counts the memory-mapped cache pages read, shared with the page cache) and anonymous memory
   (``RssAnon``: what the process itself holds) after the batches, for N and N / 5 shapes.

Nothing here asserts a time: it prints and exits 0.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from _common import load_line, run_isolated, table  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "shapenetvox32" / "03001627"


def _anon_kib() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("RssAnon:"):
            return int(line.split()[1])
    return -1


def _batches(shapes, count: int) -> float:
    import torch

    g = torch.Generator().manual_seed(0)
    t0 = time.perf_counter()
    for _ in range(count):
        index = torch.randint(0, len(shapes), (32,), generator=g)
        shapes.batch(index, 1000, g, "cpu")
    return (time.perf_counter() - t0) / max(count, 1)


def start_first_format(entries: list, batches: int) -> dict:
    import torch

    from primkit import data
    from primkit.model.training import ShapeTensors

    from _common import maxrss_kib

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    shapes = ShapeTensors([data.PreparedShape.load(p) for p in entries])
    shapes.batch(torch.arange(min(32, len(shapes))), 1000, torch.Generator().manual_seed(0), "cpu")
    start = time.perf_counter() - t0
    per_batch = _batches(shapes, batches)
    return {"start": start, "batch": per_batch, "maxrss": maxrss_kib(), "anon": _anon_kib()}


def start_cache(files: list, cache: str, batches: int, compact: bool = False) -> dict:
    import torch

    from primkit import data
    from primkit.model.training import ShapeTensors

    from _common import maxrss_kib

    torch.set_num_threads(1)
    t0 = time.perf_counter()
    coll = data.prepare_collection(files, cache_dir=cache, workers=1, progress=False, compact=compact)
    assert not coll.errors and all(seg.compact == compact for seg, _ in coll.entries)
    t1 = time.perf_counter()
    shapes = ShapeTensors(coll)
    shapes.batch(torch.arange(min(32, len(shapes))), 1000, torch.Generator().manual_seed(0), "cpu")
    start = time.perf_counter() - t0
    per_batch = _batches(shapes, batches)
    return {"start": start, "lookup": t1 - t0, "batch": per_batch, "maxrss": maxrss_kib(), "anon": _anon_kib(),
            "shapes": len(coll)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="200 shapes, 20 batches")
    ap.add_argument("--shapes", type=int, default=5000)
    ap.add_argument("--batches", type=int, default=100)
    ap.add_argument("--first-format-shapes", type=int, default=2000,
                    help="shapes the first format's start is measured on (it holds them all in memory: "
                         "about 1.2 GiB per 1,000; its time grows linearly, extrapolated to --shapes)")
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args(argv)
    if args.quick:
        args.shapes, args.batches, args.first_format_shapes = 200, 20, 200

    from primkit import data, synthetic

    tmp = Path(tempfile.mkdtemp(prefix="bench_cache."))
    if DATA.is_dir():
        files = data.find_shape_files(DATA)[: args.shapes]
        source = f"{len(files)} ShapeNetVox32 chairs"
    else:
        files = synthetic.write_collection(tmp / "shapes", "chair", min(args.shapes, 300), seed=0)
        source = f"{len(files)} procedural chairs (no ../shared/data)"
    print(f"{source}; {load_line()}")
    cache = tmp / "cache"
    t0 = time.perf_counter()
    coll = data.prepare_collection(files, cache_dir=cache, workers=args.workers, progress=True, compact=False)
    prep = time.perf_counter() - t0
    root = cache / f"v{data.CACHE_FORMAT}"
    float_segments = sorted(p for p in root.iterdir() if not p.name.startswith("."))
    settings = coll.settings
    for folder in float_segments:  # the same shapes in compact codes (what preparing with compact=True writes)
        seg = data.CacheSegment.open(folder)
        rows = [(key, data.cache.encode_row(seg.shape(j), True)) for j, key in enumerate(seg.keys())]
        data.CacheSegment.from_rows(settings, rows, True).save(root)
    compact_segments = sorted(set(p for p in root.iterdir() if not p.name.startswith(".")) - set(float_segments))
    old = tmp / "first-format"
    old.mkdir()
    entries = []
    k = min(len(coll), args.first_format_shapes)
    for i in range(k):  # the first format's start grows linearly with the shapes: measured on k of them
        p = old / f"{i:06d}.npz"
        coll[i].save(p)
        entries.append(p)
    n = len(coll)
    def size(folders):
        return sum(f.stat().st_size for d in folders for f in d.iterdir()) / n

    first = sum(p.stat().st_size for p in entries) / len(entries)
    table("Bytes per shape", ["format", "KiB per shape", "ratio", f"all {n}"],
          [["first: one .npz of float32 arrays", f"{first / 1024:.1f}", "1.00", f"{first * n / 2**20:.0f} MiB"]]
          + [[f"today: segments of {what}", f"{b / 1024:.1f}", f"{b / first:.3f}", f"{b * n / 2**20:.0f} MiB"]
             for what, b in (("float32", size(float_segments)), ("compact codes (default)", size(compact_segments)))],
          note=f"cold preparation of the {n} shapes into the cache: {prep:.1f} s ({n / prep:.1f} shapes/s)")

    rows = []
    small = max(1, n // 5)
    runs = [(f"first format, {k} shapes", start_first_format, (entries[:k], args.batches))]
    if small < k:
        runs.append((f"first format, {small} shapes", start_first_format, (entries[:small], args.batches)))
    names = [str(f) for f in files]
    runs += [(f"today's cache, float32, {n} shapes", start_cache, (names, str(cache), args.batches, False)),
             (f"today's cache, float32, {small} shapes", start_cache, (names[:small], str(cache), args.batches, False)),
             (f"today's cache, compact, {small} shapes", start_cache, (names[:small], str(cache), args.batches, True)),
             (f"today's cache, compact, {n} shapes", start_cache, (names, str(cache), args.batches, True))]
    starts = {}
    for label, fn, a in runs:
        r = run_isolated(fn, *a)
        starts[label] = r["start"]
        rows.append([label, f"{r['start']:.2f}", f"{1000 * r['batch']:.1f}", f"{r['maxrss'] / 1024:.0f}",
                     f"{r['anon'] / 1024:.0f}"])
    table("Training's start and its batches (fresh process each, 1 thread; a collection over 1 GiB decoded is streamed)",
          ["run", "start s", "ms per batch of 32", "peak RSS MiB", "anonymous MiB after batches"], rows,
          note=f"start: everything before the first step (today's: the files hashed and found in the cache, "
               f"checksums checked); {args.batches} batches of 32 shapes, 1,000 points each; {load_line()}")
    old_n = starts[runs[0][0]] * n / k
    for label in (runs[-4][0], runs[-1][0]):
        print(f"\nstart on {n} shapes: first format {old_n:.1f} s{' (extrapolated from %d)' % k if k < n else ''}, "
              f"{label} {starts[label]:.2f} s: {starts[label] / old_n:.3f} of the time")
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

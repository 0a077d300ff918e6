"""Benchmark: adapting the chair model to a collection (``primkit.model.adaptation.adapt``).

    python benchmarks/bench_adapt.py [--meshes 20] [--grids 1000] [--small-grids 100] [--steps N] [--repeats 1]
        [--ways today "first version" baseline] [--baseline DIR] [--cold-grids]

In one run, each way in a fresh process (``run_isolated``; peak RSS is that process's), alternating:

* today's: the parent's answers for the pull computed once per shape before the steps, batches
  streamed from the cache (:class:`primkit.data.PreparedCollection` passed as it is);
* the straightforward way (the first version): every prepared shape decoded into a list held in
  memory, and the parent's network run again on each batch for the pull (``parent_pass="every-step"``);
* ``baseline``: today's way run by the code in ``--baseline DIR`` (a ``primkit`` package folder's
  parent, e.g. ``git archive COMMIT primkit | tar -x -C DIR``), put first on the path of its
  process: a former version timed in the same run as this one.

Each run also prints where its time went: preparing, the frame search with the parent's answers
(``_frames_and_answers``), the steps, and the index agreement.

Cases: ``--meshes`` procedural chairs written as OBJ files, each way from its own cold cache
(preparing counted); ``--grids`` and ``--small-grids`` ShapeNetVox32 chairs
(``../shared/data/shapenetvox32/03001627``), prepared once into a shared cache first (that time
printed apart), then adapted by each way (frames found with ``align="auto"``, as by default); with
``--cold-grids`` each way prepares the grids into its own new cache instead (counted in its
total, as a user's first run).
Peak RSS for the small and the large grid collections shows whether memory is flat in the
collection's size; it counts the cache's memory-mapped pages a process has read (file-backed, shared,
dropped by the kernel under pressure), so the anonymous RSS at the end (``RssAnon``: the process's own
memory) is printed beside it. Nothing here asserts a time: it prints and exits 0. One torch thread.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import load_line, maxrss_kib, run_isolated, table  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "shapenetvox32" / "03001627"


def _one(way: str, files: list, cache: str, steps, workers: int, baseline: str | None = None) -> dict:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if way == "baseline":
        sys.path.insert(0, str(baseline))
    import torch

    from primkit import data
    from primkit.model import adaptation
    from primkit.model.abstractor import Abstractor
    from primkit.model.adaptation import AdaptConfig, adapt, default_steps

    if way == "baseline" and not adaptation.__file__.startswith(str(Path(baseline).resolve())):
        raise RuntimeError(f"--baseline {baseline}: primkit was imported from {adaptation.__file__}")
    phases = _time_phases(adaptation)
    torch.set_num_threads(1)
    parent = Abstractor.load("chair")
    t0 = time.perf_counter()
    coll = data.prepare_collection(files, data.PrepareSettings(resolution=parent.resolution), cache_dir=cache,
                                   workers=workers, progress=False)
    t1 = time.perf_counter()
    config = AdaptConfig() if steps is None else AdaptConfig(steps=steps)  # None: default_steps(count)
    if way in ("today", "baseline"):
        adapt(parent, coll, config)
    else:
        shapes = [coll[i] for i in range(len(coll))]
        adapt(parent, shapes, AdaptConfig(**{**config.to_dict(), "parent_pass": "every-step"}))
    t2 = time.perf_counter()
    steps = default_steps(len(coll)) if config.steps is None else config.steps
    anon = _rss_anon_kib()
    trimmed = _rss_anon_kib(trim=True)
    return {"anon_mib": anon / 1024, "trimmed_mib": trimmed / 1024, "prepare_s": t1 - t0, "adapt_s": t2 - t1, "total_s": t2 - t0, "rss_mib": maxrss_kib() / 1024,
            "steps": steps, "shapes": len(coll), **phases}


def _time_phases(adaptation) -> dict:
    """Wrap the adaptation's three phases so that their seconds land in the returned dict."""
    phases = {}
    for name, key in (("_frames_and_answers", "frames_s"), ("_steps", "steps_s"), ("_stream_agreement", "agreement_s")):
        inner = getattr(adaptation, name)

        def timed(*args, _inner=inner, _key=key, **kwargs):
            t = time.perf_counter()
            try:
                return _inner(*args, **kwargs)
            finally:
                phases[_key] = phases.get(_key, 0.0) + time.perf_counter() - t

        setattr(adaptation, name, timed)
    return phases


def _row(label: str, way: str, res: dict) -> list:
    return [label, way, res["steps"], f"{res['prepare_s']:.1f}", f"{res.get('frames_s', 0):.1f}",
            f"{res.get('steps_s', 0):.1f}", f"{res.get('agreement_s', 0):.1f}", f"{res['adapt_s']:.1f}",
            f"{res['total_s']:.1f}", f"{res['rss_mib']:.0f}", f"{res['anon_mib']:.0f}", f"{res['trimmed_mib']:.0f}"]


def _rss_anon_kib(trim: bool = False) -> int:
    """The process's own resident memory (``RssAnon``, KiB; 0 off Linux). ``trim``: after glibc's
    ``malloc_trim(0)`` hands freed heap pages back, so that what the process still holds is told
    apart from what the allocator kept after the frame search (measured: that retention is what grew
    with the collection, not live data)."""
    status = Path("/proc/self/status")
    if not status.exists():
        return 0
    if trim:
        import ctypes

        try:
            ctypes.CDLL("libc.so.6").malloc_trim(0)
        except (OSError, AttributeError):
            return 0
    for line in status.read_text().splitlines():
        if line.startswith("RssAnon:"):
            return int(line.split()[1])
    return 0


def _write_meshes(folder: Path, count: int) -> list:
    import trimesh

    from primkit import synthetic

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i, s in enumerate(synthetic.generate("chair", count, seed=7)):
        path = folder / f"chair{i:03d}.obj"
        trimesh.Trimesh(s.vertices, s.faces, process=False).export(path)
        out.append(str(path))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", type=int, default=20)
    ap.add_argument("--grids", type=int, default=1000)
    ap.add_argument("--small-grids", type=int, default=100)
    ap.add_argument("--steps", type=int, default=None, help="adaptation steps (default: AdaptConfig's)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--ways", nargs="+", default=["today", "first version"],
                    choices=["today", "first version", "baseline"])
    ap.add_argument("--baseline", default=None, help="folder holding a former version's primkit package")
    ap.add_argument("--cold-grids", action="store_true", help="each way prepares the grids into its own new cache")
    args = ap.parse_args()
    if "baseline" in args.ways and not args.baseline:
        ap.error("the way 'baseline' needs --baseline DIR")
    ways = tuple(args.ways)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-adapt-") as tmp:
        tmp = Path(tmp)
        print(load_line(), flush=True)
        if args.meshes:
            files = _write_meshes(tmp / "meshes", args.meshes)
            for r in range(args.repeats):
                for way in ways:
                    res = run_isolated(_one, way, files, str(tmp / f"cache-{way}-{r}"), args.steps, args.workers,
                                       args.baseline)
                    rows.append(_row(f"{args.meshes} meshes, cold", way, res))
                    print(rows[-1], load_line(), flush=True)
        grids = sorted(str(p) for p in DATA.glob("*/model.binvox"))
        sizes = [n for n in (args.small_grids, args.grids) if n]
        if sizes and len(grids) >= max(sizes) and args.cold_grids:
            for r in range(args.repeats):
                for n in sizes:
                    for way in ways:
                        res = run_isolated(_one, way, grids[:n], str(tmp / f"grids-{n}-{way}-{r}"), args.steps,
                                           args.workers, args.baseline)
                        rows.append(_row(f"{n} grids, cold", way, res))
                        print(rows[-1], load_line(), flush=True)
        elif sizes and len(grids) >= max(sizes):
            from primkit import data

            t0 = time.perf_counter()
            data.prepare_collection(grids[: max(sizes)], data.PrepareSettings(resolution=32), cache_dir=tmp / "grids",
                                    workers=args.workers, progress=False)
            print(f"preparing {max(sizes)} grids, cold cache, {args.workers} workers: {time.perf_counter() - t0:.1f} s",
                  flush=True)
            for r in range(args.repeats):
                for n in sizes:
                    for way in ways:
                        res = run_isolated(_one, way, grids[:n], str(tmp / "grids"), args.steps, args.workers,
                                           args.baseline)
                        rows.append(_row(f"{n} grids, warm", way, res))
                        print(rows[-1], load_line(), flush=True)
        elif sizes:
            print(f"{DATA}: fewer than {max(sizes)} grids, grid cases skipped")
    table("adapting the chair model (one torch thread)",
          ["collection", "way", "steps", "prepare s", "frames s", "steps s", "agreement s", "adapt s", "total s",
           "peak RSS MiB", "anon RSS MiB at end", "anon after trim"], rows, note=load_line())


if __name__ == "__main__":
    main()

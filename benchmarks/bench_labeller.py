"""What the part labeller adds to ``primkit segment``: the same collection segmented with and without
the model's labeller, alternating in one run (the preparation cache warm for both).

Each round times :meth:`primkit.segmentation.Segmenter.segment_files` (abstraction from the
preparation cache, then each file read and labelled in the worker processes, as ``primkit segment``
runs it) once with ``labeller=None`` (names by part index) and once with the model file's labeller
(``--semantic`` with a labelled model), the order alternating between rounds.

Usage (from the repository root)::

    primkit name-parts CHAIRS... --model chair --labels ../shared/data/partnet_chair_boxes -o named.safetensors
    python -m benchmarks.bench_labeller named.safetensors [--count 600] [--rounds 3] [--workers N]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from primkit import data
from primkit.segmentation import Segmenter
from primkit.segmentation.labeller import read_labeller

CHAIRS = Path(__file__).resolve().parents[2] / "shared" / "data" / "shapenetvox32" / "03001627"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="a model file with a labeller (primkit name-parts)")
    ap.add_argument("--chairs", type=Path, default=CHAIRS)
    ap.add_argument("--count", type=int, default=600)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--grid-sample", type=int, default=None, choices=[1, 2, 8],
                    help="label with this grid_sample instead of the file's (LabellerSettings)")
    args = ap.parse_args(argv)
    labeller = read_labeller(args.model)
    if labeller is None:
        raise SystemExit(f"{args.model}: no labeller in this model file (primkit name-parts writes one)")
    if args.grid_sample is not None:
        labeller = replace(labeller, settings=replace(labeller.settings, grid_sample=args.grid_sample))
    files = data.find_shape_files(args.chairs)[: args.count]
    plain, named = Segmenter(args.model, labeller=None), Segmenter(args.model, labeller=labeller)
    with tempfile.TemporaryDirectory(prefix="bench-labeller-") as cache:
        plain.abstract_files(files, cache_dir=cache, workers=args.workers, progress=False)  # warm the cache
        for segmenter in (plain, named):  # untimed: the first pass pays for reading the cache and compiling
            segmenter.segment_files(files[:20], cache_dir=cache, workers=args.workers, progress=False)
        rows = []
        for r in range(args.rounds):
            times = {}
            for label, segmenter in ((("index", plain), ("labeller", named)) if r % 2 == 0
                                     else (("labeller", named), ("index", plain))):
                t0 = time.perf_counter()
                segs, errors = segmenter.segment_files(files, cache_dir=cache, workers=args.workers, progress=False)
                times[label] = time.perf_counter() - t0
                assert len(segs) + len(errors) == len(files)
            rows.append(times)
            print(f"round {r}: index names {times['index']:.1f} s, labeller {times['labeller']:.1f} s, "
                  f"+{100 * (times['labeller'] / times['index'] - 1):.0f}%", flush=True)
    ratios = [t["labeller"] / t["index"] for t in rows]
    print(f"{len(files)} chairs, {len(labeller.ensemble.feature)} tree nodes, settings {labeller.settings}: "
          f"labelling adds {100 * (statistics.median(ratios) - 1):.0f}% (median of {len(rows)} rounds; "
          f"range {100 * (min(ratios) - 1):.0f}% to {100 * (max(ratios) - 1):.0f}%)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

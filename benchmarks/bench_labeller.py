"""What the part labeller adds to ``primkit segment``: the same collection segmented with and without
the model's labeller, alternating in one run (the preparation cache warm for both).

Each round times :meth:`primkit.segmentation.Segmenter.segment_files` (abstraction from the
preparation cache, then each file read and labelled in the worker processes, as ``primkit segment``
runs it) once with ``labeller=None`` (names by part index) and once with the model file's labeller
(``--semantic`` with a labelled model), the order alternating between rounds.

Usage (from the repository root)::

    python -m benchmarks.bench_labeller chair [--count 600] [--rounds 3] [--workers N] [--grid-sample 1,2,4,8]
        [--exact] [--before] [--no-cut] [--cache DIR]

(``chair``: the bundled chair model's labeller; a file written by ``primkit name-parts`` works too.)
``--exact`` times one more variant in every round: the labeller walking every tree (no early
stop, ``Labeller.early_stop`` None; the labels ``predict_proba`` gives). ``--before`` times one more variant in every round: the labeller as it labelled before the faster
paths (a k-d tree for the local shape, the plain tree walk), the same trees. ``--no-cut`` times the
labeller without its seat/legs layer cut (:mod:`primkit.labelling.layers`). Each pass prints its
wall time and, with ``--workers 1`` (every file labelled in this process), its CPU time, which
other jobs on a shared machine disturb less.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from primkit import data
from primkit.model.bundled import resolve_model
from primkit.segmentation import Segmenter
from primkit.segmentation.labeller import Labeller, read_labeller

CHAIRS = Path(__file__).resolve().parents[2] / "shared" / "data" / "shapenetvox32" / "03001627"


class _Before(Labeller):
    """The labeller as it labelled before ``grid_local_shape`` and the packed walk: a k-d tree for
    the local shape of a grid's voxels (over all of them) and the plain kernel, every tree walked
    (the Numba frame, profile and grid loops it shares with the labeller now)."""

    def _grid_shape(self, points, grid_index, rows):
        return None


def _before(labeller: Labeller) -> Labeller:
    ensemble = replace(labeller.ensemble)
    object.__setattr__(ensemble, "_packed", ())  # () : no packed nodes, the plain kernel walks
    return _Before(labeller.names, labeller.parts, ensemble, labeller.settings, labeller.info, labeller.prior,
                   early_stop=None)  # every tree, as before the early stop


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="a model with a labeller: a file (primkit name-parts) or a bundled name (chair)")
    ap.add_argument("--chairs", type=Path, default=CHAIRS)
    ap.add_argument("--count", type=int, default=600)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--grid-sample", default=None, metavar="N[,N...]",
                    help="label with this grid_sample (1, 2, 4 or 8) instead of the file's (LabellerSettings); "
                         "several: each timed in every round")
    ap.add_argument("--cache", type=Path, default=None,
                    help="the preparation cache to use and keep (default: a temporary one, abstracted first)")
    ap.add_argument("--exact", action="store_true",
                    help="also time the labeller walking every tree (no early stop, Labeller.early_stop None)")
    ap.add_argument("--before", action="store_true",
                    help="also time the labeller's paths before the faster ones (k-d tree, plain walk)")
    ap.add_argument("--no-cut", action="store_true",
                    help="also time the labeller without its layer cut (the chair.seat_layer_cut post-step left out)")
    args = ap.parse_args(argv)
    labeller = read_labeller(resolve_model(args.model))  # a file or a bundled model's name
    if labeller is None:
        raise SystemExit(f"{args.model}: no labeller in this model file (primkit name-parts writes one)")
    steps = [int(x) for x in args.grid_sample.split(",")] if args.grid_sample else [labeller.settings.grid_sample]
    files = data.find_shape_files(args.chairs)[: args.count]
    plain = Segmenter(args.model, labeller=None)
    variants = [("index", plain)] + [
        (f"labeller (grid_sample {g})", Segmenter(args.model, labeller=replace(
            labeller, settings=replace(labeller.settings, grid_sample=g)))) for g in steps]
    if args.exact:
        variants.append(("exact (every tree)", Segmenter(args.model, labeller=replace(labeller, early_stop=None))))
    if args.before:
        variants.append(("before (k-d tree, plain walk)", Segmenter(args.model, labeller=_before(labeller))))
    if args.no_cut:
        variants.append(("without the layer cut", Segmenter(args.model, labeller=replace(
            labeller, post=tuple(s for s in labeller.post if s.STEP != "chair.seat_layer_cut")))))
    with tempfile.TemporaryDirectory(prefix="bench-labeller-") as temporary:
        cache = str(args.cache) if args.cache else temporary
        plain.abstract_files(files, cache_dir=cache, workers=args.workers, progress=False)  # warm the cache
        for _, segmenter in variants:  # untimed: the first pass pays for reading the cache and compiling
            segmenter.segment_files(files[:20], cache_dir=cache, workers=args.workers, progress=False)
        rows, cpu_rows = [], []
        for r in range(args.rounds):
            times, cpu = {}, {}
            for label, segmenter in variants[r % len(variants):] + variants[: r % len(variants)]:  # order rotates
                t0, c0 = time.perf_counter(), time.process_time()
                segs, errors = segmenter.segment_files(files, cache_dir=cache, workers=args.workers, progress=False)
                times[label], cpu[label] = time.perf_counter() - t0, time.process_time() - c0
                assert len(segs) + len(errors) == len(files)
            rows.append(times)
            cpu_rows.append(cpu)
            print(f"round {r}: " + ", ".join(f"{k} {v:.1f} s" + ("" if k == "index" else
                                                                  f" (+{100 * (v / times['index'] - 1):.0f}%)")
                                           for k, v in times.items()), flush=True)
            if args.workers == 1:
                print(f"  CPU: " + ", ".join(f"{k} {v:.1f} s" + ("" if k == "index" else
                                                               f" (+{100 * (v / cpu['index'] - 1):.0f}%)")
                                           for k, v in cpu.items()), flush=True)
    for label, _ in variants[1:]:
        for kind, table in (("wall", rows), ("CPU", cpu_rows)) if args.workers == 1 else (("wall", rows),):
            ratios = [t[label] / t["index"] for t in table]
            print(f"{len(files)} chairs, {len(labeller.ensemble.feature)} tree nodes, {label}: labelling adds "
                  f"{100 * (statistics.median(ratios) - 1):.0f}% {kind} time (median of {len(table)} rounds; "
                  f"range {100 * (min(ratios) - 1):.0f}% to {100 * (max(ratios) - 1):.0f}%)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

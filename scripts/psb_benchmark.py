"""primkit's segmentations against the Princeton Segmentation Benchmark's human segmentations.

Usage (from the repository root, primkit importable)::

    python scripts/psb_benchmark.py [--category Chair ...] [--model FourLeg=animal.safetensors]
                                    [--align default any ...] [--json F]

The meshes are ``../shared/data/psb_seg_benchmark/<Category>/off/<id>.off`` (10 per category; not
+Y up, orientation and scale vary) with 10-15 human segmentations each in ``seg/<id>/<id>_<k>.seg``
(arbitrary segment ids per file; see the folder's README). Each category is co-segmented as one
collection by ``primkit segment``'s library call (:class:`primkit.segmentation.Segmenter`) with its
model: the bundled ``chair``, ``table``, ``airplane`` and ``animal`` for Chair, Table, Airplane and
FourLeg; ``--model CATEGORY=MODEL`` replaces one (a model file or a bundled name).
Once per ``--align`` mode (``default``: no flag, what a user gets). The part index of each face,
as ``segment`` writes it, is compared with every human segmentation of that mesh by the benchmark's
measures (:class:`primkit.metrics.ReferenceSegmentations`, all weighted by area):

* 1 - Rand index (pairs of surface points; the paper counts pairs of faces),
* the Hamming distance: ``Rm`` (missing rate), ``Rf`` (false-alarm rate) and their mean, the human
  segmentation playing the reference,
* the cut discrepancy in units of the mesh's average radius, with distances along the mesh's
  edges (``--metric euclidean``: straight lines) where the paper takes geodesics,
* the segments (distinct part indices on the faces) against the humans' mean count for that mesh,
  and the present cuboids of the abstraction.

A mesh's figure is the mean over its human segmentations; a category's the mean over its meshes
(the cut discrepancy over the meshes where it is defined: a segmentation with a single segment has
no cut). The humans' own figures: each human segmentation against the other humans of the same
mesh, averaged the same way; and the benchmark's trivial baseline, each mesh as one segment (a
low Hamming distance for it: ``Rf`` is the area outside the largest human segment, ``Rm`` is 0).
The results go to ``--json`` (by default ``psb_benchmark.json`` beside
this script).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from primkit import data, io
from primkit.metrics import ReferenceSegmentations
from primkit.model import orientation
from primkit.model.abstraction import load_model
from primkit.segmentation import Segmenter

HERE = Path(__file__).resolve().parent
PSB = HERE.parents[0].parent / "shared" / "data" / "psb_seg_benchmark"
MODELS = {"Chair": "chair", "Table": "table", "Airplane": "airplane", "FourLeg": "animal"}  # None: no model, the humans only
MEASURES = ("rand", "missing", "false_alarm", "hamming", "cut", "segments", "reference_segments")


def parse_models(pairs) -> dict:
    """``["FourLeg=animal.safetensors", ...]`` -> the category -> model mapping, defaults included."""
    models = dict(MODELS)
    for pair in pairs or ():
        category, sep, model = pair.partition("=")
        if not sep or category not in MODELS or not model:
            raise SystemExit(f"--model takes CATEGORY=MODEL with CATEGORY one of {', '.join(MODELS)}; got {pair!r}")
        models[category] = model
    return models


def _mean(rows, key) -> float:
    values = np.array([r[key] for r in rows], np.float64)
    return float(np.nanmean(values)) if np.isfinite(values).any() else float("nan")


def summary(rows) -> dict:
    """Each measure's mean over meshes (NaN cut discrepancies left out, and counted)."""
    out = {k: _mean(rows, k) for k in MEASURES}
    out["cut_undefined_meshes"] = int(sum(not np.isfinite(r["cut"]) for r in rows))
    if rows and "cuboids" in rows[0]:
        out["cuboids"] = _mean(rows, "cuboids")
    return out


def category_figures(category: str, model, modes, workers=None, metric="graph") -> dict:
    files = sorted((PSB / category / "off").glob("*.off"), key=lambda p: int(p.stem))
    refs, human_files = {}, 0
    for p in files:
        mesh = io.read_mesh(p)
        humans = [io.read_labels(h, len(mesh.faces)) for h in sorted((PSB / category / "seg" / p.stem).glob("*.seg"))]
        human_files += len(humans)
        refs[p.stem] = ReferenceSegmentations(mesh.vertices, mesh.faces, humans, metric=metric)
    out = {"model": None if model is None else str(model), "meshes": len(files), "human_files": human_files}
    humans = {k: r.among_references().to_dict() for k, r in refs.items()}
    out["humans"] = {"mean": summary(list(humans.values())), "per_mesh": humans}
    # the benchmark's trivial baseline: the whole mesh one segment (no cut, so no cut discrepancy)
    whole = {k: r.score(np.zeros(len(r.areas), np.int64)).to_dict() for k, r in refs.items()}
    out["one_segment"] = {"mean": summary(list(whole.values())), "per_mesh": whole}
    if model is None:  # not covered: no model of this category
        return out
    data.prepare_collection(files, load_model(model).settings, workers=workers, progress=False)  # the cache is
    # warm before any mode is timed: the times are the frame search, the network and the labelling
    for mode in modes:
        t0 = time.perf_counter()
        segmenter = Segmenter(model, align=None if mode == "default" else mode)
        results, errors = segmenter.abstract_files(files, workers=workers, progress=False)
        segs, errors = segmenter.segment_results(results, workers=workers, progress=False, errors=errors)
        seconds = time.perf_counter() - t0
        per_mesh = {}
        for s, r in zip(segs, results):
            row = refs[s.name].score(s.face_labels).to_dict()
            row["cuboids"] = int(r.cuboids.existence.sum())
            if r.alignment:
                row.update(up=r.alignment.up, front=r.alignment.front, decided_by=r.alignment.up_decided_by)
            per_mesh[s.name] = row
        out[mode] = {"mean": summary(list(per_mesh.values())), "seconds": round(seconds, 1), "per_mesh": per_mesh,
                     "errors": errors}
    return out


def frame_search_cost(count: int, rounds: int = 2) -> dict:
    """Seconds a shape to score the candidate frames of ``count`` ShapeNetVox32 chairs with the chair
    model: the 4 turns about a known up axis against all 24 (what the default scores, as ``any``),
    alternating, ``rounds`` times each."""
    model = load_model("chair")
    files = data.find_shape_files(PSB.parent / "shapenetvox32" / "03001627")[:count]
    coll = data.prepare_collection(files, model.settings, workers=1, progress=False)
    shapes = [coll[i] for i in range(len(coll))]
    upright = orientation.candidate_rotations("front")
    everything = orientation.candidate_rotations("any")
    times = {"4 turns": [], "24 turns": []}
    for _ in range(rounds):
        for key, candidates in (("4 turns", upright), ("24 turns", everything)):
            t0 = time.perf_counter()
            model._candidate_losses(shapes, candidates, 0.5, 16)
            times[key].append((time.perf_counter() - t0) / len(shapes))
    return {"shapes": len(shapes), **{k: [round(t, 4) for t in v] for k, v in times.items()}}


def _json_ready(value):
    """NaN and infinities as null, so that any JSON reader takes the file."""
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _row(label: str, m: dict) -> str:
    cut = f"{m['cut']:6.3f}" if m["cut_undefined_meshes"] == 0 else (
        f"{m['cut']:6.3f} ({m['cut_undefined_meshes']} undef.)" if np.isfinite(m["cut"]) else "   n/a")
    parts = f"{m['segments']:5.1f} / {m['reference_segments']:4.1f}"
    return (f"  {label:11s} {m['rand']:6.3f} {m['missing']:6.3f} {m['false_alarm']:6.3f} {m['hamming']:6.3f} "
            f"{cut:6s}  {parts}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", nargs="+", default=list(MODELS), choices=list(MODELS))
    ap.add_argument("--model", action="append", metavar="CATEGORY=MODEL", default=[],
                    help="the model of a category: a model file or a bundled name (repeat for several), "
                         "e.g. FourLeg=animal.safetensors")
    ap.add_argument("--align", nargs="+", default=["default"],
                    help="frame searches to compare: default (no flag), none, front, auto, any")
    ap.add_argument("--metric", choices=["graph", "euclidean"], default="graph",
                    help="the cut discrepancy's distances: along the mesh's edges, or straight lines")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--verbose", action="store_true", help="print every mesh's figures and frame")
    ap.add_argument("--cost", type=int, default=0, metavar="N",
                    help="also time the frame search on N ShapeNet chairs: 4 against 24 candidates a shape")
    ap.add_argument("--json", type=Path, default=HERE / "psb_benchmark.json")
    args = ap.parse_args(argv)
    models = parse_models(args.model)
    report = {"metric": args.metric, "models": {c: models[c] for c in args.category}}
    failed = False
    if args.cost:
        cost = report["cost"] = frame_search_cost(args.cost)
        print(f"frame search on {cost['shapes']} ShapeNet chairs, seconds a shape (alternating rounds): "
              f"4 turns {cost['4 turns']}, 24 turns {cost['24 turns']}")
    print(f"  {'':11s} {'1-RI':>6s} {'Rm':>6s} {'Rf':>6s} {'HD':>6s} {'CD':>6s}  segments / humans'")
    for category in args.category:
        r = report[category] = category_figures(category, models[category], args.align, args.workers, args.metric)
        print(f"{category} ({r['meshes']} meshes, {r['human_files']} human segmentations, model {r['model']})")
        print(_row("humans", r["humans"]["mean"]))
        print(_row("one segment", r["one_segment"]["mean"]))
        if r["model"] is None:
            print("  not covered: no model of this category (--model %s=MODEL)" % category)
            continue
        for m in args.align:
            print(_row(m, r[m]["mean"]) + f"  cuboids {r[m]['mean']['cuboids']:.1f}, {r[m]['seconds']:.0f} s")
            failed |= bool(r[m]["errors"])
            for e in r[m]["errors"]:
                print(e, file=sys.stderr)
            if args.verbose:
                for k, v in r[m]["per_mesh"].items():
                    print(f"    {k}: 1-RI {v['rand']:.3f} HD {v['hamming']:.3f} CD {v['cut']:.3f} segments "
                          f"{v['segments']:.0f} / {v['reference_segments']:.1f} up {v.get('up')} front {v.get('front')}")
    if args.json:
        args.json.write_text(json.dumps(_json_ready(report), indent=1, allow_nan=False))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

"""Similarity by parts against PartNet's labelled parts: does ``similar --parts P`` find chairs whose
part P is like the query's? (docs/results-applications.md, "Similarity by parts").

Usage::

    python scripts/similarity_partnet.py [--part validation|test] [--limit N] [--choose-weights] [--json F]
    python scripts/similarity_partnet.py --picture docs/images/similar-by-back.png   # the README's picture

The chairs: the PartNet validation or test part of ``scripts/partnet_chairs.py``'s split (the chair
preset's held-out ShapeNetVox32 chairs with PartNet labels; weights are chosen on validation only,
the test part is measured once). Each chair is abstracted by the bundled chair model with default
flags and its canonical grid named voxel by voxel by the model's labeller, as ``primkit embed`` and
``primkit similar`` do.

The truth for a part: PartNet's voxels of that part on each chair (in the chair's own grid),
described by their extent (height, width, depth, each over the chair's height) and their share of
the chair's voxels, each of the four standardised over the chairs; the truth distance between two
chairs is the Euclidean distance of those descriptions. For arms only the chairs whose PartNet labels
have arms are scored (the descriptors are still fitted on all chairs, as a user's collection would be).

Scores, for each part and each distance (:func:`primkit.embedding.distance_spearman`,
:func:`primkit.embedding.retrieval_gain`): Spearman's correlation with the truth distance over all
pairs, and the top-5 retrieval gain ``(random - ranked) / (random - truth's own ranking)``.

Distances compared:

* ``regions``: :class:`primkit.embedding.RegionDescriptor` with its default weights (what the commands use);
* ``signature``: the same regions described by the histogram of their voxel distances alone (a plain shape descriptor);
* ``label-boxes``: the labelled regions' oriented boxes through :class:`primkit.embedding.PartDescriptor` (the previous ``--parts`` by label);
* ``cuboids``: the model's cuboids of the part's indices (:class:`PartDescriptor`; the path of a model without a labeller);
* ``voxel-iou``: the whole shape, ``1 - IoU`` of the canonical grids (``--metric voxel-iou``).

``--choose-weights`` (validation only) searches the weights of :data:`primkit.embedding.REGION_WEIGHTS`
on a grid and prints the best; the JSON (default: beside this script,
``similarity_partnet_<part>[_from<start>].json``) holds every figure.

The bundled chair labeller learned from all 219 validation chairs, so validation scores with it
flatter the descriptor. The weights were chosen with a labeller learned from validation chairs 0-99
(``python -m scripts.build_chair_labeller -o chair-val100.safetensors --chairs 100``) naming chairs
100-218 (``--model chair-val100.safetensors --start 100``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

from partnet_chairs import PARTNET, split  # noqa: E402

from primkit import embedding  # noqa: E402
from primkit.embedding import PartDescriptor, RegionDescriptor, RegionTable  # noqa: E402

#: PartNet's label value of each labeller name (partnet_chair_boxes/README: 0 back, 1 seat, 2 leg/base, 3 arm)
PARTNET_CODES = {"back": 0, "seat": 1, "legs": 2, "arms": 3}
PARTS = ("back", "seat", "legs", "arms")
K = 5

#: The grid ``--choose-weights`` searches (extent's weight fixed at 1: only ratios matter).
WEIGHT_GRID = {"share": (0.5, 1.0, 1.5, 2.0), "place": (0.0, 0.25, 0.5), "thickness": (0.0, 0.25, 0.5),
               "fill": (0.0, 0.25, 0.5), "signature": (0.0, 0.25, 0.5)}


def truth_description(labels, code: int) -> np.ndarray:
    """``(4,)``: height, width, depth of the cells labelled ``code`` (last minus first cell, plus
    one) over the chair's height, and their share of the chair's cells; zeros when there are none.
    ``labels`` (32, 32, 32) int, -1 empty (the archive's index order: x depth, y up, z side)."""
    occupied = labels >= 0
    ys = np.flatnonzero(occupied.any(axis=(0, 2)))
    height = ys[-1] - ys[0] + 1
    x, y, z = np.nonzero(labels == code)
    if not len(x):
        return np.zeros(4)
    extent = [np.ptp(a) + 1 for a in (y, z, x)]
    return np.array([*(e / height for e in extent), len(x) / occupied.sum()])


def standardised_distances(values) -> np.ndarray:
    """Euclidean distances between rows after standardising each column (a constant column: 0)."""
    from scipy.spatial.distance import pdist, squareform

    v = np.asarray(values, float)
    std = v.std(axis=0)
    return squareform(pdist((v - v.mean(axis=0)) / np.where(std > 0, std, 1.0)))


def prepare(files, model="chair", progress: bool = False) -> dict:
    """Abstract ``files`` with the model, name their canonical voxels with its labeller, and read
    the PartNet labels: what every distance below is computed from."""
    from primkit.model.abstraction import abstract_shapes, load_model
    from primkit.model.bundled import resolve_model
    from primkit.segmentation.bylabel import labelled_grid
    from primkit.segmentation.labeller import read_labeller

    labeller = read_labeller(resolve_model(model))
    model = load_model(model)
    out = abstract_shapes([str(f) for f in files], model, progress=progress)
    if out.errors:
        raise RuntimeError("; ".join(map(str, out.errors)))
    grids = np.array([a.canonical_shape().occupancy for a in out], bool)
    labels = [labelled_grid(labeller, g, a.result.canonical) for g, a in zip(grids, out)]
    archive = np.load(PARTNET / "voxlabels.npz")
    truth = [archive[a.name] for a in out]
    return {"names": [a.name for a in out], "grids": grids, "labels": labels, "truth": truth,
            "results": out.results, "part_names": list(model.part_names), "label_names": list(labeller.names)}


def score(D, T) -> dict:
    return {"spearman": round(embedding.distance_spearman(D, T), 4), "gain": round(embedding.retrieval_gain(D, T, K), 4)}


def measure(prep: dict, weights=None) -> dict:
    """Scores of every distance for every part (see the module notes)."""
    from primkit.segmentation.bylabel import by_label

    names = prep["label_names"]
    table = RegionTable.from_grids(prep["grids"], prep["labels"], names, prep["names"])
    whole = embedding.voxel_iou_distances(prep["grids"])
    centres = [(np.argwhere(g) + 0.5) / g.shape[0] - 0.5 for g in prep["grids"]]
    slots = [lab[g] for lab, g in zip(prep["labels"], prep["grids"])]
    boxes = embedding.label_boxes(centres, slots, names, names=prep["names"])
    report = {}
    for part in PARTS:
        truth = np.array([truth_description(t, PARTNET_CODES[part]) for t in prep["truth"]])
        keep = np.flatnonzero(truth[:, 3] > 0) if part == "arms" else np.arange(len(truth))
        T = standardised_distances(truth[keep])
        sub = np.ix_(keep, keep)

        def described(X):
            return embedding.descriptor_distances(X[keep])

        chosen = by_label(part, names)
        rows = {
            "regions": described(RegionDescriptor(chosen, weights=weights).fit_transform(table)),
            "signature": described(RegionDescriptor(chosen, what="signature").fit_transform(table)),
            "label-boxes": described(PartDescriptor(chosen).fit_transform(boxes)),
            "cuboids": described(PartDescriptor(part, part_names=prep["part_names"]).fit_transform(prep["results"])),
            "voxel-iou": whole[sub],
        }
        report[part] = {"chairs": int(len(keep)), **{k: score(D, T) for k, D in rows.items()}}
    return report


def choose_weights(prep: dict) -> list:
    """Every weight set of :data:`WEIGHT_GRID`, best first: ``[(objective, weights, scores)]``, the
    objective the mean of Spearman and top-5 gain over the four parts."""
    from primkit.segmentation.bylabel import by_label

    names = prep["label_names"]
    table = RegionTable.from_grids(prep["grids"], prep["labels"], names, prep["names"])
    blocks, truths = {}, {}
    for part in PARTS:
        truth = np.array([truth_description(t, PARTNET_CODES[part]) for t in prep["truth"]])
        keep = np.flatnonzero(truth[:, 3] > 0) if part == "arms" else np.arange(len(truth))
        truths[part] = standardised_distances(truth[keep])
        chosen = by_label(part, names)
        # each property alone at weight 1: the descriptor of any weights is these blocks scaled
        blocks[part] = {p: RegionDescriptor(chosen, what=p, weights={p: 1.0}).fit_transform(table)[keep]
                        for p in embedding.REGION_PROPERTIES}
    keys = list(WEIGHT_GRID)
    rows = []
    for combo in itertools.product(*WEIGHT_GRID.values()):
        w = {"extent": 1.0, **dict(zip(keys, combo))}
        scores = {}
        for part in PARTS:
            X = np.hstack([w[p] * blocks[part][p] for p in embedding.REGION_PROPERTIES if w[p] > 0])
            scores[part] = score(embedding.descriptor_distances(X), truths[part])
        objective = float(np.mean([v for s in scores.values() for v in s.values()]))
        rows.append((round(objective, 4), w, scores))
    # best first; within 0.001 of each other, the weights using more properties first
    rows.sort(key=lambda r: (-r[0], -sum(v > 0 for v in r[1].values())))
    best = rows[0][0]
    near = [r for r in rows if r[0] >= best - 0.001]
    near.sort(key=lambda r: (-sum(v > 0 for v in r[1].values()), -r[0]))
    return near + [r for r in rows if r not in near]


def draw_picture(path: Path) -> int:
    """``primkit similar`` with ``--parts back`` and the bundled chair model, as the README shows it."""
    import tempfile

    from primkit.cli import main as primkit_main

    validation, _, _ = split()
    query, rest = validation[39], validation[:39] + validation[40:120]
    with tempfile.TemporaryDirectory() as tmp:
        return primkit_main(["similar", str(query), *map(str, rest), "--model", "chair", "--parts", "back", "-k", "4",
                             "-o", tmp, "--png", str(path), "--force", "-q"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=["validation", "test"], default="validation")
    ap.add_argument("--limit", type=int, default=0, help="the first N chairs of the part (default all)")
    ap.add_argument("--start", type=int, default=0, help="leave out the part's first N chairs (default 0)")
    ap.add_argument("--model", default="chair", help="the model and its labeller (default: the bundled chair model)")
    ap.add_argument("--choose-weights", action="store_true", help="search the region weights (validation only)")
    ap.add_argument("--json", type=Path, default=None, help="default: beside this script")
    ap.add_argument("--picture", type=Path, default=None,
                    help="only draw the README's picture here: validation chair 39 and its 4 nearest by back among "
                         "validation chairs 0-119 (primkit similar)")
    args = ap.parse_args(argv)
    if args.picture:
        return draw_picture(args.picture)
    if args.choose_weights and args.part != "validation":
        ap.error("weights are chosen on the validation part only")
    validation, test, _ = split()
    files = validation if args.part == "validation" else test
    files = files[args.start: args.start + args.limit] if args.limit else files[args.start:]
    t0 = time.perf_counter()
    prep = prepare(files, args.model)
    report = {"part": args.part, "model": str(args.model), "start": args.start, "chairs": len(prep["names"]), "k": K,
              "weights": dict(embedding.REGION_WEIGHTS), "parts": measure(prep)}
    if args.choose_weights:
        ranked = choose_weights(prep)
        report["weight_search"] = [{"objective": o, "weights": w, "scores": s} for o, w, s in ranked[:20]]
        objectives = [r[0] for r in ranked]
        report["weight_search_objectives"] = {"sets": len(ranked), "best": max(objectives), "worst": min(objectives),
                                              "median": float(np.median(objectives))}
        print(f"best weights (objective {ranked[0][0]}): {ranked[0][1]}")
    report["seconds"] = round(time.perf_counter() - t0, 1)
    print(f"{report['chairs']} PartNet {args.part} chairs ({report['seconds']:.0f} s); Spearman / top-{K} gain:")
    kinds = [k for k in report["parts"]["back"] if k != "chairs"]
    print(f"{'part':6s} {'chairs':>6s}  " + "  ".join(f"{k:>13s}" for k in kinds))
    for part, row in report["parts"].items():
        print(f"{part:6s} {row['chairs']:6d}  " + "  ".join(f"{row[k]['spearman']:6.3f}/{row[k]['gain']:6.3f}" for k in kinds))
    path = args.json or ROOT / f"similarity_partnet_{args.part}{f'_from{args.start}' if args.start else ''}.json"
    path.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

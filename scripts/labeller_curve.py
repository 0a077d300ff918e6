"""Learning curve of the part labeller (``primkit.segmentation.labeller``) on PartNet's chair labels.

Run from the repository root as a module (it reuses the fixed split of ``scripts/partnet_chairs.py``)::

    python -m scripts.labeller_curve prepare --scratch /tmp/33-scratch       # abstract once, cache
    python -m scripts.labeller_curve sweep   --scratch /tmp/33-scratch       # settings, validation only
    python -m scripts.labeller_curve curve   --scratch /tmp/33-scratch --part test   # reported once
    python -m scripts.labeller_curve coseg   --scratch /tmp/33-scratch       # 3 COSEG chairs -> the other 7
    python -m scripts.labeller_curve model --model FILE --part test          # a model file's own labeller

The split (``scripts/partnet_chairs.py``): the chair preset's held-out files with PartNet labels, even
positions **validation**, odd positions **test**. Labellers learn from the first N chairs of the
validation part in a fixed shuffled order (seed 0; other draws with ``--draws``); ``sweep`` chooses
settings by learning from validation chairs 0-99 of that order and scoring validation chairs
100-218, as ``curve --part validation`` does (its draws shuffle validation chairs 0-99);
``curve --part test`` learns from validation chairs and scores every test chair.

Scores (as ``scripts/partnet_chairs.py`` and ``primkit segment --gt``,
:func:`primkit.segmentation.evaluate_voxels`): per-label IoU per chair over its occupied voxels, 1
when a label is absent from both, averaged over chairs; the mean over back, seat and legs; arm IoU;
arm detection F1 (a chair *has* arms when at least 2% of its voxels are arm, is *predicted* to when
at least 1% are). Beside the labeller: today's naming (the bundled model's one name per index) and a
position-only labeller (the same classifier on the canonical position alone). The labeller's arms
post-step (:mod:`primkit.labelling.presence`, asked for here, kept as ``Labeller.fit`` checks it) is left out
with ``--no-presence``, its seat/legs layer cut (:mod:`primkit.labelling.layers`) with
``--no-layer-cut``; the side features (``LabellerSettings.sides``) are read with ``--sides``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from primkit import io, primitives
from primkit.segmentation import VoxelGroundTruth, evaluate_voxels
from primkit.segmentation.labeller import (Labeller, LabellerSettings, frame_features, grid_elements, grid_local_shape,
                                           mesh_elements)
from primkit.labelling.layers import LayerCut
from primkit.labelling.presence import PresenceRule
from primkit.labelling.profile import PROFILE_FEATURES, profile_features
from primkit.labelling.sides import side_features

from scripts.partnet_chairs import MEAN_OVER, split

NAMES = ["back", "seat", "legs", "arms"]
#: how the local shape of a voxel finds its nearest voxels: "grid" (:func:`grid_local_shape`, as the
#: library labels a voxel grid) or "kdtree" (a k-d tree, as the library did before; ``--knn``)
KNN = {"how": "grid"}
SIZES = [1, 3, 10, 40, 100]


# -- the cache: one abstraction per chair -------------------------------------------------------


def prepare(scratch: Path, model: str = "chair") -> None:
    """Abstract every labelled chair of both parts once (default flags) and keep what the
    labeller reads: canonical voxel centres and normals, canonical cuboids, labels, index names."""
    from primkit.segmentation import Segmenter

    validation, test, archive = split()
    segmenter = Segmenter(model)
    t0 = time.perf_counter()
    results, errors = segmenter.abstract_files(validation + test, cache_dir=scratch / "prep", progress=False)
    print(f"abstracted {len(results)} chairs in {time.perf_counter() - t0:.0f} s; errors: {errors}")
    store = {}
    index_names = [str(n) for n in segmenter.part_names]
    for r in results:
        grid = io.read_voxels(r.source)
        elements, index = grid_elements(grid, r.frame)
        truth = archive.get(r.name, grid.occupancy.shape).labels[tuple(index.T)]
        nearest = primitives.assign_points(elements.points, r.canonical)
        store[r.name] = {"points": elements.points.astype(np.float32), "normals": elements.normals.astype(np.float32),
                         "truth": truth.astype(np.int8), "nearest": nearest.astype(np.int16),
                         "index": index.astype(np.int8), "cuboids": r.canonical.to_dict()}
    meta = {"validation": [r.name for r in results if r.source in {str(p) for p in validation}],
            "test": [r.name for r in results if r.source in {str(p) for p in test}], "index_names": index_names,
            "model": model, "parts": segmenter.abstractor.parts}
    arrays = {f"{name}/{k}": v for name, d in store.items() for k, v in d.items() if k != "cuboids"}
    np.savez(scratch / "chairs.npz", **arrays)
    (scratch / "chairs.json").write_text(json.dumps({**meta, "cuboids": {n: d["cuboids"] for n, d in store.items()}}))


def prepare_mirror(scratch: Path, model: str = "chair") -> None:
    """``prepare`` for the validation chairs' left-right mirrors (:func:`primkit.segmentation.mirror.mirror_shape`
    of each grid in its abstraction's frame, abstracted again), in ``scratch/mirror``; the labels carried over."""
    from primkit.model.abstraction import abstract_shapes
    from primkit.segmentation import Segmenter
    from primkit.segmentation.mirror import mirror_shape

    validation, _, archive = split()
    segmenter = Segmenter(model)
    results, errors = segmenter.abstract_files(validation, cache_dir=scratch / "prep", progress=False)
    grids, truths, names = [], [], []
    for r in results:
        grid = io.read_voxels(r.source)
        mirrored, order = mirror_shape(grid, r.frame)
        truth = archive.get(r.name, grid.occupancy.shape).labels[tuple(np.argwhere(grid.occupancy).T)]
        grids.append(mirrored)
        truths.append(truth[order])
        names.append(r.name)
    found = abstract_shapes(grids, segmenter.abstractor, names=names, progress=False).results
    store = {}
    for r, grid, truth in zip(found, grids, truths):
        elements, index = grid_elements(grid, r.frame)
        store[r.name] = {"points": elements.points.astype(np.float32), "normals": elements.normals.astype(np.float32),
                         "truth": truth.astype(np.int8),
                         "nearest": primitives.assign_points(elements.points, r.canonical).astype(np.int16),
                         "index": index.astype(np.int8), "cuboids": r.canonical.to_dict()}
    out = scratch / "mirror"
    out.mkdir(exist_ok=True)
    np.savez(out / "chairs.npz", **{f"{n}/{k}": v for n, d in store.items() for k, v in d.items() if k != "cuboids"})
    meta = {"validation": list(store), "test": [], "index_names": [str(n) for n in segmenter.part_names],
            "model": model, "parts": segmenter.abstractor.parts}
    (out / "chairs.json").write_text(json.dumps({**meta, "cuboids": {n: d["cuboids"] for n, d in store.items()}}))
    print(f"mirrored and abstracted {len(store)} validation chairs into {out}; errors: {errors}")


class Chairs:
    """The cached chairs (``prepare``)."""

    def __init__(self, scratch: Path):
        self.scratch = scratch
        meta = json.loads((scratch / "chairs.json").read_text())
        self.validation, self.test = meta["validation"], meta["test"]
        self.index_names, self.parts = meta["index_names"], meta["parts"]
        self.cuboids = {n: primitives.Cuboids.from_dict(d) for n, d in meta["cuboids"].items()}
        z = np.load(scratch / "chairs.npz")
        self.arrays = {}
        for key in z.files:
            name, field = key.split("/")
            self.arrays.setdefault(name, {})[field] = z[key]

    def full_features(self, name):
        """Every feature (normals, local shape, the shape profile and the side features), float32;
        all but the last two cached under ``scratch/features`` (they cost milliseconds: computed
        each time)."""
        path = self.scratch / "features" / f"{name}.npy"
        if not path.is_file():
            path.parent.mkdir(exist_ok=True)
            np.save(path, self.features(name, LabellerSettings(neighbours=16, normals=True, profile=False, sides=False))
                    .astype(np.float32))
        points = self.arrays[name]["points"].astype(float)
        return np.hstack([np.load(path), profile_features(points).astype(np.float32),
                          side_features(points).astype(np.float32)])

    def features(self, name, settings, position_only=False):
        a = self.arrays[name]
        points = a["points"].astype(float)
        if position_only:
            return points
        shape = None
        if settings.neighbours and KNN["how"] == "grid":  # as Labeller.predict_proba on a grid
            index = a["index"].astype(np.int64)
            shape = grid_local_shape(points, index, np.arange(len(points)), settings.neighbours, (32, 32, 32))
        return frame_features(points, self.cuboids[name], a["normals"].astype(float), settings, local_shape=shape)


def order(names, seed):
    """The validation chairs in a fixed shuffled order."""
    return [names[i] for i in np.random.default_rng(seed).permutation(len(names))]


def score(chairs: Chairs, names, predictions) -> dict:
    """The figures of ``predictions`` (name -> (n,) label codes into NAMES) on ``names``."""
    assigned, truths = [], []
    has_t, has_p = [], []
    for name in names:
        a = chairs.arrays[name]
        idx = tuple(a["index"].astype(np.int64).T)
        grid_p = np.full((32, 32, 32), -1, np.int64)
        grid_t = np.full((32, 32, 32), -1, np.int64)
        grid_p[idx] = np.where(predictions[name] < 0, len(NAMES), predictions[name])  # unnamed: a name no label has
        grid_t[idx] = a["truth"]
        assigned.append(grid_p)
        truths.append(VoxelGroundTruth(grid_t, ["back", "seat", "legs/leg/base", "arms/arm"]))
        n = len(a["truth"])
        has_t.append(np.count_nonzero(a["truth"] == 3) >= 0.02 * n)
        has_p.append(np.count_nonzero(predictions[name] == 3) >= 0.01 * n)
    # each label code is its own "part", named after it: the model-names protocol is the identity
    report = evaluate_voxels(assigned, truths, len(NAMES) + 1, part_names=NAMES + ["unnamed"], names=list(names),
                             mean_over=MEAN_OVER).to_dict()
    e = report["protocols"]["model-names"]
    has_t, has_p = np.array(has_t), np.array(has_p)
    tp, fp, fn = np.sum(has_t & has_p), np.sum(~has_t & has_p), np.sum(has_t & ~has_p)
    return {"mean": e["mean_iou"], "arm_iou": e["iou"]["arms"], "arm_f1": float(2 * tp / (2 * tp + fp + fn)),
            "iou": e["iou"], "accuracy": e["accuracy"], "chairs": len(names)}


def index_naming(chairs: Chairs, names) -> dict:
    """Today's naming: each voxel takes its nearest cuboid's name in the model (one per index)."""
    codes = np.array([NAMES.index(n) if n in NAMES else -2 for n in chairs.index_names])
    return {n: codes[chairs.arrays[n]["nearest"].astype(np.int64)] for n in names}


def index_naming_from(chairs: Chairs, train, evaluate) -> dict:
    """Index naming learned from ``train`` as ``name-parts --index-names-only`` learns it (each
    index takes the label holding most of its voxels over the labelled chairs,
    :func:`primkit.model.parts.names_from_labels`; indices by the nearest rule), applied to ``evaluate``."""
    from primkit.model.parts import names_from_labels

    a = [chairs.arrays[n] for n in train]
    names, _ = names_from_labels([x["nearest"].astype(np.int64) for x in a], [x["truth"].astype(np.int64) for x in a],
                                 [None] * len(a), NAMES, chairs.parts)
    codes = np.array([NAMES.index(n) if n in NAMES else -2 for n in names])
    return {n: codes[chairs.arrays[n]["nearest"].astype(np.int64)] for n in evaluate}


def learn_and_label(chairs, train, evaluate, settings, *, position_only=False, **fit) -> dict:
    """Learn from ``train``, label ``evaluate`` as the library does (the classifier, smoothing over
    each voxel's 3 x 3 x 3 neighbourhood, rare labels dropped): name -> label codes."""
    from primkit.segmentation.labeller import decide, grid_neighbours, grid_sampling

    keep = _columns(chairs.parts, settings)
    data = [(chairs.full_features(n)[:, keep] if not position_only else chairs.arrays[n]["points"].astype(float),
             chairs.arrays[n]["truth"].astype(np.int64)) for n in train]
    if MIRROR["chairs"] is not None and not position_only:  # each labelled chair mirrored left-right too
        mirrored = MIRROR["chairs"]
        data += [(mirrored.full_features(n)[:, keep], mirrored.arrays[n]["truth"].astype(np.int64)) for n in train]
        if settings.prior_weight is None:  # the prior's weight follows the chairs labelled, not their mirrors
            settings = replace(settings, prior_weight=min(0.4, 4.0 / len(train)))
    if SELF_TRAINING["pool"] and not position_only:  # self-training: unlabelled validation chairs 0-99
        labeller = _fit_self_trained(chairs, data, train, keep, settings, **{**FIT, **fit})
    else:
        labeller = _fit(data, chairs.parts, settings, position_only, **{**FIT, **fit})
    return label_with(chairs, labeller, evaluate, settings, keep, position_only)


def label_with(chairs, labeller, evaluate, settings, keep, position_only=False) -> dict:
    """Label ``evaluate`` with a fitted labeller as the library does: name -> label codes."""
    from primkit.segmentation.labeller import decide, grid_neighbours

    known = np.array([NAMES.index(k) for k in labeller.names])
    out = {}
    for n in evaluate:
        near = grid_neighbours(chairs.arrays[n]["index"].astype(np.int64), (32, 32, 32))
        proba = grid_proba(chairs, labeller, n, settings, keep, near, position_only)
        if settings.smooth:
            idx = near[:, : settings.smooth_neighbours]
            for _ in range(settings.smooth):
                proba = proba[idx].mean(axis=1)
        if isinstance(labeller, Labeller):  # as Labeller.predict decides: rare labels, presence rule, layer cut
            labels = labeller.labels_from(proba, chairs.arrays[n]["points"].astype(float),
                                          grid_index=chairs.arrays[n]["index"].astype(np.int64))
        else:
            labels = decide(proba, settings.min_share)
        out[n] = known[labels]
    return out


def grid_proba(chairs, labeller, name, settings, keep, near, position_only=False) -> np.ndarray:
    """``(n, len(labeller.names))``: a chair's probabilities as :meth:`Labeller.predict_proba` has
    them on a grid before the smoothing (``near``: the chair's :func:`grid_neighbours`)."""
    from primkit.segmentation.labeller import grid_sampling

    a = chairs.arrays[name]
    X = chairs.full_features(name)[:, keep] if not position_only else a["points"].astype(float)
    # as Labeller.predict_proba on a grid: one voxel in grid_sample classified, the others filled
    # (their features are rows of the full features: the local shape is read among all voxels)
    classify, around, use = grid_sampling(a["index"].astype(np.int64), near, settings.grid_sample)
    proba = np.zeros((len(X), len(labeller.names)))  # zeros: the unclassified weigh 0 in the fill
    proba[classify] = (labeller.classify(X[classify]) if isinstance(labeller, Labeller)  # the prior blended in
                       else labeller.ensemble.predict_proba(X[classify]))
    w = use.astype(float)
    proba[~classify] = np.einsum("nk,nkc->nc", w, proba[around]) / w.sum(axis=1, keepdims=True)
    return proba


#: mirror augmentation (``--mirror``): the validation chairs mirrored left-right, abstracted again
#: (``prepare-mirror``), as :class:`Chairs`
MIRROR = {"chairs": None}
#: self-training (``--self-train``): the unlabelled pool (validation chairs 0-99 of the seed-0 order
#: not learned from; their labels never read) and :class:`primkit.segmentation.selftrain.SelfTraining`
SELF_TRAINING = {"pool": False, "how": None}


def _fit_self_trained(chairs, data, train, keep, settings, **fit):
    from primkit.segmentation.labeller import grid_neighbours
    from primkit.segmentation.selftrain import UnlabelledShape, fit_self_trained

    taken = set(train)
    pool = []
    for c in order(chairs.validation, 0)[:100]:
        if c in taken:
            continue
        a = chairs.arrays[c]  # its "truth" is not read
        pool.append(UnlabelledShape(chairs.full_features(c)[:, keep], a["points"].astype(float),
                                    grid_neighbours(a["index"].astype(np.int64), (32, 32, 32))))
    return fit_self_trained(data, pool, NAMES, chairs.parts, self_training=SELF_TRAINING["how"], settings=settings,
                            **fit)


def _fit(data, parts, settings, position_only, **fit):
    if not position_only:
        labeller = Labeller.fit(data, NAMES, parts, settings=settings, **fit)
        given = {k: v for k, v in FILL.items() if v is not None}  # --fill, --hint: the rule kept, these changed
        if given:
            labeller = replace(labeller, post=tuple(replace(s, **given) if isinstance(s, PresenceRule) else s
                                                    for s in labeller.post))
        return labeller
    # the position-only baseline: the same classifier on three columns (not a storable labeller)
    from sklearn.ensemble import HistGradientBoostingClassifier

    from primkit.segmentation.labeller import TreeEnsemble

    rng = np.random.default_rng(0)  # as Labeller.fit: at most per_shape elements of each shape
    picks = [rng.choice(len(d[1]), min(len(d[1]), fit.get("per_shape", 1000)), replace=False) for d in data]
    X = np.vstack([d[0][p] for d, p in zip(data, picks)])
    y = np.concatenate([d[1][p] for d, p in zip(data, picks)])
    w = np.concatenate([np.full(len(p), 1.0 / len(p)) for p in picks])
    present = np.unique(y)
    if len(present) < 2:
        present = np.array([present[0], (present[0] + 1) % 4])
    model = HistGradientBoostingClassifier(max_iter=fit.get("max_iter", 100), early_stopping=False, random_state=0)
    model.fit(X, np.searchsorted(present, y), sample_weight=w * len(data))

    class Fitted:
        names = [NAMES[k] for k in present]
        ensemble = TreeEnsemble.from_sklearn(model)

    return Fitted


# -- commands ----------------------------------------------------------------------------------


#: the models tried on the validation part: (features read, classifier options)
MODELS = {
    "frame (issue's features)": (LabellerSettings(neighbours=0, normals=False), {}),
    "+normals+local shape": (LabellerSettings(neighbours=16, normals=True), {}),
    "+normals+local shape, 15 leaves, l2 1": (LabellerSettings(neighbours=16, normals=True),
                                              {"max_leaf_nodes": 15, "l2_regularization": 1.0}),
}
#: the steps after the classifier, tried on each model without learning again: (smooth_neighbours,
#: smooth, min_share)
AFTER = [(9, 0, 0.0), (9, 2, 0.0), (27, 2, 0.0), (27, 4, 0.0), (9, 2, 0.01), (27, 2, 0.01), (27, 2, 0.02),
         (27, 4, 0.01), (27, 4, 0.02)]
#: ``--fill``, ``--hint``: the presence rule's fill and hint (:class:`primkit.labelling.presence.PresenceRule`)
#: instead of those ``Labeller.fit`` keeps (above 1: none)
FILL = {"fill": None, "hint": None}
#: ``--swap``: the validation protocol with the halves swapped (learn from validation chairs 100-218
#: of the seed-0 order, score chairs 0-99)
SWAP = {"on": False}
#: the classifier options of every model unless it says otherwise
FIT = {"per_shape": 1000, "max_iter": 100, "post": ["chair.arms_from_side_region", "chair.seat_layer_cut"]}
# Labeller.fit's defaults, said here, and the chair's post-steps (primkit.labelling.post)


def line(label, s):
    return (f"{label:48s} mean(back,seat,legs) {s['mean']:.3f}  arm IoU {s['arm_iou']:.3f}  arm F1 {s['arm_f1']:.3f}  "
            + " ".join(f"{k} {v:.3f}" for k, v in s["iou"].items()))


def _columns(parts, settings):
    """The columns of the full feature vector (normals and local shape) that ``settings`` read."""
    full = LabellerSettings(neighbours=16, normals=True, profile=True, sides=True)
    keep = np.ones(_feature_count(parts, full), bool)
    start = _feature_count(parts, replace(full, neighbours=0, normals=False, profile=False, sides=False))
    if not settings.normals:
        keep[start : start + 4] = False
    if not settings.neighbours:
        keep[start + 4 : start + 13] = False
    if not settings.profile:
        keep[start + 13 : start + 13 + PROFILE_FEATURES] = False
    if not settings.sides:
        keep[start + 13 + PROFILE_FEATURES :] = False
    return keep


def _feature_count(parts, settings):
    from primkit.segmentation.labeller import feature_count

    return feature_count(parts, settings)


def _knn(chairs, name, k, cache={}):
    key = (name, k)
    if key not in cache:
        from scipy.spatial import cKDTree

        points = chairs.arrays[name]["points"].astype(float)
        cache[key] = cKDTree(points).query(points, k=min(k, len(points)))[1].reshape(len(points), -1)
    return cache[key]


def _after(chairs, name, proba, smooth_neighbours, smooth, min_share, known):
    from primkit.segmentation.labeller import decide

    if smooth:
        idx = _knn(chairs, name, smooth_neighbours)
        for _ in range(smooth):
            proba = proba[idx].mean(axis=1)
    return known[decide(proba, min_share)]


def sweep(scratch: Path, sizes, only=None) -> dict:
    chairs = Chairs(scratch)
    pool = order(chairs.validation, 0)
    train_pool, held = pool[:100], pool[100:]
    print(f"validation: learn from the first N of {len(train_pool)}, score {len(held)} other validation chairs")
    print(line("index naming (bundled model)", score(chairs, held, index_naming(chairs, held))))
    need = train_pool[: max(sizes)] + held
    features = {n: chairs.full_features(n) for n in need}
    out = {}
    for label, (settings, fit) in MODELS.items():
        if only and label not in only:
            continue
        keep = _columns(chairs.parts, settings)
        for n in sizes:
            t0 = time.perf_counter()
            labeller = Labeller.fit([(features[c][:, keep], chairs.arrays[c]["truth"].astype(np.int64))
                                     for c in train_pool[:n]], NAMES, chairs.parts, settings=settings, **{**FIT, **fit})
            t1 = time.perf_counter()
            known = np.array([NAMES.index(k) for k in labeller.names])
            probas = {c: labeller.classify(features[c][:, keep]) for c in held}
            print(f"{label}, {n} chairs: {t1 - t0:.0f} s fit, {time.perf_counter() - t1:.0f} s label, "
                  f"{len(labeller.ensemble.feature)} nodes", flush=True)
            for k, rounds, share in AFTER:
                s = score(chairs, held, {c: _after(chairs, c, probas[c], k, rounds, share, known) for c in held})
                tag = f"{label}, {n}, smooth {k}x{rounds}, min share {share}"
                print("  " + line(tag, s), flush=True)
                out[tag] = s
    return out


def _validation_train(chairs, draw):
    """The labelled chairs of a validation draw: validation chairs 0-99 of the shuffle (seed 0), in
    shuffle ``draw`` (0: as they are), so that no draw learns from a scored chair (100-218);
    ``--swap``: chairs 100-218 (chairs 0-99 scored)."""
    pool = order(chairs.validation, 0)[100:] if SWAP["on"] else order(chairs.validation, 0)[:100]
    return pool if draw == 0 else order(pool, draw)


def curve(scratch: Path, part: str, sizes, draws: int, settings: LabellerSettings, labeller_only=False) -> dict:
    chairs = Chairs(scratch)
    scored = slice(100) if SWAP["on"] else slice(100, None)  # the validation chairs not learned from
    evaluate = chairs.test if part == "test" else order(chairs.validation, 0)[scored]
    print(f"{part}: {len(evaluate)} chairs scored; labellers learned from validation chairs; settings {settings}")
    rows = {"index naming (bundled model)": score(chairs, evaluate, index_naming(chairs, evaluate))}
    print(line("index naming (bundled model)", rows["index naming (bundled model)"]))
    for n in sizes:
        kinds = (("labeller", False), ("position only", True), ("index naming", None))
        for kind, position_only in kinds[:1] if labeller_only else kinds:
            runs = []
            for d in range(draws if n < 100 else 1):
                train = order(chairs.validation, d)[:n] if part == "test" else _validation_train(chairs, d)[:n]
                runs.append(score(chairs, evaluate, index_naming_from(chairs, train, evaluate) if position_only is None
                                  else learn_and_label(chairs, train, evaluate, settings, position_only=position_only)))
                print(line(f"{kind}, {n} chairs, draw {d}", runs[-1]), flush=True)
            mean = {k: float(np.mean([r[k] for r in runs])) for k in ("mean", "arm_iou", "arm_f1")}
            mean["iou"] = {k: float(np.mean([r["iou"][k] for r in runs])) for k in runs[0]["iou"]}
            rows[f"{kind}, {n} chairs"] = {"draws": runs, **mean}
            print(line(f"{kind}, {n} chairs, mean of {len(runs)}", mean), flush=True)
    return rows


def coseg(scratch: Path, settings: LabellerSettings, draws: int = 8) -> dict:
    """Learn from 3 of the 10 COSEG chairs, label the other 7 (faces right, mean over draws)."""
    from primkit.segmentation import Segmenter, read_ground_truth
    from primkit.segmentation.labeller import label_elements

    shared = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "coseg_chairs"
    conventions = {"large_chairs": "back,seat,legs", "chairs_101-120": "legs,seat,back"}
    files = sorted(shared.glob("*/shapes/*.off"))
    segmenter = Segmenter("chair")
    results, errors = segmenter.abstract_files(files, cache_dir=scratch / "prep-coseg", progress=False)
    shapes = []
    for r in results:
        folder = Path(r.source).parents[1]
        mesh = io.read_mesh(r.source)
        truth = read_ground_truth(folder / "gt" / f"{Path(r.source).stem}.seg", len(mesh.faces),
                                  conventions[folder.name], ["back", "seat", "legs"])
        el = mesh_elements(mesh.vertices, mesh.faces, r.frame)
        X = frame_features(el.points, r.canonical, el.normals, settings, el.context)
        shapes.append((r.name, X, truth.labels, el, r.canonical))
    import itertools

    triples = list(itertools.combinations(range(len(shapes)), 3))
    chosen = np.random.default_rng(0).choice(len(triples), draws, replace=False)  # distinct triples
    rows = []
    for d, t in enumerate(chosen):
        pick = np.array(triples[t])
        labeller = Labeller.fit([(shapes[i][1], shapes[i][2]) for i in pick], ["back", "seat", "legs"],
                                segmenter.abstractor.parts, settings=settings, **FIT)
        right = []
        order = np.array([["back", "seat", "legs"].index(k) for k in labeller.names])
        for i, (name, X, y, el, canonical) in enumerate(shapes):
            if i in pick:
                continue
            right.append(float(np.mean(order[label_elements(labeller, el, canonical)] == y)))  # as segment --semantic
        rows.append({"learned_from": [shapes[i][0] for i in pick], "faces_right": right, "mean": float(np.mean(right))})
        print(f"draw {d}: learned from {rows[-1]['learned_from']}: faces right on the other 7 "
              f"{np.round(right, 3).tolist()} mean {rows[-1]['mean']:.3f}", flush=True)
    print(f"mean over {draws} draws: {np.mean([r['mean'] for r in rows]):.3f}")
    return {"draws": rows, "mean": float(np.mean([r["mean"] for r in rows]))}


def model_figures(model: str, part: str) -> dict:
    """A model file's own labeller on a part, through the library (``Segmenter(model)``, as
    ``primkit segment --semantic`` runs it): the same scores as ``curve``."""
    from primkit import data
    from primkit.segmentation import Segmenter

    validation, test, archive = split()
    files = test if part == "test" else validation
    segmenter = Segmenter(model)
    if segmenter.labeller is None:
        raise SystemExit(f"{model}: no labeller in this model file")
    segs, errors = segmenter.segment_files(files, progress=False)
    index = {names: i for i, names in enumerate(NAMES)}
    codes = np.array([index[n] for n in segmenter.labeller.names])

    class Scored:  # the shape of Chairs that score() reads
        arrays = {}

    for s in segs:
        occupied = np.argwhere(s.grid.occupancy)
        truth = archive.get(s.name, s.grid.occupancy.shape).labels[tuple(occupied.T)]
        Scored.arrays[s.name] = {"index": occupied, "truth": truth}
    predictions = {s.name: codes[s.named[tuple(np.argwhere(s.grid.occupancy).T)]] for s in segs}
    out = score(Scored, [s.name for s in segs], predictions)
    print(line(f"{Path(model).name} on {len(segs)} {part} chairs", out) + f"; errors: {errors}")
    out["labelled_from"] = segmenter.labeller.info
    return {**out, "files": [data.shape_name(f) for f in files]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("command", choices=["prepare", "prepare-mirror", "sweep", "curve", "coseg", "model"])
    ap.add_argument("--model", default="chair", help="model: the model file whose labeller is scored")
    ap.add_argument("--scratch", type=Path, default=Path("/tmp/33-scratch"))
    ap.add_argument("--part", choices=["validation", "test"], default="validation")
    ap.add_argument("--sizes", default=None, help="comma-separated numbers of labelled chairs")
    ap.add_argument("--draws", type=int, default=3, help="draws of the labelled chairs under 100")
    ap.add_argument("--only", action="append", default=None, help="sweep: these candidates only")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--grid-sample", type=int, default=LabellerSettings().grid_sample, choices=[1, 2, 4, 8],
                    help="curve: classify one voxel in this many (LabellerSettings.grid_sample)")
    ap.add_argument("--labeller-only", action="store_true", help="curve: leave out the baselines")
    ap.add_argument("--knn", choices=["grid", "kdtree"], default="grid",
                    help="the local shape's nearest voxels: on the grid (as the library) or by a k-d tree (before); "
                         "give each its own --scratch (the features are cached there)")
    ap.add_argument("--profile", action=argparse.BooleanOptionalAction, default=LabellerSettings().profile,
                    help="curve, coseg: the shape-profile features (LabellerSettings.profile)")
    ap.add_argument("--presence", action=argparse.BooleanOptionalAction, default=True,
                    help="curve: the arms post-step (primkit.labelling.presence; on by default here)")
    ap.add_argument("--sides", action=argparse.BooleanOptionalAction, default=LabellerSettings().sides,
                    help="curve, coseg: the side features (LabellerSettings.sides)")
    ap.add_argument("--mirror", action="store_true",
                    help="curve: learn from the labelled chairs' mirrors too (run prepare-mirror first)")
    ap.add_argument("--self-train", default=None, metavar="ROUNDS:THRESHOLD:WEIGHT",
                    help="curve: self-training with the validation chairs 0-99 not learned from, unlabelled "
                    "(primkit.segmentation.selftrain.SelfTraining), e.g. 1:0.9:0.5")
    ap.add_argument("--fill", type=float, default=None,
                    help="curve: the presence rule's fill (default: PresenceRule's; above 1: none)")
    ap.add_argument("--hint", type=float, default=None,
                    help="curve: the presence rule's hint (default: PresenceRule's; above 1: none)")
    ap.add_argument("--layer-cut", action=argparse.BooleanOptionalAction, default=True,
                    help="curve: the seat/legs layer cut post-step (primkit.labelling.layers; on by default here)")
    ap.add_argument("--swap", action="store_true",
                    help="curve --part validation: learn from validation chairs 100-218, score chairs 0-99")
    args = ap.parse_args(argv)
    KNN["how"] = args.knn
    FILL["fill"], FILL["hint"], SWAP["on"] = args.fill, args.hint, args.swap
    if not args.presence:
        FIT["post"] = [s for s in FIT["post"] if s != PresenceRule.STEP]
    if not args.layer_cut:
        FIT["post"] = [s for s in FIT["post"] if s != LayerCut.STEP]
    if args.mirror:
        MIRROR["chairs"] = Chairs(args.scratch / "mirror")
    if args.self_train:
        from primkit.segmentation.selftrain import SelfTraining

        rounds, threshold, weight = args.self_train.split(":")
        SELF_TRAINING.update(pool=True, how=SelfTraining(int(rounds), float(threshold), float(weight)))
    args.scratch.mkdir(parents=True, exist_ok=True)
    sizes = [int(s) for s in args.sizes.split(",")] if args.sizes else None
    if args.command == "prepare":
        prepare(args.scratch)
        return 0
    if args.command == "prepare-mirror":
        prepare_mirror(args.scratch)
        return 0
    if args.command == "sweep":
        out = sweep(args.scratch, sizes or [10, 40], args.only)
    elif args.command == "model":
        out = model_figures(args.model, args.part)
    elif args.command == "curve":
        out = curve(args.scratch, args.part, sizes or SIZES, args.draws,
                    LabellerSettings(grid_sample=args.grid_sample, profile=args.profile, sides=args.sides),
                    args.labeller_only)
    else:
        out = coseg(args.scratch, LabellerSettings(profile=args.profile, sides=args.sides))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

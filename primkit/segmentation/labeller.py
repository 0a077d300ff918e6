"""Part names per element: a classifier over features of the primitive frame.

One label per primitive index (:func:`primkit.model.parts.names_from_labels`) cannot do better
than the cuboids allow: a front-leg cuboid that also holds the arm post is all ``legs`` or all
``arms``. A :class:`Labeller` names every element (voxel, face, point) on its own, from where it
sits in the shape's abstraction, which means the same thing on every shape of a model:

* the index of its nearest present cuboid (one-hot over the model's ``m`` slots);
* its coordinates in every cuboid's local frame divided by that cuboid's half extents (``m x 3``;
  NaN for absent slots), those in its nearest cuboid first;
* its distance to every cuboid (``m``; NaN for absent slots);
* its position and, where known, its outward normal, in the model's canonical frame (+Y up,
  +X front, the longest side of the bounding box 1: :class:`primkit.geometry.CanonicalFrame`);
* the local shape around it: the principal axes of its ``k`` nearest neighbours among the shape's
  elements (how flat, thin or round it is there, and which way); on a voxel grid the nearest
  voxels are found on the grid (:func:`grid_local_shape`), elsewhere by a k-d tree.
* where it sits in the shape's own occupancy (:mod:`primkit.segmentation.profile`: its place in the
  bounding box, how full its horizontal slab is, what lies above, below, in front and behind it)
  and against its seat (:mod:`primkit.segmentation.sides`: how far beside the densest slab's middle,
  whether its column rises above it: arms against seat edges and back wings).

A gradient-boosted tree ensemble (scikit-learn's ``HistGradientBoostingClassifier``) learns the
labels from a few labelled shapes; its class probabilities are blended with the index-naming
prior (the shares of the labels on each cuboid index over the labelled shapes, ``prior_weight``),
then averaged over each element's nearest neighbours (``smooth`` rounds), and each element takes
the most probable label; then the post-steps its file names run in order
(:mod:`primkit.segmentation.post`: a category's rules, e.g. a chair's arms read from what rises
beside the seat, and where its seat ends), each with the labels it was told; none is chosen by
how a label is spelled.

Storage without code: the fitted trees are exported to plain arrays (:class:`TreeEnsemble`: per
node the feature, threshold, children, leaf value and the side missing values go to) and saved as
safetensors tensors beside a JSON description with its own format version
(:func:`write_labeller`, :func:`read_labeller`). Reading one parses JSON and copies numbers; every
array is checked (shapes, dtypes, child indices inside their tree, feature indices inside the
feature vector, trees that end) before use, and any failure is one :class:`ModelFileError` line.
Predictions walk the exported trees with a Numba kernel that gives scikit-learn's
``predict_proba`` (the same ``<=`` rule, the same handling of NaN, float64 sums, the same
softmax), so the stored labeller labels exactly as the fitted one did; the nodes are packed into
two arrays on load for the walk (:meth:`TreeEnsemble.packed`), the stored arrays unchanged.

Frames: points, normals and cuboids given to :meth:`Labeller.features` are in the canonical frame
(``AbstractionResult.canonical`` and ``AbstractionResult.frame.to_canonical``); the
``label_*`` helpers take the input frame and a frame, as the segmentations hold them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import primitives
from ..model.modelfile import ModelFileError
from .layers import layer_levels
from .post import resolve_post, step_from_dict, step_to_dict
from .profile import PROFILE_FEATURES, column_range, profile_features
from .sides import SIDE_FEATURES, side_features

__all__ = [
    "LABELLER_FORMAT",
    "LABELLER_FORMAT_VERSION",
    "LABELLER_PREFIX",
    "TreeEnsemble",
    "LabellerSettings",
    "Labeller",
    "frame_features",
    "decide",
    "grid_normals",
    "grid_neighbours",
    "grid_sampling",
    "grid_knn",
    "grid_local_shape",
    "write_labeller",
    "read_labeller",
    "has_labeller",
    "names_by_index",
]

#: Value of the ``format`` key of a labeller's JSON description.
LABELLER_FORMAT = "primkit-labeller"
#: Version of the labeller's arrays and description: the only one read (a file of another version
#: is refused in one line that says how to learn it again). Every field is written, the post-steps
#: as a list (``post``, :mod:`primkit.segmentation.post`); feature and child indices as int16.
LABELLER_FORMAT_VERSION = 11
#: Every key of a labeller's description.
DESCRIPTION_KEYS = ("format", "format_version", "names", "parts", "features", "settings", "classifier", "info", "post")
#: How a labeller file rebuilds: the message of a refused version ends with it.
LABELLER_REBUILD = "learn it again with `primkit name-parts LABELLED --model MODEL -o FILE` (docs/labeller.md)"
#: Prefix of a labeller's tensors in a model file (beside the network's weights).
LABELLER_PREFIX = "labeller."
#: Metadata key of a labeller's description in a model file.
LABELLER_KEY = "labeller"

#: The value of an absent slot's coordinates and distance: past any present one (a value, not NaN:
#: scikit-learn cannot bin a column that is missing on every training shape).
ABSENT = 1.0e4

#: How the file stores the tree arrays whose type differs from the one in memory
#: (:attr:`TreeEnsemble.ARRAYS`): feature and child indices in int16 (a third of the bytes per
#: node: the bundled chair model's labeller fits the wheel).
STORED = {"feature": np.int16, "left": np.int16, "right": np.int16}

#: ``Labeller.fit`` keeps a post-step it checks when it contradicts at most this share of the
#: labelled shapes' own labels (the arms rule: it would take their label away, or give it to a
#: shape without it, on 13 of the 219 PartNet validation chairs, 5.9%; the seat cut: it would move
#: more than a tenth of a grid's seat and legs voxels on 16 of the 218 with a seat, 7%).
POST_TOLERANCE = 0.2

#: Bounds on what a stored labeller may ask for (a hostile file allocates nothing beyond them).
MAX_NODES = 50_000_000
MAX_TREES = 1_000_000
MAX_CLASSES = 256
MAX_PARTS = 1024


# ---------------------------------------------------------------------------------------------
# Tree ensembles as plain arrays
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TreeEnsemble:
    """A gradient-boosted tree ensemble as plain arrays (all the trees' nodes end to end).

    Attributes
    ----------
    feature : (N,) int64
        Feature tested at each split node (ignored at leaves).
    threshold : (N,) float64
        A sample goes left when ``x[feature] <= threshold``.
    missing_left : (N,) uint8
        1: a NaN goes left, 0: right.
    left, right : (N,) int64
        Children, as indices *inside the node's tree* (its root is 0).
    is_leaf : (N,) uint8
    value : (N,) float64
        The raw score a leaf adds.
    tree_start : (T + 1,) int64
        Tree ``t``'s nodes are ``tree_start[t]:tree_start[t + 1]``.
    tree_class : (T,) int64
        Which raw score (class column) tree ``t`` adds to.
    baseline : (K,) float64
        The raw scores before any tree (``K`` = 1 for two classes, else the number of classes).
    features : int
        Length of the feature vector.

    ``predict_proba`` follows scikit-learn's: the raw scores summed in float64 over the trees in
    order, then the logistic function (two classes) or the softmax.
    """

    feature: np.ndarray
    threshold: np.ndarray
    missing_left: np.ndarray
    left: np.ndarray
    right: np.ndarray
    is_leaf: np.ndarray
    value: np.ndarray
    tree_start: np.ndarray
    tree_class: np.ndarray
    baseline: np.ndarray
    features: int

    ARRAYS = {"feature": np.int64, "threshold": np.float64, "missing_left": np.uint8, "left": np.int64,
              "right": np.int64, "is_leaf": np.uint8, "value": np.float64, "tree_start": np.int64,
              "tree_class": np.int64, "baseline": np.float64}

    @classmethod
    def from_sklearn(cls, model) -> "TreeEnsemble":
        """Export a fitted ``HistGradientBoostingClassifier`` (numeric features only)."""
        if getattr(model, "is_categorical_", None) is not None and np.any(model.is_categorical_):
            raise ValueError("categorical features are not exported (give them one-hot)")
        nodes, starts, classes = [], [0], []
        for iteration in model._predictors:
            for k, predictor in enumerate(iteration):
                nodes.append(predictor.nodes)
                starts.append(starts[-1] + len(predictor.nodes))
                classes.append(k)
        allnodes = np.concatenate(nodes)
        return cls(allnodes["feature_idx"].astype(np.int64), allnodes["num_threshold"].astype(np.float64),
                   allnodes["missing_go_to_left"].astype(np.uint8), allnodes["left"].astype(np.int64),
                   allnodes["right"].astype(np.int64), allnodes["is_leaf"].astype(np.uint8),
                   allnodes["value"].astype(np.float64), np.array(starts, np.int64), np.array(classes, np.int64),
                   np.asarray(model._baseline_prediction, np.float64).reshape(-1), int(model.n_features_in_))

    @property
    def classes(self) -> int:
        """The number of classes: 2 for one raw score, else the number of raw scores."""
        return 2 if len(self.baseline) == 1 else len(self.baseline)

    def arrays(self) -> dict:
        return {name: getattr(self, name) for name in self.ARRAYS}

    def check(self, where="labeller") -> None:
        """Raise ValueError unless the arrays describe trees that a walk from each root ends in:
        matching lengths, children inside their own tree and after their parent (so no cycle),
        features inside the feature vector, classes inside the raw scores, finite leaf values."""
        n = len(self.feature)
        for name, dtype in self.ARRAYS.items():
            a = getattr(self, name)
            if not isinstance(a, np.ndarray) or a.dtype != dtype or a.ndim != 1:
                raise ValueError(f"{where}: {name} must be a 1-d {np.dtype(dtype).name} array")
        if not all(len(getattr(self, k)) == n for k in ("threshold", "missing_left", "left", "right", "is_leaf",
                                                        "value")):
            raise ValueError(f"{where}: the node arrays differ in length")
        trees = len(self.tree_class)
        k = len(self.baseline)
        if not 1 <= k <= MAX_CLASSES or k == 2:
            raise ValueError(f"{where}: {k} raw scores (1 for two classes, else 3 to {MAX_CLASSES})")
        if not 0 < n <= MAX_NODES or not 0 < trees <= MAX_TREES or len(self.tree_start) != trees + 1:
            raise ValueError(f"{where}: {n} nodes in {trees} trees with {len(self.tree_start)} tree starts")
        if not 0 < self.features <= 1_000_000:
            raise ValueError(f"{where}: {self.features} features")
        start = self.tree_start
        if start[0] != 0 or start[-1] != n or np.any(np.diff(start) < 1):
            raise ValueError(f"{where}: tree starts are not increasing from 0 to the node count")
        if np.any((self.tree_class < 0) | (self.tree_class >= k)):
            raise ValueError(f"{where}: a tree adds to a raw score that does not exist")
        size = np.repeat(np.diff(start), np.diff(start))
        local = np.arange(n) - np.repeat(start[:-1], np.diff(start))
        split = self.is_leaf == 0
        if np.any(self.is_leaf > 1) or np.any(self.missing_left > 1):
            raise ValueError(f"{where}: is_leaf and missing_left must be 0 or 1")
        for child in (self.left, self.right):
            if np.any(split & ((child <= local) | (child >= size))):
                raise ValueError(f"{where}: a child index points outside its tree or back up it")
        if np.any(split & ((self.feature < 0) | (self.feature >= self.features))):
            raise ValueError(f"{where}: a split tests a feature past the {self.features} features")
        if not np.all(np.isfinite(self.value[~split])) or np.any(np.isnan(self.threshold[split])):
            raise ValueError(f"{where}: non-finite leaf values or NaN thresholds")
        if not np.all(np.isfinite(self.baseline)):
            raise ValueError(f"{where}: non-finite baseline")

    def raw_predict(self, X, stop=None) -> np.ndarray:
        """``(n, K)`` float64 raw scores of the ``(n, features)`` samples ``X`` (NaN: missing).

        ``stop``: ``(rounds, margin, taper)`` or None (every tree). With it, a sample leaves the
        walk after any boosting round ``r`` from ``rounds`` on at which its two largest class
        scores (two classes: the one raw score and 0) lie more than ``margin + taper * (R - r) /
        R`` apart (``R`` rounds in all: a gap asked of it that shrinks to ``margin`` at the last
        round); its scores are then the sums over the rounds walked (:data:`EARLY_STOP`; an
        approximation, validated in ``docs/labeller.md``). Ensembles whose trees are not in
        round order walk every tree."""
        X = np.ascontiguousarray(X, np.float64)
        if X.ndim != 2 or X.shape[1] != self.features:
            raise ValueError(f"`X` must be (n, {self.features}) float, got shape {X.shape}")
        out = np.empty((len(X), len(self.baseline)))
        out[:] = self.baseline
        if len(X):
            packed = self.packed()
            if packed is not None:
                rounds, margin, taper = stop if stop is not None and self.in_rounds() else (NEVER, 0.0, 0.0)
                _packed_kernel()(X, *packed, self.tree_class, len(self.baseline), int(rounds), float(margin),
                                 float(taper), out)
            else:
                _kernel()(X, self.feature, self.threshold, self.missing_left, self.left, self.right, self.is_leaf,
                          self.value, self.tree_start, self.tree_class, out)
        return out

    def packed(self):
        """The nodes packed for :func:`_packed_kernel` (built once, kept on the instance), or
        None when they do not fit its fields (:data:`PACKED_FEATURES` features, :data:`PACKED_NODES`
        nodes; the plain kernel walks those).

        Returns ``(meta (N,) int64, split_or_value (N,) float64, missing_left (N,) uint8, roots (T,)
        int64)``: ``meta`` holds a node's feature in bits 0-15 (:data:`PACKED_LEAF` at a leaf), its
        left child's global index in bits 16-39 and its right child's in bits 40-63;
        ``split_or_value`` is the threshold at a split and the leaf value at a leaf. Two arrays of
        8 bytes a node instead of seven (a third of the bytes the walk pulls through the cache)."""
        cached = self.__dict__.get("_packed")
        if cached is None:
            n = len(self.feature)
            fits = n < PACKED_NODES and self.features < PACKED_LEAF
            if not fits:
                cached = ()
            else:
                leaf = self.is_leaf == 1
                base = np.repeat(self.tree_start[:-1], np.diff(self.tree_start))
                left = np.where(leaf, 0, base + self.left)
                right = np.where(leaf, 0, base + self.right)
                meta = np.where(leaf, PACKED_LEAF, self.feature) | (left << 16) | (right << 40)
                cached = (meta.astype(np.int64), np.where(leaf, self.value, self.threshold).astype(np.float64),
                          np.ascontiguousarray(self.missing_left, np.uint8), self.tree_start[:-1].astype(np.int64))
            object.__setattr__(self, "_packed", cached)  # frozen dataclass: a cache, not a field
        return cached or None

    def in_rounds(self) -> bool:
        """Whether the trees come in boosting rounds, one tree per raw score each (tree ``t`` adds
        to score ``t % K``), as scikit-learn's are exported: what an early stop needs."""
        k = len(self.baseline)
        return len(self.tree_class) % k == 0 and np.array_equal(self.tree_class, np.arange(len(self.tree_class)) % k)

    def predict_proba(self, X, stop=None) -> np.ndarray:
        """``(n, classes)`` probabilities, as the exported model's ``predict_proba`` (``stop``:
        :meth:`raw_predict`'s early stop; None: exactly)."""
        raw = self.raw_predict(X, stop)
        if raw.shape[1] == 1:  # scikit-learn's binomial loss: expit of the one raw score
            from scipy.special import expit

            p = expit(raw[:, 0])
            return np.stack([1.0 - p, p], axis=1)
        # scipy.special.softmax(raw, axis=1)'s three operations (the same numbers), without its
        # array-API dispatch (a quarter of a millisecond a chair)
        shifted = np.exp(raw - raw.max(axis=1, keepdims=True))
        return shifted / shifted.sum(axis=1, keepdims=True)


_KERNEL = None


def _kernel():
    """The Numba tree walk, compiled on first use (a few hundred milliseconds, cached on disk).

    Written here rather than taken from scikit-learn: its predictor needs its fitted Python
    objects (a pickle to store), and a per-level NumPy walk over every tree at once is ten times
    slower on a 4,000-voxel chair."""
    global _KERNEL
    if _KERNEL is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def walk(X, feature, threshold, missing_left, left, right, is_leaf, value, tree_start, tree_class, out):
            # one sample at a time through every tree (its row stays in cache); the trees in
            # order, as scikit-learn adds them, so the float64 sums are the same
            for i in range(X.shape[0]):
                for t in range(len(tree_class)):
                    base = tree_start[t]
                    node = base
                    while is_leaf[node] == 0:
                        x = X[i, feature[node]]
                        if np.isnan(x):
                            go_left = missing_left[node] == 1
                        else:
                            go_left = x <= threshold[node]
                        node = base + (left[node] if go_left else right[node])
                    out[i, tree_class[t]] += value[node]

        _KERNEL = walk
    return _KERNEL


#: :meth:`TreeEnsemble.packed`'s fields: a feature index below PACKED_LEAF (its value marks a
#: leaf), a node index below PACKED_NODES (24 bits)
PACKED_LEAF = 0xFFFF
PACKED_NODES = 1 << 24

#: The labeller's early stop in the tree walk (:meth:`TreeEnsemble.raw_predict`'s ``stop``, no
#: taper): after at least 15 rounds, a sample whose two best raw scores lie 2.5 apart (odds of 12
#: to 1 between them) walks no further trees: about 44 rounds of 100 on average on a chair's
#: voxels, a quarter of them walking all. Chosen on the PartNet validation chairs
#: (``docs/labeller.md``, "Cost": 99.85% of the voxels keep the label the full walk gives).
EARLY_STOP = (15, 2.5, 0.0)

#: :func:`_packed_kernel`'s ``rounds`` for a walk that never stops early (every tree)
NEVER = np.iinfo(np.int64).max

_PACKED = None


def _packed_kernel():
    """The tree walk over :meth:`TreeEnsemble.packed` nodes, compiled on first use (cached on disk).

    The same walk as :func:`_kernel` (the same ``<=`` rule, NaN to the stored side, each sample
    through the trees in order, so the float64 sums are identical), reading two arrays per node
    instead of seven: on the bundled chair labeller (24,400 nodes) about a third less time.
    Tried and slower here: a branch-free walk of every tree to its full depth, blocks of samples
    walked tree by tree (both in ``docs/labeller.md``).

    With an early stop (:meth:`TreeEnsemble.raw_predict`): the trees in rounds of ``k``, the same
    sums as the full walk over the rounds a sample walks; after each round ``r`` from ``rounds``
    on, the sample stops when its two best scores (``k`` = 1: the score and 0) differ by more
    than ``margin + taper * (R - r) / R``. ``rounds`` = :data:`NEVER` walks every tree (one
    integer test a tree more than a walk without the stop)."""
    global _PACKED
    if _PACKED is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def walk_packed(X, meta, split_or_value, missing_left, roots, tree_class, k, rounds, margin, taper, out):
            trees = roots.shape[0]
            total = trees // k
            for i in range(X.shape[0]):
                for t in range(trees):
                    node = roots[t]
                    m = meta[node]
                    while (m & 0xFFFF) != 0xFFFF:
                        x = X[i, m & 0xFFFF]
                        if x <= split_or_value[node]:
                            node = (m >> 16) & 0xFFFFFF
                        elif x > split_or_value[node]:
                            node = (m >> 40) & 0xFFFFFF
                        elif missing_left[node] == 1:  # NaN
                            node = (m >> 16) & 0xFFFFFF
                        else:
                            node = (m >> 40) & 0xFFFFFF
                        m = meta[node]
                    out[i, tree_class[t]] += split_or_value[node]
                    if (t + 1) % k == 0 and (t + 1) // k >= rounds:
                        if k == 1:
                            gap = abs(out[i, 0])
                        else:
                            best = second = -np.inf
                            for c in range(k):
                                v = out[i, c]
                                if v > best:
                                    second = best
                                    best = v
                                elif v > second:
                                    second = v
                            gap = best - second
                        if gap > margin + taper * (total - (t + 1) // k) / total:
                            break

        _PACKED = walk_packed
    return _PACKED


_MEAN = None


def _mean_kernel():
    """``out[i] = proba[idx[i, :k]].mean(axis=0)`` (the neighbours summed in order, then divided, as
    NumPy's ``proba[idx[:, :k]].mean(axis=1)``), compiled on first use: the gather NumPy does makes
    an ``(n, k, classes)`` copy and costs ten times as much on a chair's voxels. The classes come
    four at a time (``proba`` has a multiple of 4 columns, :func:`_pad4`), their sums in registers:
    half the time of one class at a time; each class's sum in the same order."""
    global _MEAN
    if _MEAN is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def mean_over(proba, idx, k, out):
            for i in range(idx.shape[0]):
                for c in range(0, proba.shape[1], 4):
                    t0 = t1 = t2 = t3 = 0.0
                    for j in range(k):
                        p = idx[i, j]
                        t0 += proba[p, c]
                        t1 += proba[p, c + 1]
                        t2 += proba[p, c + 2]
                        t3 += proba[p, c + 3]
                    out[i, c], out[i, c + 1], out[i, c + 2], out[i, c + 3] = t0 / k, t1 / k, t2 / k, t3 / k

        _MEAN = mean_over
    return _MEAN


def _pad4(proba) -> np.ndarray:
    """``proba`` as contiguous float64 with zero columns added up to a multiple of 4 (for
    :func:`_mean_kernel` and the fill of :func:`_sample_fill_kernels`)."""
    proba = np.ascontiguousarray(proba, np.float64)
    extra = -proba.shape[1] % 4
    return np.hstack([proba, np.zeros((len(proba), extra))]) if extra else proba


_SAMPLE_FILL = None


def _sample_fill_kernels():
    """``(sample, fill)``, compiled on first use (cached on disk): :func:`grid_sampling`'s
    ``classify`` and ``sampled`` from the voxel indices and the 27 neighbours in one loop, and the
    fill of :meth:`Labeller.predict_proba` read straight from the neighbours (each unclassified
    voxel's classes: the mean of its neighbours ``1:27`` that are other sampled voxels, summed in
    order, as the ``around``/``use`` arrays of :func:`grid_sampling` give it) without building
    those arrays; ``proba`` with a multiple of 4 columns (:func:`_pad4`), as :func:`_mean_kernel`."""
    global _SAMPLE_FILL
    if _SAMPLE_FILL is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def sample(index, neighbours, step, sampled, classify):
            n = index.shape[0]
            for i in range(n):
                a, b, c = index[i, 0] % 2, index[i, 1] % 2, index[i, 2] % 2
                if step == 1:
                    sampled[i] = True
                elif step == 2:
                    sampled[i] = (a + b + c) % 2 == 0
                elif step == 4:
                    sampled[i] = a == b and b == c
                else:
                    sampled[i] = a == 0 and b == 0 and c == 0
            for i in range(n):
                classify[i] = sampled[i]
                if not sampled[i]:
                    found = False
                    for j in range(1, 27):
                        p = neighbours[i, j]
                        if p != i and sampled[p]:
                            found = True
                            break
                    classify[i] = not found

        @numba.njit(cache=True, nogil=True)
        def fill(proba, neighbours, sampled, classify):
            for i in range(proba.shape[0]):
                if classify[i]:
                    continue
                for c in range(0, proba.shape[1], 4):
                    t0 = t1 = t2 = t3 = 0.0
                    count = 0
                    for j in range(1, 27):
                        p = neighbours[i, j]
                        if p != i and sampled[p]:
                            t0 += proba[p, c]
                            t1 += proba[p, c + 1]
                            t2 += proba[p, c + 2]
                            t3 += proba[p, c + 3]
                            count += 1
                    proba[i, c], proba[i, c + 1], proba[i, c + 2], proba[i, c + 3] = \
                        t0 / count, t1 / count, t2 / count, t3 / count

        _SAMPLE_FILL = (sample, fill)
    return _SAMPLE_FILL


def _grid_sample(index, neighbours, step: int):
    """``(classify (n,) bool, sampled (n,) bool)`` of :func:`grid_sampling` (its checks done by
    the caller or there)."""
    n = len(index)
    sampled, classify = np.empty(n, bool), np.empty(n, bool)
    if n:
        _sample_fill_kernels()[0](index, neighbours, int(step), sampled, classify)
    return classify, sampled


# ---------------------------------------------------------------------------------------------
# Features of the primitive frame
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LabellerSettings:
    """How a labeller reads a shape (stored with it; the defaults were chosen on the PartNet
    validation chairs, ``scripts/labeller_curve.py``).

    neighbours : int
        Elements whose principal axes describe the local shape around each element (0: none).
    smooth_neighbours, smooth : int
        The class probabilities are averaged over each element's ``smooth_neighbours`` nearest
        elements (itself included), ``smooth`` times (0: no smoothing).
    normals : bool
        Whether normals are features (zero where a shape has none).
    min_share : float
        A label given to fewer than this share of a shape's elements is dropped from it (they take
        their next most probable label): a chair with a few stray "arm" voxels has no arms.
    grid_sample : int
        On a voxel grid, the classifier reads one voxel in ``grid_sample`` (1: all; 2: a 3-D
        checkerboard, ``i + j + k`` even; 4: the voxels whose three indices are all even or all
        odd; 8: the voxels whose three indices are even); every other
        voxel takes the mean probabilities of the classified voxels of its 3 x 3 x 3 neighbourhood
        (or is classified itself when it has none), before the smoothing. Labelling costs about
        ``1 / grid_sample`` of the features and the tree walk.
    prior_weight : float
        The classifier's probabilities are blended with the index-naming prior: ``(1 - w) p + w
        prior[k]``, ``prior[k]`` the shares of the labels among the labelled elements whose nearest
        cuboid is ``k`` (:attr:`Labeller.prior`; each labelled shape weighing the same). With few
        labelled shapes the prior (what one name per index knows) steadies the trees. None (the
        default): chosen by :meth:`Labeller.fit` from the number ``s`` of labelled shapes,
        ``min(0.4, 4 / s)`` (0.4 up to 10 shapes, 0.1 from 40: the best on the PartNet
        validation chairs from 3, 10 and 40).
    profile : bool
        Whether the shape-profile features (:func:`primkit.segmentation.profile.profile_features`)
        follow the frame's.
    sides : bool
        Whether the side features (:func:`primkit.segmentation.sides.side_features`) end the
        feature vector (after the profile's).
    """

    neighbours: int = 16
    smooth_neighbours: int = 19
    smooth: int = 2
    normals: bool = True
    min_share: float = 0.01
    grid_sample: int = 4
    prior_weight: float | None = None
    profile: bool = True
    sides: bool = False

    #: the values ``grid_sample`` may take
    GRID_SAMPLES = (1, 2, 4, 8)

    def to_dict(self) -> dict:
        return {"neighbours": self.neighbours, "smooth_neighbours": self.smooth_neighbours, "smooth": self.smooth,
                "normals": self.normals, "min_share": self.min_share, "grid_sample": self.grid_sample,
                "prior_weight": self.prior_weight, "profile": self.profile, "sides": self.sides}

    @classmethod
    def from_dict(cls, d: dict) -> "LabellerSettings":
        keys = cls(prior_weight=0.0).to_dict()
        if not isinstance(d, dict) or set(d) != set(keys):
            raise ValueError(f"settings must be a JSON object with {', '.join(sorted(keys))}")
        out = {}
        for key, default in keys.items():
            value = d[key]
            if isinstance(default, bool):
                if not isinstance(value, bool):
                    raise ValueError(f"settings {key} must be true or false")
            elif isinstance(default, float):
                if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0 <= value < 1:
                    raise ValueError(f"settings {key} must be a number in [0, 1)")
                value = float(value)
            elif not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 256:
                raise ValueError(f"settings {key} must be an integer in 0-256")
            if key == "grid_sample" and value not in cls.GRID_SAMPLES:
                raise ValueError(f"settings grid_sample must be one of {', '.join(map(str, cls.GRID_SAMPLES))}")
            out[key] = value
        return cls(**out)


def feature_count(parts: int, settings: LabellerSettings) -> int:
    """Length of the feature vector of a model with ``parts`` slots."""
    return 3 + parts + 3 + 3 * parts + parts + (4 if settings.normals else 0) + (9 if settings.neighbours else 0) \
        + (PROFILE_FEATURES if settings.profile else 0) + (SIDE_FEATURES if settings.sides else 0)


def _neighbours(points: np.ndarray, k: int) -> np.ndarray:
    """``(n, min(k, n))`` indices of each point's nearest points (itself first)."""
    from scipy.spatial import cKDTree

    k = min(k, len(points))
    _, idx = cKDTree(points).query(points, k=k)
    return idx.reshape(len(points), k)


def _local_shape(points: np.ndarray, k: int) -> np.ndarray:
    """``(n, 9)``: the eigenvalues of the covariance of each point's ``k`` nearest points over
    their sum (linear, flat or round), and the absolute components of the largest and smallest
    principal axes (which way the part runs, which way it faces)."""
    if len(points) < 3:
        return np.full((len(points), 9), np.nan)
    idx = _neighbours(points, k)
    near = points[idx] - points[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", near, near) / idx.shape[1]
    return _shape_columns(cov)


def _shape_columns(cov: np.ndarray) -> np.ndarray:
    """``(n, 9)`` local-shape columns of ``(n, 3, 3)`` covariances (:func:`_local_shape`)."""
    values, vectors = np.linalg.eigh(cov)  # ascending
    total = values.sum(axis=1, keepdims=True)
    shares = np.divide(values, total, out=np.full_like(values, 1.0 / 3), where=total > 0)
    return np.hstack([shares, np.abs(vectors[:, :, 2]), np.abs(vectors[:, :, 0])])


#: how far (in voxels) :func:`grid_local_shape` looks for a voxel's nearest occupied voxels
#: before it asks a k-d tree (a ball of 2,109 offsets; a one-voxel-thin line reaches its 16
#: nearest at 8 voxels)
GRID_RADIUS = 8


@functools.lru_cache(maxsize=4)
def _ball_offsets(radius: int) -> np.ndarray:
    """``(b, 3) int64``: the grid offsets within ``radius`` voxels, nearest first (ties in
    lexicographic order), the zero offset first."""
    r = np.arange(-radius, radius + 1)
    offsets = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    d2 = np.einsum("ij,ij->i", offsets, offsets)
    offsets = offsets[d2 <= radius * radius]
    d2 = d2[d2 <= radius * radius]
    offsets = np.ascontiguousarray(offsets[np.lexsort((offsets[:, 2], offsets[:, 1], offsets[:, 0], d2))])
    offsets.flags.writeable = False  # shared between calls
    return offsets


def grid_knn(index, rows, k: int, shape, radius: int = GRID_RADIUS):
    """The ``k`` nearest occupied voxels of some occupied voxels, by index arithmetic on the grid.

    Parameters
    ----------
    index : (c, 3) int
        The occupied voxels' indices (e.g. ``np.argwhere``), all distinct, inside ``shape``.
    rows : (n,) int
        Which of them to find neighbours for (positions in ``index``).
    k : int
    shape : the grid's shape.

    Returns
    -------
    near : (n, k) int64, positions in ``index`` of each voxel's ``k`` nearest occupied voxels (by
        the distance between voxel centres, itself first; among voxels at the same distance, the
        one whose offset comes first in lexicographic order); rows not found are -1.
    found : (n,) bool, False where fewer than ``k`` occupied voxels lie within ``radius`` voxels
        (the caller asks a k-d tree for those).

    Why hand-written: a k-d tree (scipy's ``cKDTree``) on a chair's voxels spends most of the
    local-shape features' time finding what a scan of the grid around each voxel, nearest offset
    first, finds in a tenth of it (``docs/labeller.md``); the set differs from the k-d tree's only
    in which of several voxels at the k-th distance it keeps.
    """
    index = np.asarray(index, np.int64).reshape(-1, 3)
    rows = np.asarray(rows, np.int64).reshape(-1)
    lookup = np.full(tuple(np.asarray(shape, np.int64) + 2 * radius), -1, np.int64)  # padded: no bounds checks
    lookup[tuple((index + radius).T)] = np.arange(len(index))
    near = np.full((len(rows), k), -1, np.int64)
    found = np.zeros(len(rows), bool)
    if len(rows) and k > 0:
        _grid_knn_kernel()(index, rows, lookup.reshape(-1), _flat(_ball_offsets(radius), lookup.shape), radius,
                           lookup.shape[1], lookup.shape[2], near, found)
    return near, found


def _flat(offsets, shape) -> np.ndarray:
    """``(b,) int64``: 3-D grid offsets as offsets into the flattened C-order grid of ``shape``
    (the Numba lookups index one flat array: a third of the time of three-index lookups)."""
    return np.ascontiguousarray(offsets @ np.array([shape[1] * shape[2], shape[2], 1], np.int64))


_GRID_KNN = None


def _grid_knn_kernel():
    """Numba scan for :func:`grid_knn`, compiled on first use (cached on disk)."""
    global _GRID_KNN
    if _GRID_KNN is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def scan(index, rows, lookup, offsets, pad, b, c, near, found):  # lookup: (a, b, c) padded by pad, flat
            k = near.shape[1]
            for q in range(rows.shape[0]):
                base = ((index[rows[q], 0] + pad) * b + index[rows[q], 1] + pad) * c + index[rows[q], 2] + pad
                count = 0
                for o in range(offsets.shape[0]):
                    p = lookup[base + offsets[o]]
                    if p >= 0:
                        near[q, count] = p
                        count += 1
                        if count == k:
                            found[q] = True
                            break

        _GRID_KNN = scan
    return _GRID_KNN


_COV = None


def _cov_kernel():
    """``cov[i]``: the covariance of ``points[near[i]]`` (centred on their mean, divided by ``k``,
    as :func:`_local_shape`), compiled on first use: NumPy's gather makes an ``(n, k, 3)`` copy
    twice and its einsum costs as much as the k-d tree."""
    global _COV
    if _COV is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def covariance(points, near, cov):
            k = near.shape[1]
            for i in range(near.shape[0]):
                m0 = m1 = m2 = 0.0
                for j in range(k):
                    p = near[i, j]
                    m0 += points[p, 0]
                    m1 += points[p, 1]
                    m2 += points[p, 2]
                m0 /= k
                m1 /= k
                m2 /= k
                c00 = c01 = c02 = c11 = c12 = c22 = 0.0
                for j in range(k):
                    p = near[i, j]
                    d0 = points[p, 0] - m0
                    d1 = points[p, 1] - m1
                    d2 = points[p, 2] - m2
                    c00 += d0 * d0
                    c01 += d0 * d1
                    c02 += d0 * d2
                    c11 += d1 * d1
                    c12 += d1 * d2
                    c22 += d2 * d2
                cov[i, 0, 0] = c00 / k
                cov[i, 0, 1] = cov[i, 1, 0] = c01 / k
                cov[i, 0, 2] = cov[i, 2, 0] = c02 / k
                cov[i, 1, 1] = c11 / k
                cov[i, 1, 2] = cov[i, 2, 1] = c12 / k
                cov[i, 2, 2] = c22 / k

        _COV = covariance
    return _COV


def grid_local_shape(points, index, rows, k: int, shape) -> np.ndarray:
    """``(n, 9)``: :func:`_local_shape`'s columns for the voxels ``rows`` of a voxel grid whose
    occupied voxels are ``index`` (``(c, 3) int``) with centres ``points`` (``(c, 3)`` float, any
    frame that is a similarity of the grid's, e.g. canonical), the ``k`` nearest found on the grid
    (:func:`grid_knn`; a k-d tree for the voxels with fewer than ``k`` within
    :data:`GRID_RADIUS`). Among voxels at the k-th distance it may keep others than a k-d tree."""
    points = np.ascontiguousarray(points, np.float64)
    rows = np.asarray(rows, np.int64).reshape(-1)
    if len(points) < 3 or len(points) < k:
        return _local_shape(points, k)[rows]
    near, found = grid_knn(index, rows, k, shape)
    if not found.all():
        from scipy.spatial import cKDTree

        near[~found] = cKDTree(points).query(points[rows[~found]], k=k)[1].reshape(-1, k)
    cov = np.empty((len(rows), 3, 3))
    if len(rows):
        _cov_kernel()(points, near, cov)
    out = np.empty((len(rows), 9))
    if len(rows):
        _eigen_kernel()(cov, out)
    return out


_EIGEN = None


def _eigen_kernel():
    """:func:`_shape_columns` of ``(n, 3, 3)`` covariances in closed form (the eigenvalues by the
    trigonometric solution of the characteristic cubic, the axes as the longest cross product of
    two rows of ``cov - lambda I``), compiled on first use (cached on disk): a third of the time
    of ``np.linalg.eigh``'s LAPACK call per 3 x 3 matrix. Within 1e-12 of it where the
    eigenvalues are apart; where two tie, the axis of the pair is any one of the plane (LAPACK's
    is as arbitrary)."""
    global _EIGEN
    if _EIGEN is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def axis(a00, a01, a02, a11, a12, a22, lam, out, q, at, fallback):
            r00, r11, r22 = a00 - lam, a11 - lam, a22 - lam
            # cross products of the rows (r00 a01 a02), (a01 r11 a12), (a02 a12 r22)
            c0, c1, c2 = a01 * a12 - a02 * r11, a02 * a01 - r00 * a12, r00 * r11 - a01 * a01
            n = c0 * c0 + c1 * c1 + c2 * c2
            d0, d1, d2 = a01 * r22 - a02 * a12, a02 * a02 - r00 * r22, r00 * a12 - a01 * a02
            m = d0 * d0 + d1 * d1 + d2 * d2
            if m > n:
                c0, c1, c2, n = d0, d1, d2, m
            d0, d1, d2 = r11 * r22 - a12 * a12, a12 * a02 - a01 * r22, a01 * a12 - r11 * a02
            m = d0 * d0 + d1 * d1 + d2 * d2
            if m > n:
                c0, c1, c2, n = d0, d1, d2, m
            if n > 0.0:
                n = np.sqrt(n)
                out[q, at], out[q, at + 1], out[q, at + 2] = abs(c0) / n, abs(c1) / n, abs(c2) / n
            else:
                out[q, at], out[q, at + 1], out[q, at + 2] = 0.0, 0.0, 0.0
                out[q, at + fallback] = 1.0

        @numba.njit(cache=True, nogil=True)
        def eigen(cov, out):
            for q in range(cov.shape[0]):
                a00, a01, a02 = cov[q, 0, 0], cov[q, 0, 1], cov[q, 0, 2]
                a11, a12, a22 = cov[q, 1, 1], cov[q, 1, 2], cov[q, 2, 2]
                off = a01 * a01 + a02 * a02 + a12 * a12
                mean = (a00 + a11 + a22) / 3.0
                if off == 0.0:
                    e1, e2, e3 = a00, a11, a22
                    if e1 > e2:
                        e1, e2 = e2, e1
                    if e2 > e3:
                        e2, e3 = e3, e2
                    if e1 > e2:
                        e1, e2 = e2, e1
                else:
                    b00, b11, b22 = a00 - mean, a11 - mean, a22 - mean
                    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0)
                    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02)
                           + a02 * (a01 * a12 - b11 * a02)) / (p * p * p)
                    phi = np.arccos(min(max(det / 2.0, -1.0), 1.0)) / 3.0
                    e3 = mean + 2.0 * p * np.cos(phi)
                    e1 = mean + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
                    e2 = 3.0 * mean - e1 - e3
                total = e1 + e2 + e3
                if total > 0:
                    out[q, 0], out[q, 1], out[q, 2] = e1 / total, e2 / total, e3 / total
                else:
                    out[q, 0] = out[q, 1] = out[q, 2] = 1.0 / 3
                axis(a00, a01, a02, a11, a12, a22, e3, out, q, 3, 2)  # the largest's axis
                axis(a00, a01, a02, a11, a12, a22, e1, out, q, 6, 0)  # the smallest's

        _EIGEN = eigen
    return _EIGEN


def frame_features(points, cuboids: primitives.Cuboids, normals=None, settings: LabellerSettings | None = None,
                   context=None, *, local_shape=None) -> np.ndarray:
    """The features of elements in the primitive frame (see the module notes).

    Parameters
    ----------
    points : (n, 3) float
        The elements (voxel centres, face centroids, points), **canonical frame**.
    cuboids : primitives.Cuboids
        The shape's abstraction in the canonical frame (``AbstractionResult.canonical``).
    normals : (n, 3) float or None
        Outward unit normals, canonical frame; None: unknown (zero).
    settings : LabellerSettings
    context : (c, 3) float or None
        Points whose neighbourhoods describe the local shape (default ``points``).
    local_shape : (n, 9) float or None
        The local-shape columns computed already (a voxel grid's :func:`grid_local_shape`);
        None: from ``context`` by a k-d tree.

    Returns
    -------
    (n, :func:`feature_count`) float64; :data:`ABSENT` where a slot is absent, zero normals where
    unknown (as deep inside a voxel grid).
    """
    settings = settings or LabellerSettings()
    points = primitives.cuboids.as_points(points)
    c = primitives.cuboids.check_cuboids(cuboids)
    n, m = len(points), c.count
    if not c.existence.any():
        raise ValueError("no present cuboid: nothing to read the frame from")
    frame = np.zeros((n, 3 + m + 3 + 3 * m + m))
    frame[:, :3] = points
    if n:  # the nearest cuboid (one-hot), the coordinates in every cuboid over its half extents, and the
        # distances (:func:`_frame_kernel`); the nearest by assign_points' rule: ties to the larger volume
        present = c.present
        order = present[np.argsort(-c.volumes[present], kind="stable")]
        _frame_kernel()(np.ascontiguousarray(points), np.ascontiguousarray(c.rotations), c.translations,
                        c.half_extents, c.existence.astype(np.uint8), order.astype(np.int64), ABSENT, frame, 3 + m)
    columns = [frame]
    if settings.normals:
        if normals is None:
            columns.append(np.zeros((n, 4)))
        else:
            normals = np.asarray(normals, float)
            if normals.shape != (n, 3):
                raise ValueError(f"`normals` must be (n, 3) float like the points, got shape {normals.shape}")
            columns += [normals, np.abs(normals[:, 1:2])]
    if settings.neighbours:
        if local_shape is not None:
            local_shape = np.asarray(local_shape, float)
            if local_shape.shape != (n, 9):
                raise ValueError(f"`local_shape` must be (n, 9) float like the points, got shape {local_shape.shape}")
            columns.append(local_shape)
        elif context is None:
            columns.append(_local_shape(points, settings.neighbours))
        else:
            context = primitives.cuboids.as_points(context)
            from scipy.spatial import cKDTree

            _, near = cKDTree(context).query(points, k=min(settings.neighbours, len(context)))
            near = near.reshape(n, -1)
            grouped = context[near] - context[near].mean(axis=1, keepdims=True)
            cov = np.einsum("nki,nkj->nij", grouped, grouped) / near.shape[1]
            values, vectors = np.linalg.eigh(cov)
            total = values.sum(axis=1, keepdims=True)
            shares = np.divide(values, total, out=np.full_like(values, 1.0 / 3), where=total > 0)
            columns.append(np.hstack([shares, np.abs(vectors[:, :, 2]), np.abs(vectors[:, :, 0])]))
    if settings.profile:
        columns.append(profile_features(points, context))
    if settings.sides:
        columns.append(side_features(points, context))
    return np.hstack(columns)


_FRAME = None


def _frame_kernel():
    """The cuboid-frame columns of :func:`frame_features`, compiled on first use (cached on disk):
    for each point, its nearest cuboid (a one in its column of the ``m`` before column ``at``),
    from column ``at`` of ``out`` its coordinates in its nearest cuboid, in every cuboid (``R.T (x
    - t)``, as :func:`primitives.world_to_local`) over the half extents, and its distance to every
    cuboid (as :func:`primitives.point_cuboid_distance`); :data:`ABSENT` for absent slots. One pass
    over the points instead of NumPy's ``(m, n, 3)`` temporaries (a third of the features' time on
    a chair). The nearest is :func:`primitives.assign_points`' rule (the least squared distance,
    ties to the first in ``order``: the present slots by decreasing volume, then index) read from
    these distances, which round the local coordinates in another order than its matrix product:
    the same cuboid unless two lie within a rounding error of each other (none among the 1.66
    million voxels of 419 ShapeNetVox32 and PartNet chairs), and ``assign_points``' 0.36 ms a
    chair saved."""
    global _FRAME
    if _FRAME is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def frame(points, rotations, translations, half, exists, order, absent, out, at):
            m = rotations.shape[0]
            coords, dist = at + 3, at + 3 + 3 * m
            squared = np.empty(m)
            for i in range(points.shape[0]):
                for j in range(m):
                    if exists[j] == 0:
                        out[i, coords + 3 * j] = out[i, coords + 3 * j + 1] = out[i, coords + 3 * j + 2] = absent
                        out[i, dist + j] = absent
                        continue
                    d0 = points[i, 0] - translations[j, 0]
                    d1 = points[i, 1] - translations[j, 1]
                    d2 = points[i, 2] - translations[j, 2]
                    total = 0.0
                    for a in range(3):
                        x = rotations[j, 0, a] * d0 + rotations[j, 1, a] * d1 + rotations[j, 2, a] * d2
                        e = max(abs(x) - half[j, a], 0.0)
                        total += e * e
                        out[i, coords + 3 * j + a] = x / half[j, a]
                    out[i, dist + j] = np.sqrt(total)
                    squared[j] = total
                k = order[0]
                for j in order[1:]:
                    if squared[j] < squared[k]:
                        k = j
                out[i, at - m + k] = 1.0
                for a in range(3):
                    out[i, at + a] = out[i, coords + 3 * k + a]

        _FRAME = frame
    return _FRAME


def grid_neighbours(index, shape) -> np.ndarray:
    """``(n, 27) int``: for the occupied voxels at ``index`` (``(n, 3) int``, e.g. ``np.argwhere``),
    the positions in ``index`` of the occupied voxels of their 3 x 3 x 3 neighbourhood, nearest
    first (the voxel itself, its 6 face neighbours, 12 edge and 8 corner neighbours; the voxel
    itself where a neighbour is empty or off the grid). The first ``k`` columns are the ``k``
    nearest voxel centres where the grid is full, found by index arithmetic instead of a k-d tree."""
    index = np.ascontiguousarray(index, np.int64).reshape(-1, 3)
    _check_inside(index, shape)
    where = np.full(tuple(np.asarray(shape) + 2), -1, np.int64)  # padded: no bounds checks
    where[tuple((index + 1).T)] = np.arange(len(index))
    near = np.empty((len(index), len(_OFFSETS)), np.int64)
    if len(index):  # where[index + 1 + offset], the voxel itself where empty (a tenth of NumPy's gathers' time)
        _block_kernel()(index, where.reshape(-1), _flat(_OFFSETS, where.shape), where.shape[1], where.shape[2], near)
    return near


def _check_inside(index, shape) -> None:
    """ValueError unless the ``(n, 3)`` voxel indices lie inside a grid of ``shape`` (the Numba
    loops read the grid unchecked)."""
    if len(index):
        low, high = column_range(index)
        if low.min() < 0 or np.any(high >= np.asarray(shape)[:3]):
            raise ValueError(f"voxel indices outside the grid of shape {tuple(shape)}")


_BLOCK = None


def _block_kernel():
    """The lookup of :func:`grid_neighbours`, compiled on first use (cached on disk)."""
    global _BLOCK
    if _BLOCK is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def block(index, where, offsets, b, c, near):  # where: the padded (a, b, c) lookup, flat
            for i in range(index.shape[0]):
                base = ((index[i, 0] + 1) * b + index[i, 1] + 1) * c + index[i, 2] + 1
                for o in range(offsets.shape[0]):
                    p = where[base + offsets[o]]
                    near[i, o] = p if p >= 0 else i

        _BLOCK = block
    return _BLOCK


def grid_sampling(index, neighbours, step: int):
    """Which voxels a labeller classifies when it reads one in ``step`` (``LabellerSettings.grid_sample``).

    Returns ``(classify (n,) bool, around (f, 26) int, use (f, 26) bool)``: the voxels classified
    (step 2: ``i + j + k`` even; 4: all three indices even or all odd; 8: all three even; 1:
    all), and for the ``f`` others,
    their 26 neighbours' positions (``neighbours[:, 1:]``, from :func:`grid_neighbours`) and which
    of them are classified occupied voxels (the mean of those is theirs). A voxel with no such
    neighbour is classified itself, so every ``use`` row has at least one True.
    """
    index, neighbours = _check_sampling(index, neighbours, step)
    # step 4: a body-centred lattice, every voxel has one of them in its 3 x 3 x 3 block; a voxel
    # with no sampled neighbour (an empty neighbour is the voxel itself) is classified itself
    classify, sampled = _grid_sample(index, neighbours, step)
    around = neighbours[~classify, 1:27]
    use = sampled[around] & (around != np.flatnonzero(~classify)[:, None])
    return classify, around, use


def _check_sampling(index, neighbours, step: int):
    """The arguments of :func:`grid_sampling` as contiguous int64, or ValueError."""
    index = np.ascontiguousarray(index, np.int64).reshape(-1, 3)
    if step not in (1, 2, 4, 8):
        raise ValueError(f"grid sampling one voxel in {step}: only 1, 2, 4 or 8")
    n = len(index)
    neighbours = np.ascontiguousarray(neighbours, np.int64)
    low, high = column_range(neighbours) if n and neighbours.shape == (n, 27) else (np.zeros(1), np.zeros(1))
    if neighbours.shape != (n, 27) or low.min() < 0 or (n and high.max() >= n):
        raise ValueError(f"`neighbours` must be grid_neighbours' (n, 27) positions, got shape {neighbours.shape}")
    return index, neighbours


#: the 27 offsets of a 3 x 3 x 3 block, nearest first (ties in a fixed order)
_OFFSETS = np.array(sorted(((i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)),
                           key=lambda o: (sum(x * x for x in o), o)))


def grid_normals(occupancy, index=None) -> np.ndarray:
    """``(R, R, R, 3)`` outward unit normals of an occupancy grid, in its index axes: minus the
    gradient of the occupancy smoothed by a Gaussian of one voxel (scipy.ndimage), zero where flat
    (deep inside). ``index`` (``(n, 3) int``): only those voxels' normals, ``(n, 3)``, the same
    numbers (``np.gradient``'s differences taken at those voxels alone: a chair's occupied voxels
    are a tenth of its grid)."""
    from scipy import ndimage

    occupancy = np.asarray(occupancy)
    if index is None or occupancy.ndim != 3 or min(occupancy.shape) <= _GAUSS_RADIUS:
        smooth = ndimage.gaussian_filter(np.asarray(occupancy, float), 1.0)
    else:  # the same numbers, in about half the time
        smooth = _grid_gaussian(occupancy)
    if index is None:
        grad = -np.stack(np.gradient(smooth), axis=-1)
    else:
        index = np.ascontiguousarray(index, np.int64).reshape(-1, 3)
        _check_inside(index, smooth.shape)
        if min(smooth.shape) < 2:
            raise ValueError("grid_normals needs at least 2 voxels along each axis")
        out = np.zeros((len(index), 3))
        if len(index):  # the same differences and norms as below, one voxel at a time
            _normals_kernel()(smooth, index, out)
        return out
    norm = np.linalg.norm(grad, axis=-1, keepdims=True)
    return np.divide(grad, norm, out=np.zeros_like(grad), where=norm > 1e-6)


#: the radius of :func:`grid_normals`' Gaussian (scipy's ``truncate`` 4 at sigma 1)
_GAUSS_RADIUS = 4


@functools.lru_cache(maxsize=1)
def _gauss_weights() -> np.ndarray:
    """``(5,)`` float64: scipy's one-voxel Gaussian weights at offsets 0-4, read off its response
    to a unit impulse (each output there is one weight times 1 plus zeros: the weights exactly)."""
    from scipy import ndimage

    impulse = np.zeros(4 * _GAUSS_RADIUS + 1)
    impulse[2 * _GAUSS_RADIUS] = 1.0
    w = ndimage.gaussian_filter1d(impulse, 1.0)[2 * _GAUSS_RADIUS : 3 * _GAUSS_RADIUS + 1].copy()
    w.flags.writeable = False
    return w


def _grid_gaussian(occupancy) -> np.ndarray:
    """``ndimage.gaussian_filter(occupancy.astype(float), 1.0)`` of a 3-D grid at least 5 voxels a
    side, the same numbers (the tests check bit for bit): its three passes (axes 0, 1, 2, mode
    "reflect", scipy's symmetric-kernel sum ``x[l] w0 + sum_{d=4..1} (x[l-d] + x[l+d]) w_d``) by a
    Numba loop (vectorised along the last axis; the last pass leaves a row of zeros at zero): about
    0.28 against 0.49 ms on a 32^3 chair grid. Hand-written because scipy's filter, general over
    dtypes, modes and kernels, runs line by line through a buffer."""
    grid = np.ascontiguousarray(occupancy, np.float64)
    out = np.empty_like(grid)
    _gauss_kernel()(grid, out, np.empty_like(grid), np.asarray(_gauss_weights()))
    return out


_GAUSS = None


def _gauss_kernel():
    """The passes of :func:`_grid_gaussian`, compiled on first use (cached on disk). Each output
    takes the same operations in the same order as scipy's loop; the first two passes run along
    rows of the last axis (contiguous, vectorised), the third skips the rows that are all zero."""
    global _GAUSS
    if _GAUSS is None:
        import numba

        @numba.njit(cache=True, nogil=True, inline="always")
        def reflect(l, d, n):  # the indices d before and after l, mirrored at the ends as scipy's "reflect"
            lo, hi = l - d, l + d
            if lo < 0:
                lo = -lo - 1
            if hi >= n:
                hi = 2 * n - 1 - hi
            return lo, hi

        @numba.njit(cache=True, nogil=True)
        def across(inp, res, w):  # (A, n, B): filter along the middle axis, B contiguous
            r = w.shape[0] - 1
            n, m = inp.shape[1], inp.shape[2]
            for i in range(inp.shape[0]):
                for l in range(n):
                    for v in range(m):
                        res[i, l, v] = inp[i, l, v] * w[0]
                    for d in range(r, 0, -1):
                        lo, hi = reflect(l, d, n)
                        for v in range(m):
                            res[i, l, v] += (inp[i, lo, v] + inp[i, hi, v]) * w[d]

        @numba.njit(cache=True, nogil=True)
        def along(inp, res, w):  # (R, n): filter each row, a row of zeros left zero
            r = w.shape[0] - 1
            n = inp.shape[1]
            for i in range(inp.shape[0]):
                empty = True
                for l in range(n):
                    if inp[i, l] != 0.0:
                        empty = False
                        break
                if empty:
                    for l in range(n):
                        res[i, l] = 0.0
                    continue
                for l in range(n):
                    t = inp[i, l] * w[0]
                    for d in range(r, 0, -1):
                        lo, hi = reflect(l, d, n)
                        t += (inp[i, lo] + inp[i, hi]) * w[d]
                    res[i, l] = t

        @numba.njit(cache=True, nogil=True)
        def passes(grid, out, tmp, w):
            a, b, c = grid.shape
            across(grid.reshape(1, a, b * c), out.reshape(1, a, b * c), w)  # axis 0
            across(out, tmp, w)  # axis 1
            along(tmp.reshape(a * b, c), out.reshape(a * b, c), w)  # axis 2

        _GAUSS = passes
    return _GAUSS


_NORMALS = None


def _normals_kernel():
    """:func:`grid_normals` at some voxels, compiled on first use (cached on disk): per voxel and
    axis ``np.gradient``'s difference (central inside, one-sided at the grid's two ends), then
    the unit vector of minus the gradient (zero where its norm is at most 1e-6), as the NumPy
    expressions over the whole grid compute them; a loop instead of six gathers of the grid."""
    global _NORMALS
    if _NORMALS is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def normals(smooth, index, out):
            g = np.empty(3)
            for q in range(index.shape[0]):
                for axis in range(3):
                    size = smooth.shape[axis]
                    i = index[q, axis]
                    hi0, hi1, hi2 = index[q, 0], index[q, 1], index[q, 2]
                    lo0, lo1, lo2 = hi0, hi1, hi2
                    up, down = min(i + 1, size - 1), max(i - 1, 0)
                    if axis == 0:
                        hi0, lo0 = up, down
                    elif axis == 1:
                        hi1, lo1 = up, down
                    else:
                        hi2, lo2 = up, down
                    diff = smooth[hi0, hi1, hi2] - smooth[lo0, lo1, lo2]
                    g[axis] = -(diff / 2.0 if 0 < i < size - 1 else diff)
                norm = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
                if norm > 1e-6:
                    for axis in range(3):
                        out[q, axis] = g[axis] / norm

        _NORMALS = normals
    return _NORMALS


# ---------------------------------------------------------------------------------------------
# The labeller
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Labeller:
    """A per-element part classifier of one model (see the module notes).

    Attributes
    ----------
    names : list of str
        The labels, in class order (e.g. ``["back", "seat", "legs", "arms"]``).
    parts : int
        The model's slots ``m`` (the features depend on it).
    ensemble : TreeEnsemble
    settings : LabellerSettings
    info : dict
        What it was learned from (shapes, elements), JSON.
    prior : (parts, classes) float or None
        The index-naming prior: row ``k`` the shares of the labels among the labelled elements
        whose nearest cuboid is ``k``, each labelled shape weighing the same (an index no labelled
        element had: the labels' overall shares); blended in with ``settings.prior_weight``.
    early_stop : (rounds, margin, taper) or None
        How :meth:`classify` walks the trees (:meth:`TreeEnsemble.raw_predict`'s ``stop``; not
        stored: a way of labelling, not part of what was learned): :data:`EARLY_STOP`, or None
        for every tree (the exact ``predict_proba``).
    post : tuple of post-steps
        The rules run after the decision, in order (:mod:`primkit.segmentation.post`; e.g. a
        chair's :class:`~primkit.segmentation.presence.PresenceRule` and
        :class:`~primkit.segmentation.layers.LayerCut`): stored in the file by name with every
        parameter, applied because the file names them.
    """

    names: list
    parts: int
    ensemble: TreeEnsemble
    settings: LabellerSettings = field(default_factory=LabellerSettings)
    info: dict = field(default_factory=dict)
    prior: np.ndarray | None = None
    early_stop: tuple | None = EARLY_STOP
    post: tuple = ()

    @classmethod
    def fit(cls, shapes, names, parts: int, *, settings: LabellerSettings | None = None, per_shape: int = 1000,
            max_iter: int = 100, learning_rate: float = 0.1, max_leaf_nodes: int = 31, seed=0,
            info: dict | None = None, post=None, post_check: bool = True, **options) -> "Labeller":
        """Learn a labeller from labelled shapes.

        Parameters
        ----------
        shapes : iterable of (features (n_i, d) float, labels (n_i,) int[, weight float])
            Each shape's :func:`frame_features` and labels (indices into ``names``; negative:
            unlabelled, left out), and optionally what the shape weighs (default 1; a
            pseudo-labelled shape of :mod:`primkit.segmentation.selftrain` weighs less).
        names : sequence of str
        parts : int
            The model's slots.
        per_shape : int
            At most this many elements of each shape are learned from (a random subset); each
            shape weighs the same whatever its element count.
        max_iter, learning_rate, max_leaf_nodes, options : the classifier's (``l2_regularization``, ...).
        seed : int, the subsets' and the classifier's random state.
        post : None, str, dict, step or a list of them
            The post-steps to keep with the labeller (:func:`primkit.segmentation.post.resolve_post`:
            ``"chair"``, ``"chair.arms_from_side_region:label=armrest"``, a step object, ...);
            None (the default): none. A step is kept when every label it reads was learned.
        post_check : bool
            Keep a step only when it agrees with the labelled shapes themselves: it contradicts
            their own labels on at most :data:`POST_TOLERANCE` of the shapes it reads (a chair
            whose arms do not rise beside its seat, a grid whose seat and legs it would move; the
            seat cut also needs some voxel grids among them). ``info["post_check"]`` says what was
            found, per step. False: every step given is kept.
        """
        from sklearn.ensemble import HistGradientBoostingClassifier

        settings = settings or LabellerSettings()
        rng = np.random.default_rng(seed)
        Xs, ys, ws, priors = [], [], [], []
        steps = [step for step in resolve_post(post) if set(step.labels()) <= set(names)]
        checks = [[0, 0] for _ in steps]  # per step: shapes read, shapes contradicted
        for shape in shapes:
            X, y = np.asarray(shape[0], float), np.asarray(shape[1], np.int64)
            weight = float(shape[2]) if len(shape) > 2 else 1.0
            keep = np.flatnonzero((y >= 0) & (y < len(names)))
            if post_check and steps and len(keep):  # would a step contradict this shape's own labels?
                level = layer_levels(X[keep, 1])  # the first columns: canonical positions; on layers: a grid's
                for step, check in zip(steps, checks):
                    against = step.contradicts(X, y[keep], list(names), settings.min_share, level)
                    if against is not None:
                        check[0] += 1
                        check[1] += int(against)
            if len(keep) and X.shape[1] == feature_count(parts, settings):  # every labelled element
                counts = np.zeros((parts, len(names)))
                np.add.at(counts, (nearest_index(X[keep], parts), y[keep]), weight / len(keep))
                priors.append(counts)
            if len(keep) > per_shape:
                keep = rng.choice(keep, per_shape, replace=False)
            if len(keep):
                Xs.append(X[keep])
                ys.append(y[keep])
                ws.append(np.full(len(keep), weight / len(keep)))
        if not Xs:
            raise ValueError("no labelled element to learn from")
        if settings.prior_weight is None:
            settings = replace(settings, prior_weight=min(0.4, 4.0 / len(Xs)))
        X, y, w = np.vstack(Xs), np.concatenate(ys), np.concatenate(ws)
        if X.shape[1] != feature_count(parts, settings):
            raise ValueError(f"features have {X.shape[1]} columns, expected {feature_count(parts, settings)}")
        present = np.unique(y)
        if len(present) < 2:
            raise ValueError(f"the labelled shapes carry one label only ({names[present[0]]}): nothing to tell apart")
        # the classes the ensemble knows are those present, mapped back to `names` after
        model = HistGradientBoostingClassifier(max_iter=max_iter, learning_rate=learning_rate,
                                               max_leaf_nodes=max_leaf_nodes, early_stopping=False,
                                               random_state=int(seed), **options)
        model.fit(X, np.searchsorted(present, y), sample_weight=w * len(Xs))
        kept = [str(names[k]) for k in present]
        info = {**(info or {}), "shapes": len(Xs), "elements": int(len(y))}
        kept_steps = []
        for step, (read, against) in zip(steps, checks):
            if not set(step.labels()) <= set(kept):
                continue  # a label the labelled shapes never carry
            if post_check:
                info.setdefault("post_check", []).append({"step": step.STEP, "shapes": read, "contradicted": against})
                if not step.kept(read, against, POST_TOLERANCE):
                    continue
            kept_steps.append(step)
        return cls(kept, int(parts), TreeEnsemble.from_sklearn(model), settings, info,
                   index_prior(priors, present, parts), post=tuple(kept_steps))

    def features(self, points, cuboids, normals=None, context=None, *, local_shape=None) -> np.ndarray:
        """:func:`frame_features` with this labeller's settings (canonical frame)."""
        if cuboids.count != self.parts:
            raise ValueError(f"the labeller reads {self.parts} part slots, the cuboids have {cuboids.count}")
        return frame_features(points, cuboids, normals, self.settings, context, local_shape=local_shape)

    def _grid_shape(self, points, grid_index, rows):
        """The local-shape columns of the grid voxels ``rows`` (:func:`grid_local_shape`), or
        None where the settings read none or the elements are no grid."""
        if not self.settings.neighbours or grid_index is None or len(grid_index) != len(points):
            return None
        grid_index = np.asarray(grid_index, np.int64)
        shape = column_range(grid_index)[1] + 1 if len(grid_index) else np.zeros(3, np.int64)  # index.max(axis=0) + 1
        return grid_local_shape(points, grid_index, rows, self.settings.neighbours, shape)

    def predict_proba(self, points, cuboids, normals=None, context=None, neighbours=None, grid_index=None) -> np.ndarray:
        """``(n, len(names))`` smoothed label probabilities of canonical-frame elements
        (``neighbours``: see :meth:`smooth`; ``grid_index``: the ``(n, 3) int`` voxel indices of a
        grid's elements, with ``neighbours`` its :func:`grid_neighbours`, for ``grid_sample``)."""
        points = np.asarray(points, float)
        step = self.settings.grid_sample
        grid = context is None and grid_index is not None  # the local shape found on the grid
        if step == 1 or grid_index is None or neighbours is None or neighbours.shape[1] < 27:
            shape = self._grid_shape(points, grid_index, np.arange(len(points))) if grid else None
            proba = self.classify(self.features(points, cuboids, normals, context, local_shape=shape))
        else:
            grid_index, neighbours = _check_sampling(grid_index, neighbours, step)
            classify, sampled = _grid_sample(grid_index, neighbours, step)  # grid_sampling's, no around/use
            shape = self._grid_shape(points, grid_index, np.flatnonzero(classify)) if grid else None
            proba = np.empty((len(points), self.ensemble.classes + -self.ensemble.classes % 4))  # _pad4's columns
            proba[:, self.ensemble.classes:] = 0.0
            proba[classify, : self.ensemble.classes] = self.classify(self.features(
                points[classify], cuboids, None if normals is None else np.asarray(normals, float)[classify],
                points if context is None else context, local_shape=shape))  # the local shape among all the elements
            # each other voxel: the mean of its sampled neighbours' (grid_sampling's ``around[use]``)
            _sample_fill_kernels()[1](proba, neighbours, sampled, classify)
            proba = proba[:, : self.ensemble.classes]
        return self.smooth(proba, points, neighbours)

    def classify(self, X) -> np.ndarray:
        """``(n, classes)`` probabilities of elements' features ``X`` (:meth:`features`): the
        trees' (walked with :attr:`early_stop`), blended with the index prior
        (``settings.prior_weight``), before any smoothing."""
        proba = self.ensemble.predict_proba(X, self.early_stop)
        w = self.settings.prior_weight or 0.0
        if w > 0 and self.prior is not None and len(proba):
            proba = (1.0 - w) * proba + w * self.prior[nearest_index(X, self.parts)]
        return proba

    def smooth(self, proba, points, neighbours=None) -> np.ndarray:
        """Average ``(n, classes)`` probabilities over each element's ``smooth_neighbours`` nearest
        elements (itself included), ``smooth`` times. ``neighbours``: ``(n, k) int`` indices to use
        instead, nearest first (a voxel grid's :func:`grid_neighbours`), of which the first
        ``smooth_neighbours`` are used."""
        if not self.settings.smooth or len(proba) < 2:
            return proba
        k = self.settings.smooth_neighbours
        idx = neighbours if neighbours is not None else _neighbours(np.asarray(points, float), k)
        idx = np.ascontiguousarray(idx, np.int64)
        k = min(k, idx.shape[1])
        classes = proba.shape[1]
        proba = _pad4(proba)
        for _ in range(self.settings.smooth):
            out = np.empty_like(proba)
            _mean_kernel()(proba, idx, k, out)  # proba[idx[:, :k]].mean(axis=1) without the (n, k, classes) copy
            proba = out
        return proba[:, :classes]

    def predict(self, points, cuboids, normals=None, context=None, neighbours=None, grid_index=None) -> np.ndarray:
        """``(n,) int``: each element's label (an index into :attr:`names`)."""
        if len(points) == 0:
            return np.zeros(0, np.int64)
        return self.labels_from(self.predict_proba(points, cuboids, normals, context, neighbours, grid_index),
                                points, context, grid_index)

    def labels_from(self, proba, points, context=None, grid_index=None) -> np.ndarray:
        """``(n,) int``: each element's label from its smoothed probabilities (:meth:`predict_proba`):
        the most probable one that stays (``settings.min_share``), then the post-steps
        (:meth:`after`)."""
        return self.after(decide(proba, self.settings.min_share), proba, points, context, grid_index)

    def after(self, labels, proba, points, context=None, grid_index=None, weights=None) -> np.ndarray:
        """``labels`` after :attr:`post`, in order (``points``, ``context`` canonical; ``grid_index``:
        the ``(n, 3) int`` voxel indices of a grid's elements, None for faces and points;
        ``weights``: each element's weight where a step counts shares, e.g. a mesh's face areas)."""
        for step in self.post:
            labels = step.apply(self.names, labels, proba, points, context, grid_index, weights)
        return labels

    # -- storage ------------------------------------------------------------------------------

    def to_tensors(self) -> tuple[dict, dict]:
        """``(arrays, description)``: NumPy arrays named ``labeller.*`` and the JSON description.

        Feature and child indices are stored as int16 (:data:`STORED`; a split's children are
        indices inside its tree, the trees of a few dozen nodes), the rest as in memory."""
        arrays = {}
        for k, v in self.ensemble.arrays().items():
            dtype = STORED.get(k, v.dtype)
            if np.dtype(dtype) != v.dtype and len(v) and (v.min() < np.iinfo(dtype).min or v.max() > np.iinfo(dtype).max):
                raise ValueError(f"labeller {k} holds values past {np.dtype(dtype).name}: too many features or "
                                 "too large trees to store")
            arrays[LABELLER_PREFIX + k] = np.ascontiguousarray(v, dtype)
        if self.prior is not None:
            arrays[LABELLER_PREFIX + "prior"] = np.ascontiguousarray(self.prior, np.float64)
        description = {"format": LABELLER_FORMAT, "format_version": LABELLER_FORMAT_VERSION, "names": list(self.names),
                       "parts": self.parts, "features": self.ensemble.features,
                       "settings": {**self.settings.to_dict(), "prior_weight": self.settings.prior_weight or 0.0},
                       "classifier": "scikit-learn HistGradientBoostingClassifier, trees exported to arrays",
                       "info": self.info, "post": [step_to_dict(step) for step in self.post]}
        return arrays, description

    @classmethod
    def from_tensors(cls, arrays: dict, description, where="labeller") -> "Labeller":
        """The inverse of :meth:`to_tensors`, every field checked (ValueError, one line)."""
        if not isinstance(description, dict) or description.get("format") != LABELLER_FORMAT:
            raise ValueError(f"{where}: not a labeller description (format is not {LABELLER_FORMAT!r})")
        version = description.get("format_version")
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise ValueError(f"{where}: invalid labeller format_version {version!r}")
        if version > LABELLER_FORMAT_VERSION:
            raise ValueError(f"{where}: labeller format version {version} is newer than this primkit supports "
                             f"({LABELLER_FORMAT_VERSION}); upgrade primkit")
        if version != LABELLER_FORMAT_VERSION:
            raise ValueError(f"{where}: labeller format version {version} is no longer read (this primkit reads "
                             f"{LABELLER_FORMAT_VERSION}); {LABELLER_REBUILD}")
        unknown = sorted(set(description) - set(DESCRIPTION_KEYS))
        missing = sorted(set(DESCRIPTION_KEYS) - set(description))
        if unknown or missing:
            raise ValueError(f"{where}: the labeller description " + (f"lacks {', '.join(missing)}" if missing else "")
                             + ("; " if missing and unknown else "") + (f"has unknown {', '.join(unknown)}" if unknown else ""))
        names, parts = description.get("names"), description.get("parts")
        if not (isinstance(names, list) and 2 <= len(names) <= MAX_CLASSES and all(isinstance(n, str) for n in names)):
            raise ValueError(f"{where}: names must be a list of 2 to {MAX_CLASSES} strings")
        if not isinstance(parts, int) or isinstance(parts, bool) or not 1 <= parts <= MAX_PARTS:
            raise ValueError(f"{where}: parts must be an integer in 1-{MAX_PARTS}")
        settings = LabellerSettings.from_dict(description.get("settings"))
        features = description.get("features")
        if features != feature_count(parts, settings):
            raise ValueError(f"{where}: {features!r} features, but {parts} parts with these settings make "
                             f"{feature_count(parts, settings)}")
        missing = [k for k in TreeEnsemble.ARRAYS if LABELLER_PREFIX + k not in arrays]
        if missing:
            raise ValueError(f"{where}: lacks the labeller arrays {', '.join(missing)}")
        for k in TreeEnsemble.ARRAYS:
            got = np.asarray(arrays[LABELLER_PREFIX + k])
            if got.dtype != np.dtype(STORED.get(k, TreeEnsemble.ARRAYS[k])):
                raise ValueError(f"{where}: {k} is {got.dtype.name}, format version {version} stores "
                                 f"{np.dtype(STORED.get(k, TreeEnsemble.ARRAYS[k])).name}")
        ensemble = TreeEnsemble(**{k: np.asarray(arrays[LABELLER_PREFIX + k]).astype(t, copy=False)
                                   for k, t in TreeEnsemble.ARRAYS.items()}, features=features)
        ensemble.check(where)
        if ensemble.classes != len(names):
            raise ValueError(f"{where}: {len(names)} names but the trees tell {ensemble.classes} classes apart")
        prior = arrays.get(LABELLER_PREFIX + "prior")
        if prior is not None:
            prior = np.asarray(prior)
            if prior.dtype != np.float64 or prior.shape != (parts, len(names)) or not np.all(np.isfinite(prior)) \
                    or np.any(prior < 0):
                raise ValueError(f"{where}: prior must be ({parts}, {len(names)}) finite float64 shares")
        elif settings.prior_weight > 0:
            raise ValueError(f"{where}: prior_weight {settings.prior_weight} but no prior")
        info = description["info"]
        if not isinstance(info, dict):
            raise ValueError(f"{where}: info must be a JSON object")
        post = description["post"]
        if not isinstance(post, list):
            raise ValueError(f"{where}: post must be a list of post-steps")
        steps = []
        for d in post:
            try:
                step = step_from_dict(d)
            except ValueError as exc:
                raise ValueError(f"{where}: {exc}") from None
            if not set(step.labels()) <= set(names):
                raise ValueError(f"{where}: the post-step {step.STEP} reads labels "
                                 f"{', '.join(map(repr, step.labels()))} that are not all among the names")
            steps.append(step)
        return cls(list(names), parts, ensemble, settings, info, prior, post=tuple(steps))


def decide(proba, min_share: float = 0.0) -> np.ndarray:
    """``(n,) int``: each element's most probable label, leaving out the labels that would go to
    fewer than ``min_share`` of the ``n`` elements (their elements take their next best label that
    stays)."""
    proba = np.array(proba, float)
    labels = np.argmax(proba, axis=1)
    if min_share > 0 and len(labels):
        counts = np.bincount(labels, minlength=proba.shape[1])
        rare = (counts > 0) & (counts < min_share * len(labels))
        if rare.any() and not rare[counts > 0].all():
            proba[:, rare] = -np.inf
            labels = np.argmax(proba, axis=1)
    return labels.astype(np.int64)


def nearest_index(X, parts: int) -> np.ndarray:
    """``(n,) int``: each element's nearest cuboid, read from its features' one-hot columns."""
    return np.argmax(np.asarray(X)[:, 3 : 3 + parts], axis=1)


def index_prior(counts, present, parts: int) -> np.ndarray | None:
    """The index-naming prior of :attr:`Labeller.prior` from each shape's ``(parts, labels)``
    element shares: summed over the shapes, kept to the ``present`` labels, each row normalised
    (an index no element had: the labels' overall shares)."""
    if not counts:
        return None
    total = np.sum(counts, axis=0)[:, present]
    overall = total.sum(axis=0) / total.sum()
    rows = total.sum(axis=1, keepdims=True)
    return np.where(rows > 0, total / np.where(rows > 0, rows, 1.0), overall)


def write_labeller(model_path, output, labeller: Labeller, changes: dict | None = None, *,
                   overwrite: bool = False) -> Path:
    """Copy the model file ``model_path`` to ``output`` with ``labeller`` in it (replacing any
    labeller it had) and ``changes`` merged into its metadata; ``model_path`` is never modified."""
    import torch

    from ..model.modelfile import load_model_file, write_model

    from ..io import check_outputs

    check_outputs([output], inputs=[model_path], overwrite=overwrite)
    weights, metadata = load_model_file(model_path)
    weights = {k: v for k, v in weights.items() if not k.startswith(LABELLER_PREFIX)}
    arrays, description = labeller.to_tensors()
    weights.update({k: torch.from_numpy(np.array(v)) for k, v in arrays.items()})
    metadata = {**metadata, **(changes or {}), LABELLER_KEY: description}
    metadata.pop("created", None)
    return write_model(output, weights, metadata, overwrite=overwrite)


def has_labeller(model_path) -> bool:
    """Whether the model file carries a labeller (its header alone is read)."""
    from ..model.modelfile import read_metadata

    return LABELLER_KEY in read_metadata(model_path)


def read_labeller(model_path) -> Labeller | None:
    """The labeller stored in a model file, or None when it has none.

    Only the JSON header and the ``labeller.*`` tensors are read (safetensors: no code runs); the
    tensors' dtypes and shapes are checked in the header before any is read, then the trees
    (:meth:`TreeEnsemble.check`). Raises :class:`ModelFileError`, one line naming the file.
    """
    from safetensors import safe_open

    from ..model.modelfile import read_header

    metadata, tensors = read_header(model_path)
    description = metadata.get(LABELLER_KEY)
    if description is None:
        return None
    if not isinstance(description, dict):
        raise ModelFileError(model_path, "the labeller description is not a JSON object")
    version = description.get("format_version")
    if version != LABELLER_FORMAT_VERSION or isinstance(version, bool):
        try:  # an invalid, older or newer version: the description's own one-line message
            Labeller.from_tensors({}, description, where="labeller")
        except ValueError as exc:
            raise ModelFileError(model_path, str(exc)) from None
    names = {LABELLER_PREFIX + k: np.dtype(STORED.get(k, t)) for k, t in TreeEnsemble.ARRAYS.items()}
    kinds = {np.dtype(np.int64): "I64", np.dtype(np.float64): "F64", np.dtype(np.uint8): "U8", np.dtype(np.int16): "I16"}
    for name, dtype in names.items():
        if name not in tensors:
            raise ModelFileError(model_path, f"the labeller lacks its tensor {name}")
        shape, got = tensors[name]
        if got != kinds[dtype] or len(shape) != 1 or shape[0] > MAX_NODES + 1:
            raise ModelFileError(model_path, f"labeller tensor {name} is {got} {list(shape)}, expected a 1-d {kinds[dtype]}")
    if LABELLER_PREFIX + "prior" in tensors:
        shape, got = tensors[LABELLER_PREFIX + "prior"]
        if got != "F64" or len(shape) != 2 or shape[0] > MAX_PARTS or shape[1] > MAX_CLASSES:
            raise ModelFileError(model_path, f"labeller tensor {LABELLER_PREFIX}prior is {got} {list(shape)}, "
                                 "expected a (parts, classes) F64")
        names[LABELLER_PREFIX + "prior"] = np.dtype(np.float64)
    try:
        with safe_open(str(model_path), framework="numpy") as f:
            arrays = {name: f.get_tensor(name) for name in names}
    except Exception as exc:  # safetensors' own error types
        raise ModelFileError(model_path, f"cannot read the labeller's tensors ({exc})") from None
    try:
        return Labeller.from_tensors(arrays, description, where="labeller")
    except ValueError as exc:
        raise ModelFileError(model_path, str(exc)) from None


# ---------------------------------------------------------------------------------------------
# Elements of the three kinds of shape, in the canonical frame
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Elements:
    """What a labeller reads of one shape, in the canonical frame.

    points : (n, 3) float, the elements (voxel centres, face centroids, points)
    normals : (n, 3) float or None, outward unit normals
    context : (c, 3) float or None, points spread evenly over the shape for the local shape
        (a mesh's surface samples; None: the elements themselves)
    neighbours : (n, k) int or None, each element's neighbourhood for smoothing (a grid's
        :func:`grid_neighbours`; None: its nearest elements)
    grid_index : (n, 3) int or None, a grid's voxel indices (for ``LabellerSettings.grid_sample``)
    context_faces : (c,) int or None, a mesh's context samples' faces (the face each lies on; with
        ``faces`` and ``vertices``, the mesh in the input frame, for
        :func:`primkit.segmentation.meshlabels.label_faces`)
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    context: np.ndarray | None = None
    neighbours: np.ndarray | None = None
    grid_index: np.ndarray | None = None
    context_faces: np.ndarray | None = None
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None


def _rotate(frame, vectors):
    return None if vectors is None else np.asarray(vectors, float) @ np.asarray(frame.rotation, float).T


def grid_elements(grid, frame) -> tuple[Elements, np.ndarray]:
    """A voxel grid's occupied voxels: ``(Elements, index (n, 3) int)`` (``np.argwhere`` order;
    normals from :func:`grid_normals`; ``frame`` the grid's :class:`primkit.geometry.CanonicalFrame`)."""
    occupancy = np.asarray(grid.occupancy, bool)
    index = np.argwhere(occupancy)
    centres = grid.translate + (index + 0.5) * (grid.scale / grid.resolution)
    normals = grid_normals(occupancy, index)  # index axes are the model axes (uniform scale)
    return Elements(frame.to_canonical(centres), _rotate(frame, normals),
                    neighbours=grid_neighbours(index, occupancy.shape), grid_index=index), index


def mesh_elements(vertices, faces, frame, samples: int = 20000, seed=0) -> Elements:
    """A mesh's faces: centroids, face normals, and ``samples`` area-uniform surface points
    (trimesh) as the context, all canonical."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
    context, where = trimesh.sample.sample_surface(mesh, samples, seed=seed) if len(faces) else (np.zeros((0, 3)), None)
    enough = len(context) >= 3
    return Elements(frame.to_canonical(mesh.triangles_center), _rotate(frame, mesh.face_normals),
                    frame.to_canonical(context) if enough else None,
                    context_faces=np.asarray(where, np.int64) if enough else None,
                    vertices=mesh.vertices, faces=mesh.faces)


def point_elements(points, frame, normals=None) -> Elements:
    """A point cloud's points (and normals when it has them), canonical."""
    return Elements(frame.to_canonical(points), _rotate(frame, normals))


def element_features(elements: Elements, canonical: primitives.Cuboids, settings: LabellerSettings) -> np.ndarray:
    """:func:`frame_features` of every element, as :meth:`Labeller.predict_proba` reads them (a voxel
    grid's local shape found on the grid, :func:`grid_local_shape`): what a labeller learns from."""
    shape = None
    if settings.neighbours and elements.context is None and elements.grid_index is not None and len(elements.points):
        index = np.asarray(elements.grid_index, np.int64)
        shape = grid_local_shape(elements.points, index, np.arange(len(index)), settings.neighbours,
                                 index.max(axis=0) + 1)
    return frame_features(elements.points, canonical, elements.normals, settings, elements.context, local_shape=shape)


def label_elements(labeller: Labeller, elements: Elements, canonical: primitives.Cuboids, *,
                   graph=None) -> np.ndarray:
    """``(n,) int``: each element's label (index into ``labeller.names``); -1 everywhere when no
    cuboid is present. A mesh's faces (elements with ``faces``) are labelled over the mesh's
    surface (:func:`primkit.segmentation.meshlabels.label_faces`; ``graph``: the mesh's
    :func:`~primkit.segmentation.meshlabels.face_graph` when it is already built), other elements
    by :meth:`Labeller.predict`."""
    if not canonical.existence.any():
        return np.full(len(elements.points), -1, np.int64)
    if elements.faces is not None and len(elements.points):  # a mesh: over its surface (meshlabels)
        from .meshlabels import label_faces

        return label_faces(labeller, elements, canonical, graph=graph)
    return labeller.predict(elements.points, canonical, elements.normals, elements.context, elements.neighbours,
                            elements.grid_index)



def names_by_index(named, index, parts: int, label_names, fallback) -> list:
    """Each part index's name on one shape: the label most of its elements carry.

    ``named`` : (n,) int, each element's label (an index into ``label_names``; negative: none);
    ``index`` : (n,) int, each element's part index (the nearest-cuboid rule); ``fallback`` : the
    model's name of each of the ``parts`` indices, kept where an index holds no labelled element.
    Ties go to the label listed first. A name then selects, on this shape, the cuboids that hold
    mostly elements of that label (``edit --scale arms=...``: the cuboids of the arms).
    """
    named, index = np.asarray(named, np.int64), np.asarray(index, np.int64)
    if named.shape != index.shape:
        raise ValueError(f"`named` and `index` differ in shape: {named.shape} and {index.shape}")
    keep = (named >= 0) & (index >= 0) & (index < parts)
    counts = np.zeros((parts, len(label_names)), np.int64)
    np.add.at(counts, (index[keep], named[keep]), 1)
    return [str(label_names[int(np.argmax(row))]) if row.any() else str(fallback[k]) for k, row in enumerate(counts)]

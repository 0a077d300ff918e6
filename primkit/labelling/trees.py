"""Gradient-boosted tree ensembles as plain arrays, and the Numba walks that predict with them.

A labeller's fitted scikit-learn ``HistGradientBoostingClassifier`` is exported to
:class:`TreeEnsemble` (per node the feature, threshold, children, leaf value and the side missing
values go to) so that it is stored without code and read back with every array checked. The walk
gives scikit-learn's ``predict_proba`` (the same ``<=`` rule, the same handling of NaN, float64 sums
in the same order, the same softmax); the nodes are packed into two arrays on load for it
(:meth:`TreeEnsemble.packed`), and :data:`EARLY_STOP` lets a sample whose two best classes lie far
apart leave the walk early.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TreeEnsemble", "EARLY_STOP", "MAX_NODES", "MAX_TREES", "MAX_CLASSES", "MAX_PARTS"]

#: Bounds on what a stored labeller may ask for (a hostile file allocates nothing beyond them).
MAX_NODES = 50_000_000
MAX_TREES = 1_000_000
MAX_CLASSES = 256
MAX_PARTS = 1024


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
        None when they do not fit its fields (:data:`PACKED_LEAF` features, :data:`PACKED_NODES`
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

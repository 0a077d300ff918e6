"""The labeller: a per-element part classifier of one model, learned, decided and stored.

:meth:`Labeller.fit` learns scikit-learn's ``HistGradientBoostingClassifier`` from labelled shapes'
features (:mod:`primkit.labelling.features`) and exports its trees (:mod:`primkit.labelling.trees`);
:meth:`Labeller.predict` classifies (on a voxel grid one voxel in ``grid_sample``, the rest filled,
:mod:`primkit.labelling.smoothing`), blends in the index-naming prior, smooths over neighbours,
decides, then runs the post-steps its file names (:mod:`primkit.labelling.post`).
:func:`write_labeller` and :func:`read_labeller` store it in a model file: safetensors tensors and
a JSON description, one format version, every field written and checked.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..model.modelfile import ModelFileError
from .features import LabellerSettings, feature_count, frame_features, grid_local_shape, nearest_neighbours
from .layers import layer_levels
from .post import resolve_post, step_from_dict, step_to_dict
from .profile import column_range
from .smoothing import check_sampling, fill_unsampled, sample_grid, smooth_over
from .trees import EARLY_STOP, MAX_CLASSES, MAX_NODES, MAX_PARTS, TreeEnsemble

__all__ = ["Labeller", "LABELLER_FORMAT", "LABELLER_FORMAT_VERSION", "LABELLER_PREFIX", "LABELLER_KEY",
           "decide", "write_labeller", "read_labeller", "has_labeller"]

#: Value of the ``format`` key of a labeller's JSON description.
LABELLER_FORMAT = "primkit-labeller"
#: Version of the labeller's arrays and description: the only one read (a file of another version
#: is refused in one line that says how to learn it again). Every field is written, the post-steps
#: as a list (``post``, :mod:`primkit.labelling.post`); feature and child indices as int16.
LABELLER_FORMAT_VERSION = 11
#: Every key of a labeller's description.
DESCRIPTION_KEYS = ("format", "format_version", "names", "parts", "features", "settings", "classifier", "info", "post")
#: How a labeller file rebuilds: the message of a refused version ends with it.
LABELLER_REBUILD = "learn it again with `primkit name-parts LABELLED --model MODEL -o FILE` (docs/labeller.md)"
#: Prefix of a labeller's tensors in a model file (beside the network's weights).
LABELLER_PREFIX = "labeller."
#: Metadata key of a labeller's description in a model file.
LABELLER_KEY = "labeller"

#: How the file stores the tree arrays whose type differs from the one in memory
#: (:attr:`TreeEnsemble.ARRAYS`): feature and child indices in int16 (a third of the bytes per
#: node: the bundled chair model's labeller fits the wheel).
STORED = {"feature": np.int16, "left": np.int16, "right": np.int16}

#: ``Labeller.fit`` keeps a post-step it checks when it contradicts at most this share of the
#: labelled shapes' own labels (the arms rule: it would take their label away, or give it to a
#: shape without it, on 13 of the 219 PartNet validation chairs, 5.9%; the seat cut: it would move
#: more than a tenth of a grid's seat and legs voxels on 16 of the 218 with a seat, 7%).
POST_TOLERANCE = 0.2


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
        The rules run after the decision, in order (:mod:`primkit.labelling.post`; e.g. a
        chair's :class:`~primkit.labelling.presence.PresenceRule` and
        :class:`~primkit.labelling.layers.LayerCut`): stored in the file by name with every
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
            The post-steps to keep with the labeller (:func:`primkit.labelling.post.resolve_post`:
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
        grid's elements, with ``neighbours`` its
        :func:`~primkit.labelling.smoothing.grid_neighbours`, for ``grid_sample``)."""
        points = np.asarray(points, float)
        step = self.settings.grid_sample
        grid = context is None and grid_index is not None  # the local shape found on the grid
        if step == 1 or grid_index is None or neighbours is None or neighbours.shape[1] < 27:
            shape = self._grid_shape(points, grid_index, np.arange(len(points))) if grid else None
            proba = self.classify(self.features(points, cuboids, normals, context, local_shape=shape))
        else:
            grid_index, neighbours = check_sampling(grid_index, neighbours, step)
            classify, sampled = sample_grid(grid_index, neighbours, step)  # grid_sampling's, no around/use
            shape = self._grid_shape(points, grid_index, np.flatnonzero(classify)) if grid else None
            proba = np.empty((len(points), self.ensemble.classes + -self.ensemble.classes % 4))  # pad4's columns
            proba[:, self.ensemble.classes:] = 0.0
            proba[classify, : self.ensemble.classes] = self.classify(self.features(
                points[classify], cuboids, None if normals is None else np.asarray(normals, float)[classify],
                points if context is None else context, local_shape=shape))  # the local shape among all the elements
            # each other voxel: the mean of its sampled neighbours' (grid_sampling's ``around[use]``)
            fill_unsampled(proba, neighbours, sampled, classify)
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
        instead, nearest first (a voxel grid's :func:`~primkit.labelling.smoothing.grid_neighbours`), of which the first
        ``smooth_neighbours`` are used."""
        if not self.settings.smooth or len(proba) < 2:
            return proba
        k = self.settings.smooth_neighbours
        idx = neighbours if neighbours is not None else nearest_neighbours(np.asarray(points, float), k)
        return smooth_over(proba, idx, k, self.settings.smooth)

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

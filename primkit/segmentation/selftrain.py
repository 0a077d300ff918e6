"""Self-training a labeller with unlabelled shapes (learning time only).

A labeller learned from a few labelled shapes (:meth:`primkit.segmentation.labeller.Labeller.fit`)
names the elements of unlabelled shapes of the same model; the elements it names confidently
become *pseudo-labels*, and the labeller is learned again from the labelled shapes and the
pseudo-labelled ones (these weighing less), for ``rounds`` rounds. Nothing changes at labelling
time: the result is a :class:`~primkit.segmentation.labeller.Labeller` like any other (its
``info["self_training"]`` records how it was learned). The unlabelled shapes' own labels, if they
have any, are never read: only their features.

:func:`learn_labeller` is the entry point from segmented shapes (``name-parts --unlabelled``,
``--mirror``): it adds the labelled shapes' mirrors (:mod:`primkit.segmentation.mirror`) and the
unlabelled shapes, then :func:`fit_self_trained`.

Confidence is read from the probabilities the labeller gives at labelling time, blended with the
index prior and smoothed over each element's neighbours (:meth:`Labeller.classify` then
:meth:`Labeller.smooth`), on every element (no ``grid_sample``: learning time only).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .labeller import Labeller, LabellerSettings, decide

__all__ = ["SelfTraining", "UnlabelledShape", "pseudo_labels", "fit_self_trained", "unlabelled_shape", "learn_labeller"]


@dataclass(frozen=True)
class SelfTraining:
    """How unlabelled shapes join the learning.

    rounds : int
        Times the labeller labels the unlabelled shapes and is learned again (0: not at all).
    threshold : float
        An element of an unlabelled shape is learned from when its most probable label's
        (smoothed) probability is at least this.
    weight : float
        What one pseudo-labelled shape weighs against one labelled shape (each shape's elements
        share its weight, as in :meth:`Labeller.fit`).
    """

    rounds: int = 1
    threshold: float = 0.9
    weight: float = 0.5

    def __post_init__(self):
        if not 0 <= self.rounds <= 10:
            raise ValueError(f"self-training rounds must be 0-10, got {self.rounds}")
        if not 0 < self.threshold <= 1:
            raise ValueError(f"self-training threshold must be in (0, 1], got {self.threshold}")
        if not 0 < self.weight <= 1:
            raise ValueError(f"self-training weight must be in (0, 1], got {self.weight}")

    def to_dict(self) -> dict:
        return {"rounds": self.rounds, "threshold": self.threshold, "weight": self.weight}


@dataclass(frozen=True, eq=False)
class UnlabelledShape:
    """An unlabelled shape as a labeller reads it (canonical frame).

    features : (n, d) float, each element's features (:func:`primkit.segmentation.labeller.element_features`)
    points : (n, 3) float, the elements (for the smoothing's nearest neighbours)
    neighbours : (n, k) int or None, each element's neighbourhood for smoothing (a grid's
        :func:`~primkit.segmentation.labeller.grid_neighbours`; None: its nearest elements)
    """

    features: np.ndarray
    points: np.ndarray
    neighbours: np.ndarray | None = None


def pseudo_labels(labeller: Labeller, shape: UnlabelledShape, threshold: float, names) -> np.ndarray:
    """``(n,) int``: each element's label as ``labeller`` names it (an index into ``names``), -1
    where its probability is under ``threshold`` (and where the rule that drops rare labels,
    ``min_share``, moved it off its most probable label)."""
    proba = labeller.smooth(labeller.classify(np.asarray(shape.features, float)), shape.points, shape.neighbours)
    best = np.argmax(proba, axis=1)
    decided = decide(proba, labeller.settings.min_share)
    codes = np.array([list(names).index(k) for k in labeller.names], np.int64)[decided]
    sure = (proba[np.arange(len(proba)), best] >= threshold) & (decided == best)
    return np.where(sure, codes, -1)


def fit_self_trained(shapes, unlabelled, names, parts: int, *, self_training: SelfTraining | None = None,
                     settings: LabellerSettings | None = None, seed=0, progress: bool = False,
                     info: dict | None = None, **fit) -> Labeller:
    """Learn a labeller from labelled ``shapes`` and ``unlabelled`` ones (:class:`UnlabelledShape`).

    ``shapes``, ``names``, ``parts``, ``settings``, ``seed`` and ``fit`` are :meth:`Labeller.fit`'s.
    The index prior's weight follows the number of *labelled* shapes (:class:`LabellerSettings`'
    ``prior_weight``) and the prior is read from them alone: the pseudo-labels teach the trees only.
    Deterministic for a given ``seed``. ``progress``: a tqdm bar over the unlabelled shapes.
    """
    self_training = self_training or SelfTraining()
    settings = settings or LabellerSettings()
    shapes = [(np.asarray(X, float), np.asarray(y, np.int64)) for X, y in shapes]
    unlabelled = list(unlabelled)
    if settings.prior_weight is None:  # as Labeller.fit would set it from the labelled shapes alone
        settings = replace(settings, prior_weight=min(0.4, 4.0 / max(1, len(shapes))))
    labeller = first = Labeller.fit(shapes, names, parts, settings=settings, seed=seed, info=info, **fit)
    kept = 0
    for r in range(self_training.rounds if unlabelled else 0):
        from tqdm import tqdm

        pseudo = []
        for shape in tqdm(unlabelled, desc=f"self-training round {r + 1}", unit="shape", disable=not progress):
            y = pseudo_labels(labeller, shape, self_training.threshold, names)
            if np.any(y >= 0):
                pseudo.append((shape.features, y, self_training.weight))
        kept = int(sum(np.count_nonzero(y >= 0) for _, y, _ in pseudo))
        labeller = Labeller.fit(shapes + pseudo, names, parts, settings=settings, seed=seed, info=info, **fit)
        if list(labeller.names) != list(first.names):  # pseudo-labels use the first labeller's names only
            raise AssertionError("self-training changed the label set")
        labeller = replace(labeller, prior=first.prior)  # the labelled shapes' prior (its columns: these names)
    record = {**self_training.to_dict(), "unlabelled_shapes": len(unlabelled), "pseudo_labelled_elements": kept}
    new_info = {**labeller.info, "labelled_shapes": len(shapes), "self_training": record}
    return replace(labeller, info=new_info)


def unlabelled_shape(seg, result, settings: LabellerSettings) -> UnlabelledShape:
    """What self-training reads of a segmented shape (mesh, voxel grid or point cloud) and its
    :class:`~primkit.model.abstractor.AbstractionResult`: its elements' features as a labeller with
    ``settings`` reads them (:func:`~primkit.segmentation.labeller.element_features`), canonical frame."""
    from .labeller import element_features
    from .segmenter import shape_elements

    elements, _ = shape_elements(seg, result.frame)
    return UnlabelledShape(element_features(elements, result.canonical, settings), elements.points,
                           elements.neighbours)


def learn_labeller(labelled, names, parts: int, *, unlabelled=(), mirror: bool = False, segmenter=None,
                   self_training: SelfTraining | None = None, settings: LabellerSettings | None = None, seed=0,
                   progress: bool = False, **options) -> Labeller:
    """:func:`primkit.segmentation.segmenter.fit_labeller` with more to learn from: the labelled
    shapes' mirrors (``mirror``, abstracted again by ``segmenter``, :mod:`primkit.segmentation.mirror`)
    and unlabelled shapes (self-training, :func:`fit_self_trained`).

    ``labelled``: ``(segmentation, abstraction result, labels)`` as there; ``unlabelled``: an
    iterable of ``(segmentation, abstraction result)`` of the same model (their labels, if any,
    never read). The index prior's weight follows the number of labelled shapes (not their
    mirrors). ``info`` records ``mirrored`` (the mirrors learned from) and ``self_training``.
    """
    from tqdm import tqdm

    settings = settings or LabellerSettings()
    labelled = list(labelled)
    shapes = [(unlabelled_shape(seg, result, settings).features, np.asarray(y, np.int64))
              for seg, result, y in labelled]  # the labelled shapes' features, as fit_labeller reads them
    info = dict(options.pop("info", None) or {})
    if mirror:
        if segmenter is None:
            raise ValueError("mirroring needs the segmenter that abstracted the labelled shapes")
        from .mirror import mirrored_shapes

        mirrored = mirrored_shapes(labelled, segmenter, settings, progress=progress)
        shapes += mirrored
        info["mirrored"] = len(mirrored)
    if settings.prior_weight is None:  # from the labelled shapes, not their mirrors (Labeller.fit's rule)
        settings = replace(settings, prior_weight=min(0.4, 4.0 / max(1, len(labelled))))
    pool = [unlabelled_shape(seg, result, settings)
            for seg, result in tqdm(list(unlabelled), desc="unlabelled features", unit="shape", disable=not progress)]
    labeller = fit_self_trained(shapes, pool, names, parts, self_training=self_training if pool else SelfTraining(0),
                                settings=settings, seed=seed, progress=progress, info=info, **options)
    record = {**labeller.info, "labelled_shapes": len(labelled)}
    if not pool:
        record.pop("self_training", None)
    return replace(labeller, info=record)

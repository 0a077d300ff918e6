"""Whether a shape has arms at all: a label's presence read from the shape's own geometry.

A labeller decides each element on its own (then smooths and drops a label given to under
``min_share`` of the elements). Learned from a few labelled chairs it misses arms it has not seen
(a sofa's solid side blocks, called seat and back) and finds arms that are not there (a back's
wings, a seat's edge). Whether a chair has arms shows in its shape: something rises beside the
seat, over the seat's front-to-back span. :func:`side_region` marks those elements with the side
and profile features (:mod:`primkit.labelling.sides`, :mod:`primkit.labelling.profile`,
canonical frame: +Y up, +X front); a :class:`PresenceRule` then, after the labeller's decision,

* takes the label away from a shape whose side region holds under ``veto`` of its elements (they
  take their next most probable label, as the rare-label rule does);
* gives it to the side region's elements of a shape that has none of it but whose side region
  holds at least ``add`` of its elements (``grid_add`` of a voxel grid's voxels, which count the
  solid's inside where a mesh's faces or a cloud's points are its surface only), or at least
  ``hint_add`` (``grid_hint_add``) of them when the labeller's mean probability of the label over
  the region is at least ``hint`` (slim arms: the labeller leans to arms there without calling
  them, and the region is too small to decide alone; voxel grids only by default);
* on a shape that keeps the label, gives it to the side region's elements whose probability of it
  is at least ``fill`` (the labeller finds an arm's top and calls a sofa's side block below it seat
  or back; PartNet's arm box holds the whole block).

The region's bounds and the two shares were chosen on PartNet validation chairs, then ``fill``,
``grid_add`` and the hint on both halves of them in turn, ``grid_add`` on the voxel grids and
checked on their marching-cubes meshes, where ``add`` stays (``docs/labeller.md``). A stored rule
keeps the shares it was stored with.

The rule is the labeller post-step ``chair.arms_from_side_region`` (:mod:`primkit.labelling.post`):
a labeller applies it because its file names it, with the label it is told (``label``: "arms",
"armrest", ...), never because a label is spelled a certain way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sides import side_columns

__all__ = ["SIDE_ACROSS", "SIDE_RISE", "SIDE_ABOVE", "SIDE_FRONT", "PresenceRule", "side_region", "apply_presence"]

#: An element of the side region lies further across from the densest slab's middle than this
#: many of its half widths (side feature 2),
SIDE_ACROSS = 0.85
#: in a column whose top rises more than this above the densest slab (side feature 0, in box heights),
SIDE_RISE = 0.1
#: itself more than this above the densest slab's centre (profile column 5, in box heights),
SIDE_ABOVE = 0.05
#: and past this share of the densest slab's front-to-back span from its back (side feature 4).
SIDE_FRONT = 0.25


def side_region(points, context=None) -> np.ndarray:
    """``(n,) bool``: the elements that rise beside the seat (the module notes; ``points`` and
    ``context`` as :func:`primkit.labelling.sides.side_features` takes them, canonical frame)."""
    sides = side_columns(points, context)  # the side features, then the profile's height (column 5)
    return (sides[:, 2] > SIDE_ACROSS) & (sides[:, 0] > SIDE_RISE) & (sides[:, 5] > SIDE_ABOVE) \
        & (sides[:, 4] > SIDE_FRONT)


@dataclass(frozen=True)
class PresenceRule:
    """When a label is taken from a shape or given to it (the module notes): the post-step
    ``chair.arms_from_side_region``.

    label : str
        The label the rule decides (a chair's arms: ``"arms"``, ``"armrest"``, ...).
    veto : float
        The label is taken away when the side region holds under this share of the elements.
    add : float
        The label goes to the side region's elements when the shape has none of it and the region
        holds at least this share (above 1: never): a mesh's faces, a cloud's points.
    grid_add : float
        The same for a voxel grid's voxels.
    fill : float
        On a shape that keeps the label, the side region's elements whose probability of it is at
        least this take it (above 1: never).
    hint : float
        A smaller region gives the label too (``hint_add``, ``grid_hint_add``) when the labeller's
        mean probability of it over the region is at least this (above 1: never).
    hint_add : float
        That smaller share for a mesh's faces and a cloud's points (above 1: never, the default:
        on meshes it cost arms, ``docs/labeller.md``).
    grid_hint_add : float
        The same for a voxel grid's voxels.
    """

    label: str = "arms"
    veto: float = 0.01
    add: float = 0.1
    fill: float = 0.1
    grid_add: float = 0.05
    hint: float = 0.1
    hint_add: float = 2.0
    grid_hint_add: float = 0.025

    #: the post-step's name in a labeller file
    STEP = "chair.arms_from_side_region"

    def __post_init__(self):
        if not isinstance(self.label, str) or not self.label:
            raise ValueError("presence label must be a non-empty string")
        for key in ("veto", "add", "fill", "grid_add", "hint", "hint_add", "grid_hint_add"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not 0 <= value <= 2:
                raise ValueError(f"presence {key} must be a number in [0, 2]")

    def to_dict(self) -> dict:
        return {"label": self.label, "veto": float(self.veto), "add": float(self.add), "fill": float(self.fill),
                "grid_add": float(self.grid_add), "hint": float(self.hint),
                "hint_add": float(self.hint_add), "grid_hint_add": float(self.grid_hint_add)}

    @classmethod
    def from_dict(cls, d) -> "PresenceRule":
        """The inverse of :meth:`to_dict` (every key); ValueError (one line) on anything else."""
        keys = set(cls().to_dict())
        if not isinstance(d, dict) or set(d) != keys:
            raise ValueError(f"{cls.STEP} must be a JSON object with {', '.join(sorted(keys))}")
        return cls(**d)

    # -- as a labeller post-step (primkit.labelling.post) ---------------------------------

    def labels(self) -> tuple:
        """The labels the step reads (all must be the labeller's)."""
        return (self.label,)

    def describe(self) -> str:
        return f"{self.label} only where something rises beside the seat"

    def apply(self, names, labels, proba, points, context=None, grid_index=None, weights=None) -> np.ndarray:
        """``labels`` after the rule (unchanged when ``names`` lacks its label; ``points``,
        ``context`` canonical, as :func:`side_region` reads them; ``grid_index`` not None: the
        elements are a voxel grid's voxels, ``grid_add`` and ``grid_hint_add`` apply; ``weights``:
        each element's weight in the region's share, e.g. a mesh's face areas)."""
        if self.label not in names or len(labels) == 0:
            return labels
        return apply_presence(labels, proba, side_region(points, context), list(names).index(self.label), self,
                              weights, grid_index is not None)

    def contradicts(self, X, y, names, min_share: float, level) -> bool | None:
        """Whether the rule would contradict one labelled shape's own labels (take its label away
        or give it to a shape without it): ``X`` its features (canonical positions first), ``y``
        its labelled elements' labels, ``level`` their layers
        (:func:`primkit.labelling.layers.layer_levels`; None: not a grid). The hint is left out:
        it rests on probabilities."""
        if len(y) == 0:
            return None
        has = np.mean(y == list(names).index(self.label)) >= min_share
        share = float(np.mean(side_region(X[:, :3])))
        return bool(share < self.veto if has else share >= (self.add if level is None else self.grid_add))

    @staticmethod
    def kept(shapes: int, contradicted: int, tolerance: float) -> bool:
        """Whether a fit keeps the rule after its check over the labelled shapes."""
        return contradicted <= tolerance * shapes


def apply_presence(labels, proba, region, label: int, rule: PresenceRule, weights=None,
                   grid: bool = False) -> np.ndarray:
    """``(n,) int``: ``labels`` (each element's decided label) after ``rule``.

    ``proba`` : (n, classes) float, the probabilities ``labels`` were decided from (an element
    whose label is taken away takes its most probable other label); ``region`` : (n,) bool,
    :func:`side_region`; ``label`` : the rule's label's class index; ``weights`` : (n,) float or
    None, what each element weighs in the region's share and mean probability (a mesh's face
    areas; None: one each); ``grid`` : the elements are a voxel grid's voxels (the rule's
    ``grid_add`` and ``grid_hint_add`` apply).
    """
    labels = np.asarray(labels, np.int64)
    region = np.asarray(region, bool)
    if len(labels) == 0:
        return labels
    weights = np.ones(len(labels)) if weights is None else np.asarray(weights, float)
    share = float(np.sum(np.where(region, weights, 0.0)) / np.sum(weights))
    has = np.any(labels == label)
    if has and share < rule.veto:
        others = np.array(proba, float)
        others[:, label] = -np.inf
        return np.where(labels == label, np.argmax(others, axis=1), labels).astype(np.int64)
    if not has:
        bar, hint_bar = (rule.grid_add, rule.grid_hint_add) if grid else (rule.add, rule.hint_add)
        # the hint: a smaller region when the labeller's mean probability of the label over it is high enough
        leaning = share > 0 and share >= hint_bar and rule.hint <= 1 \
            and np.average(np.asarray(proba, float)[region, label], weights=weights[region]) >= rule.hint
        if share >= bar or leaning:
            return np.where(region, label, labels).astype(np.int64)
    if has and rule.fill <= 1:
        return np.where(region & (np.asarray(proba, float)[:, label] >= rule.fill), label, labels).astype(np.int64)
    return labels

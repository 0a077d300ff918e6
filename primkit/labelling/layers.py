"""Where a seat ends: one horizontal cut between two labels, on a voxel grid's layers.

A labeller learned from a few chairs finds the seat and the legs but puts the boundary between
them a voxel or two off on many chairs (the trees read each voxel on its own, and the seat's
underside looks like the top of the legs). On PartNet's chairs the boundary is nearly always one
horizontal plane: the bottom of the seat. Cut at the best plane found from the truth, the
validation chairs' seat and legs voxels would be 98% right, and the mean IoU over back, seat and
legs of a 10-chair labeller would rise from 0.76 to 0.82 (``docs/labeller.md``).

The cut reads the plane from two things: the shape's layers (the seat is the densest horizontal
layer of a solid, and its bottom is where the layers below stop being nearly as full), and the
labeller's own probabilities (which of the few planes near that bottom agrees best with them).
A :class:`LayerCut`, after the labeller's decision:

* takes the layers of the shape's elements along the canonical up axis (+Y): a voxel grid's
  elements lie on layers; a mesh's faces and a point cloud's points do not, and are left alone
  (their surface samples show a thick seat's top and bottom, not where the solid seat ends);
* finds the densest layer above the bottom ``floor`` of the layers (a sled's or a rocking chair's
  runners on the floor are no seat), then goes down while the layer below holds at least
  ``share`` of its count: the lowest layer reached is the seat's bottom;
* among the elements labelled ``upper`` or ``lower``, tries every cut within ``window`` layers of
  that bottom and keeps the one that disagrees least with their probabilities (each element
  weighing its share ``p_upper / (p_upper + p_lower)`` when put below, the rest when put above);
* labels those elements ``lower`` below the cut and ``upper`` from it up;
* a shape labelled ``upper`` but not ``lower`` (``restore``): a sofa's or an armchair's few feet,
  under 1% of its voxels, lose their label with the rare ones or are called seat, and the
  probabilities there agree with that; the cut goes at the seat's bottom itself, and the elements
  labelled ``upper`` below it become ``lower``. A shape standing on its seat's block has no layer
  below that bottom and keeps its labels. A shape without ``upper`` is left alone.

``share``, ``window``, ``floor`` and ``restore`` were chosen on PartNet validation chairs, both
halves in turn (``docs/labeller.md``). The cut is the labeller post-step ``chair.seat_layer_cut``
(:mod:`primkit.labelling.post`): a labeller applies it because its file names it, with the
labels it is told (``upper``: "seat", "Seat", ...; ``lower``: "legs", ...). Written here with NumPy counts and
cumulative sums: the best cut is a one-dimensional search over a few layers, which no graph cut or
segmentation library needs to be asked for (``graphcut.py``'s max-flow was tried for the whole
labelling and not kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .profile import column_range

__all__ = ["LayerCut", "layer_levels", "cut_reads", "apply_layer_cut", "cut_levels", "MAX_LAYERS"]

#: A shape is layered when its elements' heights take at most this many values (the network
#: grid's largest side, :data:`primkit.model.network.MAX_NETWORK_GRID`) and at most half as many as
#: it has elements.
MAX_LAYERS = 256


@dataclass(frozen=True)
class LayerCut:
    """Where ``upper`` ends and ``lower`` begins (the module notes).

    upper, lower : str
        The labels above and below the cut (a chair's ``"seat"`` and ``"legs"``).
    share : float
        The seat's bottom is the lowest layer reached from the densest one going down through
        layers holding at least this share of the densest layer's elements.
    window : int
        The cut is tried within this many layers of that bottom.
    floor : float
        The densest layer is sought above this share of the layers, counted from the lowest.
    restore : bool
        A shape labelled ``upper`` but not ``lower`` is cut too, at the seat's bottom (the
        module notes); False: such a shape is left alone.
    """

    upper: str = "seat"
    lower: str = "legs"
    share: float = 0.6
    window: int = 2
    floor: float = 0.2
    restore: bool = True

    #: the post-step's name in a labeller file
    STEP = "chair.seat_layer_cut"

    def __post_init__(self):
        for key in ("upper", "lower"):
            if not isinstance(getattr(self, key), str) or not getattr(self, key):
                raise ValueError(f"layer cut {key} must be a non-empty string")
        if self.upper == self.lower:
            raise ValueError("layer cut upper and lower must differ")
        if not isinstance(self.share, (int, float)) or isinstance(self.share, bool) or not 0 < self.share <= 1:
            raise ValueError("layer cut share must be a number in (0, 1]")
        if not isinstance(self.window, int) or isinstance(self.window, bool) or not 0 <= self.window <= MAX_LAYERS:
            raise ValueError(f"layer cut window must be an int from 0 to {MAX_LAYERS}")
        if not isinstance(self.floor, (int, float)) or isinstance(self.floor, bool) or not 0 <= self.floor < 1:
            raise ValueError("layer cut floor must be a number in [0, 1)")
        if not isinstance(self.restore, bool):
            raise ValueError("layer cut restore must be true or false")

    def to_dict(self) -> dict:
        return {"upper": self.upper, "lower": self.lower, "share": float(self.share), "window": int(self.window),
                "floor": float(self.floor), "restore": self.restore}

    @classmethod
    def from_dict(cls, d) -> "LayerCut":
        """The inverse of :meth:`to_dict` (every key); ValueError (one line) on anything else."""
        keys = set(cls().to_dict())
        if not isinstance(d, dict) or set(d) != keys:
            raise ValueError(f"{cls.STEP} must be a JSON object with {', '.join(sorted(keys))}")
        return cls(**d)

    # -- as a labeller post-step (primkit.labelling.post) ---------------------------------

    def labels(self) -> tuple:
        """The labels the step reads (all must be the labeller's)."""
        return (self.upper, self.lower)

    def describe(self) -> str:
        return f"{self.upper}/{self.lower} cut at one height on voxel grids" \
            + (f" ({self.lower} under a {self.upper} that has none)" if self.restore else "")

    def apply(self, names, labels, proba, points, context=None, grid_index=None, weights=None) -> np.ndarray:
        """``labels`` after the cut (unchanged without ``grid_index``, the ``(n, 3) int`` voxel
        indices of a grid's elements whose layers the cut reads, or when ``names`` lacks its
        labels; ``points`` canonical)."""
        if grid_index is None or len(labels) == 0 or not {self.upper, self.lower} <= set(names):
            return labels
        names = list(names)
        most = int(np.max(column_range(np.asarray(grid_index, np.int64))[1])) + 1  # a grid's largest side
        return apply_layer_cut(labels, proba, np.asarray(points, float)[:, 1], names.index(self.upper),
                               names.index(self.lower), self, most)

    def contradicts(self, X, y, names, min_share: float, level, tolerance: float = 0.1) -> bool | None:
        """Whether the cut, run on one labelled grid's own labels ``y`` (``level``: their layers,
        :func:`layer_levels`; None: not a grid, not read), would move more than ``tolerance`` of
        its ``upper`` and ``lower`` elements; None when it does not read the grid."""
        if level is None:
            return None
        names = list(names)
        upper, lower = names.index(self.upper), names.index(self.lower)
        if not cut_reads(y, upper, lower, self):
            return None
        moved = cut_levels(y, level, (y == upper).astype(float), upper, lower, self) != y
        return bool(np.count_nonzero(moved) / np.count_nonzero((y == upper) | (y == lower)) > tolerance)

    @staticmethod
    def kept(shapes: int, contradicted: int, tolerance: float) -> bool:
        """Whether a fit keeps the cut after its check: some labelled grids read, at most
        ``tolerance`` of them contradicting it (a labeller learned from meshes or points alone has
        none)."""
        return shapes > 0 and contradicted <= tolerance * shapes


def layer_levels(heights, most: int = MAX_LAYERS):
    """``(n,) int``: each element's layer (0 the lowest), or None when the heights do not lie on
    at most ``most`` layers (and at most half as many as there are elements).

    Heights within a millionth of the shape's height of each other are one layer (a grid's
    layers, carried into the canonical frame, differ in the last bits)."""
    heights = np.asarray(heights, float)
    if len(heights) < 2 or not np.all(np.isfinite(heights)):
        return None
    values, inverse = np.unique(heights, return_inverse=True)
    tol = 1e-6 * max(float(values[-1] - values[0]), 1e-12)
    layer_of_value = np.concatenate([[0], np.cumsum(np.diff(values) > tol)])
    layers = int(layer_of_value[-1]) + 1
    if layers > min(most, len(heights) // 2):
        return None
    return layer_of_value[inverse.reshape(-1)]


def cut_reads(labels, upper: int, lower: int, cut: LayerCut) -> bool:
    """Whether ``cut`` reads a shape labelled ``labels`` ((n,) int): it has ``upper``, and
    ``lower`` too unless the cut restores a missing one (``cut.restore``)."""
    labels = np.asarray(labels)
    return bool(np.any(labels == upper) and (cut.restore or np.any(labels == lower)))


def apply_layer_cut(labels, proba, heights, upper: int, lower: int, cut: LayerCut, most: int = MAX_LAYERS):
    """``(n,) int``: ``labels`` after ``cut`` (the module notes).

    ``proba`` : (n, classes) float, the probabilities ``labels`` were decided from; ``heights`` :
    (n,) float, each element's canonical height (+Y); ``upper``, ``lower`` : the class indices of
    ``cut.upper`` and ``cut.lower``; ``most`` : :func:`layer_levels`'s (a grid's largest side).
    """
    labels = np.asarray(labels, np.int64)
    if not cut_reads(labels, upper, lower, cut):
        return labels
    level = layer_levels(heights, most)
    if level is None:
        return labels
    proba = np.asarray(proba, float)
    pu, pl = proba[:, upper], proba[:, lower]
    total = pu + pl
    upperness = np.divide(pu, total, out=np.full(len(total), 0.5), where=total > 0)
    return cut_levels(labels, level, upperness, upper, lower, cut)


def cut_levels(labels, level, upperness, upper: int, lower: int, cut: LayerCut) -> np.ndarray:
    """``(n,) int``: ``labels`` after ``cut``, the elements' layers known (:func:`layer_levels`)
    and ``upperness`` (n,) float, how much each wants to be ``upper`` (``p_upper / (p_upper +
    p_lower)``; a shape's own labels: 1 for ``upper``, 0 for ``lower``). Read only where
    ``labels`` is ``upper`` or ``lower``; a shape without ``upper`` is left alone, and one without
    ``lower`` too unless ``cut.restore`` (then cut at the seat's bottom, ``upperness`` unread)."""
    labels = np.asarray(labels, np.int64)
    if not cut_reads(labels, upper, lower, cut):
        return labels
    chosen = (labels == upper) | (labels == lower)
    restoring = not np.any(labels == lower)
    count = np.bincount(level)
    low = int(np.ceil(round(cut.floor * len(count), 9)))  # the layers the seat is not sought in
    if low >= len(count):
        return labels
    densest = low + int(np.argmax(count[low:]))
    bottom = densest
    while bottom > 0 and count[bottom - 1] >= cut.share * count[densest]:
        bottom -= 1
    at = level[chosen]
    if restoring:  # the probabilities below the bottom say upper: the layers alone place the cut
        out = labels.copy()
        out[chosen] = np.where(at < bottom, lower, upper)
        return out
    s, layers = np.asarray(upperness, float)[chosen], len(count)
    below = np.concatenate([[0.0], np.cumsum(np.bincount(at, s, layers))])  # upper-ness put below cut h
    above = np.concatenate([[0.0], np.cumsum(np.bincount(at, 1.0 - s, layers))])
    cost = below + (above[-1] - above)  # cut h: layers < h lower, the others upper
    lo, hi = max(bottom - cut.window, 0), min(bottom + cut.window, layers)
    h = lo + int(np.argmin(cost[lo : hi + 1]))
    out = labels.copy()
    out[chosen] = np.where(at < h, lower, upper)
    return out

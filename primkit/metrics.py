"""Scores of a cuboid abstraction against the shape it explains, with their conventions spelled out.

Published numbers for shape abstraction mix conventions (squared or unsquared Chamfer distances, a
sum or a mean of the two directions, 10^3 or 10^5 samples, various scalings of the shape) and so
differ by 10-100x for the same result. Every Chamfer number primkit prints therefore comes with
:meth:`ChamferConvention.describe`, one line that says exactly what was computed.

All scores are in the canonical frame of :mod:`primkit` (bounding box centred at the origin,
longest side 1), and all use only the *present* cuboids: the abstraction is the union of the
solid cuboids whose ``existence`` is True.

=================  ==========================================================================
score              definition (A: the abstraction, S: the shape)
=================  ==========================================================================
``chamfer``        :func:`chamfer_distance` between area-uniform samples of the surface of A
                   (:func:`union_surface_samples`) and of S, under a :class:`ChamferConvention`.
``iou``            volume of (A and S) / volume of (A or S) on the canonical grid
                   (:func:`volumetric_iou`).
``coverage``       mean over surface samples x of S of d(x, A)^2, with d the distance to the
                   solid union (zero inside): the method's coverage loss (:func:`coverage_error`).
``consistency``    area-weighted mean over surface samples y of the present cuboids of
                   d(y, surface of S)^2 read from the closest-point grid: the method's
                   consistency loss, normalised by the total area (:func:`consistency_error`).
``parts``          number of present cuboids.
=================  ==========================================================================

``coverage`` and ``consistency`` are squared distances (units: (longest side)^2), like the losses
the abstractor is trained on. ``chamfer`` is unsquared by default (``power=1``).

An abstraction with no present part scores ``chamfer = coverage = inf``, ``consistency = nan``
(there is no part surface to average over) and ``iou = 0`` (1 when the shape is empty too).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from .geometry import grid_centres, lookup_distance_sq
from .primitives import assign_points, contains, Cuboids, sample_cuboid_surfaces, union_distance, union_surface_samples
from .primitives.cuboids import check_cuboids

if TYPE_CHECKING:  # pragma: no cover
    from .data import PreparedShape

__all__ = [
    "ChamferConvention",
    "chamfer_distance",
    "cuboid_chamfer",
    "volumetric_iou",
    "coverage_error",
    "consistency_error",
    "AbstractionScores",
    "score",
    "summarize",
    "Statistics",
    "ScoreSummary",
    "part_label_agreement",
    "LabelAgreement",
    "PartLabelAgreement",
]

#: points processed at once against all cuboids (bounds the (m, n, 3) temporaries)
_CHUNK = 65536


# --------------------------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------------------------


def _points(value: Any, name: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"`{name}` must be (n, 3) float, got shape {a.shape}")
    if len(a) == 0:
        raise ValueError(f"`{name}` must hold at least one point")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"`{name}` must be finite")
    return a






# --------------------------------------------------------------------------------------------
# Chamfer distance
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ChamferConvention:
    """Exactly which Chamfer distance is meant.

    With ``d(a, B) = min_{b in B} |a - b|`` (Euclidean) and ``p = power``::

        mean_of_means:  ( mean_{a in A} d(a, B)^p + mean_{b in B} d(b, A)^p ) / 2
        sum_of_means:     mean_{a in A} d(a, B)^p + mean_{b in B} d(b, A)^p

    Attributes
    ----------
    power : int
        1: unsquared distances (the "Chamfer-L1" of Occupancy Networks, Neural Parts, SuperDec);
        2: squared distances (the "Chamfer-L2" of Superquadrics Revisited).
    reduction : str
        ``"mean_of_means"`` (default) or ``"sum_of_means"`` (twice the former).
    samples : int
        Points on each surface: drawn on the abstraction, and taken (a random subset) from the
        shape's surface samples.
    frame : str
        The frame the points are in; informational, printed by :meth:`describe`.
    unit : str
        ``"longest-side"`` (default): distances in the canonical frame, where the shape's
        bounding box has longest side 1. ``"diagonal"``: distances divided by the length of the
        diagonal of the shape's bounding box (of its surface samples), the unit of
        per-shape fitters' papers (e.g. EMS, Liu et al. 2022); a chair's diagonal is about 1.3-1.6
        longest sides, so these figures are that much smaller.
    """

    power: int = 1
    reduction: str = "mean_of_means"
    samples: int = 10000
    frame: str = "canonical: bbox centred, longest side 1"
    unit: str = "longest-side"

    def __post_init__(self) -> None:
        if self.power not in (1, 2) or isinstance(self.power, bool):
            raise ValueError(f"`power` must be 1 or 2, got {self.power!r}")
        if self.reduction not in ("mean_of_means", "sum_of_means"):
            raise ValueError(f"`reduction` must be 'mean_of_means' or 'sum_of_means', got {self.reduction!r}")
        if int(self.samples) != self.samples or self.samples < 1:
            raise ValueError(f"`samples` must be a positive integer, got {self.samples!r}")
        if self.unit not in ("longest-side", "diagonal"):
            raise ValueError(f"`unit` must be 'longest-side' or 'diagonal', got {self.unit!r}")

    def describe(self) -> str:
        """One line stating the formula, squared or not, the sample counts and the frame."""
        sq = "^2" if self.power == 2 else ""
        body = f"mean_A min_B |a-b|{sq} + mean_B min_A |b-a|{sq}"
        formula = f"({body}) / 2" if self.reduction == "mean_of_means" else body
        squared = "squared" if self.power == 2 else "unsquared"
        unit = "" if self.unit == "longest-side" else ", in units of the shape's bounding-box diagonal"
        return (
            f"Chamfer-L{self.power} = {formula}, {squared}, "
            f"{self.samples}+{self.samples} samples, frame {self.frame}{unit}"
        )


def chamfer_distance(points_a: Any, points_b: Any, convention: ChamferConvention = ChamferConvention()) -> float:
    """Chamfer distance between two point sets under ``convention`` (its ``samples`` is not used:
    every given point counts).

    Parameters
    ----------
    points_a : (n, 3) float
    points_b : (k, 3) float

    Returns
    -------
    float
        Symmetric in its arguments; zero for identical sets.
    """
    from scipy.spatial import cKDTree

    a = _points(points_a, "points_a")
    b = _points(points_b, "points_b")
    d_ab, _ = cKDTree(b).query(a, k=1, workers=-1)
    d_ba, _ = cKDTree(a).query(b, k=1, workers=-1)
    total = np.mean(d_ab**convention.power) + np.mean(d_ba**convention.power)
    return float(total / 2.0 if convention.reduction == "mean_of_means" else total)






def cuboid_chamfer(
    cuboids: Cuboids,
    surface_points: Any,
    convention: ChamferConvention = ChamferConvention(),
    seed: Any = 0,
) -> float:
    """Chamfer distance between the surface of the assembled cuboids and the shape's surface.

    ``convention.samples`` points are drawn on the union of the present cuboids by
    :func:`union_surface_samples`, and a random subset of ``convention.samples`` of the shape's
    ``surface_points`` is taken (all of them when there are exactly that many), then
    :func:`chamfer_distance` compares the two.

    Parameters
    ----------
    cuboids : Cuboids
    surface_points : (n, 3) float
        Area-uniform samples of the shape's surface, canonical frame; ``n >= convention.samples``.
    seed : None, int or numpy Generator
        Drives both the union sampling and the subset.

    Returns
    -------
    float
        ``inf`` when no part is present.
    """
    c = check_cuboids(cuboids)
    pts = _points(surface_points, "surface_points")
    k = int(convention.samples)
    if len(pts) < k:
        raise ValueError(
            f"the shape has {len(pts)} surface points but the convention asks for {k}; "
            f"pass ChamferConvention(samples={len(pts)}) (or fewer) to score it"
        )
    if not c.existence.any():
        return float("inf")
    rng = np.random.default_rng(seed)
    ours = union_surface_samples(c, k, rng)
    unit = 1.0
    if convention.unit == "diagonal":
        unit = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))  # of all the samples, before the subset
    if len(pts) > k:
        pts = pts[rng.choice(len(pts), size=k, replace=False)]
    return chamfer_distance(ours, pts, convention) / unit**convention.power


# --------------------------------------------------------------------------------------------
# Volumetric IoU
# --------------------------------------------------------------------------------------------


def volumetric_iou(cuboids: Cuboids, solid: Any, resolution: int | None = None, supersample: int = 2) -> float:
    """Intersection over union of the assembled cuboids and the solid shape, on the canonical grid.

    The evaluation points are the cell centres of the canonical grid of resolution
    ``N = resolution * supersample`` (``resolution`` defaults to the solid's ``R``), i.e. every
    cell of the resolution-``resolution`` grid split into ``supersample^3`` equal sub-cells. At
    each point:

    * the abstraction is inside when the point lies in a present solid cuboid (boundary
      included: :func:`primkit.primitives.contains`);
    * the shape is inside when the cell of ``solid`` (resolution ``R``) holding the point is
      set, the cell being ``floor((x + 0.5) * R)`` per axis. With the defaults, each cell of
      ``solid`` contributes ``supersample^3`` points, all with the cell's value.

    The score is (points inside both) / (points inside either), each point standing for the same
    volume. A box whose faces lie on sub-cell boundaries is therefore measured exactly.

    Parameters
    ----------
    cuboids : Cuboids
    solid : (R, R, R) bool
    resolution : int, optional
        Base resolution of the evaluation grid (before supersampling); ``R`` by default.
    supersample : int
        Sub-cells per axis, >= 1.

    Returns
    -------
    float in [0, 1]
        1.0 when both the abstraction and the shape are empty on the grid.
    """
    c = check_cuboids(cuboids)
    grid = np.asarray(solid)
    if grid.ndim != 3 or len(set(grid.shape)) != 1:
        raise ValueError(f"`solid` must be (R, R, R) bool, got shape {grid.shape}")
    grid = grid.astype(bool)
    res = grid.shape[0]
    base = res if resolution is None else int(resolution)
    if base < 1 or int(supersample) < 1:
        raise ValueError("`resolution` and `supersample` must be >= 1")
    n = base * int(supersample)
    centres = grid_centres(n).reshape(-1, 3)
    cell = np.clip(np.floor((centres + 0.5) * res).astype(np.int64), 0, res - 1)
    shape_in = grid[cell[:, 0], cell[:, 1], cell[:, 2]]
    if c.existence.any():
        ours = contains(centres, c.subset(c.present)).any(axis=1)
    else:
        ours = np.zeros(len(centres), dtype=bool)
    union = np.count_nonzero(ours | shape_in)
    if union == 0:
        return 1.0
    return float(np.count_nonzero(ours & shape_in) / union)


# --------------------------------------------------------------------------------------------
# The method's two losses, as errors
# --------------------------------------------------------------------------------------------


def coverage_error(cuboids: Cuboids, surface_points: Any) -> float:
    """Mean squared distance of the shape's surface points to the union of the present cuboids.

    ``mean_x min_k d(x, cuboid_k)^2`` with the distance to the *solid* cuboid (zero inside): the
    coverage loss of the method. ``inf`` when no part is present.

    Parameters
    ----------
    cuboids : Cuboids
    surface_points : (n, 3) float
    """
    c = check_cuboids(cuboids)
    pts = _points(surface_points, "surface_points")
    if not c.existence.any():
        return float("inf")
    total = 0.0
    for start in range(0, len(pts), _CHUNK):
        total += float(union_distance(pts[start : start + _CHUNK], c, squared=True).sum())
    return total / len(pts)




def consistency_error(cuboids: Cuboids, closest: Any, samples_per_cuboid: int = 150, seed: Any = 0) -> float:
    """Area-weighted mean squared distance of the present cuboids' surfaces to the shape's surface.

    Each present cuboid gets ``samples_per_cuboid`` surface samples, split equally over its six
    faces, each weighted by ``area(face) / (samples_per_cuboid / 6)``
    (:func:`primkit.primitives.sample_cuboid_surfaces`); the squared distances come from
    :func:`lookup_distance_sq` and are averaged with these weights (sum of weight * d^2 over the sum
    of weights, the total surface area). This is the consistency loss of the method, normalised by
    area. Overlapping parts are not cut: every part's whole surface counts. ``nan`` when no part
    is present.

    Parameters
    ----------
    cuboids : Cuboids
    closest : (R, R, R, 3) float
        The shape's closest-point grid (``PreparedShape.closest``).
    samples_per_cuboid : int
        A positive multiple of 6.
    seed : None, int or numpy Generator
    """
    c = check_cuboids(cuboids)
    if not c.existence.any():
        return float("nan")
    present = c.subset(c.present)
    s = sample_cuboid_surfaces(present, samples_per_cuboid, seed)
    d2 = lookup_distance_sq(closest, s.points.reshape(-1, 3))
    w = s.weights.ravel()
    return float(np.sum(w * d2) / np.sum(w))


# --------------------------------------------------------------------------------------------
# All scores of one shape, and of a collection
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AbstractionScores:
    """The scores of one abstraction (see the module notes for the definitions).

    Attributes
    ----------
    chamfer : float
        Under ``convention``.
    iou : float
        Volumetric IoU on the canonical grid.
    coverage, consistency : float
        Squared distances.
    parts : int
        Present cuboids.
    convention : str
        :meth:`ChamferConvention.describe` of the Chamfer convention used.
    """

    chamfer: float
    iou: float
    coverage: float
    consistency: float
    parts: int
    convention: str

    def to_dict(self) -> dict:
        """A JSON-ready dict of the fields."""
        return asdict(self)


#: the numeric fields of AbstractionScores, in order
_SCORE_FIELDS = ("chamfer", "iou", "coverage", "consistency", "parts")


def score(
    cuboids: Cuboids,
    prepared_shape: PreparedShape,
    convention: ChamferConvention = ChamferConvention(),
    seed: Any = 0,
) -> AbstractionScores:
    """Every score of ``cuboids`` against one prepared shape.

    Uses ``prepared_shape.points`` (Chamfer, coverage), ``.solid`` (IoU, with the defaults of
    :func:`volumetric_iou`) and ``.closest`` (consistency, 150 samples per cuboid).
    """
    c = check_cuboids(cuboids)
    return AbstractionScores(
        chamfer=cuboid_chamfer(c, prepared_shape.points, convention, seed=seed),
        iou=volumetric_iou(c, prepared_shape.solid),
        coverage=coverage_error(c, prepared_shape.points),
        consistency=consistency_error(c, prepared_shape.closest, seed=seed),
        parts=int(c.existence.sum()),
        convention=convention.describe(),
    )


@dataclass(frozen=True)
class Statistics:
    """Mean, median and standard deviation (population, ``ddof=0``) of one score over shapes."""

    mean: float
    median: float
    std: float


@dataclass(frozen=True)
class ScoreSummary:
    """What :func:`summarize` returns: each score's :class:`Statistics` over ``count`` shapes.

    ``empty`` counts the shapes with no present part; ``convention`` is the Chamfer convention
    every score was taken under (:meth:`ChamferConvention.describe`).
    """

    count: int
    empty: int
    convention: str
    chamfer: Statistics
    iou: Statistics
    coverage: Statistics
    consistency: Statistics
    parts: Statistics

    def to_dict(self) -> dict:
        """A JSON-ready dict: ``{"count", "empty", "convention", "chamfer": {"mean", "median", "std"}, ...}``."""
        return asdict(self)


def summarize(scores: Sequence[AbstractionScores]) -> ScoreSummary:
    """Mean, median and standard deviation (population, ``ddof=0``) of each score over shapes.

    Non-finite values are kept, so one empty abstraction (``chamfer = inf``) makes the mean
    ``inf``; the median stays informative, and ``empty`` counts such shapes.

    Returns
    -------
    ScoreSummary
        Raises ValueError for an empty list or for scores taken under different conventions.
    """
    scores = list(scores)
    if not scores:
        raise ValueError("`scores` is empty")
    conventions = {s.convention for s in scores}
    if len(conventions) != 1:
        raise ValueError(f"scores were taken under different conventions: {sorted(conventions)}")
    stats = {}
    for name in _SCORE_FIELDS:
        values = np.array([getattr(s, name) for s in scores], dtype=np.float64)
        with np.errstate(invalid="ignore"):
            stats[name] = Statistics(float(np.mean(values)), float(np.median(values)), float(np.std(values)))
    return ScoreSummary(count=len(scores), empty=sum(1 for s in scores if s.parts == 0), convention=conventions.pop(),
                        **stats)


@dataclass(frozen=True)
class LabelAgreement:
    """One ground-truth label in :func:`part_label_agreement`: its most common primitive ``index``,
    the fraction of shapes whose index it is (``agreement``), and the shapes having the label."""

    index: int
    agreement: float
    shapes: int


@dataclass(frozen=True)
class PartLabelAgreement:
    """What :func:`part_label_agreement` returns: ``per_label`` (label name -> :class:`LabelAgreement`,
    in label order) and the ``mean`` and ``min`` agreement over labels (NaN when there is none)."""

    per_label: dict[str, LabelAgreement]
    mean: float
    min: float

    def to_dict(self) -> dict:
        """A JSON-ready dict: ``{"per_label": {label: {"index", "agreement", "shapes"}}, "mean", "min"}``."""
        return asdict(self)


def part_label_agreement(cuboids_list, point_sets, label_sets, names=None) -> PartLabelAgreement:
    """How consistently each ground-truth part is explained by the same primitive index across shapes.

    Each labelled surface point goes to its primitive (:func:`primkit.primitives.assign_points`:
    smallest distance, ties to the larger cuboid); on each shape a label's *index* is the primitive
    holding most of that label's points. A label's agreement is the fraction of the shapes having
    that label whose index equals the label's most common index over all shapes.

    Parameters
    ----------
    cuboids_list : list of Cuboids
        One abstraction per shape (same frame as the points).
    point_sets : list of (n, 3) float
    label_sets : list of (n,) int
        Ground-truth label per point (-1: unlabelled).
    names : sequence of str, optional
        Name of each label value, for the report.

    Returns
    -------
    PartLabelAgreement
    """
    from collections import Counter, defaultdict

    chosen = defaultdict(list)
    for cub, pts, labels in zip(cuboids_list, point_sets, label_sets):
        labels = np.asarray(labels)
        if not cub.existence.any():
            continue
        idx = assign_points(np.asarray(pts, float), cub)
        for lab in np.unique(labels[labels >= 0]):
            counts = np.bincount(idx[labels == lab], minlength=cub.count)
            chosen[int(lab)].append(int(np.argmax(counts)))
    per_label = {}
    for lab, picks in sorted(chosen.items()):
        mode, hits = Counter(picks).most_common(1)[0]
        key = names[lab] if names is not None and lab < len(names) else str(lab)
        per_label[key] = LabelAgreement(mode, hits / len(picks), len(picks))
    values = [v.agreement for v in per_label.values()]
    return PartLabelAgreement(per_label, float(np.mean(values)) if values else float("nan"),
                              float(np.min(values)) if values else float("nan"))

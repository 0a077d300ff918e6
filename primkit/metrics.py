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

Segmentations of a mesh (face labels, arbitrary segment ids) are compared by the measures of the
Princeton segmentation benchmark (Chen, Golovinskiy, Funkhouser 2009), weighted by area:
:func:`rand_distance` (1 - Rand index), :func:`hamming_distance` (``Rm``, ``Rf`` and their mean)
and :func:`cut_discrepancy`; :class:`ReferenceSegmentations` scores one segmentation against
several references (human segmentations) and the references against each other.
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
    "rand_distance",
    "hamming_distance",
    "HammingDistance",
    "cut_discrepancy",
    "SegmentationScores",
    "ReferenceSegmentations",
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


# --------------------------------------------------------------------------------------------
# Two segmentations of one mesh compared (the Princeton segmentation benchmark's measures)
# --------------------------------------------------------------------------------------------
#
# The measures of Chen, Golovinskiy and Funkhouser, "A Benchmark for 3D Mesh Segmentation"
# (SIGGRAPH 2009), on face labels. Segment ids are arbitrary: every measure depends only on the
# partition the labels make, not on the values (0 for the same partition however it is numbered).


def _labels(value: Any, name: str, count: int | None = None) -> np.ndarray:
    a = np.asarray(value)
    if a.ndim != 1 or (len(a) and not np.issubdtype(a.dtype, np.integer)):
        raise ValueError(f"`{name}` must be (f,) int, got {a.dtype} of shape {a.shape}")
    if count is not None and len(a) != count:
        raise ValueError(f"`{name}` must be (f,) int with one label per face ({count}), got {len(a)}")
    if not len(a):
        raise ValueError(f"`{name}` must hold at least one label")
    return a.astype(np.int64, copy=False)


def _weights(value: Any, count: int) -> np.ndarray:
    if value is None:
        return np.full(count, 1.0 / count)
    w = np.asarray(value, np.float64)
    if w.shape != (count,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"`weights` must be ({count},) float, finite, >= 0, not all zero")
    return w / w.sum()


def _joint(labels_a: np.ndarray, labels_b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(segments of a, segments of b) float: the weight in each pair of segments, summing to 1."""
    _, ia = np.unique(labels_a, return_inverse=True)
    _, ib = np.unique(labels_b, return_inverse=True)
    joint = np.zeros((ia.max() + 1, ib.max() + 1))
    np.add.at(joint, (ia.ravel(), ib.ravel()), w)
    return joint


def rand_distance(labels_a: Any, labels_b: Any, weights: Any = None) -> float:
    """1 - Rand index of two labellings of the same faces.

    The chance that two points drawn independently (with replacement) by ``weights`` are in the
    same segment in one labelling and in different segments in the other. With ``w_ij`` the weight
    in segment ``i`` of ``a`` and ``j`` of ``b`` (summing to 1) and ``p``, ``q`` its marginals::

        1 - RI = sum_i p_i^2 + sum_j q_j^2 - 2 sum_ij w_ij^2

    With face areas as weights, the pairs are pairs of surface points; the benchmark's paper
    counts pairs of distinct faces instead, ``f / (f - 1)`` times this with equal weights.

    Parameters
    ----------
    labels_a, labels_b : (f,) int
        Segment ids, arbitrary values.
    weights : (f,) float, optional
        Each face's weight (its area); equal by default.

    Returns
    -------
    float in [0, 1)
        Symmetric; 0 exactly when the two make the same partition (of the weighted faces).
    """
    a = _labels(labels_a, "labels_a")
    b = _labels(labels_b, "labels_b", len(a))
    return _rand(_joint(a, b, _weights(weights, len(a))))


def _rand(joint: np.ndarray) -> float:
    return float((joint.sum(1) ** 2).sum() + (joint.sum(0) ** 2).sum() - 2.0 * (joint**2).sum())


def _hamming(joint: np.ndarray) -> tuple[float, float]:
    """(Rm, Rf) of a joint table (rows: labels, columns: reference): what each column, resp. row,
    holds outside its largest cell (exactly 0 for a column, row, with one cell)."""
    return float((joint.sum(0) - joint.max(0)).sum()), float((joint.sum(1) - joint.max(1)).sum())


@dataclass(frozen=True)
class HammingDistance:
    """What :func:`hamming_distance` returns, fractions of the total weight (area).

    Attributes
    ----------
    missing : float
        ``Rm``: the weight of each reference segment outside the labelled segment that holds
        most of it, summed. 0 when the labels merge reference segments but never split one.
    false_alarm : float
        ``Rf``: the same with the roles swapped. 0 when the labels split reference segments but
        never merge two.
    distance : float
        ``(missing + false_alarm) / 2``.
    """

    missing: float
    false_alarm: float
    distance: float


def hamming_distance(labels: Any, reference: Any, weights: Any = None) -> HammingDistance:
    """Hamming distance of a labelling against a reference labelling of the same faces, both ways.

    The benchmark's definition: with ``S1`` the labels and ``S2`` the reference, the directional
    distance ``D(S1 => S2) = sum_i |S2_i minus S1_k(i)|``, ``k(i)`` the segment of ``S1`` that
    overlaps ``S2_i`` most; ``Rm = D(S1 => S2) / |S|``, ``Rf = D(S2 => S1) / |S|``, with ``|.|`` the
    total weight (area). Ties in ``k(i)`` do not change the value.

    Parameters
    ----------
    labels, reference : (f,) int
        Segment ids, arbitrary values.
    weights : (f,) float, optional
        Each face's weight (its area); equal by default.

    Returns
    -------
    HammingDistance
        Swapping the two arguments swaps ``missing`` and ``false_alarm``.
    """
    a = _labels(labels, "labels")
    b = _labels(reference, "reference", len(a))
    missing, false_alarm = _hamming(_joint(a, b, _weights(weights, len(a))))
    return HammingDistance(missing, false_alarm, 0.5 * (missing + false_alarm))


class _MeshCuts:
    """What the cut discrepancy needs of one mesh, computed once: its face pairs and their shared
    edges, the vertex graph weighted by edge length, the vertices, and the average radius."""

    def __init__(self, vertices: Any, faces: Any, metric: str):
        from .geometry import face_adjacency

        if metric not in ("graph", "euclidean"):
            raise ValueError(f"`metric` must be 'graph' or 'euclidean', got {metric!r}")
        v = _points(vertices, "vertices")
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or not len(f) or not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"`faces` must be (f, 3) int with at least one face, got {f.dtype} of shape {f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"`faces` index vertices 0..{len(v) - 1}, got {f.min()}..{f.max()}")
        self.vertices, self.faces, self.metric = v, f.astype(np.int64), metric
        corners = v[self.faces]
        self.areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
        if not self.areas.sum() > 0:
            raise ValueError("the mesh has no area")
        centres = corners.mean(axis=1)
        centroid = np.average(centres, axis=0, weights=self.areas)
        self.radius = float(np.average(np.linalg.norm(centres - centroid, axis=1), weights=self.areas))
        self.pairs, self.edges = face_adjacency(self.faces)
        self.edge_lengths = np.linalg.norm(v[self.edges[:, 0]] - v[self.edges[:, 1]], axis=1)
        self._graph = None

    def graph(self):
        if self._graph is None:
            from scipy.sparse import coo_matrix

            e = np.sort(self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
            e = np.unique(e[e[:, 0] != e[:, 1]], axis=0)
            length = np.linalg.norm(self.vertices[e[:, 0]] - self.vertices[e[:, 1]], axis=1)
            # a zero stored in a sparse graph is no edge: coincident vertices stay joined
            length = np.maximum(length, 1e-12 * max(self.radius, 1e-300))
            n = len(self.vertices)
            self._graph = coo_matrix((length, (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
        return self._graph

    def cut(self, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The vertices on the cut of ``labels`` (edges between two faces of different segments)
        and each one's weight, half the length of its cut edges."""
        cut = labels[self.pairs[:, 0]] != labels[self.pairs[:, 1]]
        edges, half = self.edges[cut], 0.5 * self.edge_lengths[cut]
        weight = np.bincount(edges.ravel(), weights=np.repeat(half, 2), minlength=len(self.vertices))
        vertices = np.unique(edges)
        return vertices, weight[vertices]

    def field(self, cut_vertices: np.ndarray) -> np.ndarray:
        """(n,) float: each vertex's distance to the nearest of ``cut_vertices``."""
        from scipy.spatial import cKDTree

        if self.metric == "graph":
            from scipy.sparse.csgraph import dijkstra

            d = dijkstra(self.graph(), directed=False, indices=cut_vertices, min_only=True)
            far = ~np.isfinite(d)  # a part of the mesh no edge joins to the cut: straight lines there
            if far.any():
                d[far] = cKDTree(self.vertices[cut_vertices]).query(self.vertices[far], k=1)[0]
            return d
        return cKDTree(self.vertices[cut_vertices]).query(self.vertices, k=1)[0]


class _Segmentation:
    """One labelling of a mesh with what the measures reuse: its cut and its distance field."""

    def __init__(self, mesh: _MeshCuts, labels: np.ndarray):
        self.labels = labels
        self.segments = int(len(np.unique(labels)))
        self.cut_vertices, self.cut_weights = mesh.cut(labels)
        self.field = mesh.field(self.cut_vertices) if len(self.cut_vertices) else None


def _cut_discrepancy(mesh: _MeshCuts, a: _Segmentation, b: _Segmentation) -> float:
    if a.field is None or b.field is None:
        return 0.0 if a.field is None and b.field is None else float("nan")
    ab = np.average(b.field[a.cut_vertices], weights=a.cut_weights)
    ba = np.average(a.field[b.cut_vertices], weights=b.cut_weights)
    return float(0.5 * (ab + ba) / mesh.radius)


def cut_discrepancy(vertices: Any, faces: Any, labels_a: Any, labels_b: Any, metric: str = "graph") -> float:
    """Cut discrepancy of two labellings of a mesh's faces: how far the cuts of one lie from the
    other's, in units of the mesh's average radius.

    A labelling's *cut* is the set of edges between two faces of different segments (edges shared
    by exactly two faces). With ``DCD(a => b)`` the mean, over the cut of ``a``, of the distance
    to the nearest vertex of the cut of ``b``::

        CD = (DCD(a => b) + DCD(b => a)) / 2 / average radius

    the average radius being the mean distance of the surface to its centroid (by area).

    Approximations, against the benchmark's geodesic distances along a continuous cut: the cut
    is sampled at its vertices, each weighted by half the length of its cut edges (so the mean
    is over the length of the cut); ``metric="graph"`` measures the shortest path along the
    mesh's edges (never shorter than the geodesic, a few percent longer on a fine mesh), falling
    back to the straight line from vertices that no path joins to the other cut (another
    connected component); ``metric="euclidean"`` takes straight lines, through the air, for all.
    The average radius is taken at the face centres, weighted by area. The benchmark's program
    pools the points of both cuts into one mean instead of averaging the two directions; the two
    agree when both cuts are equally long.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (f, 3) int
    labels_a, labels_b : (f,) int
        Segment ids, arbitrary values.
    metric : str
        ``"graph"`` or ``"euclidean"``.

    Returns
    -------
    float
        Symmetric; 0 for the same partition. Undefined (NaN) when exactly one of the two has no
        cut (a single segment); 0 when neither has.
    """
    mesh = _MeshCuts(vertices, faces, metric)
    a = _labels(labels_a, "labels_a", len(mesh.faces))
    b = _labels(labels_b, "labels_b", len(mesh.faces))
    return _cut_discrepancy(mesh, _Segmentation(mesh, a), _Segmentation(mesh, b))


@dataclass(frozen=True)
class SegmentationScores:
    """Segmentations of one mesh against reference segmentations of it
    (:class:`ReferenceSegmentations`), each measure averaged over the comparisons.

    Attributes
    ----------
    rand : float
        1 - Rand index (:func:`rand_distance`, pairs of surface points).
    missing, false_alarm, hamming : float
        ``Rm``, ``Rf`` and their mean (:func:`hamming_distance`, by area; the references play the
        reference).
    cut : float
        Cut discrepancy (:func:`cut_discrepancy`), over the comparisons where it is defined (NaN
        when it is nowhere).
    cut_undefined : int
        Comparisons left out of ``cut``: one of the two had a single segment.
    segments : float
        Segments (distinct labels) of the segmentation scored; the mean over the references for
        the references among themselves.
    reference_segments : float
        Mean segments of the references compared with.
    comparisons : int
    """

    rand: float
    missing: float
    false_alarm: float
    hamming: float
    cut: float
    cut_undefined: int
    segments: float
    reference_segments: float
    comparisons: int

    def to_dict(self) -> dict:
        """A JSON-ready dict of the fields."""
        return asdict(self)


class ReferenceSegmentations:
    """A mesh with reference segmentations of its faces (human ones), to score other
    segmentations of it against all of them, and the references against each other.

    The mesh's graph, each reference's cut and distance field are computed once.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (f, 3) int
    references : sequence of (f,) int
        Segment ids per face, arbitrary values, one array per reference.
    metric : str
        The cut discrepancy's distance (:func:`cut_discrepancy`): ``"graph"`` or ``"euclidean"``.

    Examples
    --------
    >>> refs = ReferenceSegmentations(vertices, faces, humans)      # doctest: +SKIP
    >>> refs.score(face_labels).rand, refs.among_references().rand  # doctest: +SKIP
    """

    def __init__(self, vertices: Any, faces: Any, references: Sequence[Any], metric: str = "graph"):
        self._mesh = _MeshCuts(vertices, faces, metric)
        count = len(self._mesh.faces)
        refs = [_labels(r, f"references[{k}]", count) for k, r in enumerate(references)]
        if not refs:
            raise ValueError("`references` is empty")
        self._refs = [_Segmentation(self._mesh, r) for r in refs]

    @property
    def areas(self) -> np.ndarray:
        """(f,) float: the faces' areas, the measures' weights."""
        return self._mesh.areas.copy()

    @property
    def average_radius(self) -> float:
        return self._mesh.radius

    def _scores(self, pairs) -> SegmentationScores:
        w = self._mesh.areas / self._mesh.areas.sum()
        rows = []
        for s, r in pairs:
            joint = _joint(s.labels, r.labels, w)
            missing, false_alarm = _hamming(joint)
            rows.append((_rand(joint), missing, false_alarm, _cut_discrepancy(self._mesh, s, r), s.segments,
                         r.segments))
        a = np.array(rows, np.float64)
        defined = np.isfinite(a[:, 3])
        return SegmentationScores(
            rand=float(a[:, 0].mean()), missing=float(a[:, 1].mean()), false_alarm=float(a[:, 2].mean()),
            hamming=float(0.5 * (a[:, 1] + a[:, 2]).mean()),
            cut=float(a[defined, 3].mean()) if defined.any() else float("nan"),
            cut_undefined=int((~defined).sum()), segments=float(a[:, 4].mean()),
            reference_segments=float(a[:, 5].mean()), comparisons=len(rows))

    def score(self, labels: Any) -> SegmentationScores:
        """``labels`` (f,) int against every reference, each measure averaged over them."""
        s = _Segmentation(self._mesh, _labels(labels, "labels", len(self._mesh.faces)))
        return self._scores([(s, r) for r in self._refs])

    def among_references(self) -> SegmentationScores:
        """Each reference against each other one (ordered pairs, so ``missing == false_alarm``),
        averaged over the pairs: the figure a segmentation as good as a reference would get.
        ValueError with fewer than two references."""
        if len(self._refs) < 2:
            raise ValueError("the references need at least two segmentations to be compared among themselves")
        return self._scores([(s, r) for i, s in enumerate(self._refs) for j, r in enumerate(self._refs) if i != j])

"""Deformation transfer and part editing: the cuboids as a skeleton for the real mesh.

The paper's third application. A mesh is *bound* to its abstraction; moving, turning or
stretching the cuboids then moves the mesh. Two ways to move the cuboids:

* :func:`transfer_transforms` pairs a source's cuboids with a target's **by index** (one network
  explains a whole category, so slot ``k`` is the same part on both) and maps each source cuboid
  onto its target cuboid (``primkit deform``);
* :func:`edit_cuboids` scales, turns or moves named parts in their own frames and carries the
  parts resting on them along (``primkit edit``).

Binding
-------
Each vertex ``x`` is bound to the nearest present cuboid (the co-segmentation rule of
:func:`primkit.primitives.assign_points`: nearest solid, ties to the larger) and, for every part
``k``, has local coordinates scaled by the half-extents, ``u_k = R_k^T (x - t_k) / z_k``. Moving
cuboid ``k`` to ``(z'_k, R'_k, t'_k)`` sends the vertex to ``R'_k (z'_k * u_k) + t'_k``: an affine
map ``A_k x + b_k`` with ``A_k = R'_k diag(z'_k / z_k) R_k^T``, so stretching a cuboid stretches
its part. The deformed vertex is the blend ``x + sum_k w_k(x) ((A_k - I) x + b_k)`` (written as a
displacement so that identity transforms give the source back to round-off).

Why distance-based blending weights (and not a libigl solve)
------------------------------------------------------------
With hard assignment a triangle whose corners are bound to different parts is torn apart at the
seam. The weights here come from the *signed* distance ``d_k(x)`` to each present solid cuboid
(negative inside, so a vertex deep in the seat is not shared with a leg whose cuboid merely
overlaps it): with the margin ``a_k = (d_k - min_j d_j) / falloff``, ``w_k ∝ 1 - smoothstep(a_k)``.
``min_j d_j`` is continuous, so the weights and the deformation are continuous in space: vertices
of a seam (and coincident vertices of separate components) move together, and only vertices within
``falloff`` of a second part are blended, so parts away from seams move exactly with their cuboids.

Alternatives measured on the 90 ordered COSEG chair pairs (bundled chair model; scripts in the
issue's scratch): harmonic weights on the mesh (the COSEG chairs are closed single-component
meshes) with part-interior vertices as handles did worse than the distance weights: uniform
graph Laplacian, 97.8% of pairs closer but mean flipped fraction 4.6%; inverse-edge-length
Laplacian, 0.12% mean and 17% of pairs over 0.1%, or 0.47% with a 0.05 band (distance weights:
0.28% mean, 21% of pairs over 0.1%). Smoother weights alone do not remove the folds, because a
fold comes from the *translation* mismatch of two parts' maps squeezed into the blending band.
``method="harmonic"`` (``igl.harmonic``) is kept for comparison.

Unfolding (``unfold=True``, used by ``primkit deform`` and ``primkit edit``)
---------------------------------------------------------------------------
So the blend stays the distance blend, and :func:`unfold` repairs it where it folded: the
vertices within ``r`` edges of flipped triangles are re-solved so that every edge follows the
blended *linear* maps (a Poisson / gradient-domain solve, ``sum w_e |x_i - x_j - G_e (v_i -
v_j)|^2`` with the rest held), which drops the fold-making translation term and spreads the
mismatch over the region; ``r`` doubles from 1 up to 16 until nothing is flipped. Vertices away
from folds keep the blend exactly (rigid parts stay rigid; an identity edit is untouched). On
the 90 pairs: closer to the target 84/90 (93%; the blend alone 89/90), Chamfer-L1 median 0.0186
(quartiles 0.0158, 0.0399; source 0.0502), every pair under 0.1% flipped (mean 0.003%, worst
0.093%; the blend alone 21% of pairs over, mean 0.28%, worst 2.2%). Four rounds (up to 8 edges)
left 3% of pairs over 0.1%. Edge weights 1 / rest length: uniform weights ruin the coarse,
irregular COSEG meshes (74% closer, flips left). Harmonic displacement instead of the gradient
solve (it does not reproduce affine maps) flattened the deformation (82% closer). The pairs not
closer are five of chair 23 (a swivel chair whose base the model explains with a near-degenerate
cuboid) and 19->15 (already close). ``deform`` and ``edit`` default to ``unfold=False`` so that
the result is the plain blend :meth:`Binding.apply` that apps/deformation_viewer.py shows.

Thin cuboids: the network often predicts a thin part (a leg) a few thousandths thick, fitting it
loosely. A ratio of half-extents with such a denominator blows the part up, and transferring the
thickness of parts thinner than the grid resolves is noise that folds the seams, so ratios use
half-extents floored at ``min_extent`` (default 1/32 of the canonical cube: one cell of the 32^3
grid the network reads). On the 90 COSEG chair pairs the floor 1/64 left 29% of pairs with 0.1%
or more flipped triangles, 1/32 left 21% (for a Chamfer median 0.0189 instead of 0.0187).

Blending width: where two parts meet, their maps disagree by some distance; blending over less
than that folds the surface. :func:`deform` therefore widens the falloff to :data:`SEAM_GAIN`
times the seam discrepancy (:func:`seam_falloff`); on the COSEG pairs a fixed falloff of 0.03
left 72% of pairs with 0.1% or more flipped triangles (0.1: 46%), the adaptive one 21%.

Conventions: all functions work in whatever frame the vertices and cuboids share; the editing
directions (up, front, side) default to the canonical frame of :mod:`primkit` (+Y up, +X front,
side = front x up = +Z), where :class:`~primkit.abstractor.AbstractionResult`'s
``canonical`` cuboids live. Transforms are ``(m, 4, 4)`` homogeneous matrices acting on column
vectors, one per part slot (identity for absent parts).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..primitives import Cuboids, assign_points, matrix_to_quaternion, world_to_local

__all__ = [
    "Binding",
    "bind",
    "blend_weights",
    "signed_distances",
    "cuboid_map",
    "Transfer",
    "transfer_transforms",
    "Edit",
    "Lengthening",
    "edit_cuboids",
    "parse_edit",
    "apply_transforms",
    "Deformed",
    "deform",
    "edit",
    "flipped_fraction",
    "edge_distortion",
    "DEFAULT_FALLOFF",
    "MIN_EXTENT",
    "MAX_RATIO",
    "SEAM_GAIN",
    "seam_falloff",
    "unfold",
    "UNFOLD_ROUNDS",
]

#: blending distance, as a fraction of the longest side of the vertices' bounding box
DEFAULT_FALLOFF = 0.03
#: floor on half-extents in scale ratios (canonical units: one cell of the 32^3 grid)
MIN_EXTENT = 1.0 / 32.0
#: a paired part whose size changes by more than this factor along an axis is treated as unpaired
MAX_RATIO = 3.0
#: blending distance per unit of seam discrepancy (see :func:`seam_falloff`)
SEAM_GAIN = 3.0
#: rounds of :func:`unfold` (neighbourhoods of 1, 2, 4, 8, 16 edges)
UNFOLD_ROUNDS = 5

_UP = np.array([0.0, 1.0, 0.0])
_FRONT = np.array([1.0, 0.0, 0.0])


def _points(vertices) -> np.ndarray:
    v = np.asarray(vertices, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"`vertices` must be (n, 3) float, got shape {v.shape}")
    return v


# --------------------------------------------------------------------------------------------
# Binding
# --------------------------------------------------------------------------------------------


def signed_distances(points, cuboids: Cuboids, parts=None) -> np.ndarray:
    """Signed distance from each point to each solid cuboid: positive outside, negative inside
    (minus the depth to the nearest face).

    points : (n, 3) float; parts : (p,) int slots (default: the present ones) -> (n, p) float
    """
    parts = cuboids.present if parts is None else np.asarray(parts, dtype=np.int64)
    local = world_to_local(_points(points), cuboids.subset(parts))  # (p, n, 3)
    q = np.abs(local) - cuboids.half_extents[parts][:, None, :]
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return (outside + inside).T


def _falloff_weights(sd: np.ndarray, falloff: float, offsets=None) -> np.ndarray:
    if offsets is not None:
        sd = sd + offsets
    a = np.clip((sd - sd.min(axis=1, keepdims=True)) / falloff, 0.0, 1.0)
    w = 1.0 - a * a * (3.0 - 2.0 * a)  # 1 - smoothstep: 1 at the best part, 0 past `falloff`, C1
    return w / w.sum(axis=1, keepdims=True)


def blend_weights(vertices, cuboids: Cuboids, falloff: float, *, faces=None, method: str = "distance",
                  offsets=None) -> np.ndarray:
    """Blending weights of the present parts for each vertex; rows sum to 1.

    Parameters
    ----------
    vertices : (n, 3) float
    cuboids : Cuboids
    falloff : float
        Width of the blending zone, in the vertices' units.
    faces : (f, 3) int, optional
        Needed by ``method="harmonic"``.
    method : "distance" (default) or "harmonic"
        See the module notes. ``"harmonic"`` keeps the distance weights of vertices bound to one
        part only and solves Laplace's equation (``igl.harmonic``, k = 1) for the others, per
        connected component that has such vertices.
    offsets : (p,) float, optional
        Added to the signed distances of the present parts before blending. An offset of
        ``falloff`` on part ``k`` moves its seams' blending zones wholly onto ``k``'s side of
        the boundary: vertices nearer to a neighbour than to ``k`` then get no weight from ``k``
        (the weights stay continuous, since ``min_j d_j`` is). :func:`edit` uses it so that the
        parts lengthened parts hold up stay rigid.

    Returns
    -------
    (n, p) float, columns in the order of ``cuboids.present``.
    """
    v = _points(vertices)
    if not cuboids.existence.any():
        raise ValueError("no present cuboid to bind to")
    if not falloff > 0:
        raise ValueError("`falloff` must be > 0")
    off = None if offsets is None else np.asarray(offsets, float).reshape(1, -1)
    w = _falloff_weights(signed_distances(v, cuboids), float(falloff), off)
    if method == "distance":
        return w
    if method != "harmonic":
        raise ValueError(f"method must be 'distance' or 'harmonic', got {method!r}")
    if faces is None:
        raise ValueError("method='harmonic' needs `faces`")
    return _harmonic_weights(v, np.asarray(faces, dtype=np.int64), w)


def _harmonic_weights(v: np.ndarray, f: np.ndarray, w: np.ndarray) -> np.ndarray:
    import igl
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(v)
    fixed = w.max(axis=1) > 1.0 - 1e-12
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    _, comp = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    out = w.copy()
    face_comp = comp[f[:, 0]]
    for c in np.unique(comp):
        members = np.flatnonzero(comp == c)
        if fixed[members].all() or not fixed[members].any():
            continue  # nothing to solve, or no handle (keeps the distance weights)
        sub_f = f[face_comp == c]
        local = np.full(n, -1, dtype=np.int64)
        local[members] = np.arange(len(members))
        b = np.flatnonzero(fixed[members])
        try:
            sol = igl.harmonic(v[members], local[sub_f], b, w[members][b], 1)
        except Exception:  # noqa: BLE001 - a solver failure keeps the distance weights
            continue
        if np.all(np.isfinite(sol)):
            sol = np.clip(sol, 0.0, None)
            s = sol.sum(axis=1, keepdims=True)
            ok = s[:, 0] > 1e-12
            out[members[ok]] = sol[ok] / s[ok]
    return out


@dataclass(frozen=True, eq=False)
class Binding:
    """A mesh's vertices bound to its cuboids.

    Attributes
    ----------
    vertices : (n, 3) float
        The rest positions.
    cuboids : Cuboids
        The abstraction, in the vertices' frame.
    labels : (n,) int
        Part slot each vertex is bound to (co-segmentation rule).
    parts : (p,) int
        The present slots: the columns of ``weights``.
    weights : (n, p) float
        Blending weights (rows sum to 1).
    falloff : float
        Blending distance used, in the vertices' units.
    """

    vertices: np.ndarray
    cuboids: Cuboids
    labels: np.ndarray
    parts: np.ndarray
    weights: np.ndarray
    falloff: float

    def local_coordinates(self, part: int) -> np.ndarray:
        """(n, 3) float: every vertex in part ``part``'s frame divided by its half-extents."""
        c = self.cuboids.subset([part])
        return world_to_local(self.vertices, c)[0] / c.half_extents[0]

    def apply(self, transforms) -> np.ndarray:
        """Deformed vertices ``(n, 3) float`` for per-slot transforms ``(m, 4, 4) float``."""
        t = np.asarray(transforms, dtype=float)
        if t.shape != (self.cuboids.count, 4, 4):
            raise ValueError(f"`transforms` must be (m, 4, 4) float with m = {self.cuboids.count}, got {t.shape}")
        return apply_transforms(self.vertices, self.weights, t[self.parts])

    def blended(self, transforms) -> np.ndarray:
        """(n, 3, 3) float: the blended linear part of the transforms at each vertex."""
        t = np.asarray(transforms, dtype=float)[self.parts, :3, :3]
        return np.einsum("np,pij->nij", self.weights, t)


def apply_transforms(vertices, weights, transforms) -> np.ndarray:
    """``x + sum_k w_k ((A_k - I) x + b_k)`` for every vertex.

    vertices : (n, 3) float; weights : (n, p) float; transforms : (p, 4, 4) float -> (n, 3) float
    """
    v = _points(vertices)
    t = np.asarray(transforms, dtype=float)
    lin = t[:, :3, :3] - np.eye(3)
    moved = np.flatnonzero(np.any(np.abs(lin) > 0, axis=(1, 2)) | np.any(t[:, :3, 3] != 0, axis=1))
    out = v.copy()
    for k in moved:  # p is small (parts), n is large: one vectorised pass per moving part
        wk = weights[:, k]
        sel = np.flatnonzero(wk)
        out[sel] += wk[sel, None] * (v[sel] @ lin[k].T + t[k, :3, 3])
    return out


def bind(vertices, cuboids: Cuboids, *, falloff: float | None = None, faces=None, method: str = "distance",
         offsets=None) -> Binding:
    """Bind vertices to cuboids (see the module notes).

    Parameters
    ----------
    vertices : (n, 3) float
    cuboids : Cuboids
        In the same frame, at least one present.
    falloff : float, optional
        Blending distance in the vertices' units; default :data:`DEFAULT_FALLOFF` times the
        longest side of their bounding box.
    faces, method, offsets
        See :func:`blend_weights`.
    """
    v = _points(vertices)
    if falloff is None:
        falloff = DEFAULT_FALLOFF * float(np.ptp(v, axis=0).max() if len(v) else 1.0) or DEFAULT_FALLOFF
    labels = assign_points(v, cuboids) if len(v) else np.zeros(0, np.int64)
    w = blend_weights(v, cuboids, falloff, faces=faces, method=method, offsets=offsets)
    return Binding(v.copy(), cuboids, labels, cuboids.present.copy(), w, float(falloff))


# --------------------------------------------------------------------------------------------
# Maps between cuboids
# --------------------------------------------------------------------------------------------

# the 24 proper rotations that permute and flip the axes of a cuboid (its frame's relabellings)
_AXIS_TURNS = np.array(
    [
        p
        for perm in itertools.permutations(range(3))
        for signs in itertools.product((1.0, -1.0), repeat=3)
        for p in [np.eye(3)[:, perm] * np.array(signs)]
        if np.linalg.det(p) > 0
    ]
)


def cuboid_map(source: Cuboids, target: Cuboids, k: int, *, min_extent: float = MIN_EXTENT,
               match_axes: bool = True) -> np.ndarray:
    """(4, 4) float affine map taking source cuboid ``k`` onto target cuboid ``k``.

    A cuboid's frame is ambiguous up to the 24 rotations that relabel its axes (the same solid with
    permuted half-extents), and the network's frames for one part may differ by such a relabelling
    between shapes. With ``match_axes`` the target frame is relabelled to the one closest to the
    source's (largest ``trace(R_s^T R_t P)``: the smallest turn), so a part is not spun by 90
    degrees to line up arbitrary axes.
    """
    rs, rt = source.rotations[k], target.rotations[k]
    zs, zt = source.half_extents[k], target.half_extents[k]
    if match_axes:
        best = int(np.argmax(np.trace(rs.T @ rt @ _AXIS_TURNS, axis1=1, axis2=2)))
        p = _AXIS_TURNS[best]
        rt = rt @ p
        zt = np.abs(p.T @ zt)
    ratio = np.maximum(zt, min_extent) / np.maximum(zs, min_extent)
    a = rt @ np.diag(ratio) @ rs.T
    out = np.eye(4)
    out[:3, :3] = a
    out[:3, 3] = target.translations[k] - a @ source.translations[k]
    return out


def _lattice(cuboids: Cuboids, k: int, steps: int = 5) -> np.ndarray:
    """(steps^3, 3) float points on a lattice filling cuboid ``k`` (corners included)."""
    g = np.linspace(-1.0, 1.0, steps)
    u = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3) * cuboids.half_extents[k]
    return u @ cuboids.rotations[k].T + cuboids.translations[k]


def _gap(cuboids: Cuboids, j: int, k: int) -> float:
    """Approximate distance between solid cuboids ``j`` and ``k`` (lattice points of each to the other)."""
    from ..primitives import point_cuboid_distance

    a = point_cuboid_distance(_lattice(cuboids, j), cuboids.subset([k]))[:, 0].min()
    b = point_cuboid_distance(_lattice(cuboids, k), cuboids.subset([j]))[:, 0].min()
    return float(min(a, b))


@dataclass(frozen=True)
class Transfer:
    """Per-part transforms taking a source abstraction onto a target's configuration.

    Attributes
    ----------
    transforms : (m, 4, 4) float
        One affine map per slot (identity for slots absent in the source).
    paired : list of int
        Slots present in both: mapped onto the target's cuboid.
    source_only : dict of int -> int or None
        Slots present only in the source, and the paired slot whose transform each one follows
        (the nearest paired part; None when no part is paired, then it stays put).
    target_only : list of int
        Slots present only in the target: nothing of the source can take them.
    mismatched : list of int
        Slots present in both but too different in size to map (also in ``source_only``).
    """

    transforms: np.ndarray
    paired: list
    source_only: dict
    target_only: list
    mismatched: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"paired": list(map(int, self.paired)),
                "source_only": {str(k): (None if v is None else int(v)) for k, v in self.source_only.items()},
                "target_only": list(map(int, self.target_only)),
                "mismatched": list(map(int, self.mismatched))}


def transfer_transforms(source: Cuboids, target: Cuboids, *, min_extent: float = MIN_EXTENT,
                        match_axes: bool = True, max_ratio: float = MAX_RATIO) -> Transfer:
    """Pair cuboids by index and map each source cuboid onto its target (see :func:`cuboid_map`).

    A part present only in the source follows the transform of its nearest paired part (so it
    keeps its place relative to that neighbour, e.g. an arm follows the seat); so does a part
    present in both whose size changes by more than ``max_ratio`` along some axis (*mismatched*:
    the same slot explaining something else, as a swivel chair's column in a leg's slot, where
    squashing a leg into it folds the mesh). A part present only in the target is listed and
    ignored. Raises ValueError when the two sets differ in size.
    """
    if source.count != target.count:
        raise ValueError(f"source and target have {source.count} and {target.count} part slots; they must come from one model")
    m = source.count
    transforms = np.tile(np.eye(4), (m, 1, 1))
    paired, mismatched = [], []
    for k in np.flatnonzero(source.existence & target.existence):
        transforms[k] = cuboid_map(source, target, int(k), min_extent=min_extent, match_axes=match_axes)
        ratio = _extent_ratio(source, target, int(k), min_extent)
        (paired if ratio <= max_ratio else mismatched).append(int(k))
    source_only = {}
    for k in sorted(mismatched + [int(k) for k in np.flatnonzero(source.existence & ~target.existence)]):
        if not paired:
            source_only[int(k)] = None
            continue
        nearest = min(paired, key=lambda j: _gap(source, int(k), j))
        transforms[k] = transforms[nearest]
        source_only[int(k)] = int(nearest)
    target_only = [int(k) for k in np.flatnonzero(target.existence & ~source.existence)]
    return Transfer(transforms, paired, source_only, target_only, mismatched)


def _extent_ratio(source: Cuboids, target: Cuboids, k: int, min_extent: float) -> float:
    """Largest factor by which the (floored) half-extents of part ``k`` change along matched axes."""
    lin = cuboid_map(source, target, k, min_extent=min_extent)[:3, :3]
    s = np.linalg.svd(lin, compute_uv=False)
    return float(max(s.max(), 1.0 / s.min()))


def _apply_to_cuboids(cuboids: Cuboids, transforms: np.ndarray) -> Cuboids:
    """The cuboids moved by per-slot affine maps whose linear parts map the cuboid's axes to
    orthogonal directions (true for every map made here): new frame, extents and centre."""
    z, q, t = cuboids.half_extents.copy(), cuboids.quaternions.copy(), cuboids.translations.copy()
    rot = cuboids.rotations
    for k in cuboids.present:
        cols = transforms[k, :3, :3] @ rot[k]  # images of the scaled axes
        lengths = np.linalg.norm(cols, axis=0)
        r = cols / lengths
        if np.linalg.det(r) < 0:
            r[:, 0] = -r[:, 0]
        z[k] = z[k] * lengths
        q[k] = matrix_to_quaternion(r)
        t[k] = transforms[k, :3, :3] @ t[k] + transforms[k, :3, 3]
    return Cuboids(z, q, t, cuboids.existence, cuboids.probabilities)


# --------------------------------------------------------------------------------------------
# Part edits
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Edit:
    """The result of :func:`edit_cuboids`.

    Attributes
    ----------
    cuboids : Cuboids
        The edited abstraction.
    transforms : (m, 4, 4) float
        Per-slot maps from the old cuboids to the new (identity for untouched parts).
    edited : list of int
        Slots edited directly.
    carried : dict of int -> list of int
        Slots moved because they rest on moved parts, with the parts they rest on.
    lengthening : Lengthening or None
        The cut-plane stretch of the parts edited with ``lengthen`` (their mesh follows
        :meth:`Lengthening.displacement`, not their row of ``transforms``).
    """

    cuboids: Cuboids
    transforms: np.ndarray
    edited: list
    carried: dict = field(default_factory=dict)
    lengthening: "Lengthening | None" = None


@dataclass(frozen=True)
class Lengthening:
    """Parts lengthened below a cut plane (``lengthen`` of :func:`edit_cuboids`).

    What "lengthen the legs by 30%" means here: the legs' length **below the seat's underside**
    grows by 30%. Heights are measured along ``up``; the map of a lengthened part is

        h -> h + (factor - 1) (clip(h, floor, cut) - floor)

    (a stretch along ``up`` about the floor, for the points between the floor and the cut plane;
    the points above the plane rise by the full ``rise = (factor - 1) (cut - floor)``). The feet
    stay where they are, and whatever the legs hold up (the seat, the back and arms on it) is
    translated by the rise, so the chair grows by exactly ``rise``. Why not scale the leg cuboids
    about their feet: on real chairs the rear legs continue into the back posts and the model's
    rear-leg cuboids reach up to or above the seat; stretching them whole pushes into the back
    and stretches it, and the seat no longer "rests" on them (COSEG chairs: 2-33% short of the
    expected rise, back edges stretched 12-64%).

    Attributes
    ----------
    factors : dict of int -> float
        Slot -> length factor.
    floor : float
        Height where the stretch starts (the feet; stays put).
    cut : float
        Height of the cut plane (the underside of ``support``, or given).
    support : int or None
        The slot the lengthened parts hold up (it rises by the full rise; its underside gives
        ``cut`` unless that was given). None when no part rests on them; then ``cut`` defaults
        to the top of the lengthened parts.
    up : (3,) float
        Unit up direction.
    """

    factors: dict
    floor: float
    cut: float
    support: int | None
    up: np.ndarray

    def height_map(self, heights, k: int) -> np.ndarray:
        """(n,) float: heights ``(n,) float`` after part ``k``'s stretch."""
        h = np.asarray(heights, float)
        return h + (self.factors[k] - 1.0) * (np.clip(h, self.floor, self.cut) - self.floor)

    def rise(self, k: int) -> float:
        """How far part ``k`` lifts what it holds up: ``(factor - 1) (cut - floor)``."""
        return float((self.factors[k] - 1.0) * (self.cut - self.floor))

    def displacement(self, points, k: int) -> np.ndarray:
        """(n, 3) float: displacement of points ``(n, 3) float`` under part ``k``'s stretch."""
        h = _points(points) @ self.up
        return np.outer(self.height_map(h, k) - h, self.up)

    def linear(self, points, k: int) -> np.ndarray:
        """(n, 3, 3) float: the map's linear part at the points (a stretch along ``up`` strictly
        between the floor and the cut, identity elsewhere)."""
        h = _points(points) @ self.up
        inside = (h > self.floor) & (h < self.cut)
        out = np.tile(np.eye(3), (len(h), 1, 1))
        out[inside] += (self.factors[k] - 1.0) * np.outer(self.up, self.up)
        return out


def _axis_order(rot: np.ndarray, front: np.ndarray, up: np.ndarray, side: np.ndarray):
    """Local axis index and sign matched to (front, up, side): the assignment of the three local
    axes with the largest total alignment."""
    dirs = np.stack([front, up, side])  # (3 world directions, 3)
    dots = dirs @ rot  # dots[d, i] = dir_d . axis_i
    best = max(itertools.permutations(range(3)), key=lambda p: sum(abs(dots[d, p[d]]) for d in range(3)))
    axes = np.array(best)
    signs = np.sign(dots[np.arange(3), axes])
    signs[signs == 0] = 1.0
    return axes, signs


def _rotation_about(axis: np.ndarray, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


def _bottom_height(cuboids: Cuboids, k: int, up: np.ndarray) -> float:
    return float(cuboids.translations[k] @ up - np.abs(cuboids.rotations[k].T @ up) @ cuboids.half_extents[k])


def _top_height(cuboids: Cuboids, k: int, up: np.ndarray) -> float:
    return float(cuboids.translations[k] @ up + np.abs(cuboids.rotations[k].T @ up) @ cuboids.half_extents[k])


def edit_cuboids(cuboids: Cuboids, *, scale=None, rotate=None, move=None, lengthen=None, up=_UP, front=_FRONT,
                 carry: bool = True, contact: float = 0.05, floor: float | None = None,
                 cut: float | None = None) -> Edit:
    """Scale, turn and move parts in their own frames; parts resting on moved parts move along.

    Each part's local axes are matched to the shape's (front, up, side) directions (``side =
    front x up``; with the defaults +X, +Y and +Z, the canonical frame) and every edit is read in
    that matched frame, about the part's **pivot**: the centre of its bottom face (the face whose
    axis is matched to up, on the down side) — the end of a leg on the ground, the edge where a
    back meets the seat.

    Parameters
    ----------
    cuboids : Cuboids
    scale : dict of int -> float or (3,) float
        A number scales the part uniformly; three numbers scale it along its (front, up, side)
        axes (``(1, 1.3, 1)`` lengthens a leg by 30% and keeps its thickness).
    rotate : dict of int -> float
        Degrees about the part's axis matched to ``side`` (right-handed about +side: with the
        defaults a positive angle tips the top of the part backwards, toward -front).
    move : dict of int -> (3,) float
        Displacement along the part's (front, up, side) axes, in the cuboids' units.
    lengthen : dict of int -> float
        Lengthen parts (legs) **below a cut plane** by a factor: see :class:`Lengthening` for
        the rule and why (``scale`` with ``(1, 1.3, 1)`` stretches the whole cuboid instead,
        which on real chairs also stretches the back). The cut plane is ``cut`` when given,
        otherwise the underside of the part they hold up: of the other present parts that touch
        a lengthened part (gap under ``contact``) with their centre above the lowest
        lengthened part's centre, the one with the largest footprint seen from above (a chair's
        seat, a table's top; :func:`edit` then refines the height from the mesh). ``floor`` (default: the lowest bottom of the lengthened cuboids; pass the
        mesh's, as :func:`edit` does, since cuboids fitted loosely reach below the floor) is
        where the stretch starts. A part cannot be both lengthened and scaled, turned or moved.
        In ``transforms`` a lengthened part's row is the affine map of its whole cuboid onto the
        stretched one (for ``Edit.cuboids``); the mesh follows :class:`Lengthening`.
    carry : bool
        Carry resting parts along (default). Part ``j`` rests on part ``k`` when the two touch
        (gap under ``contact``) and ``j``'s centre lies above ``k``'s top (along ``up``). Parts
        are visited from the lowest centre up; a part resting on moved parts is translated by the
        mean displacement of the points of those parts nearest its centre, after its own edit.
        So legs lengthened about their feet raise the seat, and the back and arms on the seat.
        A part touching a lengthened part is carried whatever its height: translated by the
        stretch's displacement at its centre (the full rise above the cut: the seat, and a back
        touching rear legs that continue into its posts; a part of the rise for a stretcher
        between the legs).

    Returns
    -------
    Edit
    """
    up = np.asarray(up, float) / np.linalg.norm(up)
    front = np.asarray(front, float) / np.linalg.norm(front)
    side = np.cross(front, up)
    scale, rotate, move = dict(scale or {}), dict(rotate or {}), dict(move or {})
    lengthen = {int(k): float(v) for k, v in dict(lengthen or {}).items()}
    m = cuboids.count
    own = np.tile(np.eye(4), (m, 1, 1))
    edited = sorted({int(k) for k in (*scale, *rotate, *move, *lengthen)})
    for k in edited:
        if not 0 <= k < m:
            raise ValueError(f"part index {k} is out of range (0-{m - 1})")
        if not cuboids.existence[k]:
            raise ValueError(f"part {k} is not present in this abstraction")
        if k in lengthen:
            if k in scale or k in rotate or k in move:
                raise ValueError(f"part {k} is lengthened; it cannot also be scaled, turned or moved")
            if not (np.isfinite(lengthen[k]) and lengthen[k] > 0):
                raise ValueError(f"length factors must be finite and > 0, got {lengthen[k]} for part {k}")
            continue
        rot = cuboids.rotations[k]
        axes, signs = _axis_order(rot, front, up, side)
        frame = rot[:, axes] * signs  # columns: the part's front, up, side directions
        pivot = cuboids.translations[k] - frame[:, 1] * cuboids.half_extents[k][axes[1]]
        lin = np.eye(3)
        if k in scale:
            s = np.broadcast_to(np.asarray(scale[k], float), (3,))
            if np.any(s <= 0):
                raise ValueError(f"scale factors must be > 0, got {s.tolist()} for part {k}")
            lin = frame @ np.diag(s) @ frame.T
        if k in rotate:
            lin = _rotation_about(frame[:, 2], float(rotate[k])) @ lin
        offset = frame @ np.broadcast_to(np.asarray(move.get(k, 0.0), float), (3,))
        own[k, :3, :3] = lin
        own[k, :3, 3] = pivot - lin @ pivot + offset
    stretch = _lengthening(cuboids, lengthen, up, contact, floor, cut) if lengthen else None
    for k in lengthen:  # the whole cuboid's affine equivalent, for Edit.cuboids
        b, t = _bottom_height(cuboids, k, up), _top_height(cuboids, k, up)
        nb, nt = stretch.height_map([b, t], k)
        a = (nt - nb) / (t - b) if t > b else 1.0
        own[k, :3, :3] = np.eye(3) + (a - 1.0) * np.outer(up, up)
        own[k, :3, 3] = up * (nb - a * b)
    total = own.copy()
    carried: dict = {}
    if carry:
        present = [int(k) for k in cuboids.present]
        centre_h = {k: float(cuboids.translations[k] @ up) for k in present}
        order = sorted(present, key=lambda k: centre_h[k])
        for j in order:
            if j in lengthen:
                continue
            below = [k for k in order if k != j and (k in lengthen or centre_h[j] > _top_height(cuboids, k, up))
                     and not np.allclose(total[k], np.eye(4)) and _gap(cuboids, j, k) < contact]
            if not below:
                continue
            shifts = []
            for k in below:  # the point of k nearest j's centre, moved by k's total transform
                if k in lengthen:  # the full rise for the support, else the stretch at j's centre
                    shifts.append(stretch.rise(k) * up if j == stretch.support
                                  else stretch.displacement(cuboids.translations[j][None], k)[0])
                    continue
                c = cuboids.subset([k])
                local = np.clip(world_to_local(cuboids.translations[j][None], c)[0, 0], -c.half_extents[0], c.half_extents[0])
                p = c.rotations[0] @ local + c.translations[0]
                shifts.append(total[k, :3, :3] @ p + total[k, :3, 3] - p)
            total[j, :3, 3] += np.mean(shifts, axis=0)
            carried[j] = below
    return Edit(_apply_to_cuboids(cuboids, total), total, edited, carried, stretch)


def _lengthening(cuboids: Cuboids, factors: dict, up, contact: float, floor, cut) -> Lengthening:
    """The :class:`Lengthening` of ``factors`` (see :func:`edit_cuboids` for the cut plane)."""
    parts = sorted(factors)
    if floor is None:
        floor = min(_bottom_height(cuboids, k, up) for k in parts)
    lowest = min(float(cuboids.translations[k] @ up) for k in parts)
    held = [int(j) for j in cuboids.present if int(j) not in factors
            and float(cuboids.translations[j] @ up) > lowest
            and min(_gap(cuboids, int(j), k) for k in parts) < contact]
    support = max(held, key=lambda j: _footprint(cuboids, j, up)) if held else None
    if cut is None:
        cut = _bottom_height(cuboids, support, up) if held else max(_top_height(cuboids, k, up) for k in parts)
    if not cut > floor:
        raise ValueError(f"the cut plane (height {cut:.4f}) must lie above the floor (height {floor:.4f})")
    return Lengthening({k: float(factors[k]) for k in parts}, float(floor), float(cut), support, np.asarray(up, float))


def _footprint(cuboids: Cuboids, k: int, up) -> float:
    """Area of cuboid ``k``'s shadow on the plane normal to ``up`` (seen from above)."""
    r, z = cuboids.rotations[k], cuboids.half_extents[k]
    axes = r * (2.0 * z)  # columns: the full edges
    flat = axes - np.outer(up, up @ axes)
    # the shadow of a box is the zonotope of its three projected edges: area = sum of the
    # parallelograms spanned by pairs of them
    return float(sum(abs(np.cross(flat[:, a], flat[:, b]) @ up) for a, b in ((0, 1), (0, 2), (1, 2))))


def parse_edit(text: str, names, *, kind: str) -> dict:
    """``"legs=1.3"`` / ``"back=15"`` / ``"seat=0,0.05,0"`` -> {slot: value} for every slot the
    part name or index selects (:func:`primkit.parts.resolve_parts`). ``kind`` is ``"scale"``
    (1 or 3 numbers), ``"rotate"`` (1 number), ``"move"`` (3 numbers) or ``"lengthen"`` (1
    number, ``"legs=1.3"``)."""
    from ..model.parts import resolve_parts

    if "=" not in text:
        raise ValueError(f"--{kind} {text!r}: expected PART=VALUE, e.g. legs=1.3")
    spec, value = text.split("=", 1)
    try:
        numbers = [float(x) for x in value.split(",")]
    except ValueError:
        raise ValueError(f"--{kind} {text!r}: {value!r} is not a number or a comma-separated list of numbers") from None
    allowed = {"scale": (1, 3), "rotate": (1,), "move": (3,), "lengthen": (1,)}[kind]
    if len(numbers) not in allowed:
        raise ValueError(f"--{kind} {text!r}: expected {' or '.join(map(str, allowed))} number(s), got {len(numbers)}")
    if not all(np.isfinite(numbers)):
        raise ValueError(f"--{kind} {text!r}: values must be finite")
    val = numbers[0] if len(numbers) == 1 else np.array(numbers)
    return {int(k): val for k in resolve_parts(spec, names)}


# --------------------------------------------------------------------------------------------
# Quality measures
# --------------------------------------------------------------------------------------------


def _normals(v, f):
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def _flipped_mask(before, after, faces, expected_linear=None) -> np.ndarray:
    """(f,) bool: non-degenerate triangles whose normal turned against the reference (see
    :func:`flipped_fraction`)."""
    f = np.asarray(faces, dtype=np.int64)
    n0 = _normals(np.asarray(before, float), f)
    n1 = _normals(np.asarray(after, float), f)
    area0 = np.linalg.norm(n0, axis=1)
    ok = area0 > 1e-12 * max(float(area0.max()) if len(f) else 0.0, 1e-300)
    ref = n0
    if expected_linear is not None:
        a = np.asarray(expected_linear, float)[f].mean(axis=1)  # (f, 3, 3)
        cof = np.linalg.det(a)[:, None, None] * np.linalg.inv(a).transpose(0, 2, 1)
        ref = np.einsum("fij,fj->fi", cof, n0)
    return (np.einsum("fi,fi->f", n1, ref) < 0) & ok


def flipped_fraction(before, after, faces, expected_linear=None) -> float:
    """Fraction of (non-degenerate) triangles whose normal turned against a reference.

    before, after : (n, 3) float; faces : (f, 3) int
    expected_linear : (n, 3, 3) float, optional
        The blended linear map at each vertex (:meth:`Binding.blended`). Without it the reference
        is the normal before (the plain before/after test); with it, the normal carried by the
        parts' own transforms (cofactor of the map averaged over the face's corners), so a part
        that is meant to turn does not count as flipped.
    """
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return 0.0
    n0 = np.linalg.norm(_normals(np.asarray(before, float), f), axis=1)
    ok = n0 > 1e-12 * max(float(n0.max()), 1e-300)
    return float(_flipped_mask(before, after, f, expected_linear)[ok].mean()) if ok.any() else 0.0


def _edges(faces: np.ndarray) -> np.ndarray:
    """(e, 2) int: the unique undirected edges of the faces, smaller index first."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def _gradient_solve(rest, current, edges, linear, fixed) -> np.ndarray:
    """Positions minimising ``sum_e w_e |x_i - x_j - G_e (v_i - v_j)|^2`` with ``x`` held at
    ``current`` where ``fixed``: ``G_e`` is the mean of the blended linear maps at the edge's
    ends and ``w_e = 1 / |v_i - v_j|`` (inverse rest length)."""
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import splu

    n = len(rest)
    i, j = edges[:, 0], edges[:, 1]
    w = 1.0 / np.maximum(np.linalg.norm(rest[i] - rest[j], axis=1), 1e-12)
    g = 0.5 * (linear[i] + linear[j])
    d = np.einsum("eab,eb->ea", g, rest[i] - rest[j]) * w[:, None]
    adj = coo_matrix((np.r_[w, w], (np.r_[i, j], np.r_[j, i])), shape=(n, n)).tocsr()
    lap = (diags(np.asarray(adj.sum(axis=1)).ravel()) - adj).tocsr()
    rhs = np.zeros((n, 3))
    np.add.at(rhs, i, d)
    np.add.at(rhs, j, -d)
    free, held = np.flatnonzero(~fixed), np.flatnonzero(fixed)
    out = current.copy()
    sub = lap[free]
    out[free] = splu(sub[:, free].tocsc()).solve(rhs[free] - sub[:, held] @ current[held])
    return out


def unfold(rest, deformed, faces, linear, *, rounds: int = UNFOLD_ROUNDS) -> tuple[np.ndarray, np.ndarray]:
    """Re-solve the neighbourhoods of flipped triangles so that they follow the parts' blended
    linear maps (see the module notes).

    Flipped triangles (against the normal before, or against the normal carried by ``linear``:
    both tests of :func:`flipped_fraction`) and the vertices within ``r`` edges of them are re-solved with everything else held
    (:func:`_gradient_solve`); ``r`` goes 1, 2, 4, ... for at most ``rounds`` rounds, until no
    triangle is flipped. A connected component that would be re-solved whole has nothing to hold
    it in place; the loop stops there.

    rest, deformed : (n, 3) float; faces : (f, 3) int; linear : (n, 3, 3) float

    Returns
    -------
    vertices : (n, 3) float
    resolved : (n,) bool, the vertices that were re-solved (none when nothing was flipped)
    """
    from scipy.sparse import coo_matrix

    v = _points(rest)
    x = _points(deformed).copy()
    f = np.asarray(faces, dtype=np.int64)
    lin = np.asarray(linear, float)
    resolved = np.zeros(len(v), bool)
    if len(f) == 0:
        return x, resolved
    e = _edges(f)
    adj = coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(len(v),) * 2).tocsr()
    for r in range(rounds):
        bad = _flipped_mask(v, x, f) | _flipped_mask(v, x, f, lin)
        if not bad.any():
            break
        region = np.zeros(len(v), bool)
        region[f[bad].ravel()] = True
        for _ in range(2 ** r):
            region |= (adj @ region.astype(float)) > 0
        if region.all():
            break
        x = _gradient_solve(v, x, e, lin, ~region)
        resolved |= region
    return x, resolved


def edge_distortion(before, after, faces, labels, linear=None) -> dict:
    """Relative edge-length change inside parts: ``| |e'| / |A e| - 1 |`` for edges whose two
    ends are bound to the same part, with ``A`` that part's linear map (identity without
    ``linear``: plain stretch). 0 means the part moved exactly as its cuboid.

    before, after : (n, 3) float; faces : (f, 3) int; labels : (n,) int; linear : (m, 3, 3) float

    Returns {part slot: {"edges", "median", "p99", "max"}} and "all" over every such edge.
    """
    f = np.asarray(faces, dtype=np.int64)
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    labels = np.asarray(labels)
    same = labels[e[:, 0]] == labels[e[:, 1]]
    e = e[same]
    lab = labels[e[:, 0]]
    d0 = np.asarray(before, float)[e[:, 1]] - np.asarray(before, float)[e[:, 0]]
    d1 = np.asarray(after, float)[e[:, 1]] - np.asarray(after, float)[e[:, 0]]
    if linear is not None:
        d0 = np.einsum("eij,ej->ei", np.asarray(linear, float)[lab], d0)
    l0 = np.linalg.norm(d0, axis=1)
    keep = l0 > 1e-12
    rel = np.abs(np.linalg.norm(d1, axis=1)[keep] / l0[keep] - 1.0)
    lab = lab[keep]

    def stats(x):
        if len(x) == 0:
            return {"edges": 0, "median": 0.0, "p99": 0.0, "max": 0.0}
        return {"edges": int(len(x)), "median": float(np.median(x)), "p99": float(np.percentile(x, 99)), "max": float(x.max())}

    out = {int(k): stats(rel[lab == k]) for k in np.unique(lab)}
    out["all"] = stats(rel)
    return out


# --------------------------------------------------------------------------------------------
# One call: bind, move, measure
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Deformed:
    """A deformed mesh and how it came about.

    Attributes
    ----------
    vertices : (n, 3) float
        The deformed vertices (same order as the input; faces unchanged).
    binding : Binding
    transforms : (m, 4, 4) float
        The per-part maps that were applied.
    transfer : Transfer or None
        Set by :func:`deform`.
    edit : Edit or None
        Set by :func:`edit`.
    resolved : (n,) bool or None
        Vertices :func:`unfold` re-solved (None when it did not run: no faces, or ``unfold=False``).
    linear : (n, 3, 3) float or None
        The blended linear map at each vertex when it is not ``binding.blended(transforms)``
        (parts lengthened below a cut plane: their map is piecewise).
    """

    vertices: np.ndarray
    binding: Binding
    transforms: np.ndarray
    transfer: Transfer | None = None
    edit: Edit | None = None
    resolved: np.ndarray | None = None
    linear: np.ndarray | None = None

    def quality(self, faces, *, target_points=None, source_points=None, samples: int = 10000, seed: int = 0) -> dict:
        """Quality measures of the deformation.

        * ``flipped``: fraction of triangles whose normal turned against its normal before
          (plain test); ``flipped_vs_parts``: against the normal carried by the parts'
          own transforms (see :func:`flipped_fraction`).
        * ``distortion``: :func:`edge_distortion` relative to each part's own map (how far
          blending bent the parts); ``stretch``: plain edge-length change inside parts.
        * with ``target_points`` ((k, 3) float, in the vertices' frame): ``chamfer_result_target``
          (Chamfer-L1 of :func:`primkit.metrics.chamfer_distance` between ``samples`` area-uniform
          points of the result and the target points), and with ``source_points`` also
          ``chamfer_source_target``.
        """
        from ..geometry import sample_surface
        from ..metrics import chamfer_distance

        f = np.asarray(faces, dtype=np.int64)
        b = self.binding
        lin = self.transforms[:, :3, :3]
        out = {
            "flipped": flipped_fraction(b.vertices, self.vertices, f),
            "flipped_vs_parts": flipped_fraction(b.vertices, self.vertices, f,
                                                 b.blended(self.transforms) if self.linear is None else self.linear),
            "distortion": edge_distortion(b.vertices, self.vertices, f, b.labels, lin),
            "stretch": edge_distortion(b.vertices, self.vertices, f, b.labels),
        }
        if target_points is not None:
            pts = sample_surface(self.vertices, f, samples, seed=seed).points
            out["chamfer_result_target"] = chamfer_distance(pts, target_points)
            if source_points is not None:
                out["chamfer_source_target"] = chamfer_distance(source_points, target_points)
        return out


def _finish(binding: Binding, transforms, faces, do_unfold: bool, stretch: Lengthening | None = None,
            **extra) -> Deformed:
    if stretch is None:
        out, linear, own = binding.apply(transforms), binding.blended(transforms), None
    else:  # lengthened parts follow their piecewise stretch instead of their affine row
        affine = np.array(transforms, dtype=float)
        affine[list(stretch.factors)] = np.eye(4)
        out, linear = binding.apply(affine), binding.blended(affine)
        cols = {int(k): i for i, k in enumerate(binding.parts)}
        for k in stretch.factors:
            w = binding.weights[:, cols[k]]
            sel = np.flatnonzero(w)
            out[sel] += w[sel, None] * stretch.displacement(binding.vertices[sel], k)
            linear[sel] += w[sel, None, None] * (stretch.linear(binding.vertices[sel], k) - np.eye(3))
        own = linear
    resolved = None
    if faces is not None and do_unfold:
        out, resolved = unfold(binding.vertices, out, faces, linear)
    return Deformed(out, binding, transforms, resolved=resolved, linear=own, **extra)


def deform(vertices, source: Cuboids, target: Cuboids, *, falloff: float | None = None, faces=None,
           method: str = "distance", min_extent: float = MIN_EXTENT, unfold: bool = False) -> Deformed:
    """Move a mesh bound to ``source`` so its parts take the configuration of ``target``.

    vertices : (n, 3) float, in the frame of both cuboid sets (use the canonical frames of two
    :class:`~primkit.abstractor.AbstractionResult`: the shapes are then normalised alike). See
    :func:`bind` and :func:`transfer_transforms`. With ``faces`` (and ``unfold``, the default),
    flipped triangles are re-solved by :func:`unfold`; without faces the result is the plain
    blend :meth:`Binding.apply`.
    """
    transfer = transfer_transforms(source, target, min_extent=min_extent)
    if falloff is None:
        falloff = seam_falloff(vertices, source, transfer.transforms)
    binding = bind(vertices, source, falloff=falloff, faces=faces, method=method)
    return _finish(binding, transfer.transforms, faces, unfold, transfer=transfer)


def seam_falloff(vertices, cuboids: Cuboids, transforms, *, base: float | None = None, gain: float | None = None,
                 quantile: float = 95.0, limit: float = 0.25) -> float:
    """A blending distance wide enough for the given transforms.

    Where two parts meet, their maps send a seam vertex to points ``delta`` apart; blending them
    over a distance ``w`` adds a shear of about ``delta / w`` to the deformation gradient, which
    folds triangles (flips them) once it passes 1. So the falloff is ``gain`` (default :data:`SEAM_GAIN`) times the
    ``quantile`` of ``delta`` over the seam vertices (those within ``base`` of two parts), at least
    ``base`` (default :data:`DEFAULT_FALLOFF` of the bounding box) and at most ``limit`` of it.
    """
    v = _points(vertices)
    gain = SEAM_GAIN if gain is None else float(gain)
    size = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    base = DEFAULT_FALLOFF * size if base is None else float(base)
    parts = cuboids.present
    if len(parts) < 2 or len(v) == 0:
        return base
    sd = signed_distances(v, cuboids)
    order = np.argsort(sd, axis=1)[:, :2]
    first, second = order[:, 0], order[:, 1]
    rows = np.arange(len(v))
    seam = sd[rows, second] - sd[rows, first] < base
    if not seam.any():
        return base
    t = np.asarray(transforms, float)[parts]
    x = v[seam]
    d1 = np.einsum("nij,nj->ni", t[first[seam], :3, :3], x) + t[first[seam], :3, 3]
    d2 = np.einsum("nij,nj->ni", t[second[seam], :3, :3], x) + t[second[seam], :3, 3]
    delta = np.percentile(np.linalg.norm(d1 - d2, axis=1), quantile)
    return float(np.clip(gain * delta, base, limit * size))


def edit(vertices, cuboids: Cuboids, *, scale=None, rotate=None, move=None, lengthen=None,
         falloff: float | None = None, faces=None, method: str = "distance", unfold: bool = False,
         **kwargs) -> Deformed:
    """Edit parts of a mesh bound to ``cuboids`` (see :func:`edit_cuboids` for the edits and
    their frames; ``kwargs`` go there). An empty edit gives the vertices back to round-off. The
    default falloff is :func:`seam_falloff` of the edit's transforms; ``faces`` and ``unfold``
    as in :func:`deform`.

    ``lengthen={slot: factor}`` lengthens parts below a cut plane (:class:`Lengthening`): the
    vertices bound to a lengthened part follow its piecewise stretch (blended with the
    neighbours' maps at seams like any part), the floor defaults to the lowest vertex bound to a
    lengthened part, and the chair's height grows by ``(factor - 1) (cut - floor)``: "legs=1.3"
    makes the legs' length below the seat 30% longer and lifts everything above by that much.
    """
    v = _points(vertices)
    e = edit_cuboids(cuboids, scale=scale, rotate=rotate, move=move, lengthen=lengthen, **kwargs)
    if e.lengthening is not None and len(v):
        e = _lengthen_on_mesh(v, faces, cuboids, e, scale=scale, rotate=rotate, move=move, lengthen=lengthen, **kwargs)
    if falloff is None:
        falloff = seam_falloff(v, cuboids, _seam_transforms(v, cuboids, e))
    offsets = None
    if e.lengthening is not None:  # seams blend on the legs' side: what they hold up stays rigid
        offsets = np.where(np.isin(cuboids.present, list(e.lengthening.factors)), falloff, 0.0)
    binding = bind(v, cuboids, falloff=falloff, faces=faces, method=method, offsets=offsets)
    return _finish(binding, e.transforms, faces, unfold, e.lengthening, edit=e)


def _lengthen_on_mesh(v, faces, cuboids: Cuboids, e: Edit, **edits) -> Edit:
    """Redo a lengthening edit with the floor and cut plane measured on the mesh: the floor at
    the lowest vertex bound to a lengthened part, the cut at the support's underside, the
    area-weighted median height of the support's downward-facing triangles (normal within 45
    degrees of down). The network's cuboids are loose: on the 10 COSEG chairs the seat cuboid's
    bottom is 0.01-0.1 (canonical units) off the ground-truth seat underside, the mesh's 0-0.03."""
    L = e.lengthening
    up = L.up
    labels = assign_points(v, cuboids)
    kwargs = {k: val for k, val in edits.items() if k not in ("floor", "cut")}
    floor, cut = edits.get("floor"), edits.get("cut")
    mine = np.isin(labels, list(L.factors))
    if floor is None and mine.any():
        floor = float((v[mine] @ up).min())
    if cut is None and faces is not None and L.support is not None:
        f = np.asarray(faces, dtype=np.int64)
        n = _normals(v, f)
        area = np.linalg.norm(n, axis=1)
        down = (n @ up) < -np.sqrt(0.5) * area
        sel = down & (labels[f] == L.support).all(axis=1) & (area > 0)
        if sel.any():
            h = v[f[sel]].mean(axis=1) @ up
            o = np.argsort(h)
            cum = np.cumsum(area[sel][o])
            cut = float(h[o][np.searchsorted(cum, 0.5 * cum[-1])])
    if floor is None and cut is None:
        return e
    if cut is None:
        cut = L.cut
    if not cut > (floor if floor is not None else L.floor):
        return e  # the mesh disagrees with the cuboids; keep the cuboids' planes
    return edit_cuboids(cuboids, floor=floor, cut=cut, **kwargs)


def _seam_transforms(vertices, cuboids: Cuboids, e: Edit) -> np.ndarray:
    """The edit's transforms with each lengthened part's row replaced by the translation by its
    rise (its map above the cut, where it meets what it holds up), for :func:`seam_falloff`."""
    t = e.transforms
    if e.lengthening is None:
        return t
    t = t.copy()
    for k in e.lengthening.factors:
        t[k] = np.eye(4)
        t[k, :3, 3] = e.lengthening.rise(k) * e.lengthening.up
    return t

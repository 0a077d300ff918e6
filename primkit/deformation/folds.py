"""Quality measures of a deformation (flipped triangles, edge distortion inside parts) and the
local repair of folds, :func:`unfold` (see :mod:`primkit.deformation`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .binding import as_vertices

__all__ = ["UNFOLD_ROUNDS", "face_normals", "flipped_fraction", "EdgeStats", "edge_distortion", "unfold"]


@dataclass(frozen=True)
class EdgeStats:
    """Relative edge-length changes of a set of edges (:func:`edge_distortion`): how many, their
    median, 99th percentile and maximum (all 0 for no edge)."""

    edges: int
    median: float
    p99: float
    max: float

    def to_dict(self) -> dict:
        """JSON-ready: ``{"edges", "median", "p99", "max"}``."""
        return asdict(self)


#: rounds of :func:`unfold` (neighbourhoods of 1, 2, 4, 8, 16 edges)
UNFOLD_ROUNDS = 5


def face_normals(v, f):
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def _flipped_mask(before, after, faces, expected_linear=None) -> np.ndarray:
    """(f,) bool: non-degenerate triangles whose normal turned against the reference (see
    :func:`flipped_fraction`)."""
    f = np.asarray(faces, dtype=np.int64)
    n0 = face_normals(np.asarray(before, float), f)
    n1 = face_normals(np.asarray(after, float), f)
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
    n0 = np.linalg.norm(face_normals(np.asarray(before, float), f), axis=1)
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

    v = as_vertices(rest)
    x = as_vertices(deformed).copy()
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


def edge_distortion(before, after, faces, labels, linear=None) -> dict[int | str, EdgeStats]:
    """Relative edge-length change inside parts: ``| |e'| / |A e| - 1 |`` for edges whose two
    ends are bound to the same part, with ``A`` that part's linear map (identity without
    ``linear``: plain stretch). 0 means the part moved exactly as its cuboid.

    before, after : (n, 3) float; faces : (f, 3) int; labels : (n,) int; linear : (m, 3, 3) float

    Returns {part slot: :class:`EdgeStats`} and ``"all"``: the stats over every such edge.
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
            return EdgeStats(0, 0.0, 0.0, 0.0)
        return EdgeStats(int(len(x)), float(np.median(x)), float(np.percentile(x, 99)), float(x.max()))

    out = {int(k): stats(rel[lab == k]) for k in np.unique(lab)}
    out["all"] = stats(rel)
    return out

"""Binding: each vertex bound to its cuboid in local coordinates, with the distance-based blending
weights near seams (see :mod:`primkit.deformation` for the rule and why)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..primitives import Cuboids, assign_points, world_to_local

__all__ = ["DEFAULT_FALLOFF", "as_vertices", "signed_distances", "blend_weights", "Binding", "apply_transforms", "bind"]


#: blending distance, as a fraction of the longest side of the vertices' bounding box
DEFAULT_FALLOFF = 0.03


def as_vertices(vertices) -> np.ndarray:
    v = np.asarray(vertices, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"`vertices` must be (n, 3) float, got shape {v.shape}")
    return v


def signed_distances(points, cuboids: Cuboids, parts=None) -> np.ndarray:
    """Signed distance from each point to each solid cuboid: positive outside, negative inside
    (minus the depth to the nearest face).

    points : (n, 3) float; parts : (p,) int slots (default: the present ones) -> (n, p) float
    """
    parts = cuboids.present if parts is None else np.asarray(parts, dtype=np.int64)
    local = world_to_local(as_vertices(points), cuboids.subset(parts))  # (p, n, 3)
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
    v = as_vertices(vertices)
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
    v = as_vertices(vertices)
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
    v = as_vertices(vertices)
    if falloff is None:
        falloff = DEFAULT_FALLOFF * float(np.ptp(v, axis=0).max() if len(v) else 1.0) or DEFAULT_FALLOFF
    labels = assign_points(v, cuboids) if len(v) else np.zeros(0, np.int64)
    w = blend_weights(v, cuboids, falloff, faces=faces, method=method, offsets=offsets)
    return Binding(v.copy(), cuboids, labels, cuboids.present.copy(), w, float(falloff))

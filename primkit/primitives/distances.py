"""Points against cuboids: local frames, distances to the solid cuboids and to their union,
containment, and the co-segmentation rule (:func:`assign_points`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .cuboids import Cuboids, as_points, check_cuboids

__all__ = ["world_to_local", "local_to_world", "point_cuboid_distance", "union_distance", "contains", "assign_points",
           "Assignment", "assign_points_with_distance"]

#: points processed at once against all cuboids (bounds the (m, n, 3) temporaries)
CHUNK = 65536


def world_to_local(points: Any, cuboids: Cuboids) -> np.ndarray:
    """Points in every cuboid's local frame: ``R.T @ (x - t)``.

    points : (n, 3) float  ->  (m, n, 3) float
    """
    points = as_points(points)
    c = check_cuboids(cuboids)
    d = points[None, :, :] - c.translations[:, None, :]
    return np.einsum("mji,mnj->mni", c.rotations, d)


def local_to_world(points_local: Any, cuboids: Cuboids) -> np.ndarray:
    """Inverse of :func:`world_to_local`: ``R @ x + t``.

    points_local : (m, n, 3) float  ->  (m, n, 3) float
    """
    c = check_cuboids(cuboids)
    pl = np.asarray(points_local, dtype=float)
    if pl.ndim != 3 or pl.shape[0] != c.count or pl.shape[2] != 3:
        raise ValueError(f"`points_local` must be (m, n, 3) float with m = {c.count}, got {pl.shape}")
    return np.einsum("mij,mnj->mni", c.rotations, pl) + c.translations[:, None, :]


def point_cuboid_distance(points: Any, cuboids: Cuboids, squared: bool = False) -> np.ndarray:
    """Distance from each point to each solid cuboid, absent parts included (the caller masks).

    points : (n, 3) float  ->  (n, m) float, zero inside.
    """
    local = world_to_local(points, cuboids)
    excess = np.maximum(np.abs(local) - cuboids.half_extents[:, None, :], 0.0)
    d2 = np.einsum("mni,mni->nm", excess, excess)
    return d2 if squared else np.sqrt(d2)


def union_distance(points: Any, cuboids: Cuboids, squared: bool = False) -> np.ndarray:
    """Distance from each point to the union of the present cuboids.

    points : (n, 3) float  ->  (n,) float; ``inf`` when no part is present.
    """
    points = as_points(points)
    c = check_cuboids(cuboids)
    if not c.existence.any():
        return np.full(len(points), np.inf)
    return point_cuboid_distance(points, c.subset(c.present), squared=squared).min(axis=1)


def contains(points: Any, cuboids: Cuboids, *, tol: float = 0.0) -> np.ndarray:
    """Whether each point lies in each solid cuboid (boundary included, grown by ``tol``), absent
    parts included.

    points : (n, 3) float  ->  (n, m) bool; with ``tol = 0`` equal to ``point_cuboid_distance(...) == 0``.
    Points are taken :data:`CHUNK` at a time, so the ``(m, chunk, 3)`` local coordinates stay small.
    """
    points = as_points(points)
    c = check_cuboids(cuboids)
    out = np.empty((len(points), c.count), dtype=bool)
    rot = c.rotations
    for start in range(0, len(points), CHUNK):
        d = points[None, start : start + CHUNK, :] - c.translations[:, None, :]
        local = np.einsum("mji,mnj->mni", rot, d)
        out[start : start + CHUNK] = np.all(np.abs(local) <= c.half_extents[:, None, :] + tol, axis=-1).T
    return out


@dataclass(frozen=True, eq=False)
class Assignment:
    """What :func:`assign_points_with_distance` returns.

    Attributes
    ----------
    labels : (n,) int
        The slot of each point's nearest present cuboid (:func:`assign_points`).
    distance : (n,) float
        The distance from each point to that cuboid (0 inside).
    """

    labels: np.ndarray
    distance: np.ndarray


def assign_points(points: Any, cuboids: Cuboids, *, chunk: int = 8192) -> np.ndarray:
    """Index (slot) of the nearest present cuboid for each point: the co-segmentation rule.

    Ties (several cuboids at the same distance, e.g. 0 for a point inside several) go to the
    larger volume, then to the lower index.

    points : (n, 3) float  ->  (n,) int. Raises ValueError when no part is present.
    :func:`assign_points_with_distance` gives the distances too.

    Speed: the points are taken in chunks of ``chunk``; for each chunk the local coordinates in
    all present cuboids come from one ``(c, 3) @ (3, 3k)`` product, and the excess over the
    half-extents, its squared norm and the arg-min are whole-array operations, so memory stays
    ``O(chunk * k)`` and a million points against 20 cuboids take a fraction of a second
    (``benchmarks/bench_segment.py``). Neither Open3D nor libigl offers point-to-oriented-box
    distances for many boxes at once; this is the closed form of the paper's distance.
    """
    return _assign(points, cuboids, chunk, with_distance=False)[0]


def assign_points_with_distance(points: Any, cuboids: Cuboids, *, chunk: int = 8192) -> Assignment:
    """:func:`assign_points` and the distance from each point to its cuboid, in one pass."""
    return Assignment(*_assign(points, cuboids, chunk, with_distance=True))


def _assign(points, cuboids, chunk: int, *, with_distance: bool) -> tuple[np.ndarray, np.ndarray | None]:
    points = as_points(points)
    c = check_cuboids(cuboids)
    if not c.existence.any():
        raise ValueError("no present cuboid to assign points to")
    present = c.present
    order = present[np.argsort(-c.volumes[present], kind="stable")]
    k = len(order)
    rot = c.rotations[order]  # (k, 3, 3) local -> world; local = R.T (x - t)
    # column j * k + i holds local axis j of cuboid i, so the three axes are contiguous blocks
    stacked = rot.transpose(1, 2, 0).reshape(3, 3 * k)
    offset = np.einsum("kij,ki->jk", rot, c.translations[order]).reshape(3 * k)
    extents = c.half_extents[order].T.reshape(3 * k)
    labels = np.empty(len(points), dtype=np.int64)
    dist = np.empty(len(points)) if with_distance else None
    for start in range(0, len(points), chunk):
        block = points[start : start + chunk]
        excess = block @ stacked
        excess -= offset
        np.abs(excess, out=excess)
        excess -= extents
        np.maximum(excess, 0.0, out=excess)
        excess *= excess
        d2 = excess[:, :k] + excess[:, k : 2 * k]
        d2 += excess[:, 2 * k :]
        best = np.argmin(d2, axis=1)
        labels[start : start + len(block)] = order[best]
        if dist is not None:
            dist[start : start + len(block)] = np.sqrt(np.take_along_axis(d2, best[:, None], 1)[:, 0])
    return labels, dist

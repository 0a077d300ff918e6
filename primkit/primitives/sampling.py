"""Samples of cuboids: reparametrised surface samples with importance weights (the layout is
described in :mod:`primkit.primitives`), volume samples, the published pruning of parts covered by
the others, and area-uniform samples of the surface of the union."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .cuboids import Cuboids, check_cuboids
from .distances import CHUNK, contains, local_to_world

__all__ = ["CuboidSurfaceSamples", "surface_layout", "face_area_pairs", "sample_cuboid_surfaces", "sample_volume",
           "fraction_inside_others", "prune_covered", "union_surface_samples"]

#: a sample within this distance of another cuboid's boundary counts as on it (canonical units)
_ON_BOUNDARY = 1e-11
#: step along a sample's outward normal used to test whether the union continues beyond it
_NUDGE = 1e-8


@dataclass(frozen=True, eq=False)
class CuboidSurfaceSamples:
    """Points on the surfaces of cuboids, with importance weights (see the module notes).

    Attributes
    ----------
    points : (m, k, 3) float
        World coordinates.
    weights : (m, k) float
        ``area(face) / (k / 6)``; they sum to each cuboid's surface area.
    face : (m, k) int
        Face of each sample, 0..5 (+x, -x, +y, -y, +z, -z).
    """

    points: np.ndarray
    weights: np.ndarray
    face: np.ndarray


def surface_layout(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed per-sample layout for ``k`` surface samples per cuboid.

    Returns face (k,) int, fixed (k, 3) float (the face's ±1 at its axis, 0 elsewhere) and
    spread (k, 2, 3) float (one-hot rows placing the two free coordinates ``u`` on the face).
    """
    if k <= 0 or k % 6:
        raise ValueError(f"`samples_per_cuboid` must be a positive multiple of 6, got {k}")
    face = np.repeat(np.arange(6), k // 6)
    axis = face // 2
    sign = np.where(face % 2 == 0, 1.0, -1.0)
    fixed = np.zeros((k, 3))
    fixed[np.arange(k), axis] = sign
    free = np.stack([(axis + 1) % 3, (axis + 2) % 3], axis=-1)  # (k, 2)
    spread = np.zeros((k, 2, 3))
    spread[np.arange(k)[:, None], np.arange(2)[None, :], free] = 1.0
    return face, fixed, spread


def face_area_pairs() -> np.ndarray:
    """(3,) int pairs: face on axis a has area 4 z_b z_c with (b, c) = the other axes."""
    return np.array([[1, 2], [2, 0], [0, 1]])


def _surface_from_uv(cuboids: Cuboids, uv: np.ndarray) -> CuboidSurfaceSamples:
    """Surface samples from given coefficients ``uv`` (m, k, 2) in [-1, 1]."""
    m, k = uv.shape[:2]
    face, fixed, spread = surface_layout(k)
    z = cuboids.half_extents
    unit = fixed[None] + np.einsum("mkc,kcd->mkd", uv, spread)  # (m, k, 3)
    local = unit * z[:, None, :]
    points = local_to_world(local, cuboids) if m else np.zeros((0, k, 3))
    pairs = face_area_pairs()
    areas = 4.0 * z[:, pairs[:, 0]] * z[:, pairs[:, 1]]  # (m, 3)
    weights = areas[:, face // 2] / (k // 6)
    return CuboidSurfaceSamples(points, weights, np.broadcast_to(face, (m, k)).copy())


def sample_cuboid_surfaces(cuboids: Cuboids, samples_per_cuboid: int = 150, seed: Any = None) -> CuboidSurfaceSamples:
    """Reparametrised surface samples of every cuboid (absent ones included; the caller masks).

    Parameters
    ----------
    cuboids : Cuboids
    samples_per_cuboid : int
        ``k``, a positive multiple of 6: ``k / 6`` samples on each face.
    seed : None, int or numpy Generator

    Returns
    -------
    CuboidSurfaceSamples
        ``points`` (m, k, 3), ``weights`` (m, k) summing to each surface area, ``face`` (m, k).
    """
    c = check_cuboids(cuboids)
    k = int(samples_per_cuboid)
    surface_layout(k)  # validates k
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-1.0, 1.0, size=(c.count, k, 2))
    return _surface_from_uv(c, uv)


def sample_volume(cuboids: Cuboids, samples_per_cuboid: int = 1000, seed: Any = None) -> np.ndarray:
    """Uniform samples inside every solid cuboid (absent ones included).

    Returns (m, k, 3) float world coordinates.
    """
    c = check_cuboids(cuboids)
    k = int(samples_per_cuboid)
    if k <= 0:
        raise ValueError(f"`samples_per_cuboid` must be positive, got {k}")
    rng = np.random.default_rng(seed)
    local = rng.uniform(-1.0, 1.0, size=(c.count, k, 3)) * c.half_extents[:, None, :]
    return local_to_world(local, c)


def _containment(cuboids: Cuboids, k: int, seed: Any) -> np.ndarray:
    """(m, k, m) bool: volume sample s of part i lies inside part j (computed among present parts
    only; entries involving an absent part are False)."""
    pts = sample_volume(cuboids, k, seed)
    m = cuboids.count
    out = np.zeros((m, k, m), dtype=bool)
    idx = cuboids.present
    if len(idx):
        sub = cuboids.subset(idx)
        out[np.ix_(idx, np.arange(k), idx)] = contains(pts[idx].reshape(-1, 3), sub).reshape(len(idx), k, len(idx))
    return out


def _fractions(inside: np.ndarray, existence: np.ndarray) -> np.ndarray:
    m = len(existence)
    others = existence[None, :] & ~np.eye(m, dtype=bool)  # (m, m): the present parts other than i
    frac = np.any(inside & others[:, None, :], axis=-1).mean(axis=-1) if inside.shape[1] else np.zeros(m)
    return np.where(existence, frac, np.nan)


def fraction_inside_others(cuboids: Cuboids, samples_per_cuboid: int = 1000, seed: Any = None) -> np.ndarray:
    """Monte Carlo fraction of each present part's volume inside the union of the other present parts.

    Returns (m,) float in [0, 1]; ``nan`` for absent parts.
    """
    c = check_cuboids(cuboids)
    return _fractions(_containment(c, int(samples_per_cuboid), seed), c.existence)


def prune_covered(
    cuboids: Cuboids, threshold: float = 0.6, samples_per_cuboid: int = 1000, seed: Any = 0
) -> Cuboids:
    """Remove redundant parts: while the largest :func:`fraction_inside_others` exceeds
    ``threshold``, mark that part absent and recompute (the published test-time pruning).

    The volume samples are drawn once and reused at each step. Indices are kept (removed parts
    become absent slots). Computed by :func:`prune_covered_many`; the tests check it against
    :func:`fraction_inside_others` recomputed after every removal.
    """
    return prune_covered_many([cuboids], threshold, samples_per_cuboid, seed)[0]


def _pair_containment(unit, part, a, b, half_j, chunk: int = 512) -> np.ndarray:
    """(n, k) int8: whether unit sample ``unit[part[n], s]`` mapped by ``a[n] u + b[n]`` lies in the
    box ``|x| <= half_j[n]``. Three multiply-adds per coordinate on ``(chunk, k)`` slabs rather than
    a stacked ``(k, 3) @ (3, 3)`` product (NumPy's matmul loops per 3x3 block, several times slower),
    ``chunk`` pairs at a time so the temporaries stay in cache."""
    n, k = len(part), unit.shape[1]
    # the image of the cube [-1, 1]^3 spans b +- sum_d |a_cd| on each axis c of part j: wholly
    # inside the box, or apart from it along one of j's axes (a separating axis), needs no samples
    reach = np.abs(a).sum(-1)  # (n, 3)
    whole = np.all(np.abs(b) + reach <= half_j, axis=-1)
    apart = np.any(np.abs(b) - reach > half_j, axis=-1)
    out = np.zeros((n, k), np.int8)
    out[whole] = 1
    test = np.flatnonzero(~whole & ~apart)
    part, a, b, half_j = part[test], a[test], b[test], half_j[test]
    for lo in range(0, len(test), chunk):
        u = unit[part[lo : lo + chunk]]  # (c, k, 3)
        u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
        ok = None
        for c in range(3):
            ac = a[lo : lo + chunk, c]
            x = u0 * ac[:, 0:1] + u1 * ac[:, 1:2] + u2 * ac[:, 2:3] + b[lo : lo + chunk, c : c + 1]
            within = np.abs(x) <= half_j[lo : lo + chunk, c : c + 1]
            ok = within if ok is None else ok & within
        out[test[lo : lo + chunk]] = ok
    return out


def prune_covered_many(cuboids_list, threshold: float = 0.6, samples_per_cuboid: int = 1000, seed: Any = 0) -> list:
    """:func:`prune_covered` for many sets of cuboids at once, with the same result for each.

    Every set draws the same unit volume samples (one generator per set, seeded alike), so the
    samples are drawn once per slot count. Only pairs of present parts whose bounding spheres meet
    can hold each other's samples, so containment is tested for those pairs alone, all sets
    together: sample ``u`` (unit cube) of part ``i`` lies in part ``j`` when
    ``|A_ij (h_i * u) + b_ij| <= h_j`` with ``A_ij = R_j^T R_i`` and ``b_ij = R_j^T (t_i - t_j)``,
    three multiply-adds per sample. A running count of the other present parts holding each sample
    is decreased pair by pair as parts are removed, instead of recomputing every fraction.

    Written because the per-set loop spent 4.5 ms a shape in Python overhead, and then the dense
    ``(sets, p, k, p)`` containment table 17 ms a shape for 20 crowded parts, against 0.1 ms for
    the network itself (``benchmarks/bench_abstractor.py``, section 4).
    """
    sets = [check_cuboids(c) for c in cuboids_list]
    k = int(samples_per_cuboid)
    if k <= 0:
        raise ValueError(f"`samples_per_cuboid` must be positive, got {k}")
    out = list(sets)
    by_count: dict = {}  # slot count -> the sets with something to prune
    for i, c in enumerate(sets):
        if c.existence.sum() > 1:
            by_count.setdefault(c.count, []).append(i)
    for m, members in by_count.items():
        unit = np.random.default_rng(seed).uniform(-1.0, 1.0, size=(m, k, 3))  # as sample_volume draws them
        g = len(members)
        rot = np.stack([sets[i].rotations for i in members])  # (g, m, 3, 3)
        half = np.stack([sets[i].half_extents for i in members])  # (g, m, 3)
        trans = np.stack([sets[i].translations for i in members])  # (g, m, 3)
        alive = np.stack([sets[i].existence for i in members])  # (g, m)
        # candidate pairs (shape, i, j), i != j both present, bounding spheres meeting
        radius = np.linalg.norm(half, axis=-1)
        gap = np.linalg.norm(trans[:, :, None] - trans[:, None, :], axis=-1)
        near = (gap <= radius[:, :, None] + radius[:, None, :]) & alive[:, :, None] & alive[:, None, :]
        near[:, np.arange(m), np.arange(m)] = False
        s, i, j = np.nonzero(near)
        a = np.einsum("nba,nbc->nac", rot[s, j], rot[s, i]) * half[s, i][:, None, :]  # R_j^T R_i diag(h_i)
        b = np.einsum("nba,nb->na", rot[s, j], trans[s, i] - trans[s, j])  # R_j^T (t_i - t_j)
        inside = _pair_containment(unit, i, a, b, half[s, j])  # (n, k)
        count = np.zeros((g, m, k), np.int32)  # other present parts holding each sample
        if len(s):  # pairs come sorted by (set, i); the r-th holder j of each (set, i) is added in round r
            start = np.flatnonzero(np.r_[True, (s[1:] != s[:-1]) | (i[1:] != i[:-1])])
            rank = np.arange(len(s)) - np.repeat(start, np.diff(np.r_[start, len(s)]))
            for r in range(int(rank.max()) + 1):
                sel = np.flatnonzero(rank == r)  # (set, i) distinct within a round
                count[s[sel], i[sel]] += inside[sel]
        active = alive.sum(1) > 1
        while active.any():
            frac = np.where(alive, np.count_nonzero(count, axis=-1) / k, -np.inf)
            worst = frac.argmax(1)
            best = frac[np.arange(g), worst]
            active &= (alive.sum(1) > 1) & (best > threshold)
            if not active.any():
                break
            alive[active, worst[active]] = False
            gone = active[s] & (j == worst[s])  # pairs whose holder was just removed
            count[s[gone], i[gone]] -= inside[gone]  # one removed part per set: (set, i) distinct
        for row, idx in enumerate(members):
            out[idx] = sets[idx].with_existence(alive[row].copy())
    return out


def _face_points(
    cuboids: Cuboids, part: np.ndarray, face: np.ndarray, uv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World points and outward unit normals on face ``face`` (0..5, +x -x +y -y +z -z) of ``part``."""
    n = len(part)
    axis = face // 2
    sign = np.where(face % 2 == 0, 1.0, -1.0)
    unit = np.zeros((n, 3))
    rows = np.arange(n)
    unit[rows, axis] = sign
    unit[rows, (axis + 1) % 3] = uv[:, 0]
    unit[rows, (axis + 2) % 3] = uv[:, 1]
    rot = cuboids.rotations[part]  # (n, 3, 3)
    local = unit * cuboids.half_extents[part]
    points = np.einsum("nij,nj->ni", rot, local) + cuboids.translations[part]
    normals = rot[rows, :, axis] * sign[:, None]
    return points, normals


def union_surface_samples(cuboids: Cuboids, count: int = 10000, seed: Any = None) -> np.ndarray:
    """Area-uniform samples of the boundary of the union of the present solid cuboids.

    Candidates are drawn area-uniformly over all faces of all present cuboids (a face is chosen
    with probability proportional to its area, then a uniform point on it). A candidate ``x`` on
    a face of cuboid ``i`` with outward normal ``n`` is kept when it lies on the boundary of the
    union, decided by two rules:

    * dropped if ``x + 1e-8 n`` lies in another present cuboid: ``x`` is then inside the union
      (strictly inside another cuboid, or on a face shared with a touching cuboid);
    * dropped if ``x`` lies in (or on) a present cuboid of lower index: where faces of two cuboids
      coincide, only one copy is kept, so coplanar overlaps are not sampled twice.

    Drawing continues in rounds until ``count`` samples are kept; the first ``count`` are returned.

    Parameters
    ----------
    cuboids : Cuboids
    count : int
    seed : None, int or numpy Generator

    Returns
    -------
    points : (count, 3) float
        Raises ValueError when no part is present.
    """
    c = check_cuboids(cuboids)
    count = int(count)
    if count < 1:
        raise ValueError(f"`count` must be positive, got {count}")
    if not c.existence.any():
        raise ValueError("no present cuboid to sample")
    c = c.subset(c.present)  # renumbered 0..p-1 in slot order
    p = c.count
    rng = np.random.default_rng(seed)
    z = c.half_extents
    # face f lies on axis f // 2 and has area 4 * (product of the two other half extents)
    face_area = 4.0 * np.prod(z, axis=1)[:, None] / z[:, np.arange(6) // 2]  # (p, 6)
    prob = (face_area / face_area.sum()).ravel()
    others = ~np.eye(p, dtype=bool)
    lower = np.tril(np.ones((p, p), dtype=bool), k=-1)  # lower[i, j]: j < i
    kept: list[np.ndarray] = []
    have, drawn, accepted = 0, 0, 0
    for _ in range(1000):
        need = count - have
        rate = max(accepted / drawn, 1e-3) if drawn else 1.0
        draw = int(min(max(1.2 * need / rate, 64), 4 * CHUNK))
        pick = rng.choice(p * 6, size=draw, p=prob)
        part, face = pick // 6, pick % 6
        pts, normals = _face_points(c, part, face, rng.uniform(-1.0, 1.0, size=(draw, 2)))
        covered = np.any(contains(pts + _NUDGE * normals, c) & others[part], axis=1)
        duplicate = np.any(contains(pts, c, tol=_ON_BOUNDARY) & lower[part], axis=1)
        ok = pts[~covered & ~duplicate]
        kept.append(ok)
        have += len(ok)
        drawn += draw
        accepted += len(ok)
        if have >= count:
            return np.concatenate(kept)[:count]
    raise RuntimeError("could not sample the union surface (almost every candidate was covered)")

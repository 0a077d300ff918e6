"""Maps between cuboids paired by index: the per-part transforms that take a source abstraction
onto a target's configuration (``primkit deform``)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..primitives import Cuboids, point_cuboid_distance

__all__ = ["MIN_HALF_EXTENT", "MAX_RATIO", "cuboid_map", "cuboid_gap", "Transfer", "transfer_transforms"]


#: floor on half-extents in scale ratios (canonical units: one cell of the 32^3 grid)
MIN_HALF_EXTENT = 1.0 / 32.0


#: a paired part whose size changes by more than this factor along an axis is treated as unpaired
MAX_RATIO = 3.0


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


def cuboid_map(source: Cuboids, target: Cuboids, k: int, *, min_extent: float = MIN_HALF_EXTENT,
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


def cuboid_gap(cuboids: Cuboids, j: int, k: int) -> float:
    """Approximate distance between solid cuboids ``j`` and ``k`` (lattice points of each to the other)."""
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


def transfer_transforms(source: Cuboids, target: Cuboids, *, min_extent: float = MIN_HALF_EXTENT,
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
        nearest = min(paired, key=lambda j: cuboid_gap(source, int(k), j))
        transforms[k] = transforms[nearest]
        source_only[int(k)] = int(nearest)
    target_only = [int(k) for k in np.flatnonzero(target.existence & ~source.existence)]
    return Transfer(transforms, paired, source_only, target_only, mismatched)


def _extent_ratio(source: Cuboids, target: Cuboids, k: int, min_extent: float) -> float:
    """Largest factor by which the (floored) half-extents of part ``k`` change along matched axes."""
    lin = cuboid_map(source, target, k, min_extent=min_extent)[:3, :3]
    s = np.linalg.svd(lin, compute_uv=False)
    return float(max(s.max(), 1.0 / s.min()))

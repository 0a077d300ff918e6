"""The surface of a voxel grid without a mesh: its cells, its exact closest points and its samples.

A voxel input (binvox) has no mesh to measure distances to, only voxels. Its surface is the union of
the unit squares between occupied and empty voxels (:func:`primkit.geometry.voxel_boundary_mesh`
as triangles), and what preparation needs from that surface follows from the grid itself (the
network's input is the grid: the cells a voxel surface passes through are all occupied):

* **Closest points, exactly.** Work on the doubled lattice, where voxel ``i`` spans ``[2i, 2i + 2]``
  and its centre is the odd node ``2i + 1``. The point of a closed axis-aligned square nearest to a
  point with odd coordinates is found by clamping each coordinate into the square's range, which
  gives the point itself (odd) or an end of the range (even): it is a lattice node. So the closest
  point of the whole surface to every voxel centre is the nearest *surface node* (a node whose
  neighbouring voxels are neither all occupied nor all empty), and one Euclidean distance transform
  of the lattice with its indices (scipy's ``distance_transform_edt``, exact) finds it, with no BVH
  and no triangles. A node lies on the surface, so each result is a surface point and the distance
  is exact (equal to a BVH query on the boundary mesh up to float rounding; ties between nodes at the
  same distance may pick another of them). Computed at the voxel centres only, by a compiled
  separable transform (:mod:`primkit.geometry._voxel_kernels`; SciPy's ``distance_transform_edt``
  of the whole lattice is the reference and the fallback, with the same indices).
* **Samples**: every boundary square has the same area, so area-uniform samples are uniform squares
  and uniform positions in them.

Measured in ``benchmarks/bench_prepare.py`` against the mesh path on the same grids (boundary mesh
+ Open3D BVH + voxeliser + trimesh sampling).
"""

from __future__ import annotations

import numpy as np

__all__ = ["voxel_surface_nodes", "voxel_closest_points", "voxel_surface_squares", "sample_voxel_surface"]


def _check(occupancy) -> np.ndarray:
    occ = np.asarray(occupancy, bool)
    if occ.ndim != 3:
        raise ValueError(f"`occupancy` must be (R, R, R) bool, got shape {occ.shape}")
    return occ


def _expand(a: np.ndarray, axis: int, op) -> np.ndarray:
    """Padded voxel values (length R + 2 along ``axis``) -> the 2R + 1 lattice nodes: node ``2i + 1``
    takes voxel ``i``, node ``2i`` combines voxels ``i - 1`` and ``i`` with ``op``."""
    n = a.shape[axis] - 2
    shape = list(a.shape)
    shape[axis] = 2 * n + 1
    out = np.empty(shape, a.dtype)
    take = lambda s: a[(slice(None),) * axis + (s,)]  # noqa: E731
    put = lambda s: (slice(None),) * axis + (s,)  # noqa: E731
    out[put(slice(1, None, 2))] = take(slice(1, -1))
    out[put(slice(0, None, 2))] = op(take(slice(0, -1)), take(slice(1, None)))
    return out


def voxel_surface_nodes(occupancy: np.ndarray) -> np.ndarray:
    """Nodes of the doubled lattice that lie on the voxel surface.

    Returns
    -------
    (2R + 1, 2R + 1, 2R + 1) bool
        Node ``(u, v, w)`` is the point ``-0.5 + (u, v, w) / (2R)`` of the canonical cube.
    """
    occ = np.pad(_check(occupancy), 1)
    anyocc, allocc = occ, occ
    for axis in range(3):
        anyocc = _expand(anyocc, axis, np.logical_or)
        allocc = _expand(allocc, axis, np.logical_and)
    return anyocc & ~allocc


def voxel_closest_points(occupancy: np.ndarray, engine: str = "auto") -> np.ndarray:
    """Exact closest point of the voxel surface to every cell centre (module notes).

    Parameters
    ----------
    occupancy : (R, R, R) bool
        In the canonical grid (cell ``(i, j, k)`` centred at ``-0.5 + ((i, j, k) + 0.5) / R``).

    engine : {"auto", "scipy"}
        ``"auto"``: the compiled transform at the voxel centres alone
        (:mod:`primkit.geometry._voxel_kernels`, Numba), else SciPy; ``"scipy"``: SciPy's transform
        of the whole lattice. Both give the same points.

    Returns
    -------
    closest : (R, R, R, 3) float32
        Points of the surface; an empty grid has no surface and raises ValueError.
    """
    if engine not in ("auto", "scipy"):
        raise ValueError(f"engine must be 'auto' or 'scipy', got {engine!r}")
    occ = _check(occupancy)
    if not occ.any():
        raise ValueError("the voxel grid is empty: no surface")
    res = occ.shape[0]
    nodes = voxel_surface_nodes(occ)
    at_centres = _nearest_nodes_at_centres(nodes) if engine == "auto" else _nearest_nodes_scipy(nodes)
    return -0.5 + at_centres.astype(np.float32) / np.float32(2 * res)


def _nearest_nodes_scipy(nodes: np.ndarray) -> np.ndarray:
    """(R, R, R, 3) index of the nearest surface node of each voxel centre, by SciPy's feature
    transform of the whole lattice (the reference the compiled kernel is tested against)."""
    from scipy import ndimage

    index = ndimage.distance_transform_edt(~nodes, return_distances=False, return_indices=True)
    return np.moveaxis(index[:, 1::2, 1::2, 1::2], 0, -1)


def _nearest_nodes_at_centres(nodes: np.ndarray) -> np.ndarray:
    from ._voxel_kernels import odd_feature_transform  # Numba is a dependency: no silent fallback

    return odd_feature_transform(np.ascontiguousarray(nodes))


def voxel_surface_squares(occupancy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unit squares of the voxel surface.

    Returns
    -------
    corner : (q, 3) int
        Lattice corner (in voxel units, 0..R) of each square's lower corner.
    u_axis, v_axis : (q,) int
        The two axes the square spans (its normal is the third).
    """
    occ = np.pad(_check(occupancy), 1)
    corners, us, vs = [], [], []
    for axis in range(3):
        # a square between voxels a and a + 1 along `axis` (padded indices), on the plane at a + 1 - 1
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        differ = occ[tuple(lo)] != occ[tuple(hi)]
        # trim the padding of the other two axes
        trim = [slice(1, -1)] * 3
        trim[axis] = slice(None)
        idx = np.argwhere(differ[tuple(trim)])
        if len(idx) == 0:
            continue
        corner = idx.copy()  # other axes: voxel index (lower corner); `axis`: the plane index 0..R
        corners.append(corner)
        u, v = (axis + 1) % 3, (axis + 2) % 3
        us.append(np.full(len(idx), u))
        vs.append(np.full(len(idx), v))
    if not corners:
        empty = np.zeros(0, np.int64)
        return np.zeros((0, 3), np.int64), empty, empty
    return np.concatenate(corners), np.concatenate(us), np.concatenate(vs)


def sample_voxel_surface(occupancy: np.ndarray, count: int, seed=None) -> np.ndarray:
    """``count`` points uniformly by area on the voxel surface, in the canonical cube.

    Returns
    -------
    points : (count, 3) float
    """
    occ = _check(occupancy)
    res = occ.shape[0]
    corner, u_axis, v_axis = voxel_surface_squares(occ)
    if len(corner) == 0:
        raise ValueError("the voxel grid is empty: no surface")
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(corner), count)
    uv = rng.random((count, 2))
    pts = corner[pick].astype(np.float64)
    rows = np.arange(count)
    pts[rows, u_axis[pick]] += uv[:, 0]
    pts[rows, v_axis[pick]] += uv[:, 1]
    return -0.5 + pts / res

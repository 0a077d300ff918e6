"""Shape preparation: canonical frame, occupancy grids, surface samples and distance grids.

Everything here works on plain arrays (``vertices : (n, 3) float``, ``faces : (f, 3) int``) in the
canonical frame described in :mod:`primkit` (+Y up, +X front, inside [-0.5, 0.5]^3). Grids follow
the one grid convention written there: ``grid[i, j, k]`` along X, Y, Z, cell centres at
``-0.5 + (index + 0.5) / R``.

Which library does what, and why:

* **Closest points** come from Open3D's ``RaycastingScene`` (Embree BVH, multi-threaded); the point
  on the found triangle is then recomputed in float64. libigl's AABB (``point_mesh_squared_distance``)
  measured the same speed (61 against 63 ms a mesh in ``benchmarks/bench_prepare.py``); either is
  fine, Open3D was kept because it also gives the surface voxels.
* **Occupancy** is the generalised winding number (libigl ``fast_winding_number``), which is robust
  on open and self-intersecting meshes where ray parity (Open3D's ``compute_occupancy``) is not.
* **Surface voxels** (cells a triangle passes through) are Open3D's exact triangle-box voxeliser.
* **Surface samples** are area-uniform with face ids (trimesh's ``sample_surface``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "CanonicalFrame",
    "axis_rotation",
    "canonical_frame",
    "grid_centres",
    "surface_voxels",
    "occupancy_grid",
    "SurfaceSamples",
    "sample_surface",
    "DistanceGrid",
    "distance_grid",
    "closest_points_on_triangles",
    "voxel_boundary_mesh",
    "fill_voxels",
]

_AXES = {"+x": (0, 1.0), "-x": (0, -1.0), "+y": (1, 1.0), "-y": (1, -1.0), "+z": (2, 1.0), "-z": (2, -1.0)}


def _axis_vector(name: str) -> np.ndarray:
    key = name.strip().lower()
    if key in ("x", "y", "z"):
        key = "+" + key
    if key not in _AXES:
        raise ValueError(f"axis must be one of {sorted(_AXES)}, got {name!r}")
    index, sign = _AXES[key]
    vec = np.zeros(3)
    vec[index] = sign
    return vec


def axis_rotation(up: str = "+y", front: str = "+x") -> np.ndarray:
    """Rotation taking the input's ``up`` axis to +Y and its ``front`` axis to +X.

    Parameters
    ----------
    up, front : str
        Signed axis names such as ``"+z"`` or ``"-x"``; they must be perpendicular.

    Returns
    -------
    rotation : (3, 3) float
        Proper rotation (det 1) acting on column vectors: ``canonical = rotation @ x``.
    """
    u = _axis_vector(up)
    fr = _axis_vector(front)
    if abs(u @ fr) > 0.5:
        raise ValueError(f"up {up!r} and front {front!r} must be different axes")
    # rows are the input directions that become canonical X, Y, Z
    return np.stack([fr, u, np.cross(fr, u)])


@dataclass(frozen=True)
class CanonicalFrame:
    """A similarity transform into the canonical frame: ``canonical = scale * (rotation @ x - centre)``.

    Attributes
    ----------
    rotation : (3, 3) float
        Axis permutation / sign change into +Y up, +X front.
    centre : (3,) float
        Bounding-box centre of the rotated input.
    scale : float
        Factor that makes the longest side of the bounding box ``size``.
    """

    rotation: np.ndarray
    centre: np.ndarray
    scale: float

    def to_canonical(self, points: np.ndarray) -> np.ndarray:
        """``(n, 3) float`` input-frame points to ``(n, 3) float`` canonical points."""
        points = np.asarray(points, dtype=np.float64)
        return (points @ self.rotation.T - self.centre) * self.scale

    def from_canonical(self, points: np.ndarray) -> np.ndarray:
        """``(n, 3) float`` canonical points back to the input frame."""
        points = np.asarray(points, dtype=np.float64)
        return (points / self.scale + self.centre) @ self.rotation

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) float homogeneous matrix of :meth:`to_canonical`."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = -self.scale * self.centre
        return m

    def to_dict(self) -> dict:
        return {"rotation": self.rotation.tolist(), "centre": self.centre.tolist(), "scale": float(self.scale)}

    @classmethod
    def from_dict(cls, d: dict) -> "CanonicalFrame":
        return cls(np.asarray(d["rotation"], float), np.asarray(d["centre"], float), float(d["scale"]))


def canonical_frame(points: np.ndarray, up: str = "+y", front: str = "+x", size: float = 1.0) -> CanonicalFrame:
    """Frame that rotates ``up`` to +Y and ``front`` to +X, centres the bounding box at the
    origin and scales its longest side to ``size``.

    Parameters
    ----------
    points : (n, 3) float
        Vertices or points of the shape in its own frame.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ValueError("`points` must be (n, 3) float with n > 0")
    rotation = axis_rotation(up, front)
    rotated = points @ rotation.T
    lo, hi = rotated.min(axis=0), rotated.max(axis=0)
    extent = float((hi - lo).max())
    if not np.isfinite(extent) or extent <= 0:
        raise ValueError("shape has zero extent")
    return CanonicalFrame(rotation, (lo + hi) / 2.0, size / extent)


def grid_centres(resolution: int = 32) -> np.ndarray:
    """Cell centres of the canonical grid.

    Returns
    -------
    centres : (R, R, R, 3) float
        ``centres[i, j, k] = -0.5 + ((i, j, k) + 0.5) / R``.
    """
    c = -0.5 + (np.arange(resolution) + 0.5) / resolution
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1)


def _o3d_mesh(vertices, faces):
    import open3d as o3d

    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
        o3d.utility.Vector3iVector(np.asarray(faces, np.int32)),
    )


def surface_voxels(vertices: np.ndarray, faces: np.ndarray, resolution: int = 32) -> np.ndarray:
    """Cells of the canonical grid that a triangle passes through (exact triangle-box test).

    Returns
    -------
    surface : (R, R, R) bool
    """
    import open3d as o3d

    grid = np.zeros((resolution,) * 3, dtype=bool)
    vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(
        _o3d_mesh(vertices, faces), 1.0 / resolution, np.full((3, 1), -0.5), np.full((3, 1), 0.5)
    )
    voxels = vg.get_voxels()
    if voxels:
        idx = np.array([v.grid_index for v in voxels], dtype=np.int64)
        # a triangle lying exactly on the upper boundary is reported one cell past the grid
        idx = np.clip(idx, 0, resolution - 1)
        grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    return grid


def occupancy_grid(
    vertices: np.ndarray,
    faces: np.ndarray,
    resolution: int = 32,
    include_surface: bool = False,
    surface: np.ndarray | None = None,
) -> np.ndarray:
    """Solid occupancy of the canonical grid: generalised winding number > 0.5 at each cell centre.

    The winding number (libigl's fast approximation) is robust where ray parity is not: on open
    meshes (a chair with a hole), self-intersections and duplicated faces. We also tried evaluating
    it only on surface cells plus a few cells per connected free region: identical grids, but
    ``benchmarks/bench_prepare.py`` measured it slower (29 ms against 20 ms a mesh), so every cell
    is evaluated.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (f, 3) int
    include_surface : bool
        Also mark the cells the surface passes through, so that parts thinner than a cell still
        show in the grid (this is the network's input).
    surface : (R, R, R) bool, optional
        Precomputed :func:`surface_voxels` (used with ``include_surface``).

    Returns
    -------
    occupancy : (R, R, R) bool
    """
    import igl

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    centres = grid_centres(resolution).reshape(-1, 3)
    occupancy = (igl.fast_winding_number(vertices, faces, centres) > 0.5).reshape((resolution,) * 3)
    if include_surface:
        occupancy |= surface if surface is not None else surface_voxels(vertices, faces, resolution)
    return occupancy


@dataclass(frozen=True)
class SurfaceSamples:
    """Area-uniform samples of a surface.

    Attributes
    ----------
    points : (n, 3) float
    face_index : (n,) int
        The face each sample lies on (for voxel inputs: the face of the voxel boundary mesh).
    """

    points: np.ndarray
    face_index: np.ndarray


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int = 10000, seed=None) -> SurfaceSamples:
    """Draw ``count`` points uniformly by area on the triangle mesh, with their face ids."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)
    points, face_index = trimesh.sample.sample_surface(mesh, count, seed=np.random.default_rng(seed))
    return SurfaceSamples(np.asarray(points, np.float64), np.asarray(face_index, np.int64))


def closest_points_on_triangles(points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact closest point on triangle ``(a, b, c)`` to each point, vectorised over rows.

    Written here (rather than calling a library) because it runs on arbitrary point/triangle
    *pairs*, which the libraries' mesh-level queries do not offer. Region tests follow the standard
    Voronoi-region construction (vertex, edge, face regions).

    Parameters
    ----------
    points, a, b, c : (n, 3) float

    Returns
    -------
    closest : (n, 3) float
    """
    p = np.asarray(points, np.float64)
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    with np.errstate(divide="ignore", invalid="ignore"):
        # face interior by default
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        out = a + ab * v[:, None] + ac * w[:, None]
        # edge bc
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out[m] = (b + (c - b) * t[:, None])[m]
        # edge ac
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / (d2 - d6)
        out[m] = (a + ac * t[:, None])[m]
        # edge ab
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / (d1 - d3)
        out[m] = (a + ab * t[:, None])[m]
        # vertex regions
        m = (d6 >= 0) & (d5 <= d6)
        out[m] = c[m]
        m = (d3 >= 0) & (d4 <= d3)
        out[m] = b[m]
        m = (d1 <= 0) & (d2 <= 0)
        out[m] = a[m]
    # degenerate triangles (zero area) can leave NaNs: fall back to the nearest vertex
    bad = ~np.isfinite(out).all(axis=1)
    if bad.any():
        cand = np.stack([a[bad], b[bad], c[bad]], axis=1)
        k = np.argmin(((cand - p[bad, None]) ** 2).sum(-1), axis=1)
        out[bad] = cand[np.arange(len(k)), k]
    return out


@dataclass(frozen=True)
class DistanceGrid:
    """Unsigned distance to the surface and the closest surface point, per cell of the canonical grid.

    Attributes
    ----------
    distance : (R, R, R) float32
        Distance from each cell centre to the surface.
    closest : (R, R, R, 3) float32
        The closest surface point to each cell centre.
    """

    distance: np.ndarray
    closest: np.ndarray

    @property
    def resolution(self) -> int:
        return self.distance.shape[0]


def _raycasting_scene(vertices, faces):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)),
    )
    return scene


def distance_grid(vertices: np.ndarray, faces: np.ndarray, resolution: int = 32) -> DistanceGrid:
    """Distance to the surface and closest surface point at every cell centre of the canonical grid.

    Open3D's BVH finds the closest triangle of every cell (in float32); the closest point on that
    triangle is then recomputed in float64 by :func:`closest_points_on_triangles`, so the stored
    distances are exact point-to-triangle distances up to float32 storage.

    We tried answering only a band of cells near the surface with the BVH and finishing far cells
    from the band's closest triangles: on finely tessellated meshes (triangles much smaller than a
    cell) it was off by up to 1.5e-3 of the unit cube, so every cell is queried.

    Parameters
    ----------
    vertices : (n, 3) float
        Canonical-frame vertices.
    faces : (f, 3) int

    Returns
    -------
    DistanceGrid
    """
    import open3d as o3d

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    centres = grid_centres(resolution).reshape(-1, 3)
    result = _raycasting_scene(vertices, faces).compute_closest_points(o3d.core.Tensor(centres.astype(np.float32)))
    t = faces[result["primitive_ids"].numpy().astype(np.int64)]
    closest = closest_points_on_triangles(centres, vertices[t[:, 0]], vertices[t[:, 1]], vertices[t[:, 2]])
    distance = np.linalg.norm(closest - centres, axis=1)
    shape = (resolution,) * 3
    return DistanceGrid(distance.reshape(shape).astype(np.float32), closest.reshape(shape + (3,)).astype(np.float32))


def voxel_boundary_mesh(occupancy: np.ndarray, voxel_size: float | None = None, origin=None) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of the faces between occupied and empty voxels (two triangles per face).

    Shared vertices are merged, so the result is closed. Written here because the libraries'
    voxel-to-mesh routines either emit a cube per voxel (interior faces included) or smooth the
    surface (marching cubes), and we want exactly the voxel surface.

    Parameters
    ----------
    occupancy : (R, R, R) bool
    voxel_size : float, optional
        Edge length of a voxel; ``1 / R`` by default (the canonical grid).
    origin : (3,) float, optional
        Position of the grid's lower corner; ``(-0.5, -0.5, -0.5)`` by default.

    Returns
    -------
    vertices : (n, 3) float
    faces : (f, 3) int
        Outward-facing triangles.
    """
    occ = np.asarray(occupancy, bool)
    res = np.array(occ.shape)
    if voxel_size is None:
        voxel_size = 1.0 / res.max()
    origin = np.full(3, -0.5) if origin is None else np.asarray(origin, float)
    padded = np.pad(occ, 1)
    quads = []
    for axis in range(3):
        for sign in (1, -1):
            shifted = np.roll(padded, -sign, axis=axis)
            exposed = padded & ~shifted
            idx = np.argwhere(exposed[1:-1, 1:-1, 1:-1])
            if len(idx) == 0:
                continue
            # corner of the face: voxel corner offset by 1 along `axis` for the + side
            base = idx.copy()
            if sign > 0:
                base[:, axis] += 1
            u, v = [(axis + 1) % 3, (axis + 2) % 3]
            du = np.zeros(3, np.int64)
            dv = np.zeros(3, np.int64)
            du[u] = 1
            dv[v] = 1
            corners = np.stack([base, base + du, base + du + dv, base + dv], axis=1)
            if sign < 0:
                corners = corners[:, ::-1]
            quads.append(corners)
    if not quads:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    quads = np.concatenate(quads)
    flat = quads.reshape(-1, 3)
    unique, inverse = np.unique(flat, axis=0, return_inverse=True)
    q = inverse.reshape(-1, 4)
    faces = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    vertices = origin + unique * voxel_size
    return vertices.astype(np.float64), faces.astype(np.int64)


def fill_voxels(occupancy: np.ndarray) -> np.ndarray:
    """Fill enclosed cavities of a voxel grid (cells not reachable from outside become occupied).

    Returns
    -------
    filled : (R, R, R) bool
    """
    from scipy import ndimage

    return ndimage.binary_fill_holes(np.asarray(occupancy, bool))

"""Shape preparation: canonical frame, occupancy grids, surface samples and distance grids.

Everything here works on plain arrays (``vertices : (n, 3) float``, ``faces : (f, 3) int``) in the
canonical frame described in :mod:`primkit` (+Y up, +X front, inside [-0.5, 0.5]^3). Grids follow
the one grid convention written there: ``grid[i, j, k]`` along X, Y, Z, cell centres at
``-0.5 + (index + 0.5) / R``.

Which library does what, and why:

* **Closest points** of the distance grid come from primkit's compiled search
  (:mod:`~primkit.geometry._mesh_kernels`, Numba), in float64: within 2 cells of the surface each
  cell is searched exactly (the cells in order, each search bounded by the previous cell's
  triangle); farther cells take the nearest of their nearer neighbours' triangles, then step across
  edges to a nearer one (never nearer than the truth; measured within 5e-3 of the unit cube, see
  :func:`~primkit.geometry.distance_grid`). libigl's AABB (``point_mesh_squared_distance``) and
  Open3D's ``RaycastingScene`` (Embree BVH) answer each point from the root and took about twice the
  exact search's time; Open3D stays as ``engine="open3d"`` (``benchmarks/bench_prepare.py``);
  Numba is a dependency, and a kernel that fails to load raises rather than falling back.
* **Occupancy** is the generalised winding number, robust on open and self-intersecting meshes
  where ray parity (Open3D's ``compute_occupancy``) is not: primkit's (the same tree, a first-order
  dipole far field) at the surface cells and a few cells per free region, which gave libigl's
  ``fast_winding_number`` grids in about half its time, the tree's build included (which the
  distances then reuse; ``engine="igl"`` keeps libigl's).
* **Surface voxels** (cells a triangle passes through): an exact triangle-box test compiled with
  Numba that finds Open3D's cells (``create_from_triangle_mesh_within_bounds``, the fallback) in a
  sixth of its time.
* **Surface samples** are area-uniform with face ids (trimesh's ``sample_surface``).

Modules: :mod:`~primkit.geometry.frames` (the canonical frame), :mod:`~primkit.geometry.grids`
(cell centres, surface cells, occupancy, voxel surfaces), :mod:`~primkit.geometry.distances`
(closest points and distance grids), :mod:`~primkit.geometry.sampling` (surface samples),
:mod:`~primkit.geometry.voxels` (a voxel grid's surface without a mesh: exact closest points by a
distance transform, samples), :mod:`~primkit.geometry.quantize` (the cache's compact codes of
closest points and samples), :mod:`~primkit.geometry.topology` (edge-sharing face pairs).
``primkit.geometry`` imports nothing else of primkit.
"""

from .distances import DistanceGrid, closest_points_on_triangles, distance_grid, lookup_distance_sq
from .frames import CanonicalFrame, axis_rotation, canonical_frame
from .grids import fill_voxels, grid_centres, occupancy_grid, surface_voxels, voxel_boundary_mesh
from .quantize import (POINT_ERROR, centres_planar, closest_error, closest_scales, decode_closest, decode_points,
                       encode_closest, encode_points, near_shift)
from .sampling import SurfaceSamples, sample_surface
from .topology import face_adjacency
from .voxels import sample_voxel_surface, voxel_closest_points, voxel_surface_nodes, voxel_surface_squares

__all__ = [
    "face_adjacency",
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
    "lookup_distance_sq",
    "voxel_boundary_mesh",
    "fill_voxels",
    "voxel_surface_nodes",
    "voxel_closest_points",
    "voxel_surface_squares",
    "sample_voxel_surface",
    "encode_closest",
    "decode_closest",
    "encode_points",
    "decode_points",
    "closest_error",
    "POINT_ERROR",
    "closest_scales",
    "centres_planar",
    "near_shift",
]

"""Cuboid primitives: the value type, their geometry, and differentiable versions for training.

A set of ``m`` cuboids is one :class:`Cuboids` value. Part ``k`` is slot ``k`` of the arrays, for
good: parts that do not exist keep their slot (``existence[k]`` is False) and are never renumbered,
so an index names the same part across shapes predicted by one model.

Conventions (the ones that bite)
--------------------------------
* **Half extents.** ``half_extents[k] = (z0, z1, z2)``: the cuboid spans ``[-z_i, z_i]`` along its
  local axis ``i``, so its full size is ``2 z`` and its volume ``8 z0 z1 z2``.
* **Quaternions** are unit and real part first: ``q = (w, x, y, z)``. ``q`` and ``-q`` are the same
  rotation; :func:`matrix_to_quaternion` returns the one with ``w >= 0``.
* **Rotation matrices** ``R = quaternion_to_matrix(q)`` act on column vectors and map local to
  world coordinates::

      x_world = R @ x_local + t          x_local = R.T @ (x_world - t)

* **Distance** from a point to a cuboid is to the *solid*: ``|| max(|x_local| - z, 0) ||``, zero
  inside. The distance to a set of parts is the minimum over the *present* parts.

Corners and faces in local coordinates (used by :meth:`Cuboids.to_mesh` and the surface sampling)::

                 y
                 |
                 2 ---------------- 3          corner c = (±z0, ±z1, ±z2) with
                /|                 /|          bit 0 of c -> +x, bit 1 -> +y, bit 2 -> +z:
               / |                / |            0 (-,-,-)   1 (+,-,-)
              6 ---------------- 7  |            2 (-,+,-)   3 (+,+,-)
              |  |               |  |            4 (-,-,+)   5 (+,-,+)
              |  0 --------------|- 1 --- x      6 (-,+,+)   7 (+,+,+)
              | /                | /
              |/                 |/            face f: axis f // 2, side + if f is even
              4 ---------------- 5               0 +x   1 -x   2 +y   3 -y   4 +z   5 -z
             /
            z                                  mesh triangles 2f and 2f+1 lie on face f

Surface samples are split equally over the six faces (``k`` samples per cuboid, ``k`` a multiple
of 6, face ``f`` owning samples ``f*k/6 .. (f+1)*k/6 - 1``); each carries the importance weight
``area(face) / (k/6)``, so the weights of one cuboid sum to its surface area (the paper's appendix
A1). A sample is reparametrised: the face's fixed coordinate is ``±z_axis`` and the two others are
``u * z_i`` with ``u ~ U[-1, 1]``, then it is rotated and translated, so gradients reach ``z``,
``q`` and ``t``.

NumPy functions take and return arrays (``n`` points, ``m`` parts). The ``*_torch`` functions are
for training: batch first (``B``), differentiable, and follow the device and dtype of their inputs;
torch is imported only when one of them is called.

Modules: :mod:`~primkit.primitives.cuboids` (the value type), :mod:`~primkit.primitives.rotations`,
:mod:`~primkit.primitives.distances` (points against cuboids), :mod:`~primkit.primitives.sampling`,
:mod:`~primkit.primitives.differentiable` (the torch twins), :mod:`~primkit.primitives.palette` (the
colour of each part index). ``primkit.primitives`` imports only
:mod:`primkit.io` (to write JSON atomically).
"""

from .cuboids import CORNER_SIGNS, SCHEMA_VERSION, Cuboids
from .differentiable import (cuboid_distance_sq_torch, quaternion_to_matrix_torch, sample_cuboid_surfaces_torch,
                             surface_coefficients_torch, surface_samples_from_coefficients_torch, world_to_local_torch)
from .distances import Assignment, assign_points, assign_points_with_distance, contains, local_to_world, point_cuboid_distance, union_distance, world_to_local
from .rotations import matrix_to_quaternion, quaternion_to_matrix
from .sampling import CuboidSurfaceSamples, fraction_inside_others, prune_covered, prune_covered_many, sample_cuboid_surfaces, sample_volume, union_surface_samples

__all__ = [
    "SCHEMA_VERSION",
    "CORNER_SIGNS",
    "Cuboids",
    "CuboidSurfaceSamples",
    "quaternion_to_matrix",
    "matrix_to_quaternion",
    "world_to_local",
    "local_to_world",
    "point_cuboid_distance",
    "union_distance",
    "contains",
    "sample_cuboid_surfaces",
    "sample_volume",
    "fraction_inside_others",
    "prune_covered",
    "prune_covered_many",
    "union_surface_samples",
    "assign_points",
    "assign_points_with_distance",
    "Assignment",
    "quaternion_to_matrix_torch",
    "world_to_local_torch",
    "cuboid_distance_sq_torch",
    "sample_cuboid_surfaces_torch",
    "surface_coefficients_torch",
    "surface_samples_from_coefficients_torch",
]

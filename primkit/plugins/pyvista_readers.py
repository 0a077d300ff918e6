"""``pyvista.read`` of the formats primkit reads and VTK does not: ``.off``, ``.binvox``, ``.xyz``, ``.npy``.

Installing primkit declares these readers in the ``pyvista.readers`` entry-point group
(``setup.cfg``; pyvista 0.48 or later): pyvista imports this module the first time one of these
suffixes is read, with no ``import primkit`` by the user::

    import pyvista as pv
    chair = pv.read("chair.off")              # PolyData: the triangles, in file order
    grid = pv.read("chair.binvox")            # ImageData: cell_data["occupancy"] (uint8, 1 = filled)
    cloud = pv.read("points.xyz")             # PolyData of points (point_data["Normals"] with 6 columns)
    grid.threshold(0.5)                       # the filled voxels, as an UnstructuredGrid

The files are read by :mod:`primkit.io` (so they come back exactly as primkit sees them: faces in
file order, polygons triangulated, float64 coordinates) and converted. A broken file raises
:class:`primkit.io.ShapeFileError`, one line naming the file. The other formats primkit reads
(``.obj .ply .stl .glb .gltf``) are VTK's: pyvista reads them itself (a ``.glb``/``.gltf`` as a
``MultiBlock`` of its meshes, where primkit flattens the scene into one mesh).

A ``.binvox`` grid comes back as a ``pyvista.ImageData`` of ``R`` cells per axis: origin the
grid's minimum corner (``translate``), spacing ``scale / R``, so the centre of voxel ``[i, j, k]``
is where :class:`primkit.io.VoxelGrid` puts it; cell ``[i, j, k]`` is VTK's cell
``i + R * j + R * R * k`` (x fastest). ``dataset.primkit`` abstracts such a grid as a voxel grid.
``.npy`` files are read as point clouds ((n, 3) or (n, 6) arrays); any other array raises.
"""

from __future__ import annotations

import numpy as np

from .. import io
from ..viz.backend import pyvista_module
from ..viz.interop import to_pyvista

__all__ = ["read_off", "read_binvox", "read_point_dataset", "voxels_to_pyvista", "voxels_from_pyvista", "OCCUPANCY"]

#: The cell array of a voxel grid read from ``.binvox``.
OCCUPANCY = "occupancy"


def _no_options(path, kwargs) -> None:
    if kwargs:
        raise TypeError(f"{path}: primkit's reader takes no options, got {', '.join(sorted(kwargs))}")


def read_off(path, **kwargs):
    """An ``.off`` mesh as ``pyvista.PolyData`` (triangles, file order; see the module notes)."""
    _no_options(path, kwargs)
    mesh = io.read_mesh(path)
    return to_pyvista((mesh.vertices, mesh.faces))


def voxels_to_pyvista(grid: io.VoxelGrid):
    """A :class:`primkit.io.VoxelGrid` as ``pyvista.ImageData`` with ``cell_data["occupancy"]``
    ((R^3,) uint8), laid out as the module notes say."""
    pv = pyvista_module()
    r = grid.resolution
    image = pv.ImageData(dimensions=(r + 1,) * 3, spacing=(grid.scale / r,) * 3, origin=grid.translate)
    image.cell_data[OCCUPANCY] = grid.occupancy.astype(np.uint8).ravel(order="F")  # VTK: x fastest
    return image


def voxels_from_pyvista(image) -> io.VoxelGrid | None:
    """The :class:`primkit.io.VoxelGrid` of an ``ImageData`` carrying ``cell_data["occupancy"]`` (cubic,
    equal spacing); None for any other dataset."""
    pv = pyvista_module()
    if not isinstance(image, pv.ImageData) or OCCUPANCY not in image.cell_data:
        return None
    cells = tuple(int(d) - 1 for d in image.dimensions)
    spacing = np.asarray(image.spacing, dtype=np.float64)
    if len(set(cells)) != 1 or not np.allclose(spacing, spacing[0]):
        raise ValueError(f"a voxel grid must be cubic with equal spacing, got {cells} cells of {spacing.tolist()}")
    occupancy = np.asarray(image.cell_data[OCCUPANCY]).reshape(cells, order="F") > 0
    return io.VoxelGrid(occupancy, np.asarray(image.origin, dtype=np.float64), float(spacing[0] * cells[0]))


def read_binvox(path, **kwargs):
    """A ``.binvox`` grid as ``pyvista.ImageData`` (see :func:`voxels_to_pyvista`)."""
    _no_options(path, kwargs)
    return voxels_to_pyvista(io.read_voxels(path))


def read_point_dataset(path, **kwargs):
    """An ``.xyz`` or ``.npy`` point cloud as ``pyvista.PolyData`` of points (``point_data["Normals"]``
    when the file has them)."""
    _no_options(path, kwargs)
    cloud = io.read_points(path)
    poly = to_pyvista(cloud.points)
    if cloud.normals is not None:
        poly.point_data["Normals"] = cloud.normals
    return poly

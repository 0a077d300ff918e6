"""Open3D and pyvista geometry read back as primkit's arrays.

The input side of :mod:`primkit.viz.interop`: a shape handed over as an Open3D or pyvista object
becomes ``(n, 3) float`` vertices, ``(f, 3) int`` faces and ``uint8`` colours. It lives here, below
the model, because :func:`primkit.model.abstraction.as_shape` takes such objects as input;
:mod:`primkit.viz.interop` re-exports every name (the same functions) beside the conversions the
other way.

Colours are ``(k, 3) uint8`` on primkit's side and float in [0, 1] on Open3D's side; conversions
scale by 255 and round. Open3D and pyvista are imported inside the functions: importing this
module costs nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["O3DMesh", "mesh_from_o3d", "points_from_o3d", "from_pyvista", "is_tensor_geometry"]


@dataclass(frozen=True, eq=False)
class O3DMesh:
    """A mesh read back from Open3D.

    Attributes
    ----------
    vertices : (n, 3) float
    faces : (f, 3) int
    vertex_colors : (n, 3) uint8 or None
    face_colors : (f, 3) uint8 or None
        Set when every face's three vertex colours agree (a mesh written by
        :func:`primkit.viz.interop.mesh_to_o3d` with ``face_colors``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None = None
    face_colors: np.ndarray | None = None


def is_tensor_geometry(obj) -> bool:
    """True for ``open3d.t.geometry`` objects (named attributes: ``vertex``/``triangle``/``point``/``line``)."""
    module = type(obj).__module__
    return module.split(".")[0] == "open3d" and ".t." in module + "."


def colors_to_uint8(colors) -> np.ndarray:
    """Float colours in [0, 1] as ``uint8`` in 0..255 (scaled by 255, rounded, clipped)."""
    return np.clip(np.rint(np.asarray(colors, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)


def mesh_from_o3d(mesh) -> O3DMesh:
    """An Open3D triangle mesh (``open3d.geometry.TriangleMesh`` or the tensor
    ``open3d.t.geometry.TriangleMesh``) as arrays (:class:`O3DMesh`), colours as uint8."""
    if is_tensor_geometry(mesh):
        v = mesh.vertex.positions.numpy().astype(np.float64)
        f = mesh.triangle.indices.numpy().astype(np.int64).reshape(-1, 3) if "indices" in mesh.triangle else \
            np.zeros((0, 3), np.int64)
        colors = mesh.vertex.colors.numpy() if "colors" in mesh.vertex else None
    else:
        v = np.asarray(mesh.vertices, dtype=np.float64).copy()
        f = np.asarray(mesh.triangles, dtype=np.int64).copy().reshape(-1, 3)
        colors = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else None
    vc = fc = None
    if colors is not None:
        vc = colors_to_uint8(colors)
        if len(f):
            corner = vc[f]  # (f, 3 corners, 3 channels)
            if np.all(corner == corner[:, :1]):
                fc = corner[:, 0].copy()
    return O3DMesh(v, f, vc, fc)


def points_from_o3d(pcd) -> tuple[np.ndarray, np.ndarray | None]:
    """An Open3D point cloud (``open3d.geometry.PointCloud`` or ``open3d.t.geometry.PointCloud``) as
    ``(points (n, 3) float, colors (n, 3) uint8 or None)``."""
    if is_tensor_geometry(pcd):
        p = pcd.point.positions.numpy().astype(np.float64)
        c = colors_to_uint8(pcd.point.colors.numpy()) if "colors" in pcd.point else None
        return p, c
    p = np.asarray(pcd.points, dtype=np.float64).copy()
    c = colors_to_uint8(np.asarray(pcd.colors)) if pcd.has_colors() else None
    return p, c


def from_pyvista(poly) -> tuple[np.ndarray, np.ndarray]:
    """A pyvista (or any VTK) surface as ``(vertices (n, 3) float, faces (f, 3) int)``.

    Polygons with more than three corners are triangulated first (pyvista's ``triangulate``).
    """
    # Plain import, not primkit.viz.backend.pyvista_module: nothing is rendered here, so the EGL
    # window choice that function makes does not apply (and io may not import viz).
    import pyvista as pv

    poly = pv.wrap(poly)
    if not isinstance(poly, pv.PolyData):
        poly = poly.extract_surface()
    if poly.n_cells and not poly.is_all_triangles:
        poly = poly.triangulate()
    faces = poly.faces.reshape(-1, 4)[:, 1:] if poly.faces.size else np.zeros((0, 3), np.int64)
    return np.asarray(poly.points, dtype=np.float64).copy(), faces.astype(np.int64)

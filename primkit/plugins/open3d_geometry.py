"""primkit on Open3D geometry, legacy or tensor, out as tensor geometry with a ``part`` attribute.

    import open3d as o3d
    from primkit.plugins import open3d_geometry as pk
    mesh = o3d.t.io.read_triangle_mesh("chair.ply")          # or o3d.io.read_triangle_mesh
    seg = pk.segment(mesh, model="chair")
    seg.geometry.triangle["part"]                             # (f,) int32: part index per face
    seat = seg.geometry.select_faces_by_mask(seg.geometry.triangle["part"] == 16)   # part kept
    o3d.visualization.draw([seg.geometry, seg.cuboid_edges])

A mesh comes back as an ``open3d.t.geometry.TriangleMesh`` with ``triangle["part"]`` and
``vertex["part"]`` (int32) and ``vertex["colors"]`` (float32, the part colour of each vertex); a point
cloud as an ``open3d.t.geometry.PointCloud`` with ``point["part"]`` and ``point["colors"]``. The
attributes travel through Open3D's own operations (``select_faces_by_mask``, ``select_by_mask``,
``select_by_index``). Cuboids come as tensor geometry too (:func:`primkit.viz.interop.cuboids_to_o3d_tensor`,
``triangle["part"]``; and the 12 edges of each as a ``LineSet`` with ``line["part"]``).

``options`` are those of :func:`primkit.abstract` (``up``, ``front``, ``align``, ``refine``, ...).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..viz.interop import (cuboids_to_o3d_tensor, cuboids_to_o3d_tensor_lineset, mesh_from_o3d, mesh_to_o3d_tensor,
                           points_from_o3d, points_to_o3d_tensor)
from ..viz.palette import part_colors
from .common import Labelled, label_shapes

__all__ = ["O3DSegmentation", "segment", "segment_all"]


@dataclass(frozen=True, eq=False)
class O3DSegmentation:
    """A shape co-segmented, as Open3D tensor geometry.

    Attributes
    ----------
    geometry : open3d.t.geometry.TriangleMesh or PointCloud
        The input's geometry with ``part`` (and ``colors``) attributes (see the module notes).
    cuboid_mesh : open3d.t.geometry.TriangleMesh
        The present cuboids, ``triangle["part"]``, ``vertex["colors"]``.
    cuboid_edges : open3d.t.geometry.LineSet
        Their 12 edges each, ``line["part"]``, ``line["colors"]``.
    labelled : primkit.plugins.common.Labelled
        The labels as NumPy arrays and the abstraction (``labelled.cuboids``, ``labelled.abstraction``).
    """

    geometry: object
    cuboid_mesh: object
    cuboid_edges: object
    labelled: Labelled

    @property
    def cuboids(self):
        """:class:`primkit.primitives.Cuboids` in the input's frame."""
        return self.labelled.cuboids

    @property
    def part_names(self) -> list:
        return self.labelled.part_names


def _is_mesh(geometry) -> bool:
    return type(geometry).__name__ == "TriangleMesh"


def _arrays(geometry):
    """``(vertices, faces)`` of a mesh or ``(n, 3)`` points of a cloud, either Open3D API."""
    kind = type(geometry).__name__
    if kind == "TriangleMesh":
        m = mesh_from_o3d(geometry)
        return (m.vertices, m.faces)
    if kind == "PointCloud":
        return points_from_o3d(geometry)[0]
    raise TypeError(f"expected an Open3D TriangleMesh or PointCloud (legacy or tensor), got {kind}")


def _to_tensor(shape, labelled: Labelled):
    """The tensor geometry of ``shape`` (arrays from :func:`_arrays`) with the labels of ``labelled``."""
    palette = np.vstack([part_colors(max(len(labelled.part_names), 1)), [[200, 200, 200]]]) / 255.0
    point_part = labelled.point_labels
    colours = palette[np.where(point_part < 0, -1, point_part)]
    if isinstance(shape, tuple):
        vertices, faces = shape
        return mesh_to_o3d_tensor(vertices, faces, vertex_attributes={"part": point_part, "colors": colours},
                                  triangle_attributes={"part": labelled.face_labels})
    return points_to_o3d_tensor(shape, attributes={"part": point_part, "colors": colours})


def segment_all(geometries, model="chair", **options) -> list[O3DSegmentation]:
    """:func:`segment` of several geometries, abstracted in one batch."""
    shapes = [_arrays(g) for g in geometries]
    out = []
    for shape, labelled in zip(shapes, label_shapes(shapes, model, **options)):
        out.append(O3DSegmentation(_to_tensor(shape, labelled), cuboids_to_o3d_tensor(labelled.cuboids),
                                   cuboids_to_o3d_tensor_lineset(labelled.cuboids), labelled))
    return out


def segment(geometry, model="chair", **options) -> O3DSegmentation:
    """Abstract and co-segment one Open3D mesh or point cloud (see the module notes)."""
    return segment_all([geometry], model, **options)[0]

"""primkit on Open3D geometry, legacy or tensor, out as tensor geometry with a ``part`` attribute.

    import open3d as o3d
    from primkit.plugins import open3d_geometry as pk
    mesh = o3d.t.io.read_triangle_mesh("chair.ply")          # or o3d.io.read_triangle_mesh
    seg = pk.segment_geometry(mesh, model="chair")
    seg.geometry.triangle["part"]                             # (f,) int32: part index per face
    seat = seg.geometry.select_faces_by_mask(seg.geometry.triangle["part"] == 16)   # part kept
    o3d.visualization.draw([seg.geometry, seg.cuboid_edges])
    pk.write("seg.npz", seg.geometry)                         # o3d.t.io.read_triangle_mesh keeps part

A mesh comes back as an ``open3d.t.geometry.TriangleMesh`` with ``triangle["part"]`` ((f,) int32),
``vertex["part"]`` ((n, 1) int32) and ``vertex["colors"]`` (float32, the part colour of each
vertex); a point cloud as an ``open3d.t.geometry.PointCloud`` with ``point["part"]`` ((n, 1) int32)
and ``point["colors"]``. The attributes travel through Open3D's own operations
(``select_faces_by_mask``, ``select_by_mask`` (with ``point["part"][:, 0] == k``),
``select_by_index``). When the model has a labeller (:mod:`primkit.segmentation.labeller`, the
bundled chair model's names ``back``, ``seat``, ``legs``, ``arms``), each face of a mesh also gets
its name, ``triangle["label"]`` ((f,) int32), and each point of a cloud ``point["label"]`` ((n, 1)
int32): indices into :attr:`O3DSegmentation.label_names` (-1: none), the labeller's names of the
elements as :func:`primkit.segmentation.labeller.label_elements` gives them (``labeller=None``
turns it off); :meth:`O3DSegmentation.label_colors` colours them with the label palette
(:func:`primkit.viz.palette.label_colors`). ``label`` travels and is written and read as ``part``
is (below); the names are not in the geometry. Cuboids come as tensor geometry too
(:func:`primkit.viz.interop.cuboids_to_o3d_tensor`, ``triangle["part"]``; and the 12 edges of each
as a ``LineSet`` with ``line["part"]``).

Files (measured with Open3D 0.20, ``tests/plugins/test_open3d_io.py``)
--------------------------------------------------------------------
Per-vertex and per-point attributes are ``(n, 1)`` because Open3D's writers need that shape: a
1-D ``point["part"]`` makes ``o3d.t.io.write_point_cloud`` fail on ``.ply`` and skip it on
``.pcd``, and a 1-D ``vertex["part"]`` makes ``o3d.t.io.read_triangle_mesh`` raise on the ``.npz``
it wrote. ``triangle["part"]`` stays 1-D, the mask ``select_faces_by_mask`` takes. What survives
``o3d.t.io`` write-and-read (:data:`KEEPS_PART`):

* point clouds: ``part`` survives ``.ply``, ``.pcd`` and ``.npz``; ``.xyz``, ``.xyzn``, ``.xyzrgb``
  and ``.pts`` drop it;
* meshes: only ``.npz`` keeps ``triangle["part"]``; Open3D's ``.npz`` reader drops
  ``vertex["part"]`` (it is in the file), and its ``.ply``, ``.obj``, ``.off``, ``.stl``,
  ``.glb``/``.gltf`` writers drop every custom attribute.

:func:`write` writes with Open3D where the format keeps ``part``, writes ``.ply`` meshes itself
(``part`` per vertex and per face as PLY properties, through trimesh; Open3D's reader reads the
same file's positions and colours but not ``part``), and elsewhere writes with Open3D after a
one-line warning that ``part`` is not kept. :func:`read` reads every file :func:`write` wrote with
its ``part`` attributes back.

``options`` are those of :func:`primkit.abstract` (``up``, ``front``, ``align``, ``refine``, ...).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..viz.interop import (cuboids_to_o3d_tensor, cuboids_to_o3d_tensor_lineset, is_tensor_geometry, mesh_from_o3d,
                           mesh_to_o3d_tensor, points_from_o3d, points_to_o3d_tensor)
from ..viz.palette import label_element_colors, part_colors
from .common import Labelled, label_shapes

__all__ = ["O3DSegmentation", "segment_geometry", "segment_all", "write", "read", "KEEPS_PART"]

#: The suffixes whose ``o3d.t.io`` round trip keeps ``part`` (see the module notes): per kind of geometry.
KEEPS_PART = {"TriangleMesh": (".npz",), "PointCloud": (".ply", ".pcd", ".npz")}


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

    With a labeller in the model, ``geometry`` also carries ``label`` (``triangle["label"]`` of a
    mesh, ``point["label"]`` of a cloud), indices into :attr:`label_names`.
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

    @property
    def label_names(self) -> list | None:
        """The labeller's names, which ``label`` indexes; None when the model has no labeller."""
        return self.labelled.label_names

    def label_colors(self) -> np.ndarray | None:
        """``(f, 3)`` (a mesh's faces) or ``(n, 3)`` (a cloud's points) float in [0, 1]: each
        element's label colour (:func:`primkit.viz.palette.label_element_colors`); None without a
        labeller. E.g. ``seg.geometry.point["colors"] = o3d.core.Tensor(seg.label_colors().astype("float32"))``."""
        if self.labelled.labels is None:
            return None
        return label_element_colors(self.labelled.labels, len(self.label_names)) / 255.0


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
    point_part = point_part.reshape(-1, 1)  # (n, 1): the shape Open3D's writers keep (module notes)
    named = None if labelled.labels is None else labelled.labels.astype(np.int32)
    if isinstance(shape, tuple):
        vertices, faces = shape
        triangle = {"part": labelled.face_labels} | ({} if named is None else {"label": named})
        return mesh_to_o3d_tensor(vertices, faces, vertex_attributes={"part": point_part, "colors": colours},
                                  triangle_attributes=triangle)
    point = {"part": point_part, "colors": colours} | ({} if named is None else {"label": named.reshape(-1, 1)})
    return points_to_o3d_tensor(shape, attributes=point)


def segment_all(geometries, model="chair", **options) -> list[O3DSegmentation]:
    """:func:`segment_geometry` of several geometries, abstracted in one batch."""
    shapes = [_arrays(g) for g in geometries]
    out = []
    for shape, labelled in zip(shapes, label_shapes(shapes, model, **options)):
        out.append(O3DSegmentation(_to_tensor(shape, labelled), cuboids_to_o3d_tensor(labelled.cuboids),
                                   cuboids_to_o3d_tensor_lineset(labelled.cuboids), labelled))
    return out


def segment_geometry(geometry, model="chair", **options) -> O3DSegmentation:
    """Abstract and co-segment one Open3D mesh or point cloud (see the module notes)."""
    return segment_all([geometry], model, **options)[0]


def _kind(geometry) -> str:
    kind = type(geometry).__name__
    if kind not in KEEPS_PART or not is_tensor_geometry(geometry):
        raise TypeError(f"expected an Open3D tensor TriangleMesh or PointCloud, got {type(geometry).__module__}.{kind}")
    return kind


def write(path, geometry, *, overwrite: bool = False):
    """Write Open3D tensor geometry (e.g. :attr:`O3DSegmentation.geometry`) so that ``part`` survives
    where the format can hold it (see the module notes); returns the path. Never replaces a file
    unless ``overwrite``; written atomically."""
    import warnings

    import open3d as o3d

    from .. import io

    path = Path(path)
    kind = _kind(geometry)
    if not overwrite and os.path.lexists(path):  # said to a library caller: no --force here
        raise FileExistsError(f"{path}: exists (pass overwrite=True to replace it)")
    suffix = path.suffix.lower()
    has_part = "part" in (geometry.triangle if kind == "TriangleMesh" else geometry.point) or \
        (kind == "TriangleMesh" and "part" in geometry.vertex)
    if kind == "TriangleMesh" and suffix == ".ply":
        return _write_mesh_ply(path, geometry, overwrite)
    if has_part and suffix not in KEEPS_PART[kind]:
        keep = ", ".join(KEEPS_PART[kind] + ((".ply (primkit's writer)",) if kind == "TriangleMesh" else ()))
        warnings.warn(f"{path}: Open3D's {suffix} keeps no 'part' attribute; written without it (keeps it: {keep})",
                      stacklevel=2)
    with io.atomic_output(path, overwrite=overwrite) as tmp:
        writer = o3d.t.io.write_triangle_mesh if kind == "TriangleMesh" else o3d.t.io.write_point_cloud
        if not writer(str(tmp), geometry):
            raise OSError(f"{path}: Open3D could not write this {kind}")
    return path


def _write_mesh_ply(path: Path, mesh, overwrite: bool) -> Path:
    """A binary PLY with ``part`` as an int property of each vertex and face (trimesh writes the
    attributes Open3D's PLY writer drops), and the vertex colours."""
    import trimesh

    from .. import io

    t = trimesh.Trimesh(mesh.vertex.positions.numpy(), mesh.triangle.indices.numpy(), process=False)
    if "colors" in mesh.vertex:
        t.visual.vertex_colors = np.clip(np.rint(mesh.vertex["colors"].numpy() * 255), 0, 255).astype(np.uint8)
    for name, attributes, store in (("vertex", mesh.vertex, t.vertex_attributes), ("face", mesh.triangle, t.face_attributes)):
        for key in ("part", "label"):
            if key in attributes:
                store[key] = attributes[key].numpy().reshape(-1).astype(np.int32)
    data = trimesh.exchange.ply.export_ply(t, encoding="binary", include_attributes=True)
    with io.atomic_output(path, overwrite=overwrite) as tmp:
        Path(tmp).write_bytes(data)
    return path


def read(path):
    """Read a file :func:`write` wrote as Open3D tensor geometry with its ``part`` attributes: Open3D's
    reader, plus what it leaves out (a mesh's ``part`` from primkit's ``.ply``, ``vertex["part"]``
    from an ``.npz``). A ``.ply`` or ``.npz`` without faces is a point cloud."""
    import open3d as o3d

    path = Path(path)
    suffix = path.suffix.lower()
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    mesh = o3d.t.io.read_triangle_mesh(str(path)) if suffix not in (".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts") else None
    if mesh is None or len(mesh.triangle.indices) == 0:
        return o3d.t.io.read_point_cloud(str(path))
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as stored:
            if "vertex_part" in stored.files:
                mesh.vertex["part"] = o3d.core.Tensor(stored["vertex_part"].reshape(-1, 1).astype(np.int32))
    elif suffix == ".ply":
        import trimesh

        # trimesh keeps every PLY property it parsed in metadata["_ply_raw"] (the only place it exposes
        # properties it has no name for); Open3D's tensor PLY reader keeps none for meshes
        raw = trimesh.load(path, process=False).metadata.get("_ply_raw", {})
        for element, attributes, shape in (("vertex", mesh.vertex, (-1, 1)), ("face", mesh.triangle, (-1,))):
            data = raw.get(element, {}).get("data")
            for key in ("part", "label"):
                if data is not None and data.dtype.names and key in data.dtype.names:
                    attributes[key] = o3d.core.Tensor(np.asarray(data[key]).reshape(shape).astype(np.int32))
    return mesh

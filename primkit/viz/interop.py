"""Conversions between primkit's NumPy values and the geometry of Open3D and pyvista.

primkit's own values are plain arrays (``(n, 3) float`` vertices, ``(f, 3) int`` faces,
:class:`primkit.primitives.Cuboids`); the viewers people already use hold their own objects. This
module is the one place that converts, both ways, so viewers and user scripts never copy arrays by
hand:

=================================  ===========================================  =====================
primkit                            Open3D                                       pyvista
=================================  ===========================================  =====================
``Cuboids`` (edges)                ``LineSet`` (:func:`cuboids_to_lineset`)     ``to_pyvista(c, edges=True)``
``Cuboids`` (solid)                ``TriangleMesh`` (:func:`cuboids_to_o3d`)    ``to_pyvista(c)``
``(vertices, faces[, colours])``   ``TriangleMesh`` (:func:`mesh_to_o3d`)       ``to_pyvista((v, f))``
``(n, 3)`` points [+ colours]      ``PointCloud`` (:func:`points_to_o3d`)       ``to_pyvista(points)``
``Cuboids`` one block per part                                                  :func:`to_pyvista_blocks`
=================================  ===========================================  =====================

and to Open3D's tensor geometry (``open3d.t.geometry``), whose named attributes carry the part
index through Open3D's own operations: :func:`mesh_to_o3d_tensor` (``triangle["part"]``),
:func:`points_to_o3d_tensor` (``point["part"]``), :func:`cuboids_to_o3d_tensor` and
:func:`cuboids_to_o3d_tensor_lineset`; the functions back take either API.

and back: :func:`mesh_from_o3d`, :func:`points_from_o3d`, :func:`from_pyvista` (defined in
:mod:`primkit.io.objects`, below the model, which takes such objects as input; the same functions).

Decisions:

* **Colours** are ``(k, 3) uint8`` on primkit's side (as :func:`primkit.viz.palette.part_colors`
  and :func:`primkit.io.write_mesh`) and float in [0, 1] on Open3D's side; conversions scale by 255
  and round.
* **Face colours in Open3D.** ``o3d.geometry.TriangleMesh`` has vertex colours only. A mesh with
  per-face colours (a segmentation) is converted with its vertices *unshared*: every face gets its
  own three vertices carrying the face's colour, so colours do not bleed across part boundaries
  (``3 f`` vertices; :func:`mesh_from_o3d` returns that unshared mesh).
* **Part index travels with the geometry.** pyvista objects carry ``cell_data["part"]`` (the slot
  of each triangle or edge, as :meth:`Cuboids.to_mesh`) and ``cell_data["rgb"]`` (its colour), so a
  picked cell tells which primitive it belongs to. Open3D's legacy geometry has no per-element
  integer field (the converters colour by part instead); its tensor geometry has, by name:
  ``triangle["part"]``, ``point["part"]``, ``line["part"]`` (int32).
* **pv.wrap-friendly.** :func:`to_pyvista` returns a ``pyvista.PolyData``, which is a
  ``vtkPolyData``: ``pv.wrap`` returns it unchanged and any VTK filter takes it.

Open3D and pyvista are imported inside the functions: importing this module costs nothing.
"""

from __future__ import annotations

import numpy as np

from ..io.objects import O3DMesh, colors_to_uint8, from_pyvista, is_tensor_geometry, mesh_from_o3d, points_from_o3d
from ..primitives import CORNER_SIGNS, Cuboids
from ..primitives.palette import part_colors
from .backend import pyvista_module
from .camera import CAMERA
from ..io import atomic_output

__all__ = [
    "cuboid_edges",
    "cuboids_to_lineset",
    "cuboids_to_o3d",
    "mesh_to_o3d",
    "mesh_from_o3d",
    "points_to_o3d",
    "points_from_o3d",
    "mesh_to_o3d_tensor",
    "points_to_o3d_tensor",
    "cuboids_to_o3d_tensor",
    "cuboids_to_o3d_tensor_lineset",
    "is_tensor_geometry",
    "to_pyvista",
    "to_pyvista_blocks",
    "from_pyvista",
    "O3DMesh",
    "draw",
]

# The 12 edges of a cuboid as pairs of corners (``CORNER_SIGNS`` order): corners that differ in
# exactly one sign. Derived, not typed in, so it cannot disagree with the corner layout.
_EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8)
                   if np.sum(CORNER_SIGNS[a] != CORNER_SIGNS[b]) == 1], dtype=np.int64)


def _check_colors(colors, count: int, what: str) -> np.ndarray:
    c = np.asarray(colors)
    if c.shape != (count, 3):
        raise ValueError(f"`{what}` must be ({count}, 3) uint8, got shape {c.shape}")
    if c.dtype.kind == "f":
        raise ValueError(f"`{what}` must be (k, 3) uint8 in 0..255, got float (multiply by 255 first)")
    return c.astype(np.uint8)


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"`vertices` must be (n, 3) float, got shape {v.shape}")
    if f.size == 0:
        f = f.reshape(0, 3)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"`faces` must be (f, 3) int, got shape {f.shape}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"`faces` index vertices 0..{len(v) - 1}, got {f.min()}..{f.max()}")
    return v, f


def _check_cuboids(cuboids) -> Cuboids:
    if not isinstance(cuboids, Cuboids):
        raise TypeError(f"expected primkit.primitives.Cuboids, got {type(cuboids).__name__}")
    return cuboids


# --------------------------------------------------------------------------------------------
# cuboids
# --------------------------------------------------------------------------------------------


def cuboid_edges(cuboids: Cuboids, include_absent: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edges of the cuboids as a line set.

    Returns
    -------
    points : (8 p, 3) float
        The corners of the ``p`` drawn cuboids, 8 each, in :meth:`Cuboids.to_mesh` order.
    lines : (12 p, 2) int
        Corner pairs, 12 edges per cuboid.
    part : (12 p,) int
        The part index (slot) of each edge.
    """
    c = _check_cuboids(cuboids)
    v, _, face_part = c.to_mesh(include_absent=include_absent)
    p = len(v) // 8
    lines = (_EDGES[None] + 8 * np.arange(p)[:, None, None]).reshape(-1, 2)
    idx = face_part[::12]  # to_mesh writes 12 triangles per cuboid, cuboid after cuboid
    return v, lines, np.repeat(idx, len(_EDGES))


def cuboids_to_lineset(cuboids: Cuboids, colors=None, include_absent: bool = False):
    """The cuboids' edges as an ``open3d.geometry.LineSet``, each edge coloured by its part.

    colors : (m, 3) uint8 or None
        One colour per part slot; default :func:`primkit.viz.palette.part_colors`.
    """
    import open3d as o3d

    c = _check_cuboids(cuboids)
    points, lines, part = cuboid_edges(c, include_absent)
    palette = part_colors(c.count) if colors is None else _check_colors(colors, c.count, "colors")
    ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(points), o3d.utility.Vector2iVector(lines.astype(np.int32)))
    ls.colors = o3d.utility.Vector3dVector(palette[part].astype(np.float64) / 255.0)
    return ls


def cuboids_to_o3d(cuboids: Cuboids, colors=None, include_absent: bool = False):
    """The cuboids as one ``open3d.geometry.TriangleMesh`` (8 vertices per cuboid, coloured by part).

    Each cuboid has its own 8 vertices, so vertex colours are exactly the part colours.
    """
    import open3d as o3d

    c = _check_cuboids(cuboids)
    v, f, part = c.to_mesh(include_absent=include_absent)
    palette = part_colors(c.count) if colors is None else _check_colors(colors, c.count, "colors")
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
    vertex_part = np.repeat(part[::12], 8)
    mesh.vertex_colors = o3d.utility.Vector3dVector(palette[vertex_part].astype(np.float64) / 255.0)
    mesh.compute_vertex_normals()
    return mesh


# --------------------------------------------------------------------------------------------
# meshes and points
# --------------------------------------------------------------------------------------------


def mesh_to_o3d(vertices, faces, *, vertex_colors=None, face_colors=None):
    """A triangle mesh as an ``open3d.geometry.TriangleMesh``.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (f, 3) int
    vertex_colors : (n, 3) uint8, optional
    face_colors : (f, 3) uint8, optional
        Per-face colours (e.g. a segmentation). Open3D colours vertices only, so the mesh is
        unshared: face ``i`` gets vertices ``3i, 3i+1, 3i+2`` (see the module notes).
    """
    import open3d as o3d

    v, f = _check_mesh(vertices, faces)
    if vertex_colors is not None and face_colors is not None:
        raise ValueError("give `vertex_colors` or `face_colors`, not both")
    vc = None
    if vertex_colors is not None:
        vc = _check_colors(vertex_colors, len(v), "vertex_colors")
    if face_colors is not None:
        fc = _check_colors(face_colors, len(f), "face_colors")
        v, f = v[f].reshape(-1, 3), np.arange(3 * len(f), dtype=np.int64).reshape(-1, 3)
        vc = np.repeat(fc, 3, axis=0)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
    if vc is not None:
        mesh.vertex_colors = o3d.utility.Vector3dVector(vc.astype(np.float64) / 255.0)
    mesh.compute_vertex_normals()
    return mesh


def points_to_o3d(points, colors=None, normals=None):
    """Points as an ``open3d.geometry.PointCloud``.

    points : (n, 3) float; colors : (n, 3) uint8, optional; normals : (n, 3) float, optional.
    """
    import open3d as o3d

    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"`points` must be (n, 3) float, got shape {p.shape}")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    if colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(_check_colors(colors, len(p), "colors").astype(np.float64) / 255.0)
    if normals is not None:
        nrm = np.asarray(normals, dtype=np.float64)
        if nrm.shape != p.shape:
            raise ValueError(f"`normals` must be {p.shape} float like `points`, got shape {nrm.shape}")
        pcd.normals = o3d.utility.Vector3dVector(nrm)
    return pcd


# --------------------------------------------------------------------------------------------
# Open3D tensor geometry (open3d.t.geometry): attributes by name
# --------------------------------------------------------------------------------------------


def _tensor(values, dtype=None):
    import open3d as o3d

    return o3d.core.Tensor(np.ascontiguousarray(values if dtype is None else np.asarray(values, dtype)))


def _check_attributes(attributes, count: int, what: str) -> dict:
    out = {}
    for name, values in (attributes or {}).items():
        a = np.asarray(values)
        if a.shape[:1] != (count,):
            raise ValueError(f"`{what}[{name!r}]` must have one row per {what.split('_')[0]} ({count}), got shape {a.shape}")
        out[name] = a.astype(np.int32) if a.dtype.kind in "iub" else a.astype(np.float32)
    return out


def mesh_to_o3d_tensor(vertices, faces, *, vertex_attributes=None, triangle_attributes=None):
    """A triangle mesh as an ``open3d.t.geometry.TriangleMesh`` with named attributes.

    Parameters
    ----------
    vertices : (n, 3) float; faces : (f, 3) int
    vertex_attributes : dict name -> (n, ...) array, optional (``mesh.vertex[name]``)
    triangle_attributes : dict name -> (f, ...) array, optional (``mesh.triangle[name]``), e.g.
        ``{"part": labels}``; integer arrays become int32 tensors, others float32.

    Positions are float32 and indices int32 (Open3D's defaults). Attributes travel with the faces
    through Open3D's own operations (``select_faces_by_mask``, ``select_by_index``).
    """
    import open3d as o3d

    v, f = _check_mesh(vertices, faces)
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = _tensor(v, np.float32)
    mesh.triangle.indices = _tensor(f, np.int32)
    for name, a in _check_attributes(vertex_attributes, len(v), "vertex_attributes").items():
        mesh.vertex[name] = _tensor(a)
    for name, a in _check_attributes(triangle_attributes, len(f), "triangle_attributes").items():
        mesh.triangle[name] = _tensor(a)
    return mesh


def points_to_o3d_tensor(points, *, attributes=None):
    """Points as an ``open3d.t.geometry.PointCloud`` with named attributes (``pcd.point[name]``,
    one row per point; e.g. ``{"part": labels}``, integers as int32, others float32)."""
    import open3d as o3d

    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"`points` must be (n, 3) float, got shape {p.shape}")
    pcd = o3d.t.geometry.PointCloud(_tensor(p, np.float32))
    for name, a in _check_attributes(attributes, len(p), "point_attributes").items():
        pcd.point[name] = _tensor(a)
    return pcd


def cuboids_to_o3d_tensor(cuboids: Cuboids, colors=None, include_absent: bool = False):
    """The cuboids as one ``open3d.t.geometry.TriangleMesh``: 8 vertices and 12 triangles per cuboid,
    ``triangle["part"]`` (int32 slot per triangle), ``vertex["part"]`` and ``vertex["colors"]``
    (float32 in [0, 1], the part's colour; each cuboid has its own vertices)."""
    c = _check_cuboids(cuboids)
    v, f, part = c.to_mesh(include_absent=include_absent)
    palette = part_colors(c.count) if colors is None else _check_colors(colors, c.count, "colors")
    vertex_part = np.repeat(part[::12], 8)
    return mesh_to_o3d_tensor(v, f, vertex_attributes={"part": vertex_part, "colors": palette[vertex_part] / 255.0},
                              triangle_attributes={"part": part})


def cuboids_to_o3d_tensor_lineset(cuboids: Cuboids, colors=None, include_absent: bool = False):
    """The cuboids' 12 edges each as an ``open3d.t.geometry.LineSet`` with ``line["part"]`` (int32)
    and ``line["colors"]`` (float32 in [0, 1])."""
    import open3d as o3d

    c = _check_cuboids(cuboids)
    points, lines, part = cuboid_edges(c, include_absent)
    palette = part_colors(c.count) if colors is None else _check_colors(colors, c.count, "colors")
    ls = o3d.t.geometry.LineSet()
    ls.point.positions = _tensor(points, np.float32)
    ls.line.indices = _tensor(lines, np.int32)
    ls.line["part"] = _tensor(part, np.int32)
    ls.line["colors"] = _tensor(palette[part] / 255.0, np.float32)
    return ls


# --------------------------------------------------------------------------------------------
# pyvista
# --------------------------------------------------------------------------------------------


def _faces_to_cells(faces: np.ndarray) -> np.ndarray:
    return np.hstack([np.full((len(faces), 1), 3, dtype=np.int64), faces]).ravel()


def to_pyvista(obj, *, colors=None, face_colors=None, edges: bool = False, include_absent: bool = False):
    """A ``pyvista.PolyData`` for primkit values and Open3D geometry.

    Parameters
    ----------
    obj : one of
        * :class:`~primkit.primitives.Cuboids`: the solid cuboids (or their edges with ``edges=True``)
          with ``cell_data["part"]`` (slot per triangle or edge) and ``cell_data["rgb"]``
          (``colors`` per slot, default :func:`primkit.viz.palette.part_colors`);
        * ``(vertices, faces)``, a :class:`primkit.io.Mesh` or anything with ``.vertices`` and
          ``.faces``: a triangle mesh (``face_colors`` (f, 3) uint8 become ``cell_data["rgb"]``);
        * ``(n, 3)`` points: a point cloud (``colors`` (n, 3) uint8 become ``point_data["rgb"]``);
        * an Open3D ``TriangleMesh``, ``PointCloud`` or ``LineSet`` (colours kept as ``rgb``).

    Returns
    -------
    pyvista.PolyData
        Draw colours with ``plotter.add_mesh(poly, scalars="rgb", rgb=True)``.
    """
    pv = pyvista_module()
    if isinstance(obj, Cuboids):
        palette = part_colors(obj.count) if colors is None else _check_colors(colors, obj.count, "colors")
        if edges:
            pts, lines, part = cuboid_edges(obj, include_absent)
            poly = pv.PolyData(pts, lines=np.hstack([np.full((len(lines), 1), 2), lines]).ravel())
        else:
            v, f, part = obj.to_mesh(include_absent=include_absent)
            poly = pv.PolyData(v, _faces_to_cells(f)) if len(f) else pv.PolyData()
        if poly.n_cells:
            poly.cell_data["part"] = part
            poly.cell_data["rgb"] = palette[part]
        return poly
    kind = type(obj).__module__.split(".")[0]
    if kind == "open3d":
        name = type(obj).__name__
        if name == "TriangleMesh":
            m = mesh_from_o3d(obj)
            return to_pyvista((m.vertices, m.faces), face_colors=m.face_colors) if m.vertex_colors is None or m.face_colors is not None \
                else _with_point_rgb(to_pyvista((m.vertices, m.faces)), m.vertex_colors)
        if name == "PointCloud":
            p, c = points_from_o3d(obj)
            return to_pyvista(p, colors=c)
        if name == "LineSet":
            if is_tensor_geometry(obj):
                pts = obj.point.positions.numpy().astype(np.float64)
                lines = obj.line.indices.numpy().astype(np.int64).reshape(-1, 2)
                colors = obj.line.colors.numpy() if "colors" in obj.line else None
            else:
                pts = np.asarray(obj.points, dtype=np.float64)
                lines = np.asarray(obj.lines, dtype=np.int64).reshape(-1, 2)
                colors = np.asarray(obj.colors) if obj.has_colors() else None
            poly = pv.PolyData(pts, lines=np.hstack([np.full((len(lines), 1), 2), lines]).ravel())
            if colors is not None:
                poly.cell_data["rgb"] = colors_to_uint8(colors)
            if is_tensor_geometry(obj) and "part" in obj.line:
                poly.cell_data["part"] = obj.line["part"].numpy().astype(np.int64).ravel()
            return poly
        raise TypeError(f"cannot convert open3d {name} to pyvista")
    if hasattr(obj, "vertices") and hasattr(obj, "faces"):
        obj = (obj.vertices, obj.faces)
    if isinstance(obj, tuple) and len(obj) == 2:
        v, f = _check_mesh(*obj)
        poly = pv.PolyData(v, _faces_to_cells(f)) if len(f) else pv.PolyData(v)
        if face_colors is not None:
            poly.cell_data["rgb"] = _check_colors(face_colors, len(f), "face_colors")
        return poly
    p = np.asarray(obj, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise TypeError("expected Cuboids, (vertices, faces), a mesh, (n, 3) points or open3d geometry")
    poly = pv.PolyData(p)
    if colors is not None:
        poly.point_data["rgb"] = _check_colors(colors, len(p), "colors")
    return poly


def _with_point_rgb(poly, colors):
    poly.point_data["rgb"] = colors
    return poly


def to_pyvista_blocks(cuboids: Cuboids, names=None, *, colors=None, edges: bool = False):
    """The present cuboids as a ``pyvista.MultiBlock``, one block per part, in slot order.

    Block ``"<k> <name>"`` is :func:`to_pyvista` of cuboid ``k`` alone (solid, or its 12 edges with
    ``edges=True``, with ``cell_data["part"]`` and ``cell_data["rgb"]``) and carries
    ``field_data["part"]`` (``[k]``) and ``field_data["part_name"]`` (``[name]``).
    ``names``: one per slot (default ``part<k>``).
    """
    pv = pyvista_module()
    c = _check_cuboids(cuboids)
    from ..model.parts import default_part_names  # here: reading files through pyvista must not load primkit.model

    names = list(names) if names is not None else default_part_names(c.count)
    if len(names) < c.count:
        raise ValueError(f"`names` must have one name per part slot ({c.count}), got {len(names)}")
    palette = part_colors(c.count) if colors is None else _check_colors(colors, c.count, "colors")
    blocks = pv.MultiBlock()
    for k in c.present:
        poly = to_pyvista(c.with_existence(np.arange(c.count) == k), colors=palette, edges=edges)
        poly.field_data["part"] = np.array([int(k)])
        poly.field_data["part_name"] = np.array([str(names[k])])
        blocks.append(poly, f"{int(k)} {names[k]}")
    return blocks


# --------------------------------------------------------------------------------------------
# draw
# --------------------------------------------------------------------------------------------


def _as_o3d(obj):
    """Open3D geometry for one of the things :func:`draw` accepts (a list when it makes several)."""
    if is_tensor_geometry(obj):
        return [obj.to_legacy()]  # the legacy Visualizer draws legacy geometry
    if type(obj).__module__.split(".")[0] == "open3d":
        return [obj]
    if isinstance(obj, Cuboids):
        return [cuboids_to_o3d(obj), cuboids_to_lineset(obj)]
    if hasattr(obj, "cuboids") and isinstance(getattr(obj, "cuboids"), Cuboids):  # AbstractionResult
        return _as_o3d(obj.cuboids)
    if hasattr(obj, "vertices") and hasattr(obj, "faces"):
        return [mesh_to_o3d(obj.vertices, obj.faces)]
    if isinstance(obj, tuple) and len(obj) == 2:
        return [mesh_to_o3d(*obj)]
    return [points_to_o3d(obj)]


def _set_view(control, geoms) -> None:
    """Look from :data:`primkit.viz.camera.CAMERA`'s direction (front-right-above, +Y up) at the geometry."""
    lo = np.min([g.get_min_bound() for g in geoms], axis=0)
    hi = np.max([g.get_max_bound() for g in geoms], axis=0)
    control.set_lookat((lo + hi) / 2)
    control.set_front(np.asarray(CAMERA.direction, float) / np.linalg.norm(CAMERA.direction))
    control.set_up(CAMERA.up)
    control.set_zoom(0.8)


def draw(*objects, png=None, window_size: tuple[int, int] = (800, 600), title: str = "primkit"):
    """Show primkit values (or Open3D geometry) in Open3D's viewer, or write a PNG without a window.

    Parameters
    ----------
    *objects : Cuboids, AbstractionResult, (vertices, faces), primkit.io.Mesh, (n, 3) points or
        Open3D geometry; cuboids are drawn as coloured solids with their edges.
    png : path, optional
        Write a picture instead of opening a window (Open3D's legacy ``Visualizer`` with an
        invisible window; works off screen through EGL as well as under X). The newer
        ``OffscreenRenderer`` is avoided: it needs Vulkan and took seconds per frame on CPU. The
        picture is taken from the camera direction of :data:`primkit.viz.camera.CAMERA`.

    Returns
    -------
    list of the Open3D geometries drawn.
    """
    import open3d as o3d

    geoms = [g for obj in objects for g in _as_o3d(obj)]
    if png is None:
        o3d.visualization.draw_geometries(geoms, window_name=title, width=window_size[0], height=window_size[1])
        return geoms

    vis = o3d.visualization.Visualizer()
    if not vis.create_window(window_name=title, width=window_size[0], height=window_size[1], visible=False):
        raise RuntimeError("Open3D could not create an off-screen window (no EGL or X display)")
    try:
        for g in geoms:
            vis.add_geometry(g)
        vis.get_render_option().mesh_show_back_face = True
        _set_view(vis.get_view_control(), geoms)
        vis.poll_events()
        vis.update_renderer()
        with atomic_output(png, overwrite=True) as tmp:
            vis.capture_screen_image(str(tmp), do_render=True)
    finally:
        vis.destroy_window()
    return geoms

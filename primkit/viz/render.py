"""Pictures of shapes and their abstractions (pyvista, off screen; no display needed).

What the rest of primkit uses:

* :func:`write_png` (the helper behind every ``--png`` option): a grid of :class:`Tile` s, each a
  title and a few :class:`Layer` s (a mesh, coloured faces, cuboids, points), into one PNG.
* :class:`ThumbnailRenderer`: one off-screen plotter reused for many single-tile pictures
  (thumbnails of a collection; ``benchmarks/bench_render.py`` measures what reuse buys).
* :func:`render_pairs` / :func:`render_abstractions`: each shape beside its cuboids (the demo and
  the bundled-model build script).

The camera is :data:`primkit.viz.camera.CAMERA` (the convention is written there).

"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io import atomic_output
from .backend import pyvista_module
from .camera import CAMERA, Camera, apply_camera
from .interop import to_pyvista
from .palette import part_colors

__all__ = [
    "write_image",
    "Layer",
    "Tile",
    "mesh_layer",
    "cuboid_layer",
    "segmentation_layer",
    "points_layer",
    "point_segmentation_layer",
    "render_tiles",
    "write_png",
    "ThumbnailRenderer",
    "render_pairs",
    "render_abstractions",
]


@dataclass
class Layer:
    """One thing drawn in a tile.

    vertices : (n, 3) float; faces : (f, 3) int or None (None: points);
    face_colors : (f, 3) uint8 or None (per-face colours, e.g. parts); point_colors : (n, 3) uint8
    or None (per-point colours of a point layer); color : a single colour otherwise; opacity in
    [0, 1]; edges : draw the creases (edges between faces meeting at more than 30 degrees, and open
    borders) in black.
    """

    vertices: np.ndarray
    faces: np.ndarray | None = None
    face_colors: np.ndarray | None = None
    color: str = "lightgrey"
    opacity: float = 1.0
    edges: bool = False
    point_size: float = 4.0
    point_colors: np.ndarray | None = None

    def bounds(self) -> np.ndarray:
        """(2, 3) float: ``[min, max]`` of the vertices."""
        v = np.asarray(self.vertices, float)
        return np.stack([v.min(0), v.max(0)])

    def to_pyvista(self):
        if self.faces is None:
            return to_pyvista(np.asarray(self.vertices, float), colors=self.point_colors)
        return to_pyvista((self.vertices, self.faces), face_colors=self.face_colors)

    def add_to(self, plotter, **kwargs):
        """Add this layer to ``plotter``; returns the actor."""
        poly = self.to_pyvista()
        if self.faces is None:
            colour = dict(scalars="rgb", rgb=True) if self.point_colors is not None else dict(color=self.color)
            return plotter.add_mesh(poly, **colour, point_size=self.point_size, render_points_as_spheres=True,
                                    opacity=self.opacity, reset_camera=False, **kwargs)
        style = dict(opacity=self.opacity, smooth_shading=False, reset_camera=False)
        if self.face_colors is not None:
            actor = plotter.add_mesh(poly, scalars="rgb", rgb=True, **style, **kwargs)
        else:
            actor = plotter.add_mesh(poly, color=self.color, **style, **kwargs)
        if self.edges and self.opacity > 0:
            # creases only (30 degrees): a cuboid shows its 12 edges, not its triangles' diagonals
            creases = poly.extract_feature_edges(feature_angle=30, boundary_edges=True, non_manifold_edges=False,
                                                 manifold_edges=False)
            if creases.n_cells:
                plotter.add_mesh(creases, color="black", line_width=1.0, opacity=self.opacity, reset_camera=False)
        return actor


@dataclass
class Tile:
    """One picture in a grid: a title and its layers, framed together.

    frame : (2, 3) float or None
        The box the camera frames (``[min, max]``); None: the box around every layer.
    """

    title: str
    layers: list = field(default_factory=list)
    frame: np.ndarray | None = None

    def __post_init__(self):
        # a shape named after a file name that is not UTF-8 (os.fsdecode's surrogates): U+FFFD
        # for its undecodable bytes, which the text renderers can draw
        self.title = str(self.title).encode("utf-8", "surrogateescape").decode("utf-8", "replace")

    def bounds(self) -> np.ndarray:
        """(2, 3) float: the framed box."""
        if self.frame is not None:
            return np.asarray(self.frame, float)
        b = np.stack([layer.bounds() for layer in self.layers])
        return np.stack([b[:, 0].min(0), b[:, 1].max(0)])


def mesh_layer(vertices, faces, face_colors=None, **kwargs) -> Layer:
    """A mesh, plain grey or with (f, 3) uint8 face colours."""
    return Layer(np.asarray(vertices, float), np.asarray(faces, np.int64),
                 None if face_colors is None else np.asarray(face_colors, np.uint8), **kwargs)


def cuboid_layer(cuboids, colors=None, **kwargs) -> Layer:
    """The present cuboids coloured by part index (``colors`` (m, 3) uint8, default
    :func:`primkit.viz.palette.part_colors`), edges drawn."""
    v, f, part = cuboids.to_mesh()
    palette = part_colors(cuboids.count) if colors is None else np.asarray(colors, np.uint8)
    kwargs.setdefault("edges", True)
    return Layer(v, f, palette[part], **kwargs)


def segmentation_layer(vertices, faces, labels, count: int | None = None, **kwargs) -> Layer:
    """A mesh coloured by a part index per face (``labels`` (f,) int; -1 or out of range: grey),
    with the same colours as the cuboids of those indices."""
    labels = np.asarray(labels, np.int64)
    count = int(max(count or 0, labels.max(initial=-1) + 1))
    palette = np.vstack([part_colors(max(count, 1)), [[200, 200, 200]]]).astype(np.uint8)
    return mesh_layer(vertices, faces, palette[np.where(labels < 0, -1, labels)], **kwargs)


def points_layer(points, colors=None, **kwargs) -> Layer:
    """Points, one colour (``color=``) or ``colors`` (n, 3) uint8 per point."""
    return Layer(np.asarray(points, float), None, point_colors=None if colors is None else np.asarray(colors, np.uint8),
                 **kwargs)


def point_segmentation_layer(points, labels, count: int | None = None, **kwargs) -> Layer:
    """Points coloured by a part index each (``labels`` (n,) int; -1: grey), the cuboids' colours."""
    labels = np.asarray(labels, np.int64)
    count = int(max(count or 0, labels.max(initial=-1) + 1))
    palette = np.vstack([part_colors(max(count, 1)), [[200, 200, 200]]]).astype(np.uint8)
    return points_layer(points, palette[np.where(labels < 0, -1, labels)], **kwargs)


def _grid(n: int, columns: int) -> tuple[int, int]:
    cols = max(1, min(columns, n))
    return int(np.ceil(n / cols)), cols


def _common_radius(tiles, radius) -> float:
    if radius is not None:
        return float(radius)
    return max(0.5 * float(np.linalg.norm(np.diff(t.bounds(), axis=0))) for t in tiles)


def render_tiles(tiles, *, columns: int = 4, tile: int = 260, camera: Camera = CAMERA, radius: float | None = None,
                 background: str = "white", font_size: int = 8) -> np.ndarray:
    """Render tiles in a grid (row by row) and return the picture.

    Parameters
    ----------
    tiles : list of Tile
    columns : tiles per row; tile : pixel size of one square tile.
    radius : float or None
        The common scale (see the module notes); None: the largest bounding-sphere radius.

    Returns
    -------
    image : (rows * tile, cols * tile, 3) uint8
    """
    pv = pyvista_module()
    tiles = [t for t in tiles]
    if not tiles or any(not t.layers for t in tiles):
        raise ValueError("every tile needs at least one layer")
    rows, cols = _grid(len(tiles), columns)
    r = _common_radius(tiles, radius)
    plotter = pv.Plotter(off_screen=True, shape=(rows, cols), window_size=(tile * cols, tile * rows), border=False)
    try:
        plotter.set_background(background)
        for i, t in enumerate(tiles):
            plotter.subplot(*divmod(i, cols))
            for layer in t.layers:
                layer.add_to(plotter)
            if t.title:
                plotter.add_text(t.title, position=(0.03, 0.9), viewport=True, font_size=font_size, color="black")
            apply_camera(plotter, t.bounds().mean(0), r, camera)
        return np.asarray(plotter.screenshot(return_img=True))[..., :3].copy()
    finally:
        plotter.close()


def _save_image(image: np.ndarray, path, overwrite: bool) -> None:
    from PIL import Image

    with atomic_output(path, overwrite=overwrite) as tmp:
        Image.fromarray(image).save(tmp, format="PNG", optimize=True)


def write_image(path, image: np.ndarray, *, overwrite: bool = False) -> Path:
    """Write a rendered picture (``(h, w, 3) uint8``) as a PNG, atomically; an existing file is kept
    unless ``overwrite``. Returns the path."""
    _save_image(np.asarray(image, np.uint8), path, overwrite)
    return Path(path)


def write_png(path, tiles, *, overwrite: bool = False, **kwargs):
    """Render ``tiles`` (see :func:`render_tiles`, same keywords) into the PNG ``path``, atomically;
    an existing file is kept unless ``overwrite``. Returns the path."""
    _save_image(render_tiles(tiles, **kwargs), path, overwrite)
    return Path(path)


class ThumbnailRenderer:
    """One off-screen plotter reused for many single-tile pictures.

    Creating a plotter (an OpenGL context) costs far more than drawing a small mesh; a collection's
    thumbnails go through one plotter whose actors are cleared between shapes.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, size: int = 260, camera: Camera = CAMERA, radius: float | None = None,
                 background: str = "white", font_size: int = 8):
        pv = pyvista_module()
        self.size, self.camera, self.radius, self.font_size = size, camera, radius, font_size
        self.plotter = pv.Plotter(off_screen=True, window_size=(size, size), border=False)
        self.plotter.set_background(background)

    def render(self, tile: Tile, path=None, *, radius: float | None = None, overwrite: bool = False,
               transparent: bool = False) -> np.ndarray:
        """The picture of one tile, (size, size, 3) uint8 ((size, size, 4) RGBA with a transparent
        background when ``transparent``); also written to ``path`` when given.
        ``radius`` (or the renderer's) fixes the scale; None frames the tile alone."""
        p = self.plotter
        p.clear_actors()
        for layer in tile.layers:
            layer.add_to(p)
        if tile.title:
            p.add_text(tile.title, position=(0.03, 0.9), viewport=True, font_size=self.font_size, color="black",
                       name="title")
        r = _common_radius([tile], radius if radius is not None else self.radius)
        apply_camera(p, tile.bounds().mean(0), r, self.camera)
        p.render()  # after the first picture, screenshot() alone returns the last frame drawn
        image = np.asarray(p.screenshot(return_img=True, transparent_background=transparent))
        image = image.copy() if transparent else image[..., :3].copy()
        if path is not None:
            _save_image(image, path, overwrite)
        return image

    def close(self) -> None:
        self.plotter.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def render_pairs(items, path, *, tile: int = 260, columns: int = 4) -> None:
    """Draw each shape beside its cuboids, in a grid of tiles, into a PNG (replaced if it exists).

    Parameters
    ----------
    items : list of (title, (vertices, faces), (vertices, faces, face_colors))
        The shape mesh and the cuboid mesh with ``(f, 3) uint8`` colours, in the same frame.
    path : path of the PNG to write (atomically).

    Both tiles of a pair share the pair's focal point (the shape's box centre) and all tiles share
    one scale (:data:`CAMERA` convention), so shapes of a collection line up.
    """
    tiles = []
    for title, (sv, sf), (cv, cf, cc) in items:
        shape = mesh_layer(sv, sf)
        tiles.append(Tile(title, [shape]))
        tiles.append(Tile("", [mesh_layer(cv, cf, cc, edges=True)], frame=shape.bounds()))
    write_png(path, tiles, columns=2 * min(columns, max(1, len(items))), tile=tile, overwrite=True)


def render_abstractions(results, meshes, path, *, canonical: bool = False, note: str = "", **kwargs) -> None:
    """Draw abstraction results beside their shapes, cuboids coloured by part index (one colour per index).

    Parameters
    ----------
    results : list of primkit.model.abstractor.AbstractionResult
    meshes : list of (vertices, faces)
        Each result's shape in the input's frame.
    canonical : bool
        Draw in the model's canonical frame (upright, front toward +X) instead of the input's.
    note : str
        Appended to each tile's title.
    """
    items = []
    for r, (v, f) in zip(results, meshes):
        cub = r.canonical if canonical else r.cuboids
        if canonical:
            v = r.frame.to_canonical(v)
        cv, cf, part = cub.to_mesh()
        items.append((f"{r.name[:12]}: {int(cub.existence.sum())} parts{note}", (v, f), (cv, cf, part_colors(cub.count)[part])))
    render_pairs(items, path, **kwargs)

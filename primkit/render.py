"""Pictures of shapes and their abstractions (pyvista, off screen; no display needed).

The vtk wheel renders through EGL (Mesa) when there is no X display; we ask for EGL directly so it
does not first try (and warn about) an X server.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["render_pairs", "render_abstractions"]


def _pyvista():
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    return pv


def _polydata(pv, vertices, faces):
    faces = np.asarray(faces, np.int64)
    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    return pv.PolyData(np.asarray(vertices, float), cells)


def render_pairs(items, path, *, tile: int = 260, columns: int = 4) -> None:
    """Draw each shape beside its cuboids, in a grid of tiles, into a PNG.

    Parameters
    ----------
    items : list of (title, (vertices, faces), (vertices, faces, face_colors))
        The shape mesh and the cuboid mesh with ``(f, 3) uint8`` colours, in the same frame.
    path : path of the PNG to write (atomically).
    """
    from .io import atomic_output

    pv = _pyvista()
    n = len(items)
    cols = min(columns, n) * 2
    rows = int(np.ceil(n / max(1, cols // 2)))
    plotter = pv.Plotter(off_screen=True, shape=(rows, cols), window_size=(tile * cols, tile * rows), border=False)
    for i, (title, (sv, sf), (cv, cf, cc)) in enumerate(items):
        r, c = divmod(i, cols // 2)
        plotter.subplot(r, 2 * c)
        plotter.add_mesh(_polydata(pv, sv, sf), color="lightgrey", smooth_shading=False)
        plotter.add_text(title, font_size=8)
        plotter.view_vector((1.0, 0.6, 1.2), viewup=(0, 1, 0))
        plotter.subplot(r, 2 * c + 1)
        mesh = _polydata(pv, cv, cf)
        mesh.cell_data["rgb"] = np.asarray(cc, np.uint8)
        plotter.add_mesh(mesh, scalars="rgb", rgb=True, show_edges=True, edge_color="black", line_width=0.5)
        plotter.view_vector((1.0, 0.6, 1.2), viewup=(0, 1, 0))
        # each shape and its cuboids share one camera, framed on the shape; pairs differ in size
        plotter.subplot(r, 2 * c)
        plotter.reset_camera()
        first = r * cols + 2 * c
        plotter.link_views((first, first + 1))
    with atomic_output(path, overwrite=True) as tmp:
        plotter.screenshot(str(tmp))
    plotter.close()


def render_abstractions(results, meshes, path, *, canonical: bool = False, note: str = "", **kwargs) -> None:
    """Draw abstraction results beside their shapes, cuboids coloured by part index (one colour per index).

    Parameters
    ----------
    results : list of primkit.abstractor.AbstractionResult
    meshes : list of (vertices, faces)
        Each result's shape in the input's frame.
    canonical : bool
        Draw in the model's canonical frame (upright, front toward +X) instead of the input's.
    note : str
        Appended to each tile's title.
    """
    from .abstractor import part_colors

    items = []
    for r, (v, f) in zip(results, meshes):
        cub = r.canonical if canonical else r.cuboids
        if canonical:
            v = r.frame.to_canonical(v)
        cv, cf, part = cub.to_mesh()
        items.append((f"{r.name[:12]}: {int(cub.existence.sum())} parts{note}", (v, f), (cv, cf, part_colors(cub.count)[part])))
    render_pairs(items, path, **kwargs)

"""3D scenes for web pages, drawn by plotly.js, that open without a network.

:func:`scene_figure` lays shapes out as pairs, each segmented surface beside its cuboids (solid,
with their 12 edges), and returns a plotly figure as plain JSON-ready dicts; :func:`figure_div` and
:func:`figure_script` (or :func:`figure_html`, both at once) embed a figure and the plotly.js library
in HTML that needs nothing else.

Why plotly.js: it is a maintained WebGL renderer (lighting, depth, orthographic cameras, legends
that toggle traces, hover, menus), MIT licensed, and its minified library already comes with the
installed stack (the ``plotly`` Python package, which Open3D's dependencies bring too), so the page
can inline it and open offline. The library is large (about 4.8 MB) but needs no build step;
three.js is smaller (about 0.7 MB) but would need vendoring its file into this repository and
writing our own lighting, picking, menus and legend.

Conventions:

* **Camera**: :data:`primkit.viz.camera.CAMERA`'s direction and up vector, orthographic projection,
  as every primkit picture.
* **Layout**: shape ``i`` sits at cell ``(row, 2 col)`` of a grid in the plane spanned by the screen's
  right direction (flattened onto the floor) and +Y, its cuboids at ``(row, 2 col + 1)``, so that no
  shape hides another; :func:`scene_offsets` gives the translations.
* **Traces** are grouped by part index: the surface faces labelled ``k`` on every shape, the cuboid
  ``k`` of every shape and its edges share the legend entry ``legendgroup="part<k>"``; clicking it
  toggles part ``k`` everywhere. Every trace carries ``meta = {"shape": i, "part": k, "kind": ...}``.
  With ``label_names`` (a labeller's names) the surfaces are grouped by name instead: the faces
  named ``j`` on every shape share ``legendgroup="label<j>"``, coloured as every picture by name
  (:func:`primkit.viz.palette.label_colors`, :data:`~primkit.viz.palette.UNLABELLED` for none), with
  ``meta = {"shape": i, "label": j, "kind": "surface"}``, listed before the cuboids' parts.
* **Arrays** are JSON number lists, coordinates rounded to 1e-4 (plotly's base64 typed arrays were
  measured no smaller and no faster to load for these scenes: 5.53 MB and 3.94 s against 5.50 MB
  and 3.97 s for a page of 8 chairs).
* **Safe inline JSON**: :func:`figure_json` is plotly's own encoder, which writes ``<``, ``>`` and
  ``/`` as ``\\uXXXX`` escapes (and non-ASCII, the JavaScript line separators included), so no string
  of the data (a shape named ``<!--<script>``) can end or change the script element that holds it;
  names shown by plotly are HTML-escaped as well (plotly decodes entities).
"""

from __future__ import annotations

import html
import json

import numpy as np

from .camera import CAMERA, Camera
from .interop import cuboid_edges
from .palette import UNLABELLED, label_colors, part_colors

__all__ = ["figure_json", "plotly_js", "scene_offsets", "scene_figure", "figure_div", "figure_script", "figure_html",
           "GREY"]

#: Colour of surface faces with no part (label -1).
GREY = (200, 200, 200)

_CELL = 1.15  # grid pitch of the layout, in units of the canonical cube's side
_ROW = 1.35


def figure_json(figure: dict) -> str:
    """A figure as JSON that can sit inside an HTML ``<script>`` element (plotly's encoder: NumPy
    arrays become lists; ``<``, ``>``, ``/`` and non-ASCII characters are ``\\uXXXX`` escapes)."""
    import plotly.io

    return plotly.io.to_json(figure, validate=False, pretty=False)


def plotly_js() -> str:
    """The minified plotly.js shipped inside the ``plotly`` Python package."""
    from plotly.offline import get_plotlyjs

    return get_plotlyjs()


def scene_offsets(count: int, camera: Camera = CAMERA) -> tuple[np.ndarray, np.ndarray, int]:
    """Where each shape and its cuboids go (see the module notes).

    Returns ``(shape_offsets (count, 3) float, cuboid_offsets (count, 3) float, shapes_per_row)``.
    """
    _, _, right = camera.basis()
    flat = np.array([right[0], 0.0, right[2]])
    flat = flat / np.linalg.norm(flat) if np.linalg.norm(flat) > 1e-9 else np.array([1.0, 0.0, 0.0])
    per_row = max(1, min(count, int(np.ceil(np.sqrt(2 * count)))))
    i = np.arange(count)
    row, col = i // per_row, i % per_row
    up = np.asarray(camera.up, float)
    shapes = (2 * col * _CELL)[:, None] * flat + (-row * _ROW)[:, None] * up
    return shapes, shapes + _CELL * flat, per_row


def _rgb(c) -> str:
    return f"rgb({int(c[0])},{int(c[1])},{int(c[2])})"


def _mesh_trace(vertices, faces, color, **extra) -> dict:
    used, inverse = np.unique(np.asarray(faces, np.int64).ravel(), return_inverse=True)
    v = np.asarray(vertices, float)[used]
    f = inverse.reshape(-1, 3)
    v = np.round(v, 4)
    return {"type": "mesh3d", "x": v[:, 0], "y": v[:, 1], "z": v[:, 2], "i": f[:, 0], "j": f[:, 1], "k": f[:, 2],
            "color": _rgb(color), "flatshading": True,
            "lighting": {"ambient": 0.78, "diffuse": 0.22, "specular": 0.0, "roughness": 1.0, "fresnel": 0.0},
            "lightposition": {"x": 1000, "y": 2000, "z": 1500}, **extra}


def _edges_trace(points, lines, **extra) -> dict:
    xyz = [[], [], []]
    for a, b in lines:
        for axis in range(3):
            xyz[axis] += [round(float(points[a, axis]), 4), round(float(points[b, axis]), 4), None]
    return {"type": "scatter3d", "mode": "lines", "x": xyz[0], "y": xyz[1], "z": xyz[2],
            "line": {"color": "black", "width": 2}, "hoverinfo": "skip", **extra}


def scene_figure(shapes, part_names, *, count: int | None = None, camera: Camera = CAMERA, height: int | None = None,
                 zoom: float = 2.5, label_names=None) -> dict:
    """A plotly figure of shapes, their co-segmentation (or their names) and their cuboids.

    Parameters
    ----------
    shapes : list of (name, vertices (n, 3) float, faces (f, 3) int, labels (f,) int, cuboids)
        In one frame (primkit's canonical one for a collection); ``labels`` are part indices, or
        with ``label_names`` indices into it; -1 is grey.
    part_names : list of str, one per slot.
    count : part slots (default ``len(part_names)``); colours are :func:`primkit.viz.palette.part_colors`.
    label_names : list of str, optional: the surfaces are coloured and grouped by name (see the
        module notes); the cuboids stay by part index.
    height : pixels (default from the number of rows).
    zoom : the scene box's longest side in plotly's units (an orthographic camera's size is set by
        the box, not by the eye's distance).

    Returns
    -------
    dict with ``data`` (the traces), ``layout`` and ``config``, ready for ``Plotly.newPlot``.
    """
    count = int(count or len(part_names))
    palette = part_colors(max(count, 1))
    by_name = label_names is not None
    names_palette = label_colors(len(label_names)) if by_name else None
    shape_at, cuboid_at, per_row = scene_offsets(len(shapes), camera)
    traces, in_legend = [], set()

    def entry(group: str, label: str, rank: int) -> dict:
        first = group not in in_legend
        in_legend.add(group)
        return {"legendgroup": group, "name": html.escape(label), "showlegend": first, "legendrank": rank}

    def legend(k: int) -> dict:  # part k (names first: their entries rank below 100)
        label = f"{k} {part_names[k]}" if 0 <= k < len(part_names) else "no part"
        return entry(f"part{k}" if k >= 0 else "unlabelled", label, (k if k >= 0 else 999) + 100 * by_name)

    def named(j: int) -> tuple[dict, str, tuple]:  # name j: legend entry, hover text, colour
        label = str(label_names[j]) if 0 <= j < len(label_names) else "no name"
        colour = names_palette[j] if 0 <= j < len(label_names) else UNLABELLED
        return entry(f"label{j}" if j >= 0 else "unnamed", label, j if j >= 0 else 99), f"named {label}", colour

    for i, (name, vertices, faces, labels, cuboids) in enumerate(shapes):
        v = np.asarray(vertices, float) + shape_at[i]
        faces = np.asarray(faces, np.int64)
        labels = np.asarray(labels, np.int64)
        shown = html.escape(str(name))
        for k in np.unique(labels):
            k = int(k)
            if by_name:
                group, what, colour = named(k)
                meta = {"shape": i, "label": k, "kind": "surface"}
            else:
                part = f"{k} {part_names[k]}" if 0 <= k < len(part_names) else "no part"
                group, what, colour = legend(k), f"of part {part}", palette[k] if 0 <= k < count else GREY
                meta = {"shape": i, "part": k, "kind": "surface"}
            traces.append(_mesh_trace(v, faces[labels == k], colour, **group,
                                      hovertemplate=f"{shown}<br>surface {html.escape(what)}<extra></extra>", meta=meta))
        shift = np.eye(4)
        shift[:3, 3] = cuboid_at[i]
        moved = cuboids.transformed(shift)
        cv, cf, cpart = moved.to_mesh()
        points, lines, epart = cuboid_edges(moved)
        for k in np.unique(cpart):
            k = int(k)
            traces.append(_mesh_trace(cv, cf[cpart == k], palette[k], **legend(k),
                                      hovertemplate=f"{shown}<br>cuboid {k} {html.escape(part_names[k])}<extra></extra>",
                                      meta={"shape": i, "part": k, "kind": "cuboid"}))
            traces.append(_edges_trace(points, lines[epart == k], **legend(k), meta={"shape": i, "part": k, "kind": "edges"}))
    # one label under each pair
    d, up, _ = camera.basis()
    below = -0.78 * np.asarray(camera.up, float)[None] + 1.2 * d[None]  # under the pair, in front of it
    traces.append({"type": "scatter3d", "mode": "text", "showlegend": False, "hoverinfo": "skip",
                   "x": list(np.round((shape_at + cuboid_at)[:, 0] / 2 + below[0, 0], 4)),
                   "y": list(np.round((shape_at + cuboid_at)[:, 1] / 2 + below[0, 1], 4)),
                   "z": list(np.round((shape_at + cuboid_at)[:, 2] / 2 + below[0, 2], 4)),
                   "text": [html.escape(str(s[0])[:24]) for s in shapes], "textfont": {"size": 11, "color": "#333"},
                   "meta": {"kind": "names"}})
    corners = np.vstack([shape_at - 0.5, shape_at + 0.5, cuboid_at - 0.5, cuboid_at + 0.5]) if len(shapes) else np.zeros((2, 3))
    extent = np.maximum(np.ptp(corners, axis=0), 1e-6)
    rows = int(np.ceil(len(shapes) / per_row)) if len(shapes) else 1
    # fixed ranges with an aspect ratio in proportion: one scale on every axis (no autorange)
    axes = {f"{a}axis": {"visible": False, "showspikes": False, "autorange": False,
                         "range": [float(corners[:, n].min()), float(corners[:, n].max())]} for n, a in enumerate("xyz")}
    layout = {
        "height": int(height or min(900, 220 + 190 * rows)), "margin": {"l": 0, "r": 0, "t": 0, "b": 0}, "paper_bgcolor": "white",
        "legend": {"title": {"text": "surface by name,<br>cuboids by part (click to toggle)" if by_name
                             else "parts (click to toggle)"}, "itemsizing": "constant", "y": 0.92},
        "scene": {**axes, "bgcolor": "white", "aspectmode": "manual",
                  "aspectratio": dict(zip("xyz", map(float, zoom * extent / extent.max()))),
                  "camera": {"eye": dict(zip("xyz", map(float, 2.0 * d))),
                             "up": dict(zip("xyz", map(float, camera.up))), "center": {"x": 0, "y": 0, "z": 0},
                             "projection": {"type": "orthographic"}}},
    }
    config = {"displaylogo": False, "responsive": True, "modeBarButtonsToRemove": ["sendDataToCloud"]}
    return {"data": traces, "layout": layout, "config": config}


def figure_div(figure: dict, div_id: str = "scene") -> str:
    """The ``<div>`` a figure is drawn in, with the figure beside it as inline JSON (:func:`figure_json`)."""
    return (f'<div id="{html.escape(div_id)}"></div>\n'
            f'<script id="{html.escape(div_id)}-data" type="application/json">{figure_json(figure)}</script>\n')


def figure_script(div_id: str = "scene", *, include_library: bool = True, ready: str = "") -> str:
    """The scripts that draw the figure of :func:`figure_div`: plotly.js itself (with
    ``include_library``, so the page needs no network) and the ``Plotly.newPlot`` call. Placed at the
    end of a page's body, they let the rest of the page show while the library loads.

    ``ready`` is JavaScript run once the figure is drawn (``gd`` is the plot's element)."""
    library = f"<script>{plotly_js()}</script>\n" if include_library else ""
    return (f"{library}"
            "<script>(function(){\"use strict\";\n"
            f"const gd = document.getElementById({json.dumps(div_id)});\n"
            f"const F = JSON.parse(document.getElementById({json.dumps(div_id + '-data')}).textContent);\n"
            f"Plotly.newPlot(gd, F.data, F.layout, F.config).then(function(){{{ready}}});\n"
            "})();</script>\n")


def figure_html(figure: dict, div_id: str = "scene", *, include_library: bool = True, ready: str = "") -> str:
    """:func:`figure_div` and :func:`figure_script` together: an HTML fragment that draws ``figure``."""
    return figure_div(figure, div_id) + figure_script(div_id, include_library=include_library, ready=ready)

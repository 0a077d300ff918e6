"""Pictures of a collection: thumbnails of shapes (with chosen parts highlighted), a 2D map of
thumbnails, and a query's matches in a row; what ``primkit embed --png`` and ``primkit similar
--png`` draw. Meshes are in the canonical frame (+Y up, front toward +X, centred, longest side 1)."""

from __future__ import annotations

import numpy as np

from ..io import atomic_output
from .camera import CAMERA
from .render import ThumbnailRenderer, Tile, mesh_layer

__all__ = ["region_layers", "render_thumbnails", "draw_map", "draw_matches"]

def region_layers(occupancy, labels, chosen, colours, rest_opacity: float = 0.22) -> list:
    """The layers of one shape's thumbnail with chosen parts highlighted: the voxels labelled with
    one of ``chosen`` as a voxel surface in that label's colour, the other voxels grey and
    see-through.

    ``occupancy (R, R, R) bool`` and ``labels (R, R, R) int`` (indices into the label names, negative:
    none) in the canonical frame; ``chosen``: label indices; ``colours (count, 3) uint8``: each
    label's colour (:func:`primkit.viz.palette.label_colors`). Returns a list of
    :class:`primkit.viz.render.Layer` (empty for an empty grid), what :func:`render_thumbnails` draws.
    """
    from ..geometry import voxel_boundary_mesh

    occ = np.asarray(occupancy, bool)
    labels = np.asarray(labels)
    colours = np.asarray(colours, np.uint8).reshape(-1, 3)
    layers = []
    highlighted = np.zeros(occ.shape, bool)
    for j in chosen:
        mine = occ & (labels == j)
        highlighted |= mine
        v, f = voxel_boundary_mesh(mine)
        if len(f):
            layers.append(mesh_layer(v, f, np.repeat(colours[j][None], len(f), axis=0)))
    v, f = voxel_boundary_mesh(occ & ~highlighted)
    if len(f):
        layers.append(mesh_layer(v, f, color="#9a9a9a", opacity=rest_opacity))
    return layers


def render_thumbnails(meshes, size: int = 96, progress: bool = False) -> list[np.ndarray]:
    """Small pictures of meshes in the canonical frame: ``(size, size, 4) uint8`` RGBA each.

    ``meshes``: ``(vertices, faces)``, ``(vertices, faces, (f, 3) uint8 face colours)``, or a list of
    :class:`primkit.viz.render.Layer` (:func:`region_layers`). One off-screen plotter is reused
    (:class:`primkit.viz.render.ThumbnailRenderer`); every thumbnail is framed on the canonical
    frame's origin at one scale, so sizes compare across thumbnails.
    """
    from tqdm import tqdm

    frame = np.array([[-0.5] * 3, [0.5] * 3])  # centred on the origin of the canonical frame
    radius = 0.62 / (1.0 + CAMERA.margin)  # a viewport half-height of 0.62: a unit-size shape with room
    images = []
    with ThumbnailRenderer(size=size) as renderer:
        for item in tqdm(meshes, desc="thumbnails", unit="shape", disable=not progress):
            if isinstance(item, list):
                layers = item
            else:
                v, f = item[0], item[1]
                colors = item[2] if len(item) > 2 else None
                layers = [mesh_layer(v, f, colors, color="#b8c4d6")] if len(f) else []
            images.append(renderer.render(Tile("", layers, frame=frame), radius=radius, transparent=True))
    return images


def draw_map(coords, images, path, *, colors=None, title: str = "", zoom: float = 0.6, spacing: float = 0.035,
             svg=None) -> None:
    """Draw thumbnails at 2D map positions (PNG; also SVG when ``svg`` is a path).

    Every shape gets a dot; thumbnails are drawn for shapes at least ``spacing`` (a fraction of the
    map's extent, per axis) from every thumbnail already drawn, so dense clusters stay readable.

    ``coords (s, 2) float``, ``images``: one RGBA thumbnail per shape (or None for a dot alone);
    ``colors``: optional ``(s,) float`` values (a known attribute) that colour the dots and the
    thumbnails' frames, with a colour bar.
    """
    from matplotlib.figure import Figure  # matplotlib: imported on first use
    from matplotlib.offsetbox import AnnotationBbox, OffsetImage

    coords = np.asarray(coords, float)
    # a Figure of its own (no pyplot): drawing here never switches the caller's backend
    fig = Figure(figsize=(14, 14), dpi=100)
    ax = fig.subplots()
    edge = None
    if colors is None:
        ax.scatter(coords[:, 0], coords[:, 1], s=12, c="0.6")
    else:
        dots = ax.scatter(coords[:, 0], coords[:, 1], s=40, c=colors, cmap="coolwarm")
        edge = dots.to_rgba(np.asarray(colors, float))
        fig.colorbar(dots, ax=ax, shrink=0.5, pad=0.01)
    # thumbnails drawn greedily in a fixed random order, skipping those that would mostly cover one
    # already drawn: the dots show every shape, the thumbnails stay readable
    unit = (coords - coords.min(axis=0)) / (np.ptp(coords, axis=0) + 1e-12)
    drawn = np.empty((0, 2))
    for i in np.random.default_rng(0).permutation(len(coords)):
        if images[i] is None or (len(drawn) and np.min(np.abs(drawn - unit[i]).max(axis=1)) < spacing):
            continue
        drawn = np.vstack([drawn, unit[i]])
        framed = edge is not None
        ax.add_artist(AnnotationBbox(OffsetImage(images[i], zoom=zoom), coords[i], frameon=framed, pad=0.05,
                                     bboxprops={"edgecolor": edge[i], "linewidth": 2.0} if framed else None))
    pad = 0.06 * (np.ptp(coords, axis=0) + 1e-9)
    ax.set_xlim(coords[:, 0].min() - pad[0], coords[:, 0].max() + pad[0])
    ax.set_ylim(coords[:, 1].min() - pad[1], coords[:, 1].max() + pad[1])
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=11)
    fig.tight_layout()
    for out, fmt in ((path, "png"), (svg, "svg")):
        if out is not None:
            with atomic_output(out, overwrite=True) as tmp:
                fig.savefig(tmp, format=fmt)


def draw_matches(query_image, images, names, distances, path, *, query_name: str = "query", title: str = "") -> None:
    """The query's thumbnail, then its matches in rank order with names and distances, in one PNG row."""
    from matplotlib.figure import Figure  # matplotlib: imported on first use

    n = len(images) + 1
    fig = Figure(figsize=(2.2 * n, 2.6), dpi=100)  # no pyplot: the caller's backend is left alone
    axes = fig.subplots(1, n)
    axes = np.atleast_1d(axes)
    panels = [(query_image, f"query\n{query_name[:18]}")]
    panels += [(img, f"#{i + 1} {nm[:16]}\nd = {d:.3g}") for i, (img, nm, d) in enumerate(zip(images, names, distances))]
    for ax, (img, label) in zip(axes, panels):
        ax.imshow(img)
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    axes[0].patch.set_edgecolor("black")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png")

"""Embedding explorer: the t-SNE map of a collection, drawn with the shapes themselves.

The map (:func:`primkit.embedding.tsne_map` of :class:`primkit.embedding.PartDescriptor`, so the
similarity looks only at the chosen parts) is laid out on the screen plane of the camera convention
and every shape is drawn at its map position, small (``style="thumbnails"``) or as a dot
(``style="points"``). Clicking one selects it: it turns orange, its nearest neighbours (in the
descriptor space, not on the map) turn blue, and the row below the map shows it large beside its
neighbours with their distances.

    primkit view embedding chairs/ --model chair --parts back,seat
    primkit view embedding chairs/ --model chair --parts arms      # by label, as embed --parts arms

With the model's labeller (``labeller``) and ``parts`` naming only its names (``arms``;
:func:`primkit.segmentation.bylabel.by_label`), the similarity looks at each shape's labelled
voxels, whichever cuboids hold them, as ``primkit embed --parts arms`` does (:func:`label_table`,
:class:`primkit.embedding.RegionDescriptor`);
otherwise at the part indices the names select.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..viz.interop import to_pyvista
from ..viz.camera import CAMERA, apply_camera
from .. import embedding

from . import common

__all__ = ["EmbeddingExplorer", "embedding_explorer", "label_table"]

GREY, ORANGE, BLUE = "lightgrey", "#f28e2b", "#4e79a7"
MAP_WIDTH = 8.0  # the map's larger side, in canonical shape sizes
ROW_STEP = 1.5  # spacing of the chosen shape and its neighbours


@dataclass
class EmbeddingExplorer:
    plotter: object
    names: list
    coords: np.ndarray  # (s, 2) float: t-SNE map
    positions: np.ndarray  # (s, 3) float: where each shape sits in the scene
    neighbors: object  # primkit.embedding.Neighbors, k per shape
    map_actors: list
    shapes: list
    row_actors: list = field(default_factory=list)
    info_actor: object = None
    selected: int | None = None

    def select(self, i: int) -> None:
        """Show shape ``i`` and its nearest neighbours."""
        self.selected = int(i)
        near = self.neighbors.indices[i]
        for j, a in enumerate(self.map_actors):
            a.GetProperty().SetColor(_rgb(ORANGE if j == i else BLUE if j in near else GREY))
        for a in self.row_actors:
            self.plotter.remove_actor(a)
        self.row_actors = []
        _, up, right = CAMERA.basis()
        row = [i, *near]
        spots = self.row_positions()
        labels = [f"{self.names[i][:16]}"] + [f"{self.names[j][:12]} d={d:.2f}"
                                                         for j, d in zip(near, self.neighbors.distances[i])]
        for n, (j, text) in enumerate(zip(row, labels)):
            s = self.shapes[j]
            where = spots[n]
            color = ORANGE if n == 0 else BLUE
            self.row_actors.append(self.plotter.add_mesh(to_pyvista((s.canonical_vertices() + where, s.faces)),
                                                         color=color, smooth_shading=False, pickable=False,
                                                         reset_camera=False))
            self.row_actors.append(self.plotter.add_point_labels([where - 0.6 * up], [text], font_size=10,
                                                                 shape_opacity=0.0, show_points=False,
                                                                 always_visible=True, text_color="black",
                                                                 pickable=False, reset_camera=False))
        self.info_actor.SetInput(f"{self.names[i]}: nearest " + ", ".join(self.names[j] for j in near))

    def row_positions(self) -> np.ndarray:
        """(k + 1, 3) float: where the chosen shape and its neighbours are drawn, under the map."""
        _, up, right = CAMERA.basis()
        n = self.neighbors.indices.shape[1] + 1
        below = self.positions @ up
        base = self.positions.mean(0) - (self.positions.mean(0) @ up - below.min() + 1.4) * up
        return base + (np.arange(n) - 0.5 * (n - 1))[:, None] * ROW_STEP * right[None]

    def pick_at(self, x: float, y: float) -> int | None:
        actor = common.pick_actor(self.plotter, x, y, self.map_actors)
        i = next((i for i, a in enumerate(self.map_actors) if a is actor), None)
        if i is not None:
            self.select(i)
        return i

    @property
    def info(self) -> str:
        return common.text_of(self.info_actor)


def _rgb(color):
    from pyvista import Color

    return Color(color).float_rgb


def label_table(labeller, shapes) -> "embedding.RegionTable":
    """Each shape's voxels named by ``labeller``, as regions (:meth:`primkit.embedding.RegionTable.from_grids`
    of :func:`primkit.segmentation.bylabel.labelled_grid` on the shape's canonical grid): what
    ``embed --parts arms`` describes. ``shapes``: abstractions (or the viewers' point shapes,
    :class:`primkit.viewers.common.PointShape`)."""
    from ..segmentation.bylabel import labelled_grid

    grids = [getattr(s, "abstraction", s).canonical_shape().occupancy for s in shapes]
    labels = [labelled_grid(labeller, g, s.result.canonical) for g, s in zip(grids, shapes)]
    return embedding.RegionTable.from_grids(grids, labels, labeller.names, [s.name for s in shapes])


def embedding_explorer(shapes, part_names=None, *, parts="all", neighbors: int = 4, style: str = "thumbnails",
                       coords=None, off_screen: bool = False, window_size=(1280, 900), title: str = "",
                       random_state: int = 0, labeller=None) -> EmbeddingExplorer:
    """Build the explorer.

    Parameters
    ----------
    shapes : list of primkit.model.abstraction.Abstraction (at least 3)
    parts : the parts the similarity looks at (:class:`primkit.embedding.PartDescriptor`)
    coords : (s, 2) float, optional: a map computed elsewhere (default t-SNE of the descriptors)
    labeller : primkit.segmentation.labeller.Labeller, optional
        The model's labeller: ``parts`` naming only its names goes by label (:func:`label_table`).
    """
    if len(shapes) < 3:
        raise ValueError(f"a map needs at least 3 shapes, got {len(shapes)}")
    if style not in ("thumbnails", "points"):
        raise ValueError(f"style must be 'thumbnails' or 'points', got {style!r}")
    from ..segmentation.bylabel import by_label

    chosen = by_label(parts, None if labeller is None else labeller.names)
    if chosen is not None:  # each shape's labelled regions
        X = embedding.RegionDescriptor(chosen).fit_transform(label_table(labeller, shapes))
        what = f"labels {','.join(chosen)}, each shape's labelled voxels"
    else:
        X = embedding.PartDescriptor(parts=parts, part_names=part_names).fit_transform([s.result for s in shapes])
        what = str(parts)
    k = min(neighbors, len(shapes) - 1)
    near = embedding.nearest_neighbors(X, k=k)
    if coords is None:
        coords = embedding.tsne_map(X, random_state=random_state)
    coords = np.asarray(coords, float)
    span = max(float(np.ptp(coords, axis=0).max()), 1e-9)
    flat = (coords - coords.mean(0)) / span * MAP_WIDTH
    _, up, right = CAMERA.basis()
    positions = flat[:, :1] * right + flat[:, 1:2] * up
    p = common.new_plotter(off_screen, window_size, f"primkit - {title or 'embedding'}")
    map_actors = []
    pv = __import__("pyvista")
    for s, where in zip(shapes, positions):
        if style == "thumbnails":
            poly = to_pyvista((s.canonical_vertices() * 0.5 + where, s.faces))
        else:
            poly = pv.Sphere(radius=0.12, center=where)
        map_actors.append(p.add_mesh(poly, color=GREY, smooth_shading=False))
    explorer = EmbeddingExplorer(p, [s.name for s in shapes], coords, positions, near, map_actors, list(shapes))
    explorer.info_actor = p.add_text("click a shape", position=(10, window_size[1] - 40), font_size=10, color="black")
    p.add_text(f"t-SNE of part descriptors ({what})", position="upper_right", font_size=9, color="black")
    explorer.select(0)
    # frame the map and the row under it (with room for the labels, and for the title line above
    # the map: 0.3 left a thumbnail under the title)
    extent = np.vstack([positions + 0.7 * up, positions - 0.3 * up, explorer.row_positions() + 0.6 * up,
                        explorer.row_positions() - 0.8 * up, explorer.row_positions() + 0.8 * right,
                        explorer.row_positions() - 0.8 * right, positions + 0.3 * right, positions - 0.3 * right])
    u, r = extent @ up, extent @ right
    center = 0.5 * (u.max() + u.min()) * up + 0.5 * (r.max() + r.min()) * right
    aspect = window_size[0] / window_size[1]
    apply_camera(p, center, 0.5 * max(np.ptp(u), np.ptp(r) / aspect))
    common.on_click(p, explorer.pick_at)
    return explorer


"""Collection browser: every shape of a folder in one grid, parts coloured the same on every shape.

One network explains the whole category, so part ``k`` is the same part everywhere and gets the
same colour (:func:`primkit.viz.palette.part_colors`) on every shape. Three modes, chosen with the
buttons at the bottom left: the meshes, their cuboids, or the meshes coloured by co-segmentation
(each face takes its nearest cuboid's index). With the model's labeller (``labeller``), a fourth
mode, ``names``, colours each face by the name the labeller gives it on that shape (the label
palette, :func:`primkit.viz.palette.label_colors`, as ``segment --semantic --png``) with a legend
of the names. Clicking a shape names it and lists its parts (and its names' shares of its faces).

Layout: shapes are drawn in the canonical frame (upright, front toward +X, longest side 1) and
placed along the screen's right and down directions of the camera convention
(:data:`primkit.viz.camera.CAMERA`, parallel projection), so the grid is a true grid on screen and
every shape is drawn at the same scale.

    primkit view collection chairs/ --model chair
    primkit view collection chairs/ --model chair --mode names
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model.parts import default_part_names
from ..viz.palette import label_colors, label_element_colors, part_colors
from ..viz.interop import to_pyvista
from ..viz.camera import CAMERA, apply_camera

from . import common

__all__ = ["CollectionBrowser", "collection_browser", "MODES"]

MODES = ("mesh", "cuboids", "segmentation", "names")  # names: with a labeller only
SPACING = 1.25  # canonical shapes fit in a unit cube; a quarter of it between neighbours


@dataclass
class CollectionBrowser:
    """The plotter and its controls."""

    plotter: object
    names: list
    actors: dict  # mode -> list of actors, one per shape
    offsets: np.ndarray  # (s, 3) float: where each shape is drawn
    buttons: dict = field(default_factory=dict)
    info_actor: object = None
    mode: str = "cuboids"
    selected: int | None = None
    part_names: list = field(default_factory=list)
    cuboids: list = field(default_factory=list)
    edge_actors: list = field(default_factory=list)  # the cuboids' edges, shown with the cuboids
    named: list = field(default_factory=list)  # per shape (f,) or (n,) int: each face's label (with a labeller)
    label_names: list | None = None
    legend: list = field(default_factory=list)  # the names in the legend shown

    def set_mode(self, mode: str) -> None:
        """Show every shape as ``mode`` (one of :data:`MODES`); the buttons follow."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        if mode == "names" and self.label_names is None:
            raise ValueError("mode 'names' needs the model's labeller (collection_browser(..., labeller=...))")
        self.mode = mode
        for m, actors in self.actors.items():
            for a in actors:
                a.SetVisibility(m == mode)
        for a in self.edge_actors:
            a.SetVisibility(mode == "cuboids")
        for m, w in self.buttons.items():
            w.GetRepresentation().SetState(int(m == mode))
        if self.legend:
            self.plotter.remove_legend(render=False)
            self.legend = []
        if mode == "names":
            present = sorted(set(np.concatenate([np.unique(n) for n in self.named]).tolist()) - {-1})
            self.legend = [self.label_names[j] for j in present]
            colours = label_colors(len(self.label_names)) / 255.0
            self.plotter.add_legend([[self.label_names[j], colours[j]] for j in present], bcolor="white",
                                    face="rectangle", loc="upper right", size=(0.12, 0.035 * len(present)))

    def select(self, i: int | None) -> None:
        self.selected = i
        if i is None:
            self.info_actor.SetInput("click a shape")
            return
        present = self.cuboids[i].present
        named = ", ".join(f"{k} {self.part_names[k]}" for k in present)
        if self.label_names is not None:
            counts = np.bincount(self.named[i][self.named[i] >= 0], minlength=len(self.label_names))
            named += "\nnames: " + ", ".join(f"{n} {c / max(len(self.named[i]), 1):.0%}"
                                             for n, c in zip(self.label_names, counts) if c)
        self.info_actor.SetInput(f"{self.names[i]}: {len(present)} parts\n{named}")

    def pick_at(self, x: float, y: float) -> int | None:
        """Select the shape under display position ``(x, y)``; returns its position in the grid."""
        actor = common.pick_actor(self.plotter, x, y, self.actors[self.mode])
        i = next((i for i, a in enumerate(self.actors[self.mode]) if a is actor), None)
        self.select(i)
        return i

    @property
    def info(self) -> str:
        return common.text_of(self.info_actor)


def grid_offsets(count: int, columns: int, camera=CAMERA, spacing: float = SPACING) -> np.ndarray:
    """(count, 3) float: positions of a ``columns``-wide grid, row by row, along the camera's
    screen right and down directions."""
    _, up, right = camera.basis()
    rows, cols = np.divmod(np.arange(count), columns)
    return spacing * (cols[:, None] * right[None] - rows[:, None] * up[None])


def collection_browser(shapes, part_names=None, *, columns: int | None = None, mode: str = "cuboids",
                       off_screen: bool = False, window_size=(1280, 900), title: str = "",
                       labeller=None) -> CollectionBrowser:
    """Build the browser.

    Parameters
    ----------
    shapes : list of primkit.model.abstraction.Abstraction (a mesh and its AbstractionResult)
    part_names : one name per part slot (the model's ``part_names``)
    columns : shapes per row (default about the square root of the count, wider than tall)
    labeller : primkit.segmentation.labeller.Labeller, optional
        The model's labeller: adds the ``names`` mode (each face, or point, named on its own by
        :func:`primkit.segmentation.bylabel.labelled_surface`).
    """
    if not shapes:
        raise ValueError("no shapes to browse")
    count = shapes[0].result.canonical.count
    part_names = list(part_names) if part_names is not None else default_part_names(count)
    columns = columns or int(np.ceil(np.sqrt(len(shapes) * 1.5)))
    offsets = grid_offsets(len(shapes), columns)
    p = common.new_plotter(off_screen, window_size, f"primkit - {title or 'collection'}")
    colors = part_colors(count)
    actors = {m: [] for m in MODES}
    edge_actors, named = [], []
    if labeller is not None:
        from ..segmentation.bylabel import labelled_surface
    for s, off in zip(shapes, offsets):
        v = s.canonical_vertices() + off
        cub = s.result.canonical.transformed(np.block([[np.eye(3), off[:, None]], [np.zeros((1, 3)), 1.0]]))
        actors["mesh"].append(p.add_mesh(to_pyvista((v, s.faces)), color="lightgrey", smooth_shading=False))
        poly = to_pyvista(cub, colors=colors)
        actors["cuboids"].append(p.add_mesh(poly, scalars="rgb", rgb=True, smooth_shading=False))
        edges = common.add_cuboid_edges(p, cub)
        if edges is not None:
            edge_actors.append(edges)
        labels = common.part_labels(v, s.faces, cub)
        palette = np.vstack([colors, [[200, 200, 200]]]).astype(np.uint8)
        seg = to_pyvista((v, s.faces), face_colors=palette[labels]) if len(s.faces) else to_pyvista(v, colors=palette[labels])
        actors["segmentation"].append(p.add_mesh(seg, scalars="rgb", rgb=True, smooth_shading=False))
        if labeller is not None:
            named.append(labelled_surface(labeller, s.vertices, s.faces, s.result))
            rgb = label_element_colors(named[-1], len(labeller.names))
            poly = to_pyvista((v, s.faces), face_colors=rgb) if len(s.faces) else to_pyvista(v, colors=rgb)
            actors["names"].append(p.add_mesh(poly, scalars="rgb", rgb=True, smooth_shading=False))
    _, up, _ = CAMERA.basis()
    p.add_point_labels(offsets - 0.62 * up, [s.name[:20] for s in shapes], font_size=10, shape_opacity=0.0,
                       show_points=False, always_visible=True, text_color="black", pickable=False)
    browser = CollectionBrowser(p, [s.name for s in shapes], actors, offsets, part_names=part_names,
                                cuboids=[s.result.canonical for s in shapes], edge_actors=edge_actors, named=named,
                                label_names=None if labeller is None else list(labeller.names))
    for i, m in enumerate(m for m in MODES if actors[m]):
        browser.buttons[m] = p.add_checkbox_button_widget(
            lambda state, m=m: browser.set_mode(m) if state else browser.set_mode(browser.mode),
            value=m == mode, position=(10, 10 + i * 28), size=22, color_on="black", color_off="white",
            background_color="grey")
        p.add_text(m, position=(40, 13 + i * 28), font_size=9, color="black")
    browser.info_actor = p.add_text("click a shape", position=(10, window_size[1] - 60), font_size=9, color="black")
    browser.set_mode(mode)
    lo, hi = (offsets.min(0) - 0.5), (offsets.max(0) + 0.5)
    radius = 1.12 * _grid_radius(offsets, window_size)  # room for the buttons under the grid
    apply_camera(p, (lo + hi) / 2 - 0.1 * radius * CAMERA.basis()[1], radius)
    common.on_click(p, browser.pick_at)
    return browser


def _grid_radius(offsets, window_size) -> float:
    """Half the screen height, in world units, that fits the whole grid into the window."""
    _, up, right = CAMERA.basis()
    span_up = np.ptp(offsets @ up) + SPACING
    span_right = np.ptp(offsets @ right) + SPACING
    aspect = window_size[0] / window_size[1]
    return 0.5 * max(span_up, span_right / aspect) / (1 + CAMERA.margin)


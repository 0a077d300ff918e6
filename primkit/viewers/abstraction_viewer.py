"""Abstraction viewer: one shape and its cuboids.

Controls: a checkbox per present part (coloured like the part) shows or hides it; a checkbox shows
or hides the mesh; a slider sets the cuboids' opacity; clicking a cuboid (without dragging) shows
its index, name (the model's ``part_names``) and parameters, and outlines it. The shape is seen
from the camera convention of :mod:`primkit.viz.render`.

    primkit view abstraction chair.off --model chair
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..model.parts import default_part_names
from ..viz.palette import part_colors
from ..viz.interop import to_pyvista
from ..viz.camera import apply_camera

from . import common

__all__ = ["AbstractionViewer", "abstraction_viewer"]

BOX, GAP = 20, 26  # checkbox size and spacing in pixels


@dataclass
class AbstractionViewer:
    """The plotter and its controls. Each method is what a widget calls."""

    plotter: object
    cuboids: object
    names: list
    mesh_actor: object
    part_actors: dict
    edge_actors: dict = field(default_factory=dict)  # part -> its 12 edges
    checkboxes: dict = field(default_factory=dict)
    mesh_checkbox: object = None
    slider: object = None
    info_actor: object = None
    outline_actor: object = None
    selected: int | None = None

    def toggle_part(self, k: int, visible: bool) -> None:
        """Show or hide part ``k`` (its faces and edges); a hidden part cannot be picked and loses its outline."""
        self.part_actors[k].SetVisibility(bool(visible))
        if k in self.edge_actors:
            self.edge_actors[k].SetVisibility(bool(visible))
        if not visible and self.selected == k:
            self.select(None)

    def toggle_mesh(self, visible: bool) -> None:
        self.mesh_actor.SetVisibility(bool(visible))

    def set_opacity(self, value: float) -> None:
        """Opacity of every cuboid, in [0, 1]."""
        for a in self.part_actors.values():
            a.GetProperty().SetOpacity(float(np.clip(value, 0.0, 1.0)))

    def select(self, k: int | None) -> None:
        """Show part ``k``'s index, name and parameters and outline it (None: clear)."""
        self.selected = k
        if self.outline_actor is not None:
            self.plotter.remove_actor(self.outline_actor)
            self.outline_actor = None
        if k is None:
            self.info_actor.SetInput("click a cuboid")
            return
        self.info_actor.SetInput(common.describe_part(self.cuboids, k, self.names))
        one = self.cuboids.with_existence(np.arange(self.cuboids.count) == k)
        self.outline_actor = self.plotter.add_mesh(to_pyvista(one, edges=True), color="black", line_width=4,
                                                   reset_camera=False, pickable=False)

    def pick_at(self, x: float, y: float) -> int | None:
        """Select the cuboid under display position ``(x, y)`` (what a click does); returns its index."""
        actor = common.pick_actor(self.plotter, x, y, list(self.part_actors.values()))
        k = next((k for k, a in self.part_actors.items() if a is actor), None)
        self.select(k)
        return k

    @property
    def info(self) -> str:
        """The text shown in the info panel."""
        return common.text_of(self.info_actor)


def abstraction_viewer(vertices, faces, cuboids, names=None, *, title: str = "", opacity: float = 0.6,
                       off_screen: bool = False, window_size=(1024, 768)) -> AbstractionViewer:
    """Build the viewer for one shape.

    Parameters
    ----------
    vertices : (n, 3) float; faces : (f, 3) int
    cuboids : primkit.primitives.Cuboids, in the mesh's frame
    names : list of str, one per part slot (default ``part<k>``)
    """
    names = list(names) if names is not None else default_part_names(cuboids.count)
    p = common.new_plotter(off_screen, window_size, f"primkit - {title or 'abstraction'}")
    # no depth peeling: with Mesa (llvmpipe, EGL or Xvfb) it hid every translucent cuboid
    mesh_actor = p.add_mesh(to_pyvista((vertices, faces)), color="lightgrey", smooth_shading=False, pickable=False)
    colors = part_colors(cuboids.count)
    part_actors, edge_actors = {}, {}
    for k in cuboids.present:
        one = cuboids.with_existence(np.arange(cuboids.count) == k)
        part_actors[int(k)] = p.add_mesh(to_pyvista(one), color=colors[k] / 255.0, opacity=opacity,
                                         smooth_shading=False, name=f"part{k}")
        edge_actors[int(k)] = common.add_cuboid_edges(p, one)
    viewer = AbstractionViewer(p, cuboids, names, mesh_actor, part_actors, edge_actors)
    height = window_size[1]
    for i, k in enumerate(part_actors):
        y = height - 40 - i * GAP
        viewer.checkboxes[k] = p.add_checkbox_button_widget(
            lambda state, k=k: viewer.toggle_part(k, state), value=True, position=(10, y), size=BOX,
            color_on=colors[k] / 255.0, color_off="white", background_color="grey")
        p.add_text(f"{k} {names[k]}", position=(10 + BOX + 6, y + 3), font_size=9, color="black")
    viewer.mesh_checkbox = p.add_checkbox_button_widget(viewer.toggle_mesh, value=True, position=(10, 10), size=BOX,
                                                        color_on="lightgrey", color_off="white", background_color="grey")
    p.add_text("mesh", position=(10 + BOX + 6, 13), font_size=9, color="black")
    viewer.slider = p.add_slider_widget(viewer.set_opacity, rng=(0.0, 1.0), value=opacity, title="cuboid opacity",
                                        pointa=(0.62, 0.08), pointb=(0.95, 0.08), interaction_event="always",
                                        style="modern", color="black")
    viewer.info_actor = p.add_text("click a cuboid", position=(window_size[0] - 360, height - 110), font_size=9,
                                   color="black")
    if title:
        p.add_text(title, position="upper_edge", font_size=11, color="black")
    v = np.asarray(vertices, float)
    bounds = np.vstack([v.min(0), v.max(0)])
    apply_camera(p, bounds.mean(0), 0.5 * np.linalg.norm(bounds[1] - bounds[0]))
    common.on_click(p, viewer.pick_at)
    return viewer


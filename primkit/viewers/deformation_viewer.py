"""Deformation viewer: source, target and result side by side, live.

The source mesh is bound once to its cuboids (:func:`primkit.deformation.bind`, with the blending
distance :func:`primkit.deformation.seam_falloff` picks for the transfer), so every control only
re-applies per-part transforms (a few milliseconds):

* the **blend** slider goes from the source (0) to the deformation transfer onto the target's
  parts (1): each part's transform is blended linearly with the identity, which makes every
  vertex's displacement exactly ``t`` times its displacement at 1 (the deformation is written as
  a displacement, see :mod:`primkit.deformation`);
* **scale**, **turn** and **raise** sliders edit the chosen part of the source in its own frame
  (:func:`primkit.deformation.edit_cuboids`: about its pivot, parts resting on it carried along);
  the edit is applied first, then the transfer;
* clicking a cuboid of the source chooses the part the sliders edit (the edit is reset).

Everything is drawn in the canonical frame (upright, front +X), the three panels in a row along
the screen's right direction of the camera convention; the result is coloured by the part each
vertex is bound to.

    primkit view deformation source.off target.off --model chair --part seat
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..viz.palette import part_colors
from ..viz.interop import to_pyvista
from ..viz.camera import CAMERA, apply_camera
from ..deformation import bind, edit_cuboids, seam_falloff, transfer_transforms
from ..model.parts import default_part_names

from . import common

__all__ = ["DeformationViewer", "deformation_viewer"]

STEP = 1.4  # distance between the panels, in canonical shape sizes


@dataclass
class DeformationViewer:
    plotter: object
    binding: object  # primkit.deformation.Binding of the source (canonical frame)
    transfer: object  # primkit.deformation.Transfer, source -> target
    names: list
    offset: np.ndarray  # (3,) float: where the result panel sits
    result_poly: object
    source_actors: dict  # part -> actor
    sliders: dict = field(default_factory=dict)
    info_actor: object = None
    part: int = 0
    blend: float = 1.0
    edits: dict = field(default_factory=lambda: {"scale": 1.0, "turn": 0.0, "raise": 0.0})

    def transforms(self) -> np.ndarray:
        """(m, 4, 4) float: the transforms applied now (edit of the chosen part, then blended transfer)."""
        c = self.binding.cuboids
        e = edit_cuboids(c, scale={self.part: self.edits["scale"]}, rotate={self.part: self.edits["turn"]},
                         move={self.part: (0.0, self.edits["raise"], 0.0)})
        t = (1.0 - self.blend) * np.eye(4)[None] + self.blend * self.transfer.transforms
        return np.einsum("kij,kjl->kil", t, e.transforms)

    def result_vertices(self) -> np.ndarray:
        """(n, 3) float: the deformed source, in the canonical frame (not offset)."""
        return self.binding.apply(self.transforms())

    def update(self) -> None:
        self.result_poly.points = self.result_vertices() + self.offset
        k = self.part
        self.info_actor.SetInput(f"blend {self.blend:.2f}; part {k} ({self.names[k]}): scale {self.edits['scale']:.2f}, "
                                 f"turn {self.edits['turn']:.0f} deg, raise {self.edits['raise']:.2f}")

    def set_blend(self, value: float) -> None:
        self.blend = float(np.clip(value, 0.0, 1.0))
        self.update()

    def set_edit(self, what: str, value: float) -> None:
        """``what``: "scale" (factor), "turn" (degrees about the part's side axis) or "raise" (along its up axis)."""
        if what not in self.edits:
            raise ValueError(f"edit must be one of {', '.join(self.edits)}, got {what!r}")
        self.edits[what] = float(value)
        self.update()

    def choose_part(self, k: int) -> None:
        """Edit part ``k`` from now on (its edit starts from nothing)."""
        if k not in self.source_actors:
            raise ValueError(f"part {k} is not present on the source (present: {sorted(self.source_actors)})")
        self.part = int(k)
        self.edits.update({"scale": 1.0, "turn": 0.0, "raise": 0.0})
        for what, w in self.sliders.items():
            if what in self.edits:
                w.GetRepresentation().SetValue(self.edits[what])
        for j, a in self.source_actors.items():
            a.GetProperty().SetOpacity(0.9 if j == k else 0.35)
        self.update()

    def pick_at(self, x: float, y: float) -> int | None:
        actor = common.pick_actor(self.plotter, x, y, list(self.source_actors.values()))
        k = next((k for k, a in self.source_actors.items() if a is actor), None)
        if k is not None:
            self.choose_part(k)
        return k

    @property
    def info(self) -> str:
        return common.text_of(self.info_actor)


def deformation_viewer(source, target, part_names=None, *, part: int | None = None, off_screen: bool = False,
                       window_size=(1280, 700), title: str = "") -> DeformationViewer:
    """Build the viewer for two :class:`primkit.model.abstraction.Abstraction` s abstracted by one model."""
    sc, tc = source.result.canonical, target.result.canonical
    sv, tv = source.canonical_vertices(), target.canonical_vertices()
    names = list(part_names) if part_names is not None else default_part_names(sc.count)
    transfer = transfer_transforms(sc, tc)
    binding = bind(sv, sc, falloff=seam_falloff(sv, sc, transfer.transforms),
                   faces=source.faces if len(source.faces) else None)  # a point cloud: no faces
    _, up, right = CAMERA.basis()
    offsets = [-STEP * right, np.zeros(3), STEP * right]
    p = common.new_plotter(off_screen, window_size, f"primkit - {title or 'deformation'}")
    # no depth peeling: with Mesa (llvmpipe, EGL or Xvfb) it hid every translucent cuboid
    colors = part_colors(sc.count)
    p.add_mesh(to_pyvista((sv + offsets[0], source.faces)), color="lightgrey", smooth_shading=False, pickable=False)
    p.add_mesh(to_pyvista((tv + offsets[1], target.faces)), color="lightgrey", smooth_shading=False, pickable=False)
    move = lambda off: np.block([[np.eye(3), off[:, None]], [np.zeros((1, 3)), 1.0]])  # noqa: E731
    source_actors = {}
    for k in sc.present:
        one = sc.with_existence(np.arange(sc.count) == k).transformed(move(offsets[0]))
        source_actors[int(k)] = p.add_mesh(to_pyvista(one), color=colors[k] / 255.0, opacity=0.35, smooth_shading=False)
    p.add_mesh(to_pyvista(tc.transformed(move(offsets[1])), colors=colors), scalars="rgb", rgb=True, opacity=0.35,
               smooth_shading=False, pickable=False)
    common.add_cuboid_edges(p, sc.transformed(move(offsets[0])), opacity=0.5, line_width=1.0)
    common.add_cuboid_edges(p, tc.transformed(move(offsets[1])), opacity=0.5, line_width=1.0)
    result = to_pyvista((binding.vertices + offsets[2], source.faces))
    palette = colors[binding.labels]
    result.point_data["rgb"] = palette
    p.add_mesh(result, scalars="rgb", rgb=True, smooth_shading=False, pickable=False)
    p.add_point_labels(np.array(offsets) - 0.62 * up, [f"source: {source.name[:18]}", f"target: {target.name[:18]}",
                                                       "result"], font_size=11, shape_opacity=0.0, show_points=False,
                       always_visible=True, text_color="black", pickable=False)
    k0 = part if part is not None else int(sc.present[np.argmax(sc.volumes[sc.present])])
    viewer = DeformationViewer(p, binding, transfer, names, offsets[2], result, source_actors, part=k0)
    viewer.info_actor = p.add_text("", position=(10, window_size[1] - 40), font_size=10, color="black")
    style = dict(interaction_event="always", style="modern", color="black", title_height=0.02, fmt="%.2f")
    viewer.sliders["blend"] = p.add_slider_widget(viewer.set_blend, rng=(0.0, 1.0), value=1.0, title="source -> target",
                                                  pointa=(0.03, 0.1), pointb=(0.23, 0.1), **style)
    viewer.sliders["scale"] = p.add_slider_widget(lambda v: viewer.set_edit("scale", v), rng=(0.5, 2.0), value=1.0,
                                                  title="scale part", pointa=(0.28, 0.1), pointb=(0.48, 0.1), **style)
    viewer.sliders["turn"] = p.add_slider_widget(lambda v: viewer.set_edit("turn", v), rng=(-45.0, 45.0), value=0.0,
                                                 title="turn part (deg)", pointa=(0.53, 0.1), pointb=(0.73, 0.1), **style)
    viewer.sliders["raise"] = p.add_slider_widget(lambda v: viewer.set_edit("raise", v), rng=(-0.3, 0.3), value=0.0,
                                                  title="raise part", pointa=(0.78, 0.1), pointb=(0.98, 0.1), **style)
    viewer.choose_part(k0)
    aspect = window_size[0] / window_size[1]
    apply_camera(p, -0.1 * up, 0.5 * max(1.5, (2 * STEP + 1.2) / aspect))
    common.on_click(p, viewer.pick_at)
    return viewer


"""Abstraction viewer: one shape and its cuboids.

Controls: a checkbox per present part (coloured like the part) shows or hides it; a checkbox shows
or hides the mesh; a slider sets the cuboids' opacity; clicking a cuboid (without dragging) shows
its index, name (the model's ``part_names``) and parameters, and outlines it. The shape is seen
from the camera convention of :mod:`primkit.viz.render`.

    primkit view abstraction chair.off --model chair
    primkit view abstraction chair.off --model chair --label-to labels/chair.seg   # label by hand

With ``named`` (the model's labeller's name of each face or point; ``primkit view abstraction``
computes it when the model has a labeller) a *by name* checkbox colours the shape by name (the
label palette, :func:`primkit.viz.palette.label_colors`, as ``segment --semantic --png``) with a
legend of the names, and each cuboid is called by the name most of its faces get on this shape
(:func:`primkit.segmentation.labeller.names_by_index`); ``by_name`` (``--semantic``) starts with it on.

    primkit view abstraction chair.off --model chair --semantic

With ``label_to`` (``--label-to``) it is also a labelling tool (:class:`LabellingControls`): name the
faces of a clicked cuboid by typing, paint names with a brush, undo, save a label file that
``primkit name-parts`` reads.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..model.parts import default_part_names
from ..viz.palette import UNLABELLED, label_colors, name_colors, part_colors
from ..viz.interop import to_pyvista
from ..viz.camera import apply_camera

from . import common

__all__ = ["AbstractionViewer", "LabellingControls", "abstraction_viewer", "label_colors"]

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
    labelling: "LabellingControls | None" = None
    named: np.ndarray | None = None  # (f,) or (n,) int: each face's (point's) label, into label_names
    label_names: list | None = None
    names_actor: object = None  # the shape coloured by name
    names_checkbox: object = None
    by_name: bool = False
    legend: list = field(default_factory=list)  # the names in the legend shown

    def colour_by_name(self, on: bool) -> None:
        """Colour the shape by name (with a legend of the names) or show it grey (needs ``named``)."""
        if self.names_actor is None:
            raise ValueError("no names to colour by: the model has no labeller")
        self.by_name = bool(on)
        shown = self.mesh_actor.GetVisibility() or self.names_actor.GetVisibility()
        self.names_actor.SetVisibility(self.by_name and shown)
        self.mesh_actor.SetVisibility(not self.by_name and shown)
        if self.names_checkbox is not None:
            self.names_checkbox.GetRepresentation().SetState(int(self.by_name))
        if self.legend:
            self.plotter.remove_legend(render=False)
            self.legend = []
        if self.by_name:
            present = sorted(set(np.unique(self.named).tolist()) - {-1})
            self.legend = [self.label_names[j] for j in present]
            colours = label_colors(len(self.label_names)) / 255.0
            self.plotter.add_legend([[self.label_names[j], colours[j]] for j in present], bcolor="white",
                                    face="rectangle", loc="center right", size=(0.14, 0.035 * len(present)))

    def toggle_part(self, k: int, visible: bool) -> None:
        """Show or hide part ``k`` (its faces and edges); a hidden part cannot be picked and loses its outline."""
        self.part_actors[k].SetVisibility(bool(visible))
        if k in self.edge_actors:
            self.edge_actors[k].SetVisibility(bool(visible))
        if not visible and self.selected == k:
            self.select(None)

    def toggle_mesh(self, visible: bool) -> None:
        if self.names_actor is not None:
            self.names_actor.SetVisibility(bool(visible) and self.by_name)
            self.mesh_actor.SetVisibility(bool(visible) and not self.by_name)
            return
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
        """Select the cuboid under display position ``(x, y)`` (what a click does); returns its index.
        With the labelling brush on, a click paints instead (:class:`LabellingControls`)."""
        if self.labelling is not None and self.labelling.brush_on:
            return self.selected
        actor = common.pick_actor(self.plotter, x, y, list(self.part_actors.values()))
        k = next((k for k, a in self.part_actors.items() if a is actor), None)
        self.select(k)
        return k

    @property
    def info(self) -> str:
        """The text shown in the info panel."""
        return common.text_of(self.info_actor)


#: Printable characters a label name may hold (typed in the window).
NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_. ")
_KEY_CHARS = {"minus": "-", "underscore": "_", "period": ".", "space": " "}
ERASER = "-"  # the name that takes names away


@dataclass
class LabellingControls:
    """Labelling by hand in the abstraction viewer (``--label-to``): the handlers its keys,
    buttons and mouse call, over a GUI-free :class:`primkit.segmentation.handlabels.HandLabels`.

    Typing builds a name (shown in the window); Enter gives it to the faces (points) of the
    selected cuboid, or with the brush on makes it the brush's name. The brush (Tab, or its
    checkbox) paints the current name where the left button presses and drags (the camera stays
    still while it paints on the shape). Ctrl+Z undoes the last step, Ctrl+S (or the save button)
    writes the label file and its names file (never over a file it did not write, without
    ``overwrite``). BackSpace takes a character back, Escape clears the name; the name ``-``
    is the eraser (what it is given is unlabelled again). The shape is coloured by name (grey:
    unlabelled; a name the model's labeller knows, ``known``, in the colour it has everywhere,
    :func:`primkit.viz.palette.name_colors`).
    """

    viewer: AbstractionViewer
    labels: object  # HandLabels
    path: object
    overwrite: bool = False
    source: object = None
    typed: str = ""
    current: str | None = None
    brush_on: bool = False
    radius: float = 0.05
    message: str = ""
    poly: object = None  # the shape's PolyData, coloured by name
    status_actor: object = None
    brush_checkbox: object = None
    radius_slider: object = None
    save_button: object = None
    undo_button: object = None
    saved: bool = False
    painting: bool = field(default=False, repr=False)
    _legend: list = field(default_factory=list, repr=False)
    known: list = field(default_factory=list)  # the model's label names: a name typed keeps their colour

    # ---- the handlers -------------------------------------------------------------------------

    def key(self, sym: str, code: str = "", ctrl: bool = False) -> None:
        """A key press: ``sym`` VTK's key symbol (``"a"``, ``"Return"``), ``code`` its character."""
        low = (sym or "").lower()
        if ctrl and low == "z":
            self.undo()
        elif ctrl and low == "s":
            self.save()
        elif sym in ("Return", "KP_Enter"):
            self.enter()
        elif sym == "BackSpace":
            self.typed = self.typed[:-1]
        elif sym == "Escape":
            self.typed = ""
        elif sym == "Tab":
            self.set_brush(not self.brush_on)
            return
        elif not ctrl:
            char = _KEY_CHARS.get(sym) or (code if code and len(code) == 1 else (sym if len(sym or "") == 1 else ""))
            if char in NAME_CHARS:
                self.typed += char
        self.refresh()

    def type_text(self, text: str) -> None:
        """Type ``text`` as key presses would."""
        for ch in text:
            self.key(ch, ch)

    def enter(self) -> int:
        """Take the typed name (or keep the current one) and give it to the selected cuboid's
        elements unless the brush is on; returns how many elements changed."""
        name = self.typed.strip()
        self.typed = ""
        if name:
            self.current = name
        if self.current is None:
            self.message = "type a name first"
            return 0
        k = self.viewer.selected
        if self.brush_on or k is None:
            self.message = f"brush name: {self.current}" if self.brush_on else "click a cuboid, then Enter"
            self.refresh()
            return 0
        changed = self.labels.assign_part(k, self._name())
        self.message = f"part {k} -> {self.current} ({changed} {self._unit()})"
        self.refresh()
        return changed

    def set_brush(self, on: bool) -> None:
        """Turn the brush on or off (it paints the current name)."""
        self.brush_on = bool(on)
        if self.brush_checkbox is not None:
            self.brush_checkbox.GetRepresentation().SetState(int(self.brush_on))
        self.viewer.mesh_actor.SetPickable(self.brush_on)
        self.refresh()

    def set_radius(self, value: float) -> None:
        self.radius = float(value)
        self.refresh()

    def paint_at(self, x: float, y: float) -> bool:
        """Paint the current name around the shape's point under display position ``(x, y)``;
        False when nothing of the shape is there (or no name is chosen)."""
        if self.current is None:
            self.message = "type a name and Enter before painting"
            self.refresh()
            return False
        import vtk

        picker = vtk.vtkCellPicker()
        picker.SetTolerance(0.002)
        picker.PickFromListOn()
        picker.AddPickList(self.viewer.mesh_actor)
        was = self.viewer.mesh_actor.GetPickable()
        self.viewer.mesh_actor.SetPickable(True)
        picker.Pick(float(x), float(y), 0.0, self.viewer.plotter.renderer)
        self.viewer.mesh_actor.SetPickable(was)
        if picker.GetActor() is None:
            return False
        cell = int(picker.GetCellId())
        start = cell if cell >= 0 and self.labels.adjacency is not None else None
        self.paint(picker.GetPickPosition(), start)
        return True

    def paint(self, centre, start=None) -> int:
        """Paint the current name within the brush radius of ``centre`` (from element ``start``)."""
        changed = self.labels.paint(centre, self.radius, self._name(), start)
        if changed:
            self.message = f"painted {changed} {self._unit()} {self.current}"
            self.refresh()
        return changed

    def undo(self) -> bool:
        done = self.labels.undo()
        self.message = "undone" if done else "nothing to undo"
        self.refresh()
        return done

    def save(self) -> bool:
        """Write the label and names files; the outcome is shown in the window."""
        try:
            label, names = self.labels.save(self.path, overwrite=self.overwrite, source=self.source)
        except (FileExistsError, ValueError, OSError) as exc:
            self.message = str(exc).splitlines()[0]
            self.refresh()
            return False
        self.saved = True
        self.message = f"saved {label.name} + {names.name}"
        self.refresh()
        return True

    # ---- what the window shows ----------------------------------------------------------------

    def _name(self):
        """The name given: None (unlabelled) for the eraser ``-``."""
        return None if self.current == ERASER else self.current

    def _unit(self) -> str:
        return "faces" if self.labels.adjacency is not None else "points"

    def colors(self) -> np.ndarray:
        """``(n, 3) uint8``: each element's colour (its name's, or grey)."""
        table = np.vstack([np.array([UNLABELLED], np.uint8), name_colors(self.labels.names, self.known)])
        return table[self.labels.codes]

    def status(self) -> str:
        counts = self.labels.counts()
        total = len(self.labels.codes)
        done = sum(counts.values())
        mode = f"brush on, radius {self.radius:.3g} (Tab)" if self.brush_on else "click a cuboid, Enter names it (Tab: brush)"
        lines = [f"LABELLING -> {getattr(self.path, 'name', self.path)}",
                 f"name: {self.typed}_" + (f"   current: {self.current}" if self.current else ""),
                 mode, "Ctrl+Z undo   Ctrl+S save",
                 f"labelled {done}/{total} {self._unit()}"]
        items = [f"{n} {c}" for n, c in counts.items()]
        lines += [", ".join(items[i:i + 3]) for i in range(0, len(items), 3)]
        if self.message:
            lines.append(self.message)
        return "\n".join(lines)

    def refresh(self) -> None:
        if self.poly is not None:
            key = "hand" if "hand" in self.poly.cell_data else None
            data = self.poly.cell_data if key else self.poly.point_data
            data["hand"] = self.colors()
            data.active_scalars_name = "hand"
        if self.status_actor is not None:
            self.status_actor.SetInput(self.status())
            p = self.viewer.plotter
            if self.labels.names != self._legend:  # the names in their colours
                if self._legend:
                    p.remove_legend(render=False)
                self._legend = list(self.labels.names)
                if self._legend:
                    colors = name_colors(self._legend, self.known) / 255.0
                    p.add_legend([[n, c] for n, c in zip(self._legend, colors)], bcolor="white", face="rectangle",
                                 loc="center right", size=(0.14, 0.035 * len(self._legend)))

    @property
    def text(self) -> str:
        """The text shown in the labelling panel."""
        return common.text_of(self.status_actor)


def _add_names(viewer: AbstractionViewer, vertices, faces, labels, label_names, on: bool) -> None:
    """The shape coloured by name (hidden until :meth:`AbstractionViewer.colour_by_name`) and its checkbox."""
    from ..viz.palette import label_element_colors

    p = viewer.plotter
    viewer.named, viewer.label_names = labels, label_names
    colours = label_element_colors(labels, len(label_names))
    poly = to_pyvista((vertices, faces), face_colors=colours) if len(faces) else to_pyvista(np.asarray(vertices, float),
                                                                                          colors=colours)
    viewer.names_actor = p.add_mesh(poly, scalars="rgb", rgb=True, smooth_shading=False, pickable=False,
                                    reset_camera=False, point_size=6)
    viewer.names_actor.SetVisibility(False)
    y = 10 + GAP  # above the mesh checkbox
    viewer.names_checkbox = p.add_checkbox_button_widget(viewer.colour_by_name, value=False, position=(10, y),
                                                         size=BOX, color_on="orange", color_off="white",
                                                         background_color="grey")
    p.add_text("by name", position=(10 + BOX + 6, y + 3), font_size=9, color="black")
    viewer.colour_by_name(on)


def _add_labelling(viewer: AbstractionViewer, vertices, faces, window_size, *, label_to, overwrite, source,
                   parts=None, known=()) -> LabellingControls:
    """Labelling mode: the shape drawn coloured by name, the panel, keys, buttons and the brush."""
    from ..segmentation.handlabels import HandLabels

    p = viewer.plotter
    parts = common.part_labels(vertices, faces, viewer.cuboids) if parts is None else parts
    labels = (HandLabels.for_mesh(vertices, faces, parts) if len(faces)
              else HandLabels(np.asarray(vertices, float), parts))
    v = np.asarray(vertices, float)
    size = float(np.linalg.norm(v.max(0) - v.min(0))) if len(v) else 1.0
    ctl = LabellingControls(viewer, labels, label_to, overwrite=overwrite, source=source, radius=0.05 * size,
                            known=list(known))
    viewer.labelling = ctl
    # the shape again, coloured by name, in place of the grey one
    p.remove_actor(viewer.mesh_actor)
    if len(faces):
        ctl.poly = to_pyvista((v, faces))
        ctl.poly.cell_data["hand"] = ctl.colors()
    else:
        ctl.poly = to_pyvista(v)
        ctl.poly.point_data["hand"] = ctl.colors()
    viewer.mesh_actor = p.add_mesh(ctl.poly, scalars="hand", rgb=True, smooth_shading=False, pickable=False,
                                   reset_camera=False, point_size=6)
    w, h = window_size
    ctl.status_actor = p.add_text(ctl.status(), position=(w - 470, 150), font_size=9, color="black")
    buttons = {}
    for i, (label, callback, color) in enumerate([("brush (Tab)", ctl.set_brush, "orange"),
                                                  ("undo (Ctrl+Z)", lambda state: ctl.undo(), "white"),
                                                  ("save (Ctrl+S)", lambda state: ctl.save(), "white")]):
        y = 10 + GAP * (3 - i)  # above the mesh checkbox
        buttons[label] = p.add_checkbox_button_widget(callback, value=False, position=(10, y), size=BOX,
                                                      color_on=color, color_off="white", background_color="grey")
        p.add_text(label, position=(10 + BOX + 6, y + 3), font_size=9, color="black")
    ctl.brush_checkbox, ctl.undo_button, ctl.save_button = buttons.values()
    ctl.radius_slider = p.add_slider_widget(ctl.set_radius, rng=(0.005 * size, 0.25 * size), value=ctl.radius,
                                            title="brush radius", pointa=(0.25, 0.08), pointb=(0.55, 0.08),
                                            interaction_event="always", style="modern", color="black")
    _wire_labelling_events(p, ctl)
    return ctl


def _wire_labelling_events(p, ctl: LabellingControls) -> None:
    """Keys type names (VTK's and pyvista's own single-key commands are turned off: typing
    "seat" must not switch to surface mode nor quit); with the brush on, a left press on the
    shape paints and drags paint on, the camera left still."""
    iren = getattr(p, "iren", None)
    if iren is None:
        return
    inter = iren.interactor
    iren.clear_key_event_callbacks()
    inter.RemoveObservers("CharEvent")

    def key(obj, event):
        ctl.key(obj.GetKeySym() or "", obj.GetKeyCode() or "", bool(obj.GetControlKey()))

    tags = {}

    def press(obj, event):
        if ctl.brush_on and ctl.paint_at(*obj.GetEventPosition()):
            ctl.painting = True
            obj.GetCommand(tags["press"]).SetAbortFlag(1)

    def move(obj, event):
        if ctl.painting:
            ctl.paint_at(*obj.GetEventPosition())
            obj.GetCommand(tags["move"]).SetAbortFlag(1)

    def release(obj, event):
        ctl.painting = False

    inter.AddObserver("KeyPressEvent", key)
    tags["press"] = inter.AddObserver("LeftButtonPressEvent", press, 10.0)
    tags["move"] = inter.AddObserver("MouseMoveEvent", move, 10.0)
    inter.AddObserver("LeftButtonReleaseEvent", release, 10.0)


def abstraction_viewer(vertices, faces, cuboids, names=None, *, title: str = "", opacity: float = 0.6,
                       off_screen: bool = False, window_size=(1024, 768), label_to=None, overwrite: bool = False,
                       source=None, label_from=None, label_guess=None, named=None,
                       by_name: bool = False) -> AbstractionViewer:
    """Build the viewer for one shape.

    Parameters
    ----------
    vertices : (n, 3) float; faces : (f, 3) int
    cuboids : primkit.primitives.Cuboids, in the mesh's frame
    names : list of str, one per part slot (default ``part<k>``)
    label_to : path, optional
        Labelling mode (:class:`LabellingControls`, ``viewer.labelling``): the label file saving
        writes, ``<stem>.seg`` for a mesh, ``<stem>.labels.npy`` for a point cloud (``faces``
        empty), with ``<stem>.names.json`` beside it; ``overwrite`` lets it replace existing files;
        ``source`` (the shape's file) is recorded in the names file; ``label_from``: a label file
        to start from (:meth:`primkit.segmentation.handlabels.HandLabels.load`); ``label_guess``:
        ``(labels (n,) int, names)`` to start from instead (a labeller's guess,
        :meth:`~primkit.segmentation.handlabels.HandLabels.start_from`).
    named : ``(labels, label_names)``, optional
        The model's labeller's name of each face (each point of a cloud): ``labels`` (f,) or (n,)
        int, indices into ``label_names`` (-1 none), e.g.
        :func:`primkit.segmentation.bylabel.labelled_surface`. Adds the *by name* checkbox (not in
        labelling mode), and each cuboid takes the name most of its faces get
        (:func:`primkit.segmentation.labeller.names_by_index`); ``by_name`` starts coloured by name.
    """
    names = list(names) if names is not None else default_part_names(cuboids.count)
    if named is not None:
        from ..segmentation.labeller import names_by_index

        labels, label_names = np.asarray(named[0], np.int64), list(named[1])
        expected = len(faces) if len(faces) else len(vertices)
        if labels.shape != (expected,):
            raise ValueError(f"`named` labels must be ({expected},) int, one per {'face' if len(faces) else 'point'}, "
                             f"got {labels.shape}")
        names = names_by_index(labels, common.part_labels(vertices, faces, cuboids), cuboids.count, label_names, names)
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
    if named is not None and label_to is None:
        _add_names(viewer, vertices, faces, labels, label_names, by_name)
    v = np.asarray(vertices, float)
    bounds = np.vstack([v.min(0), v.max(0)])
    apply_camera(p, bounds.mean(0), 0.5 * np.linalg.norm(bounds[1] - bounds[0]))
    common.on_click(p, viewer.pick_at)
    if label_to is not None:
        ctl = _add_labelling(viewer, vertices, faces, window_size, label_to=Path(label_to), overwrite=overwrite,
                             source=source, known=label_names if named is not None else ())
        if label_from is not None or label_guess is not None:
            if label_from is not None:
                ctl.labels.load(label_from)
            else:
                ctl.labels.start_from(*label_guess)
            ctl.current = ctl.labels.names[-1] if ctl.labels.names else None
            ctl.message = f"started from {Path(label_from).name if label_from is not None else 'the labeller'}"
            ctl.refresh()
    return viewer


"""Pieces shared by the viewers: segmentation labels, cuboid edges, text and picking."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import io
from ..model.parts import default_part_names
from ..segmentation import face_labels as segmentation_face_labels
from ..segmentation import point_labels
from ..viz.backend import pyvista_module
from ..viz.interop import to_pyvista

__all__ = ["face_labels_or_unlabelled", "part_labels", "PointShape", "drawable", "add_cuboid_edges", "describe_part", "text_of", "pick_actor", "on_click",
           "display_position", "new_plotter"]


def face_labels_or_unlabelled(vertices, faces, cuboids) -> np.ndarray:
    """(f,) int: the co-segmentation (:func:`primkit.segmentation.face_labels`), -1 when no part is present."""
    if not cuboids.existence.any():
        return np.full(len(faces), -1, np.int64)
    return segmentation_face_labels(vertices, faces, cuboids)


def part_labels(vertices, faces, cuboids) -> np.ndarray:
    """The co-segmentation of what a viewer draws: per face for a mesh, per point when ``faces``
    is empty (a point cloud); -1 when no part is present."""
    if len(faces):
        return face_labels_or_unlabelled(vertices, faces, cuboids)
    if not cuboids.existence.any():
        return np.full(len(vertices), -1, np.int64)
    return point_labels(vertices, cuboids)


@dataclass(frozen=True, eq=False)
class PointShape:
    """A point cloud's :class:`~primkit.model.abstraction.Abstraction` as the viewers take shapes:
    ``vertices`` are its points and ``faces`` is empty, so the viewers draw points."""

    abstraction: object
    points: np.ndarray

    @property
    def name(self) -> str:
        return self.abstraction.name

    @property
    def result(self):
        return self.abstraction.result

    @property
    def cuboids(self):
        return self.abstraction.cuboids

    @property
    def vertices(self) -> np.ndarray:
        return self.points

    @property
    def faces(self) -> np.ndarray:
        return np.zeros((0, 3), np.int64)

    def canonical_vertices(self) -> np.ndarray:
        return self.result.frame.to_canonical(self.points)


def drawable(abstraction):
    """The abstraction itself for a mesh, a :class:`PointShape` for a point cloud (file or memory).
    Raises :class:`primkit.io.ShapeFileError` for a voxel grid (nothing to draw but its cuboids)."""
    given = abstraction.given
    if isinstance(given, io.PointCloud):
        return PointShape(abstraction, given.points)
    if given is None and abstraction.source:
        shape = io.read_shape(abstraction.source)
        if isinstance(shape, io.PointCloud):
            return PointShape(abstraction, shape.points)
    abstraction.mesh  # noqa: B018 - a mesh, or the one-line error of a voxel grid
    return abstraction


def add_cuboid_edges(plotter, cuboids, *, opacity: float = 1.0, line_width: float = 1.5):
    """The 12 edges of each present cuboid in black (never their triangles' diagonals), not
    pickable; returns the actor, or None when no cuboid is present."""
    if not cuboids.existence.any():
        return None
    return plotter.add_mesh(to_pyvista(cuboids, edges=True), color="black", line_width=line_width, opacity=opacity,
                            pickable=False, reset_camera=False)


def describe_part(cuboids, k: int, names) -> str:
    """Several lines: index, name and parameters of part ``k``."""
    q = cuboids.quaternions[k]
    lines = [f"part {k}: {names[k] if k < len(names) else default_part_names(k + 1)[k]}",
             "size " + " x ".join(f"{2 * z:.3f}" for z in cuboids.half_extents[k]),
             "centre (" + ", ".join(f"{t:.3f}" for t in cuboids.translations[k]) + ")",
             "rotation wxyz (" + ", ".join(f"{x:.3f}" for x in q) + ")"]
    if cuboids.probabilities is not None:
        lines.append(f"existence p = {cuboids.probabilities[k]:.2f}")
    return "\n".join(lines)


def text_of(actor) -> str:
    """The string a pyvista text actor shows (a vtkTextActor or a corner annotation)."""
    if hasattr(actor, "GetInput"):
        return actor.GetInput() or ""
    return "\n".join(actor.GetText(i) or "" for i in range(8))


def pick_actor(plotter, x: float, y: float, actors):
    """The actor among ``actors`` under display position ``(x, y)`` (pixels from the bottom left),
    the front-most visible one, or None. A cell picker restricted to those actors, so meshes drawn
    around them never hide them from the click."""
    import vtk

    picker = vtk.vtkCellPicker()
    picker.SetTolerance(0.0005)
    picker.PickFromListOn()
    for a in actors:
        picker.AddPickList(a)
    picker.Pick(float(x), float(y), 0.0, plotter.renderer)
    return picker.GetActor()


def on_click(plotter, callback, tolerance: int = 3) -> None:
    """Call ``callback(x, y)`` on a left click that did not drag (a drag turns the camera).
    Nothing happens without an interactor (off-screen plotters)."""
    iren = getattr(plotter, "iren", None)
    if iren is None:
        return
    state = {}

    def press(obj, event):
        state["at"] = iren.get_event_position()

    def release(obj, event):
        x, y = iren.get_event_position()
        x0, y0 = state.get("at", (x, y))
        if abs(x - x0) <= tolerance and abs(y - y0) <= tolerance:
            callback(x, y)

    iren.add_observer("LeftButtonPressEvent", press)
    iren.add_observer("LeftButtonReleaseEvent", release)


def display_position(plotter, point) -> tuple[float, float]:
    """Display coordinates (pixels from the bottom left) of a world point (3,) in the current renderer."""
    ren = plotter.renderer
    ren.SetWorldPoint(*np.asarray(point, float), 1.0)
    ren.WorldToDisplay()
    x, y, _ = ren.GetDisplayPoint()
    return x, y


def new_plotter(off_screen: bool, window_size, title: str, **kwargs):
    pv = pyvista_module()
    p = pv.Plotter(off_screen=off_screen, window_size=window_size, title=title, **kwargs)
    p.set_background("white")
    return p

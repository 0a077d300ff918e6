"""Open3D viewer: one shape (mesh or point cloud), its parts and its cuboids in Open3D's own window
(``open3d.visualization.draw``), beside the pyvista viewers.

Actions (buttons in the window's settings panel, as ``open3d.visualization.draw(actions=...)`` makes
them): one per present part that shows or hides the
part's surface (or points) and its cuboid; ``cuboids`` and ``surface`` for all of them at once;
``refine +N`` runs N more gradient steps on the shape's own losses and redraws; ``export`` writes
the cuboids (``<name>.cuboids.json``), the labels (``<name>.seg`` per face, or ``<name>.parts.npy``
per point) and the coloured parts (``<name>.parts.ply``) into the export folder, never over an
existing file.

    primkit view open3d chair.ply --model chair
    primkit view open3d chair.ply --model chair --semantic     # the surface coloured by name

With ``names=True`` (``--semantic``) and a model that has a labeller
(:mod:`primkit.segmentation.labeller`, e.g. the bundled chair model), the surface is drawn by name
instead of by part: one geometry per name, ``label j <name>`` (the faces or points whose
``label`` attribute is ``j``, :mod:`primkit.plugins.open3d_geometry`), in the label palette's
colours (:func:`primkit.viz.palette.label_colors`), and a ``colour by name`` button switches
between names and parts; a picture (``--png``) gets a legend of the names under it.

The geometry is Open3D's tensor geometry (:mod:`primkit.plugins.open3d_geometry`): part ``k``'s
surface is ``select_faces_by_mask(triangle["part"] == k)`` of the segmented mesh (for a cloud,
``select_by_mask(point["part"][:, 0] == k)``), each cuboid a tensor mesh and its 12 edges a line set.
Like the pyvista viewers, :func:`open3d_viewer` builds the scene and the actions and returns them
(:class:`Open3DViewer`); the actions take the window (``O3DVisualizer``) as Open3D passes it, so
tests call them directly; :meth:`Open3DViewer.show` opens the window. Open3D's window renders with
Filament on Vulkan: on machines without a GPU, Mesa's CPU Vulkan driver (Debian:
``mesa-vulkan-drivers``, which ``scripts/setup.sh`` installs) does it, under X (or ``xvfb-run``).
:meth:`Open3DViewer.picture` (``primkit view open3d ... --png``) needs no display: it draws the
same scene with Open3D's ``OffscreenRenderer`` (:meth:`Open3DViewer.render`), on the same Vulkan
driver with no window (``--png --window``: the window's own frame, under X).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import io
from ..plugins.open3d_geometry import O3DSegmentation, segment_geometry
from ..viz.camera import CAMERA
from ..viz.palette import label_colors, part_colors

__all__ = ["Open3DViewer", "ExportedFiles", "open3d_viewer"]

SURFACE, CUBOIDS, LABEL = "surface", "cuboids", "label"


def _material(shader: str, color, *, line_width: float = 1.0, point_size: float = 4.0):
    from open3d.visualization import rendering

    m = rendering.MaterialRecord()
    m.shader = shader
    m.base_color = [float(c) for c in color]
    m.line_width = float(line_width)
    m.point_size = float(point_size)
    return m


@dataclass(frozen=True)
class ExportedFiles:
    """What :meth:`Open3DViewer.export` wrote: ``<name>.cuboids.json``, the labels (``<name>.seg``
    per face, or ``<name>.parts.npy`` per point) and the coloured parts (``<name>.parts.ply``)."""

    cuboids: Path
    labels: Path
    parts: Path


@dataclass
class Open3DViewer:
    """The scene and what its buttons do. Each action is ``callable(window)``; the window is Open3D's
    ``O3DVisualizer`` (its ``show_geometry``, ``add_geometry``, ``remove_geometry``, ``post_redraw``
    and ``show_message_box`` are what the actions use)."""

    name: str
    shape: object  # (vertices, faces) or (n, 3) points, in the input's frame
    source: object  # the same as Open3D tensor geometry (what is segmented)
    model: object  # the Abstractor
    segmentation: O3DSegmentation
    options: dict = field(default_factory=dict)
    refine_step: int = 100
    export_folder: Path = Path("primkit-export")
    hidden: set = field(default_factory=set)
    show_surface: bool = True
    show_cuboids: bool = True
    messages: list = field(default_factory=list)
    by_name: bool = False  # the surface coloured by the labeller's names (when the geometry has them)

    # ---- the scene ------------------------------------------------------------------------------

    @property
    def parts(self) -> list[int]:
        """The present parts (slots), in slot order."""
        return [int(k) for k in self.segmentation.cuboids.present]

    @property
    def refined(self) -> int:
        """Gradient steps the shown cuboids were refined by."""
        return int(self.options.get("refine", 0))

    def _surface_of(self, k: int):
        """Part ``k``'s faces (or points) of the segmented geometry, positions only (drawn in the
        material's colour; the per-vertex colours would blend across part borders)."""
        import open3d as o3d

        g = self.segmentation.geometry
        if type(g).__name__ == "TriangleMesh":
            part = g.select_faces_by_mask(g.triangle["part"] == k)
            return o3d.t.geometry.TriangleMesh(part.vertex.positions, part.triangle.indices)
        return o3d.t.geometry.PointCloud(g.select_by_mask(g.point["part"][:, 0] == k).point.positions)

    @property
    def named(self) -> bool:
        """Whether the surface is drawn by name: asked for, and the model has a labeller."""
        return self.by_name and self.segmentation.label_names is not None

    def _named_surface_of(self, j: int):
        """The faces (or points) the labeller names ``j``, positions only."""
        import open3d as o3d

        g = self.segmentation.geometry
        if type(g).__name__ == "TriangleMesh":
            part = g.select_faces_by_mask(g.triangle["label"] == j)
            return o3d.t.geometry.TriangleMesh(part.vertex.positions, part.triangle.indices)
        return o3d.t.geometry.PointCloud(g.select_by_mask(g.point["label"][:, 0] == j).point.positions)

    def _cuboid_of(self, k: int):
        mesh, edges = self.segmentation.cuboid_mesh, self.segmentation.cuboid_edges
        return mesh.select_faces_by_mask(mesh.triangle["part"] == k), _lines_of(edges, k)

    def visible(self, name: str) -> bool:
        """Whether the geometry ``name`` is shown (its part not hidden, its kind switched on)."""
        kind, k = name.split()[:2]
        if kind == LABEL:
            return self.show_surface
        if int(k) in self.hidden:
            return False
        return self.show_surface if kind == SURFACE else self.show_cuboids

    def geometries(self) -> list[dict]:
        """The named geometries of the scene, as ``open3d.visualization.draw`` takes them:
        ``surface k`` (part ``k``'s faces or points), or by name ``label j <name>`` (:attr:`named`),
        ``cuboids k`` (its cuboid) and ``edges k``."""
        palette = part_colors(max(self.segmentation.cuboids.count, 1)) / 255.0
        mesh = type(self.segmentation.geometry).__name__ == "TriangleMesh"
        out = []
        labels = self.segmentation.labelled.face_labels if mesh else self.segmentation.labelled.point_labels
        if self.named:
            names = self.segmentation.label_names
            colours = label_colors(len(names)) / 255.0
            for j in sorted(set(np.unique(self.segmentation.labelled.labels).tolist()) - {-1}):
                material = _material("defaultLit" if mesh else "defaultUnlit", [*colours[j], 1.0])
                out.append({"name": f"{LABEL} {j} {names[j]}", "geometry": self._named_surface_of(j),
                            "material": material, "group": SURFACE, "is_visible": self.visible(f"{LABEL} {j}")})
        for k in [] if self.named else sorted(set(np.unique(labels).tolist()) - {-1}):
            colour = [*palette[k], 1.0]
            material = _material("defaultLit" if mesh else "defaultUnlit", colour)
            out.append({"name": f"{SURFACE} {k}", "geometry": self._surface_of(k), "material": material,
                        "group": SURFACE, "is_visible": self.visible(f"{SURFACE} {k}")})
        for k in self.parts:
            box, edges = self._cuboid_of(k)
            out.append({"name": f"{CUBOIDS} {k}", "geometry": box, "group": CUBOIDS,
                        "material": _material("defaultLitTransparency", [*palette[k], 0.45]),
                        "is_visible": self.visible(f"{CUBOIDS} {k}")})
            out.append({"name": f"{CUBOIDS} {k} edges", "geometry": edges, "group": CUBOIDS,
                        "material": _material("unlitLine", [0.0, 0.0, 0.0, 1.0], line_width=2.0),
                        "is_visible": self.visible(f"{CUBOIDS} {k}")})
        return out

    def _names(self) -> list[str]:
        return [g["name"] for g in self.geometries()]

    def _apply(self, window) -> None:
        for g in self.geometries():
            window.show_geometry(g["name"], g["is_visible"])
        window.post_redraw()

    # ---- the actions ----------------------------------------------------------------------------

    def actions(self) -> list[tuple[str, object]]:
        """``(label, callable(window))`` pairs, one button each."""
        names = self.segmentation.part_names
        acts = [(f"part {k} {names[k]}", lambda w, k=k: self.toggle_part(w, k)) for k in self.parts]
        acts += [("surface", self.toggle_surface), ("cuboids", self.toggle_cuboids)]
        if self.segmentation.label_names is not None:
            acts.append(("colour by name", self.toggle_names))
        return acts + [(f"refine +{self.refine_step}", self.refine), ("export", self.export)]

    def toggle_part(self, window, k: int) -> bool:
        """Hide part ``k`` (its surface and cuboid) if shown, show it if hidden; returns whether it is shown."""
        self.hidden ^= {int(k)}
        self._apply(window)
        return int(k) not in self.hidden

    def toggle_surface(self, window) -> bool:
        self.show_surface = not self.show_surface
        self._apply(window)
        return self.show_surface

    def toggle_cuboids(self, window) -> bool:
        self.show_cuboids = not self.show_cuboids
        self._apply(window)
        return self.show_cuboids

    def toggle_names(self, window) -> bool:
        """Colour the surface by name if by part, by part if by name (the geometries are swapped);
        returns whether it is by name."""
        for name in self._names():
            window.remove_geometry(name)
        self.by_name = not self.by_name
        for g in self.geometries():
            window.add_geometry(g)
        window.post_redraw()
        return self.named

    def refine(self, window) -> int:
        """Refine the cuboids by ``refine_step`` more steps (from the network's answer: refine=total)
        and redraw; returns the total."""
        for name in self._names():
            window.remove_geometry(name)
        self.options = {**self.options, "refine": self.refined + self.refine_step}
        self.segmentation = segment_geometry(self.source, self.model, **self.options)
        for g in self.geometries():
            window.add_geometry(g)
        window.post_redraw()
        self._tell(window, "refined", f"{self.name}: cuboids refined by {self.refined} steps")
        return self.refined

    def export(self, window) -> ExportedFiles | None:
        """Write the cuboids, labels and coloured parts into :attr:`export_folder` (refused, with a
        message, when a file is there already). Returns the paths written (None when refused)."""
        folder = Path(self.export_folder)
        labelled = self.segmentation.labelled
        mesh = labelled.face_labels is not None
        written = ExportedFiles(cuboids=folder / f"{self.name}.cuboids.json",
                                labels=folder / (f"{self.name}.seg" if mesh else f"{self.name}.parts.npy"),
                                parts=folder / f"{self.name}.parts.ply")
        paths = {"cuboids": written.cuboids, "labels": written.labels, "parts": written.parts}
        there = [p for p in paths.values() if p.exists()]
        if there:
            self._tell(window, "not exported", f"{there[0]} exists: nothing written (remove it, or start the viewer "
                                               "with another --export folder)")
            return None
        folder.mkdir(parents=True, exist_ok=True)
        palette = np.vstack([part_colors(max(labelled.cuboids.count, 1)), [[200, 200, 200]]]).astype(np.uint8)
        labelled.abstraction.result.save_json(paths["cuboids"])
        if mesh:
            vertices, faces = self.shape
            io.write_labels(paths["labels"], labelled.face_labels)
            io.write_mesh(paths["parts"], vertices, faces, face_colors=palette[labelled.face_labels])
        else:
            with io.atomic_output(paths["labels"]) as tmp, open(tmp, "wb") as handle:
                np.save(handle, labelled.point_labels)
            io.write_points(paths["parts"], self.shape, labels=labelled.point_labels,
                            colors=palette[labelled.point_labels])
        self._tell(window, "exported", "wrote " + ", ".join(str(p) for p in paths.values()))
        return written

    def _tell(self, window, title: str, text: str) -> None:
        self.messages.append(text)
        if hasattr(window, "show_message_box"):
            window.show_message_box(title, text)

    # ---- the window -----------------------------------------------------------------------------

    def window(self, *, width: int = 1280, height: int = 900, settings: bool = True):
        """Open3D's window with this scene and these actions (an ``O3DVisualizer``, what
        ``open3d.visualization.draw`` builds), added to the GUI application: ``(app, window)``.
        ``app.run()`` runs it until closed; ``app.run_one_tick()`` one frame at a time."""
        import open3d as o3d

        app = o3d.visualization.gui.Application.instance
        app.initialize()
        w = o3d.visualization.O3DVisualizer(f"primkit - {self.name}", width, height)
        w.show_skybox(False)
        w.set_background((1.0, 1.0, 1.0, 1.0), None)
        w.show_settings = settings
        for g in self.geometries():
            w.add_geometry(g)
        for label, action in self.actions():
            w.add_action(label, action)
        app.add_window(w)
        app.run_one_tick()  # laid out: now the camera can be set
        w.scene.view.set_post_processing(False)  # plain colours on white (no tone mapping)
        self._look(w, width, height)
        return app, w

    def _look(self, window, width: int, height: int) -> None:
        """Point the window's camera (:meth:`_aim`)."""
        self._aim(window.scene.camera, width, height)
        window.post_redraw()

    def _aim(self, cam, width: int, height: int) -> None:
        """The camera convention of every primkit picture (:data:`primkit.viz.camera.CAMERA`'s direction
        and up), perspective here, the shape's bounding sphere filling the view."""
        from open3d.visualization import rendering

        points = self.shape[0] if isinstance(self.shape, tuple) else self.shape
        lo, hi = np.min(points, axis=0), np.max(points, axis=0)
        centre, radius = (lo + hi) / 2, max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
        d = np.asarray(CAMERA.direction, float) / np.linalg.norm(CAMERA.direction)
        fov = 30.0
        distance = 1.1 * radius / np.tan(np.radians(fov / 2))
        cam.look_at(centre.astype(np.float32), (centre + distance * d).astype(np.float32), np.asarray(CAMERA.up, np.float32))
        cam.set_projection(fov, width / max(height, 1), 0.01 * distance, 10.0 * distance,
                           rendering.Camera.FovType.Vertical)

    def render(self, *, width: int = 1280, height: int = 900) -> np.ndarray:
        """The scene as the window shows it (visible geometry, white background, the same camera),
        drawn by Open3D's ``OffscreenRenderer``, which needs no display: Filament on EGL or, here,
        Vulkan (Mesa's llvmpipe on the CPU). Returns ``(height, width, 3) uint8``."""
        from open3d.visualization import rendering

        renderer = rendering.OffscreenRenderer(int(width), int(height))
        try:
            scene = renderer.scene
            scene.set_background([1.0, 1.0, 1.0, 1.0])
            scene.view.set_post_processing(False)  # plain colours on white, as in the window
            scene.set_lighting(rendering.Open3DScene.LightingProfile.NO_SHADOWS, -np.asarray(CAMERA.direction, np.float32))
            for g in self.geometries():
                if g["is_visible"]:
                    scene.add_geometry(g["name"], g["geometry"], g["material"])
            self._aim(scene.camera, width, height)
            return np.asarray(renderer.render_to_image()).copy()
        finally:
            del renderer

    def show(self, *, width: int = 1280, height: int = 900) -> None:
        """Open the window and run it until it is closed."""
        app, _ = self.window(width=width, height=height)
        app.run()

    def picture(self, path, *, width: int = 1280, height: int = 900, timeout: float = 60.0, overwrite: bool = False,
                offscreen: bool | None = None):
        """Write the scene to the PNG ``path``; returns the path.

        ``offscreen`` (default: when there is no ``DISPLAY``/``WAYLAND_DISPLAY``) draws it with
        :meth:`render`, no window; otherwise the window's first frames are taken (under X or
        ``xvfb-run``) and the window then closes."""
        import os
        import time

        path = Path(path)
        io.refuse_existing(path, overwrite)
        if offscreen is None:
            offscreen = not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
        if offscreen:
            from PIL import Image

            image = self._with_legend(self.render(width=width, height=height))
            with io.atomic_output(path, overwrite=overwrite) as tmp:
                Image.fromarray(image).save(tmp, format="PNG")
            return path
        app, w = self.window(width=width, height=height, settings=False)
        with io.atomic_output(path, overwrite=overwrite) as tmp:
            target = Path(tmp).with_name(Path(tmp).stem + ".open3d.png")  # Open3D writes it when a frame is drawn
            for _ in range(5):
                app.run_one_tick()
            w.export_current_image(str(target))
            w.post_redraw()  # the picture is taken when the next frame is drawn
            deadline = time.monotonic() + timeout
            while not target.is_file() and time.monotonic() < deadline:
                app.run_one_tick()
            if not target.is_file():
                raise RuntimeError(f"Open3D drew no picture in {timeout:.0f} s")
            target.replace(tmp)
        w.close()
        app.run_one_tick()
        return path


    def _with_legend(self, image: np.ndarray) -> np.ndarray:
        """``image`` with a legend of the names under it when the surface is drawn by name."""
        if not self.named:
            return image
        from ..segmentation.outputs import legend_strip

        names = self.segmentation.label_names
        return np.vstack([image, legend_strip(names, label_colors(len(names)), image.shape[1])])


def _lines_of(edges, k: int):
    """The lines of part ``k`` of a tensor line set (with their attributes; all points kept)."""
    import open3d as o3d

    keep = np.flatnonzero(edges.line["part"].numpy() == k)
    ls = o3d.t.geometry.LineSet()
    ls.point.positions = edges.point.positions
    ls.line.indices = o3d.core.Tensor(edges.line.indices.numpy()[keep])
    ls.line["part"] = o3d.core.Tensor(edges.line["part"].numpy()[keep])
    ls.line["colors"] = o3d.core.Tensor(edges.line["colors"].numpy()[keep])
    return ls


def open3d_viewer(shape, model="chair", *, name: str = "shape", refine_step: int = 100,
                  export_folder="primkit-export", names: bool = False, labeller="auto", **options) -> Open3DViewer:
    """Build the Open3D viewer of one shape.

    Parameters
    ----------
    shape : ``(vertices, faces)`` or ``(n, 3)`` points (the input's frame), or an Open3D mesh or cloud
    model : a bundled model's name, a model file or an Abstractor
    names : draw the surface by name at start (the model's labeller; by part when it has none)
    labeller : ``"auto"`` (the model file's, when ``model`` is a file or a bundled name), None, or a
        :class:`primkit.segmentation.labeller.Labeller`; with one, a ``colour by name`` button
    options : :func:`primkit.abstract`'s (``up``, ``front``, ``align``, ``refine``, ...)
    """
    from ..model.abstraction import load_model
    from ..segmentation import resolve_labeller
    from ..viz.interop import mesh_to_o3d_tensor, points_to_o3d_tensor

    options["labeller"] = resolve_labeller(model, labeller)
    abstractor = load_model(model)
    if type(shape).__module__.split(".")[0] == "open3d":
        from ..viz.interop import mesh_from_o3d, points_from_o3d

        if type(shape).__name__ == "TriangleMesh":
            m = mesh_from_o3d(shape)
            shape = (m.vertices, m.faces)
        else:
            shape = points_from_o3d(shape)[0]
    if isinstance(shape, tuple):
        source = mesh_to_o3d_tensor(*shape)
    else:
        shape = np.asarray(shape, float)
        source = points_to_o3d_tensor(shape)
    seg = segment_geometry(source, abstractor, **options)
    return Open3DViewer(name, shape, source, abstractor, seg, options=dict(options), refine_step=refine_step,
                        export_folder=Path(export_folder), by_name=bool(names))

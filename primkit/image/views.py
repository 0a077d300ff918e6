"""Training views: pictures of shapes rendered off screen, with their cameras, cached to disk.

The image abstractor (:mod:`primkit.image.distill`) learns from pictures of shapes whose cuboids the
volume model already knows. This module makes those pictures: a shape's surface in its canonical
frame (+Y up, front toward +X, longest side 1), seen from a random viewpoint around the upright
shape, under random lighting and a random object colour, composited over a random background.

The camera is :class:`primkit.image.camera.OrbitCamera` (its convention is written there).

Decisions:

* **Surface.** ShapeNetVox32 has only grids, so the picture is of the grid's surface: VTK's
  flying-edges contour of the occupancy at 0.5 (smoother than the voxel faces, closer to what a
  photo of the object shows). A grid too thin to contour falls back to
  :func:`primkit.geometry.voxel_boundary_mesh`.
* **Backgrounds are drawn in NumPy, not by the renderer.** The shape is rendered once over a
  transparent background (VTK's alpha channel is the silhouette), then composited over a
  background image. That keeps the renderer's work to the shape and makes the background families
  easy to hold out: ``palette="seen"`` (training) uses solid colours, linear gradients and smooth
  noise with hues in [0, 0.5); ``palette="unseen"`` (evaluation) uses radial gradients, stripes,
  checkers and fine noise with hues in [0.5, 1). Neither the kinds nor the colours of the unseen
  backgrounds occur in training.
* **Foregrounds for background swapping.** ``render_views(..., keep_foreground=True)`` also keeps
  each view's shape alone (``foreground``: colour premultiplied by coverage, and ``alpha``), so
  that training can lay a fresh background under every view at every step
  (:func:`primkit.image.distill.train_image_model`) instead of learning one fixed background per view.
* **Anti-aliasing** by rendering at ``supersample`` times the size and averaging blocks.
* **Determinism.** Every random choice of view ``j`` of shape ``i`` comes from
  ``np.random.default_rng([seed, i, j])``, so a view does not depend on which other views are
  rendered, and the software rasteriser (Mesa llvmpipe through EGL) gives the same pixels.
* **One plotter for many views.** :class:`ViewRenderer` keeps one off-screen plotter and swaps the
  mesh, camera and lights per view (``benchmarks/bench_image.py`` measures what that saves over a
  new plotter per view).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import voxel_boundary_mesh
from ..io import atomic_output
from ..viz.backend import pyvista_module
from .backgrounds import PALETTES, random_background, random_colour
from .camera import OrbitCamera, ViewSettings, random_camera

__all__ = ["RenderedViews", "ViewRenderer", "shape_surface", "render_views", "render_views_cached", "load_views"]


def shape_surface(occupancy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A triangle surface of an occupancy grid in the canonical frame.

    occupancy : (R, R, R) bool (the grid convention of :mod:`primkit`).
    Returns ``vertices (n, 3) float, faces (f, 3) int`` (VTK's flying-edges contour at 0.5 of the
    grid padded by one empty cell; the voxel boundary if the contour is empty).
    """
    pv = pyvista_module()
    occ = np.asarray(occupancy, bool)
    r = occ.shape[0]
    padded = np.pad(occ, 1).astype(np.float32)
    image = pv.ImageData(dimensions=padded.shape, spacing=(1.0 / r,) * 3, origin=(-0.5 - 0.5 / r,) * 3)
    image.point_data["occ"] = padded.ravel(order="F")
    surface = image.contour([0.5], scalars="occ")
    if surface.n_cells == 0:
        return voxel_boundary_mesh(occ)
    surface = surface.triangulate()
    faces = surface.faces.reshape(-1, 4)[:, 1:]
    return np.asarray(surface.points, float), faces.astype(np.int64)


@dataclass(frozen=True)
class RenderedViews:
    """Views of shapes, aligned arrays.

    images : (k, S, S, 3) uint8
    shape_index : (k,) int, which shape each view shows (index into the shapes given)
    cameras : (k, 4) float, :meth:`OrbitCamera.as_array` of each view
    names : list of str, the shapes' names (``len(shapes)``)
    settings : ViewSettings
    palette : str
    seed : int
    foreground : (k, S, S, 3) uint8 or None, the shape alone: colour times coverage (premultiplied)
    alpha : (k, S, S) uint8 or None, the shape's coverage of each pixel (255: fully covered)

    ``images`` is ``foreground + background * (1 - alpha)`` (up to rounding), so with the two
    optional arrays a view can be laid over any background (:meth:`composite`).
    """

    images: np.ndarray
    shape_index: np.ndarray
    cameras: np.ndarray
    names: list
    settings: ViewSettings
    palette: str
    seed: int
    foreground: np.ndarray | None = None
    alpha: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.images)

    def camera(self, i: int) -> OrbitCamera:
        return OrbitCamera.from_array(self.cameras[i])

    def composite(self, backgrounds: np.ndarray) -> np.ndarray:
        """The views laid over other backgrounds.

        backgrounds : (k, S, S, 3) float in [0, 1], one per view. Returns ``(k, S, S, 3) uint8``.
        Needs views rendered with ``keep_foreground=True``.
        """
        if self.foreground is None:
            raise ValueError("these views were rendered without keep_foreground=True")
        a = self.alpha[..., None] / 255.0
        img = self.foreground / 255.0 + np.asarray(backgrounds, float) * (1 - a)
        return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)

    def save(self, path) -> None:
        """Write an ``.npz`` file (atomically; replaces an existing one: it is a cache)."""
        import json

        meta = {"names": list(self.names), "settings": self.settings.to_dict(), "palette": self.palette, "seed": self.seed}
        extra = {} if self.foreground is None else {"foreground": self.foreground, "alpha": self.alpha}
        with atomic_output(path, overwrite=True) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, images=self.images, shape_index=self.shape_index, cameras=self.cameras,
                         meta=np.array(json.dumps(meta)), **extra)


def load_views(path) -> RenderedViews:
    """Read views written by :meth:`RenderedViews.save`."""
    import json

    with np.load(path) as z:
        meta = json.loads(str(z["meta"]))
        fg = (z["foreground"], z["alpha"]) if "foreground" in z.files else (None, None)
        return RenderedViews(z["images"], z["shape_index"], z["cameras"], meta["names"],
                             ViewSettings.from_dict(meta["settings"]), meta["palette"], int(meta["seed"]), *fg)


class ViewRenderer:
    """One off-screen plotter that renders many views (mesh, camera and lights swapped per view).

    ``render(vertices, faces, camera, rng)`` returns ``(rgb (S, S, 3) float in [0, 1],
    alpha (S, S) float in [0, 1])`` at ``settings.size`` (rendered ``supersample`` times larger and
    block-averaged). Use as a context manager or call :meth:`close`.
    """

    def __init__(self, settings: ViewSettings = ViewSettings()):
        self.settings = settings
        self._pv = pyvista_module()
        big = settings.size * settings.supersample
        self._plotter = self._pv.Plotter(off_screen=True, window_size=(big, big), lighting="none")
        self._plotter.set_background("black")
        # pyvista moves an unset camera to its default view at a plotter's first render: spend that
        # first render on the empty scene, so every view gets the camera it asks for
        self._plotter.screenshot(return_img=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self._plotter is not None:
            self._plotter.close()
            self._plotter = None

    def render(self, vertices, faces, camera: OrbitCamera, rng: np.random.Generator):
        pv, pl, s = self._pv, self._plotter, self.settings
        faces = np.asarray(faces, np.int64)
        mesh = pv.PolyData(np.asarray(vertices, float), np.hstack([np.full((len(faces), 1), 3), faces]).ravel())
        colour = random_colour(rng, (0.0, 1.0), saturation=(0.0, 0.8), value=(0.35, 1.0))
        pl.add_mesh(mesh, color=colour, name="shape", smooth_shading=True,
                    ambient=rng.uniform(0.1, 0.35), diffuse=rng.uniform(0.6, 0.9),
                    specular=rng.uniform(0.0, 0.4), specular_power=rng.uniform(5, 30))
        pl.remove_all_lights()
        for _ in range(int(rng.integers(1, 3))):
            direction = rng.normal(size=3)
            direction[1] = abs(direction[1]) + 0.3  # light from above more often than not
            light = pv.Light(position=tuple(3 * direction / np.linalg.norm(direction)), focal_point=(0, 0, 0),
                             intensity=rng.uniform(0.5, 1.0), light_type="scene light")
            pl.add_light(light)
        pl.camera_position = [tuple(camera.position), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)]
        pl.camera.view_angle = camera.view_angle_deg
        pl.camera.clipping_range = (max(camera.distance - 1.5, 0.01), camera.distance + 1.5)
        pl.render()
        rgba = pl.screenshot(transparent_background=True, return_img=True).astype(float) / 255.0
        k = s.supersample
        rgba = rgba.reshape(s.size, k, s.size, k, 4).mean(axis=(1, 3))
        return rgba[..., :3], rgba[..., 3]


def render_views(
    occupancies,
    views_per_shape: int = 1,
    *,
    settings: ViewSettings = ViewSettings(),
    palette: str = "seen",
    seed: int = 0,
    names=None,
    renderer: ViewRenderer | None = None,
    progress: bool = False,
    first_index: int = 0,
    keep_foreground: bool = False,
) -> RenderedViews:
    """Render ``views_per_shape`` random views of each shape.

    Parameters
    ----------
    occupancies : sequence of (R, R, R) bool
        Canonical occupancy grids (``PreparedShape.occupancy``).
    palette : "seen" or "unseen"
        The background family (see the module docstring).
    seed : int
        View ``j`` of shape ``i`` draws everything from ``default_rng([seed, i, j])``.
    renderer : ViewRenderer, optional
        Reuse an open renderer (its settings win); a new one is opened and closed otherwise.
    first_index : int
        Number the shapes from here in the seed (to render a long list in chunks with the same
        pixels as in one go).
    keep_foreground : bool
        Also keep each view's shape alone (``foreground``, ``alpha``) for background swapping.
        The composited ``images`` are the same pixels either way.
    """
    if palette not in PALETTES:
        raise ValueError(f"palette must be one of {PALETTES}, got {palette!r}")
    own = renderer is None
    renderer = renderer or ViewRenderer(settings)
    settings = renderer.settings
    images, index, cams, fgs, alphas = [], [], [], [], []
    shapes = 0
    try:
        from tqdm.auto import tqdm

        for i, occ in enumerate(tqdm(occupancies, desc="rendering", unit="shape", disable=not progress)):
            v, f = shape_surface(occ)
            shapes = i + 1
            for j in range(views_per_shape):
                rng = np.random.default_rng([seed, first_index + i, j])
                cam = random_camera(rng, settings)
                rgb, alpha = renderer.render(v, f, cam, rng)
                bg = random_background(settings.size, rng, palette)
                img = rgb * alpha[..., None] + bg * (1 - alpha[..., None])
                images.append(np.clip(np.round(img * 255), 0, 255).astype(np.uint8))
                if keep_foreground:
                    fgs.append(np.clip(np.round(rgb * alpha[..., None] * 255), 0, 255).astype(np.uint8))
                    alphas.append(np.clip(np.round(alpha * 255), 0, 255).astype(np.uint8))
                index.append(i)
                cams.append(cam.as_array())
    finally:
        if own:
            renderer.close()
    count = len(index)
    names = list(names) if names is not None else [f"shape{i}" for i in range(shapes)]
    s = settings.size
    fg = ((np.array(fgs, np.uint8).reshape(count, s, s, 3), np.array(alphas, np.uint8).reshape(count, s, s))
          if keep_foreground else (None, None))
    return RenderedViews(np.array(images, np.uint8).reshape(count, s, s, 3), np.array(index, np.int64),
                         np.array(cams, float).reshape(count, 4), names, settings, palette, int(seed), *fg)


def render_views_cached(path, occupancies, views_per_shape: int = 1, **kwargs) -> RenderedViews:
    """:func:`render_views` through an ``.npz`` cache file: read it when it exists and was made
    with the same settings, palette, seed and shape names; render and write it otherwise."""
    path = Path(path)
    names = kwargs.get("names")
    if path.is_file():
        views = load_views(path)
        same = (views.settings == kwargs.get("settings", ViewSettings()) and views.palette == kwargs.get("palette", "seen")
                and views.seed == kwargs.get("seed", 0) and (names is None or list(names) == views.names)
                and len(views) == len(views.names) * views_per_shape
                and (views.foreground is not None or not kwargs.get("keep_foreground")))
        if same:
            return views
    views = render_views(occupancies, views_per_shape, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    views.save(path)
    return views

"""Training views: pictures of shapes rendered off screen, with their cameras, cached to disk.

The image abstractor (:mod:`primkit.image_model`) learns from pictures of shapes whose cuboids the
volume model already knows. This module makes those pictures: a shape's surface in its canonical
frame (+Y up, front toward +X, longest side 1), seen from a random viewpoint around the upright
shape, under random lighting and a random object colour, composited over a random background.

Camera convention (written once, here)::

    position = distance * (cos(el) cos(az), sin(el), -cos(el) sin(az))    looking at the origin, +Y up
    az = 0: seen from the front (+X); az = 90 deg: from the shape's right (-Z); el > 0: from above
    view_angle: vertical field of view (VTK's); images are square, pixel (0, 0) is the top left

:func:`project` maps canonical points to pixels with exactly this camera; a test checks it against
the rendered silhouette.

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
  (:func:`primkit.image_model.train_image_model`) instead of learning one fixed background per view.
* **Anti-aliasing** by rendering at ``supersample`` times the size and averaging blocks.
* **Determinism.** Every random choice of view ``j`` of shape ``i`` comes from
  ``np.random.default_rng([seed, i, j])``, so a view does not depend on which other views are
  rendered, and the software rasteriser (Mesa llvmpipe through EGL) gives the same pixels.
* **One plotter for many views.** :class:`ViewRenderer` keeps one off-screen plotter and swaps the
  mesh, camera and lights per view (``benchmarks/bench_image.py`` measures what that saves over a
  new plotter per view).
"""

from __future__ import annotations

import colorsys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .. import geometry

__all__ = [
    "ViewSettings",
    "Camera",
    "RenderedViews",
    "ViewRenderer",
    "shape_surface",
    "random_background",
    "project",
    "render_views",
    "load_views",
]

PALETTES = ("seen", "unseen")
#: hue ranges (HSV hue in [0, 1)) of the background palettes
PALETTE_HUES = {"seen": (0.0, 0.5), "unseen": (0.5, 1.0)}


@dataclass(frozen=True)
class ViewSettings:
    """How views are drawn. ``size`` is the image side in pixels (what the image network reads)."""

    size: int = 64
    supersample: int = 2
    elevation_deg: tuple = (0.0, 40.0)
    distance: tuple = (1.9, 2.3)
    view_angle_deg: float = 35.0

    def to_dict(self) -> dict:
        d = asdict(self)
        d["elevation_deg"] = list(self.elevation_deg)
        d["distance"] = list(self.distance)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ViewSettings":
        d = dict(d)
        d["elevation_deg"] = tuple(d["elevation_deg"])
        d["distance"] = tuple(d["distance"])
        return cls(**d)


@dataclass(frozen=True)
class Camera:
    """A camera looking at the origin of the canonical frame with +Y up (see the module docstring)."""

    azimuth_deg: float
    elevation_deg: float
    distance: float
    view_angle_deg: float

    @property
    def position(self) -> np.ndarray:
        """``(3,) float``: the camera centre in the canonical frame."""
        az, el = np.radians(self.azimuth_deg), np.radians(self.elevation_deg)
        return self.distance * np.array([np.cos(el) * np.cos(az), np.sin(el), -np.cos(el) * np.sin(az)])

    def as_array(self) -> np.ndarray:
        """``(4,) float``: azimuth, elevation (degrees), distance, view angle (degrees)."""
        return np.array([self.azimuth_deg, self.elevation_deg, self.distance, self.view_angle_deg], float)

    @classmethod
    def from_array(cls, a) -> "Camera":
        a = np.asarray(a, float)
        return cls(float(a[0]), float(a[1]), float(a[2]), float(a[3]))


def project(points: np.ndarray, camera: Camera, size: int) -> np.ndarray:
    """Pixel coordinates of canonical points seen by ``camera`` in a ``size`` x ``size`` image.

    points : (n, 3) float. Returns ``(n, 2) float`` as (column, row), (0, 0) the top-left corner of
    the top-left pixel; points behind the camera come back as NaN.
    """
    points = np.asarray(points, float).reshape(-1, 3)
    eye = camera.position
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    d = points - eye
    x, y, z = d @ right, d @ up, d @ forward
    f = (size / 2.0) / np.tan(np.radians(camera.view_angle_deg) / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([size / 2.0 + f * x / z, size / 2.0 - f * y / z], axis=1)
    uv[z <= 1e-9] = np.nan
    return uv


def shape_surface(occupancy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A triangle surface of an occupancy grid in the canonical frame.

    occupancy : (R, R, R) bool (the grid convention of :mod:`primkit`).
    Returns ``vertices (n, 3) float, faces (f, 3) int`` (VTK's flying-edges contour at 0.5 of the
    grid padded by one empty cell; the voxel boundary if the contour is empty).
    """
    from ..viz.render import _pyvista

    pv = _pyvista()
    occ = np.asarray(occupancy, bool)
    r = occ.shape[0]
    padded = np.pad(occ, 1).astype(np.float32)
    image = pv.ImageData(dimensions=padded.shape, spacing=(1.0 / r,) * 3, origin=(-0.5 - 0.5 / r,) * 3)
    image.point_data["occ"] = padded.ravel(order="F")
    surface = image.contour([0.5], scalars="occ")
    if surface.n_cells == 0:
        return geometry.voxel_boundary_mesh(occ)
    surface = surface.triangulate()
    faces = surface.faces.reshape(-1, 4)[:, 1:]
    return np.asarray(surface.points, float), faces.astype(np.int64)


def _colour(rng, hues, saturation=(0.2, 0.9), value=(0.25, 1.0)) -> np.ndarray:
    h = rng.uniform(*hues)
    return np.array(colorsys.hsv_to_rgb(h % 1.0, rng.uniform(*saturation), rng.uniform(*value)))


def _smooth_noise(rng, size: int, cells: int) -> np.ndarray:
    """``(size, size) float`` in [0, 1]: a ``cells`` x ``cells`` random grid, bilinearly upsampled."""
    from scipy.ndimage import zoom

    g = rng.uniform(0, 1, (cells + 1, cells + 1))
    z = zoom(g, size / (cells + 1), order=1, mode="nearest")[:size, :size]
    z = np.pad(z, ((0, size - z.shape[0]), (0, size - z.shape[1])), mode="edge")
    return (z - z.min()) / max(z.max() - z.min(), 1e-9)


def random_background(size: int, rng: np.random.Generator, palette: str = "seen") -> np.ndarray:
    """A background image ``(size, size, 3) float`` in [0, 1] from one of the two palettes
    (see the module docstring: ``"seen"`` for training, ``"unseen"`` held out for evaluation)."""
    if palette not in PALETTES:
        raise ValueError(f"palette must be one of {PALETTES}, got {palette!r}")
    hues = PALETTE_HUES[palette]
    a, b = _colour(rng, hues), _colour(rng, hues)
    yy, xx = np.mgrid[0:size, 0:size] / max(size - 1, 1)
    if palette == "seen":
        kind = rng.integers(3)
        if kind == 0:  # solid
            w = np.zeros((size, size))
        elif kind == 1:  # linear gradient in a random direction
            t = rng.uniform(0, 2 * np.pi)
            w = np.cos(t) * xx + np.sin(t) * yy
            w = (w - w.min()) / max(w.max() - w.min(), 1e-9)
        else:  # smooth noise
            w = _smooth_noise(rng, size, int(rng.integers(2, 6)))
    else:
        kind = rng.integers(4)
        if kind == 0:  # radial gradient
            c = rng.uniform(0, 1, 2)
            w = np.clip(np.hypot(xx - c[0], yy - c[1]) / 1.2, 0, 1)
        elif kind == 1:  # stripes
            t = rng.uniform(0, np.pi)
            period = rng.uniform(0.08, 0.3)
            w = (np.floor((np.cos(t) * xx + np.sin(t) * yy) / period) % 2).astype(float)
        elif kind == 2:  # checker
            period = rng.uniform(0.08, 0.3)
            w = ((np.floor(xx / period) + np.floor(yy / period)) % 2).astype(float)
        else:  # fine noise
            w = _smooth_noise(rng, size, int(rng.integers(10, 24)))
    return a * (1 - w[..., None]) + b * w[..., None]


@dataclass(frozen=True)
class RenderedViews:
    """Views of shapes, aligned arrays.

    images : (k, S, S, 3) uint8
    shape_index : (k,) int, which shape each view shows (index into the shapes given)
    cameras : (k, 4) float, :meth:`Camera.as_array` of each view
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

    def camera(self, i: int) -> Camera:
        return Camera.from_array(self.cameras[i])

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

        from ..io import atomic_output

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
        from ..viz.render import _pyvista

        self.settings = settings
        self._pv = _pyvista()
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

    def render(self, vertices, faces, camera: Camera, rng: np.random.Generator):
        pv, pl, s = self._pv, self._plotter, self.settings
        faces = np.asarray(faces, np.int64)
        mesh = pv.PolyData(np.asarray(vertices, float), np.hstack([np.full((len(faces), 1), 3), faces]).ravel())
        colour = _colour(rng, (0.0, 1.0), saturation=(0.0, 0.8), value=(0.35, 1.0))
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


def random_camera(rng: np.random.Generator, settings: ViewSettings) -> Camera:
    """Azimuth uniform all around, elevation and distance uniform in the settings' ranges."""
    return Camera(float(rng.uniform(0, 360)), float(rng.uniform(*settings.elevation_deg)),
                  float(rng.uniform(*settings.distance)), float(settings.view_angle_deg))


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

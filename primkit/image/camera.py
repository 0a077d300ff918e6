"""The training views' camera and how views are drawn.

OrbitCamera convention (written once, here)::

    position = distance * (cos(el) cos(az), sin(el), -cos(el) sin(az))    looking at the origin, +Y up
    az = 0: seen from the front (+X); az = 90 deg: from the shape's right (-Z); el > 0: from above
    view_angle: vertical field of view (VTK's); images are square, pixel (0, 0) is the top left

:func:`project` maps canonical points to pixels with exactly this camera; a test checks it against
the rendered silhouette.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["ViewSettings", "OrbitCamera", "project", "random_camera", "viewpoint_targets"]


@dataclass(frozen=True)
class ViewSettings:
    """How views are drawn. ``size`` is the image side in pixels (what the image network reads)."""

    size: int = 64
    supersample: int = 2
    elevation_deg: tuple = (0.0, 40.0)
    distance: tuple = (1.9, 2.3)
    view_angle_deg: float = 35.0

    def to_dict(self) -> dict:
        """JSON-ready: the ranges as lists."""
        return {**asdict(self), "elevation_deg": list(self.elevation_deg), "distance": list(self.distance)}

    @classmethod
    def from_dict(cls, d: dict) -> "ViewSettings":
        return cls(**{**d, "elevation_deg": tuple(d["elevation_deg"]), "distance": tuple(d["distance"])})


@dataclass(frozen=True)
class OrbitCamera:
    """A perspective camera on an orbit around the origin of the canonical frame, looking at it with
    +Y up (see the module docstring). Not :class:`primkit.viz.camera.Camera`, the drawing kit's view
    direction shared by every tile."""

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
    def from_array(cls, a) -> "OrbitCamera":
        a = np.asarray(a, float)
        return cls(float(a[0]), float(a[1]), float(a[2]), float(a[3]))


def project(points: np.ndarray, camera: OrbitCamera, size: int) -> np.ndarray:
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


def random_camera(rng: np.random.Generator, settings: ViewSettings) -> OrbitCamera:
    """Azimuth uniform all around, elevation and distance uniform in the settings' ranges."""
    return OrbitCamera(float(rng.uniform(0, 360)), float(rng.uniform(*settings.elevation_deg)),
                  float(rng.uniform(*settings.distance)), float(settings.view_angle_deg))


def viewpoint_targets(cameras: np.ndarray) -> np.ndarray:
    """``(k, 3) float``: (cos az, sin az, el in radians) from ``(k, 4)`` camera arrays."""
    az, el = np.radians(cameras[:, 0]), np.radians(cameras[:, 1])
    return np.stack([np.cos(az), np.sin(az), el], axis=1)

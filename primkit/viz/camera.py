"""The camera of primkit's pictures.

**The camera convention** (so pictures of a collection line up): every tile is seen from the same
direction, ``CAMERA.direction = (1, 0.6, 1.2)`` from the focal point toward the eye, i.e. from the
front (+X in primkit's canonical frame), a little to the right (+Z) and above (+Y), with +Y up on
screen, and with a *parallel* projection. The focal point is the centre of the tile's bounding box;
the scale is common to all tiles of one picture: the largest bounding-sphere radius among them
(half the box diagonal), plus 5 %. So two shapes of the same size are drawn at the same size, a
shape half as large is drawn half as large, and a moved shape is drawn the same. For canonical
shapes (inside [-0.5, 0.5]^3) pass ``radius=CANONICAL_RADIUS`` to fix the scale across pictures
too. Perspective would make sizes depend on depth, hence parallel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Camera", "CAMERA", "CANONICAL_RADIUS", "apply_camera"]


#: Bounding-sphere radius of the canonical cube [-0.5, 0.5]^3.
CANONICAL_RADIUS = float(np.sqrt(3) / 2)


@dataclass(frozen=True)
class Camera:
    """A view direction and up vector shared by every tile (see the module notes).

    direction : (3,) float, from the focal point toward the eye; up : (3,) float; margin : fraction
    of the radius left around the shape.
    """

    direction: tuple = (1.0, 0.6, 1.2)
    up: tuple = (0.0, 1.0, 0.0)
    margin: float = 0.05

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit vectors ``(toward the eye, screen up, screen right)``, each (3,) float."""
        d = np.asarray(self.direction, float)
        d = d / np.linalg.norm(d)
        up = np.asarray(self.up, float)
        up = up - d * (up @ d)
        up = up / np.linalg.norm(up)
        return d, up, np.cross(up, d)


CAMERA = Camera()


def apply_camera(renderer, center, radius: float, camera: Camera = CAMERA) -> None:
    """Point ``renderer``'s camera (a pyvista Plotter or Renderer) at ``center`` (3,) from
    ``camera.direction``, parallel projection, a viewport half-height of ``radius * (1 + margin)``."""
    d, up, _ = camera.basis()
    center = np.asarray(center, float)
    radius = float(max(radius, 1e-9))
    cam = renderer.camera
    cam.focal_point = tuple(center)
    cam.position = tuple(center + d * 4.0 * radius)
    cam.up = tuple(up)
    cam.enable_parallel_projection()
    cam.parallel_scale = radius * (1.0 + camera.margin)
    renderer.reset_camera_clipping_range()

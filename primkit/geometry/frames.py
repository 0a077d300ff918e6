"""The canonical frame: the input's up and front axes turned to +Y and +X, the bounding box centred
and scaled (the convention written in :mod:`primkit`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CanonicalFrame", "axis_rotation", "canonical_frame"]


_AXES = {"+x": (0, 1.0), "-x": (0, -1.0), "+y": (1, 1.0), "-y": (1, -1.0), "+z": (2, 1.0), "-z": (2, -1.0)}


def _axis_vector(name: str) -> np.ndarray:
    key = name.strip().lower()
    if key in ("x", "y", "z"):
        key = "+" + key
    if key not in _AXES:
        raise ValueError(f"axis must be one of {sorted(_AXES)}, got {name!r}")
    index, sign = _AXES[key]
    vec = np.zeros(3)
    vec[index] = sign
    return vec


def axis_rotation(up: str = "+y", front: str = "+x") -> np.ndarray:
    """Rotation taking the input's ``up`` axis to +Y and its ``front`` axis to +X.

    Parameters
    ----------
    up, front : str
        Signed axis names such as ``"+z"`` or ``"-x"``; they must be perpendicular.

    Returns
    -------
    rotation : (3, 3) float
        Proper rotation (det 1) acting on column vectors: ``canonical = rotation @ x``.
    """
    u = _axis_vector(up)
    fr = _axis_vector(front)
    if abs(u @ fr) > 0.5:
        raise ValueError(f"up {up!r} and front {front!r} must be different axes")
    # rows are the input directions that become canonical X, Y, Z
    return np.stack([fr, u, np.cross(fr, u)])


@dataclass(frozen=True)
class CanonicalFrame:
    """A similarity transform into the canonical frame: ``canonical = scale * (rotation @ x - centre)``.

    Attributes
    ----------
    rotation : (3, 3) float
        Axis permutation / sign change into +Y up, +X front.
    centre : (3,) float
        Bounding-box centre of the rotated input.
    scale : float
        Factor that makes the longest side of the bounding box ``size``.
    """

    rotation: np.ndarray
    centre: np.ndarray
    scale: float

    def to_canonical(self, points: np.ndarray) -> np.ndarray:
        """``(n, 3) float`` input-frame points to ``(n, 3) float`` canonical points."""
        points = np.asarray(points, dtype=np.float64)
        return (points @ self.rotation.T - self.centre) * self.scale

    def from_canonical(self, points: np.ndarray) -> np.ndarray:
        """``(n, 3) float`` canonical points back to the input frame."""
        points = np.asarray(points, dtype=np.float64)
        return (points / self.scale + self.centre) @ self.rotation

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) float homogeneous matrix of :meth:`to_canonical`."""
        m = np.eye(4)
        m[:3, :3] = self.scale * self.rotation
        m[:3, 3] = -self.scale * self.centre
        return m

    def to_dict(self) -> dict:
        return {"rotation": self.rotation.tolist(), "centre": self.centre.tolist(), "scale": float(self.scale)}

    @classmethod
    def from_dict(cls, d: dict) -> "CanonicalFrame":
        return cls(np.asarray(d["rotation"], float), np.asarray(d["centre"], float), float(d["scale"]))


def canonical_frame(points: np.ndarray, up: str = "+y", front: str = "+x", size: float = 1.0) -> CanonicalFrame:
    """Frame that rotates ``up`` to +Y and ``front`` to +X, centres the bounding box at the
    origin and scales its longest side to ``size``.

    Parameters
    ----------
    points : (n, 3) float
        Vertices or points of the shape in its own frame.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ValueError("`points` must be (n, 3) float with n > 0")
    rotation = axis_rotation(up, front)
    rotated = points @ rotation.T
    lo, hi = rotated.min(axis=0), rotated.max(axis=0)
    extent = float((hi - lo).max())
    if not np.isfinite(extent) or extent <= 0:
        raise ValueError("shape has zero extent")
    return CanonicalFrame(rotation, (lo + hi) / 2.0, size / extent)

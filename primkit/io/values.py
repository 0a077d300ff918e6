"""The values the readers return: :class:`Mesh`, :class:`PointCloud`, :class:`VoxelGrid`, and
:class:`ShapeFileError`, the one error a file that cannot be used raises."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ShapeFileError", "Mesh", "PointCloud", "VoxelGrid"]


class ShapeFileError(ValueError):
    """A shape or label file that cannot be used, with the reason on one line.

    ``str(err) == f"{path}: {reason}"``; ``err.path`` and ``err.reason`` keep the parts.
    """

    def __init__(self, path, reason):
        reason = " ".join(str(reason).split())
        self.path = path
        self.reason = reason
        super().__init__(f"{path}: {reason}")

    def __reduce__(self):
        # rebuild from both parts so the error survives pickling (worker processes)
        return (type(self), (self.path, self.reason))


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices : (n, 3) float64
      Vertex positions.
    faces : (f, 3) int64
      Indices into ``vertices``, with the winding and order of the file they came from.
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        vertices = np.asarray(self.vertices, dtype=np.float64)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ValueError(f"`vertices` must be (n, 3) float, got shape {vertices.shape}")
        faces = np.asarray(self.faces)
        if faces.size == 0:
            faces = faces.reshape((0, 3))
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"`faces` must be (f, 3) int, got shape {faces.shape}")
        if faces.size and not np.issubdtype(faces.dtype, np.integer):
            raise ValueError(f"`faces` must be (f, 3) int, got dtype {faces.dtype}")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces.astype(np.int64, copy=False))

    def __repr__(self):
        return f"Mesh(vertices={self.vertices.shape}, faces={self.faces.shape})"

    def face_areas(self) -> np.ndarray:
        """Area of every face.

        Returns
        -------
        areas : (f,) float
        """
        # np.cross and np.linalg.norm spelt out: the same operations in the same order, so the
        # same bits, in half the time (the readers check every mesh's area)
        v, f = self.vertices, self.faces
        a = v[f[:, 0]]
        u, w = v[f[:, 1]] - a, v[f[:, 2]] - a
        cx = u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1]
        cy = u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2]
        cz = u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]
        return 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)

    def area(self) -> float:
        """Total surface area."""
        return float(self.face_areas().sum())

    def bounds(self) -> np.ndarray:
        """Axis-aligned bounding box of the vertices.

        Returns
        -------
        bounds : (2, 3) float
          ``[min, max]`` corners.
        """
        if len(self.vertices) == 0:
            raise ValueError("a mesh without vertices has no bounds")
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])


@dataclass(frozen=True, eq=False)
class PointCloud:
    """A set of points, with optional normals.

    Attributes
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64 or None
    """

    points: np.ndarray
    normals: np.ndarray | None = None

    def __post_init__(self):
        points = np.asarray(self.points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"`points` must be (n, 3) float, got shape {points.shape}")
        object.__setattr__(self, "points", points)
        if self.normals is not None:
            normals = np.asarray(self.normals, dtype=np.float64)
            if normals.shape != points.shape:
                raise ValueError(
                    f"`normals` must be (n, 3) float like `points` {points.shape}, "
                    f"got shape {normals.shape}"
                )
            object.__setattr__(self, "normals", normals)

    def __repr__(self):
        normals = None if self.normals is None else self.normals.shape
        return f"PointCloud(points={self.points.shape}, normals={normals})"


@dataclass(frozen=True, eq=False)
class VoxelGrid:
    """A cubic occupancy grid in the coordinates of the model it was made from.

    Attributes
    ----------
    occupancy : (R, R, R) bool
      Indexed ``[x, y, z]``. For ShapeNetVox32 files +y is up and chair backs lie toward low x.
    translate : (3,) float64
      Model coordinates of the grid's minimum corner.
    scale : float
      Side length of the whole grid in model units.

    The centre of voxel ``idx = (i, j, k)`` is ``translate + (idx + 0.5) / R * scale``.
    """

    occupancy: np.ndarray
    translate: np.ndarray
    scale: float

    def __post_init__(self):
        occupancy = np.asarray(self.occupancy, dtype=bool)
        if occupancy.ndim != 3 or len(set(occupancy.shape)) != 1:
            raise ValueError(f"`occupancy` must be (R, R, R) bool, got shape {occupancy.shape}")
        translate = np.asarray(self.translate, dtype=np.float64)
        if translate.shape != (3,):
            raise ValueError(f"`translate` must be (3,) float, got shape {translate.shape}")
        object.__setattr__(self, "occupancy", occupancy)
        object.__setattr__(self, "translate", translate)
        object.__setattr__(self, "scale", float(self.scale))

    def __repr__(self):
        return (
            f"VoxelGrid(resolution={self.resolution}, occupied={int(self.occupancy.sum())}, "
            f"translate={self.translate.tolist()}, scale={self.scale})"
        )

    @property
    def resolution(self) -> int:
        """Cells per axis, ``R``."""
        return int(self.occupancy.shape[0])

    def voxel_centres(self) -> np.ndarray:
        """Centre of every voxel in model coordinates.

        Returns
        -------
        centres : (R, R, R, 3) float
          ``centres[i, j, k] = translate + ((i, j, k) + 0.5) / R * scale``.
        """
        r = self.resolution
        index = np.stack(np.meshgrid(*(np.arange(r),) * 3, indexing="ij"), axis=-1)
        return self.translate + (index + 0.5) / r * self.scale

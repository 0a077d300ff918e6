"""The values the readers return: :class:`Mesh`, :class:`PointCloud`, :class:`VoxelGrid`, and
:class:`ShapeFileError`, the one error a file that cannot be used raises."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ShapeFileError", "Mesh", "PointCloud", "VoxelGrid", "COORDINATE_LIMIT", "mesh_arrays",
           "check_coordinates", "usable_shape"]

#: the largest coordinate magnitude a shape may have: the frames scale shapes by their extent and
#: the cuboid transforms take the cube root of their matrix's determinant, so an extent cubed must
#: stay a finite float64 (1e100 ** 3 = 1e300); from about 1e103 it overflows to inf. No real shape
#: comes near; a file that does holds garbage.
COORDINATE_LIMIT = 1e100


def _numeric(values, what: str, shape: str) -> np.ndarray:
    """``values`` as an array of real numbers, or TypeError naming ``what`` and its dtype."""
    try:
        a = np.asarray(values)
    except (ValueError, TypeError) as exc:  # ragged nested lists
        raise TypeError(f"`{what}` must be {shape}, got {type(values).__name__} ({exc})") from None
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise TypeError(f"`{what}` must be {shape}, got dtype {a.dtype}")
    return a


def mesh_arrays(vertices, faces, *, empty: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices, faces)`` as ``(n, 3) float64`` and ``(f, 3) int64`` with every face index in
    ``0..n-1``: the structure every compiled mesh kernel relies on (an index out of range would
    read past the vertex array).

    TypeError for a dtype that is not real numbers (faces: integers), ValueError for a shape or an
    index out of range; ``empty=False`` also refuses meshes without faces.
    """
    v = _numeric(vertices, "vertices", "(n, 3) float").astype(np.float64, copy=False)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"`vertices` must be (n, 3) float, got shape {v.shape}")
    f = np.asarray(faces)
    if f.size == 0 and f.dtype.kind in "fOU":  # [] and np.array([]) are no faces, whatever their dtype
        f = f.astype(np.int64)
    f = _numeric(f, "faces", "(f, 3) int")
    if f.size and not np.issubdtype(f.dtype, np.integer):  # ValueError as before: a float array is numbers
        raise ValueError(f"`faces` must be (f, 3) int, got dtype {f.dtype}")
    if f.size == 0:
        f = f.reshape((0, 3))
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"`faces` must be (f, 3) int, got shape {f.shape}")
    if not empty and len(f) == 0:
        raise ValueError("no faces")
    if f.size:
        lo, hi = int(f.min()), int(f.max())
        if lo < 0 or hi >= len(v):
            raise ValueError(f"face index out of range ({lo}..{hi} for {len(v)} vertices)")
    return v, f.astype(np.int64, copy=False)


def check_coordinates(values: np.ndarray, what: str) -> None:
    """ValueError unless every coordinate of ``values`` ((n, 3) float) is finite and within
    :data:`COORDINATE_LIMIT`; the message says how many rows are not."""
    finite = np.isfinite(values).all(axis=1)
    if not finite.all():
        raise ValueError(f"NaN or inf coordinates in {int((~finite).sum())} of {len(values)} {what}")
    far = (np.abs(values) > COORDINATE_LIMIT).any(axis=1)
    if far.any():
        raise ValueError(f"coordinates beyond +-{COORDINATE_LIMIT:g} in {int(far.sum())} of {len(values)} {what} "
                         f"(largest {float(np.abs(values).max()):.3g})")


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
        vertices, faces = mesh_arrays(self.vertices, self.faces)
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)

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
        points = _numeric(self.points, "points", "(n, 3) float").astype(np.float64, copy=False)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"`points` must be (n, 3) float, got shape {points.shape}")
        object.__setattr__(self, "points", points)
        if self.normals is not None:
            normals = _numeric(self.normals, "normals", "(n, 3) float").astype(np.float64, copy=False)
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
        occupancy = np.asarray(self.occupancy)
        if occupancy.dtype != bool:
            # a float grid (a distance field, probabilities) cast to bool would be silently all True
            raise TypeError(f"`occupancy` must be (R, R, R) bool, got dtype {occupancy.dtype}")
        if occupancy.ndim != 3 or len(set(occupancy.shape)) != 1:
            raise ValueError(f"`occupancy` must be (R, R, R) bool, got shape {occupancy.shape}")
        translate = np.asarray(self.translate, dtype=np.float64)
        if translate.shape != (3,):
            raise ValueError(f"`translate` must be (3,) float, got shape {translate.shape}")
        scale = float(self.scale)
        if not (np.isfinite(translate).all() and np.isfinite(scale) and scale > 0):
            raise ValueError(f"a voxel grid needs a finite `translate` and a `scale` > 0, got {translate.tolist()}, {scale}")
        object.__setattr__(self, "occupancy", occupancy)
        object.__setattr__(self, "translate", translate)
        object.__setattr__(self, "scale", scale)

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


def usable_shape(shape):
    """The check every shape passes before it is prepared, however it came (a file, arrays, a
    trimesh, pyvista or Open3D object): ``(shape, dropped)`` with ``dropped`` the number of
    vertices no face references, left out of a returned copy of a mesh (a stray vertex would
    otherwise stretch the canonical frame built from the vertices' bounding box).

    ValueError (one line, without the input's name: the caller adds it) for an empty shape, NaN or
    inf coordinates, coordinates beyond :data:`COORDINATE_LIMIT`, zero extent or zero area.
    The value constructors have already checked dtypes, shapes and face indices.
    """
    if isinstance(shape, VoxelGrid):
        if not shape.occupancy.any():
            raise ValueError("empty voxel grid (no occupied voxel)")
        if shape.occupancy.all():  # as the file readers refuse it: no surface inside the grid
            raise ValueError("every voxel is occupied (no surface inside the grid)")
        check_coordinates(shape.translate[None], "translations")
        if shape.scale > COORDINATE_LIMIT:
            raise ValueError(f"voxel grid scale {shape.scale:.3g} beyond {COORDINATE_LIMIT:g}")
        return shape, 0
    if isinstance(shape, PointCloud):
        if len(shape.points) == 0:
            raise ValueError("no points")
        check_coordinates(shape.points, "points")
        if not np.ptp(shape.points, axis=0).max() > 0:
            raise ValueError("zero extent (all points are equal)")
        return shape, 0
    if not isinstance(shape, Mesh):
        raise TypeError(f"expected a Mesh, PointCloud or VoxelGrid, got {type(shape).__name__}")
    if len(shape.faces) == 0:
        raise ValueError("no faces")
    used = np.zeros(len(shape.vertices), bool)
    used[shape.faces.ravel()] = True
    dropped = int(len(used) - used.sum())
    if dropped:
        renumber = np.cumsum(used) - 1
        shape = Mesh(shape.vertices[used], renumber[shape.faces])
    check_coordinates(shape.vertices, "vertices")
    extent = float(np.ptp(shape.vertices, axis=0).max())
    if not shape.area() > 1e-12 * extent**2 or extent == 0:
        raise ValueError("zero total area (all faces are degenerate)")
    return shape, dropped

"""One shape's preparation: a mesh, point cloud or voxel grid turned into the arrays the abstractor
learns from, in the canonical frame (:func:`prepare`, :class:`PreparedShape`, :class:`PrepareSettings`)."""

from __future__ import annotations

import json
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import geometry, io


#: bump when the arrays produced by :func:`prepare` change meaning; part of every cache key
#: (2: an inside-out mesh keeps its interior; 3: voxel grids prepared from the grid itself, samples
#: drawn on the voxel squares; 4: a mesh's far cells take their closest points from their
#: neighbours', exact within 2 cells of the surface, and its occupancy primkit's winding numbers)
PREPARATION_VERSION = 4


@dataclass(frozen=True)
class PrepareSettings:
    """How shapes are prepared. Every field is part of the cache key.

    Attributes
    ----------
    resolution : int
        Cells per axis of the occupancy and distance grids (32 in the paper).
    samples : int
        Area-uniform surface samples kept per shape.
    up, front : str
        The input's up and front axes (``"+y"``, ``"-z"``, ...); COSEG and ShapeNet are ``+y`` up.
    seed : int
        Seed of the surface sampling.
    """

    resolution: int = 32
    samples: int = 10000
    up: str = "+y"
    front: str = "+x"
    seed: int = 0

    def __post_init__(self):
        if self.resolution < 4:
            raise ValueError("`resolution` must be >= 4")
        if self.samples < 1:
            raise ValueError("`samples` must be >= 1")
        geometry.axis_rotation(self.up, self.front)  # validates the axes

    def key(self) -> str:
        payload = dict(asdict(self), version=PREPARATION_VERSION)
        return json.dumps(payload, sort_keys=True)


@dataclass(frozen=True)
class PreparedShape:
    """One shape, ready for training or inference (canonical frame, grid convention of :mod:`primkit`).

    Attributes
    ----------
    name : str
        File stem (or a caller's name).
    occupancy : (R, R, R) bool
        Network input: solid cells (winding number) plus every cell the surface passes through.
    solid : (R, R, R) bool
        Solid occupancy alone (for volumetric IoU).
    closest : (R, R, R, 3) float32
        Closest surface point of each cell centre; the distance grid is ``|closest - centres|``.
    points : (n, 3) float32
        Area-uniform surface samples.
    point_faces : (n,) int32
        Face of each sample of the input mesh (-1 for voxel grids prepared at their own resolution
        and for point clouds).
    point_labels : (n,) int32
        Part label of each sample's face when a ``.seg`` file accompanies the mesh, else -1.
    frame : geometry.CanonicalFrame
        Maps the input's coordinates to the canonical frame (``frame.from_canonical`` undoes it).
    source : str
        Path of the file it came from ('' when prepared from arrays).
    kind : str
        ``"mesh"``, ``"points"`` or ``"voxels"``.
    """

    name: str
    occupancy: np.ndarray
    solid: np.ndarray
    closest: np.ndarray
    points: np.ndarray
    point_faces: np.ndarray
    point_labels: np.ndarray
    frame: geometry.CanonicalFrame
    source: str = ""
    kind: str = "mesh"
    info: dict = field(default_factory=dict)

    @property
    def resolution(self) -> int:
        return self.occupancy.shape[0]

    @property
    def distance(self) -> np.ndarray:
        """(R, R, R) float32 distance of each cell centre to the surface."""
        centres = geometry.grid_centres(self.resolution)
        return np.linalg.norm(self.closest - centres, axis=-1).astype(np.float32)

    def save(self, path) -> None:
        """Write to an uncompressed ``.npz`` (atomically)."""
        meta = {"name": self.name, "frame": self.frame.to_dict(), "source": self.source, "kind": self.kind, "info": self.info}
        with io.atomic_output(path, overwrite=True) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(
                    fh,
                    occupancy=np.packbits(self.occupancy),
                    solid=np.packbits(self.solid),
                    closest=self.closest,
                    points=self.points,
                    point_faces=self.point_faces,
                    point_labels=self.point_labels,
                    meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
                )

    @classmethod
    def load(cls, path) -> "PreparedShape":
        """Read a file written by :meth:`save` (plain arrays only; nothing is unpickled)."""
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(z["meta"].tobytes().decode())
            closest = z["closest"]
            res = closest.shape[0]
            shape = (res, res, res)
            return cls(
                name=meta["name"],
                occupancy=np.unpackbits(z["occupancy"])[: res**3].reshape(shape).astype(bool),
                solid=np.unpackbits(z["solid"])[: res**3].reshape(shape).astype(bool),
                closest=closest,
                points=z["points"],
                point_faces=z["point_faces"],
                point_labels=z["point_labels"],
                frame=geometry.CanonicalFrame.from_dict(meta["frame"]),
                source=meta["source"],
                kind=meta["kind"],
                info=meta.get("info", {}),
            )


def _rotate_voxels(occupancy: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Apply a signed axis permutation to a cubic grid about its centre."""
    res = occupancy.shape[0]
    idx = np.argwhere(occupancy)
    c = (res - 1) / 2.0
    new = np.rint((idx - c) @ rotation.T + c).astype(np.int64)
    out = np.zeros_like(occupancy)
    out[new[:, 0], new[:, 1], new[:, 2]] = True
    return out


def _from_surface(vertices, faces, solid, surface, settings, frame, *, face_labels=None, name, source, kind,
                  samples=None) -> PreparedShape:
    """The part of preparation shared by meshes and voxel grids: distances, samples, labels.

    The samples are drawn on a second thread while the distances are found (``samples``: a future
    of them already started by the caller): the far cells of the distance grid take one core."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:
        drawn = samples or pool.submit(geometry.sample_surface, vertices, faces, settings.samples, seed=settings.seed)
        dist = geometry.distance_grid(vertices, faces, settings.resolution, surface=surface)
        samples = drawn.result()
    if face_labels is not None:
        face_labels = np.asarray(face_labels)
        if len(face_labels) != len(faces):
            raise ValueError(f"{len(face_labels)} labels for {len(faces)} faces")
        labels = face_labels[samples.face_index].astype(np.int32)
    else:
        labels = np.full(len(samples.points), -1, np.int32)
    return PreparedShape(
        name=name,
        occupancy=solid | surface,
        solid=solid,
        closest=dist.closest,
        points=samples.points.astype(np.float32),
        point_faces=samples.face_index.astype(np.int32),
        point_labels=labels,
        frame=frame,
        source=source,
        kind=kind,
    )


def _canonical_voxels(grid: io.VoxelGrid, settings: PrepareSettings):
    """A voxel grid turned to the canonical axes, recentred by whole voxels, its cavities filled; and its frame."""
    occ = np.asarray(grid.occupancy, bool)
    res_in = occ.shape[0]
    if occ.shape != (res_in,) * 3:
        raise ValueError(f"voxel grid must be cubic, got {occ.shape}")
    rotation = geometry.axis_rotation(settings.up, settings.front)
    occ = _rotate_voxels(occ, rotation)
    # recentre by whole voxels so that voxels stay aligned with cells
    idx = np.argwhere(occ)
    lo, hi = idx.min(0), idx.max(0)
    shift = np.floor(((res_in - 1) - (lo + hi)) / 2.0 + 0.5).astype(np.int64)
    shifted = np.zeros_like(occ)
    new = idx + shift
    shifted[new[:, 0], new[:, 1], new[:, 2]] = True
    occ = geometry.fill_voxels(shifted)
    # frame: canonical = scale * (rotation @ x - centre), one voxel = 1 / res_in
    voxel = grid.scale / res_in
    scale = 1.0 / grid.scale
    i0 = np.argwhere(np.asarray(grid.occupancy, bool))[0]  # any occupied voxel: its centre fixes the offset
    x0 = grid.translate + (i0 + 0.5) * voxel
    c = (res_in - 1) / 2.0
    i0_can = np.rint((i0 - c) @ rotation.T + c) + shift
    p0 = -0.5 + (i0_can + 0.5) / res_in
    centre = rotation @ x0 - p0 / scale
    return occ, geometry.CanonicalFrame(rotation, centre, scale)


def _prepare_voxels(grid: io.VoxelGrid, settings: PrepareSettings, name: str, source: str) -> PreparedShape:
    occ, frame = _canonical_voxels(grid, settings)
    res_in = occ.shape[0]
    res = settings.resolution
    if res == res_in:
        # the grid is the network's input as it is, and its surface needs no mesh: exact closest
        # points by a distance transform, samples on the voxel squares (geometry.voxels)
        return PreparedShape(
            name=name,
            occupancy=occ,
            solid=occ,
            closest=geometry.voxel_closest_points(occ),
            points=geometry.sample_voxel_surface(occ, settings.samples, seed=settings.seed).astype(np.float32),
            point_faces=np.full(settings.samples, -1, np.int32),
            point_labels=np.full(settings.samples, -1, np.int32),
            frame=frame,
            source=source,
            kind="voxels",
        )
    vertices, faces = geometry.voxel_boundary_mesh(occ)
    touched = geometry.surface_voxels(vertices, faces, res)
    solid = geometry.occupancy_grid(vertices, faces, res, surface=touched)
    surface = touched & solid
    # cells of a voxel grid touched by the boundary include empty neighbours; keep occupied ones
    return _from_surface(vertices, faces, solid, surface, settings, frame, name=name, source=source, kind="voxels")


def _prepare_points(cloud: io.PointCloud, settings: PrepareSettings, name: str, source: str) -> PreparedShape:
    from scipy.spatial import cKDTree

    frame = geometry.canonical_frame(cloud.points, settings.up, settings.front)
    pts = frame.to_canonical(cloud.points)
    rng = np.random.default_rng(settings.seed)
    take = rng.choice(len(pts), settings.samples, replace=len(pts) < settings.samples)
    res = settings.resolution
    centres = geometry.grid_centres(res).reshape(-1, 3)
    _, nearest = cKDTree(pts).query(centres)
    closest = pts[nearest].reshape(res, res, res, 3)
    cells = np.clip(np.floor((pts + 0.5) * res).astype(np.int64), 0, res - 1)
    surface = np.zeros((res,) * 3, bool)
    surface[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    solid = geometry.fill_voxels(surface)
    return PreparedShape(
        name=name,
        occupancy=solid,
        solid=solid,
        closest=closest.astype(np.float32),
        points=pts[take].astype(np.float32),
        point_faces=np.full(settings.samples, -1, np.int32),
        point_labels=np.full(settings.samples, -1, np.int32),
        frame=frame,
        source=source,
        kind="points",
    )


def prepare(
    shape: io.Mesh | io.PointCloud | io.VoxelGrid,
    settings: PrepareSettings = PrepareSettings(),
    *,
    face_labels: np.ndarray | None = None,
    name: str = "shape",
    source: str = "",
) -> PreparedShape:
    """Prepare one shape for the abstractor.

    * **Meshes**: canonical frame from the vertices' bounding box; solid occupancy by winding
      number; surface cells; closest points (exact within 2 cells of the surface, propagated beyond:
      :func:`primkit.geometry.distance_grid`); area-uniform samples (with the label of each
      sample's face if ``face_labels`` is given).
    * **Voxel grids** (binvox): rotated to the canonical axes and recentred by whole voxels, so one
      voxel stays one cell and the grid is not resampled (one voxel = ``1 / R`` of the canonical
      cube, so a ShapeNetVox32 shape spanning the grid keeps its longest side 1). Enclosed cavities
      are filled. Samples and distances come from the voxel boundary surface; at the grid's own
      resolution from the grid itself (:mod:`primkit.geometry.voxels`: exact closest points by a
      distance transform, no mesh), otherwise through the boundary mesh.
    * **Point clouds**: samples are the points (resampled to ``settings.samples``); the closest
      point of a cell is the nearest input point; occupancy is the cells holding points with their
      enclosed cavities filled. This is an approximation: give a mesh when you have one.

    Parameters
    ----------
    face_labels : (f,) int, optional
        Per-face part labels of a mesh.
    """
    # the one check of every shape's values, however it came: compiled kernels below read what it lets through
    shape, dropped = io.values.usable_shape(shape)
    if dropped:
        warnings.warn(f"{source or name}: {dropped} vertices referenced by no face left out", stacklevel=2)
    if isinstance(shape, io.VoxelGrid):
        return _prepare_voxels(shape, settings, name, source)
    if isinstance(shape, io.PointCloud):
        return _prepare_points(shape, settings, name, source)
    if not isinstance(shape, io.Mesh):
        raise TypeError(f"cannot prepare {type(shape).__name__}")
    frame = geometry.canonical_frame(shape.vertices, settings.up, settings.front)
    vertices = frame.to_canonical(shape.vertices)
    faces = shape.faces
    res = settings.resolution
    from concurrent.futures import ThreadPoolExecutor

    # the samples on a second thread from the start: the surface cells and the tree are one thread's work
    with ThreadPoolExecutor(1) as pool:
        samples = pool.submit(geometry.sample_surface, vertices, faces, settings.samples, seed=settings.seed)
        surface = geometry.surface_voxels(vertices, faces, res)
        solid = geometry.occupancy_grid(vertices, faces, res, surface=surface)
        return _from_surface(vertices, faces, solid, surface, settings, frame, face_labels=face_labels,
                             name=name, source=source, kind="mesh", samples=samples)

"""Prepared shapes and collections: from files to the arrays the abstractor learns from.

:func:`prepare` turns one mesh, point cloud or voxel grid into a :class:`PreparedShape` in the
canonical frame. :func:`prepare_collection` does it for a whole folder, in parallel, through a cache
keyed by each file's content *and* the preparation settings, so an edited file or a changed setting
is prepared again and nothing stale is read. The torch ``Dataset`` on top lives in
:mod:`primkit.model.training` (torch stays in the model and training code).

Cache layout (:data:`CACHE_FORMAT` 2): ``<cache>/v2/<segment>/`` folders of up to
:data:`SEGMENT_SHAPES` shapes each, one ``.npy`` file per array with a row per shape (compact codes,
:mod:`primkit.geometry.quantize`; memory-mapped when read) and an ``index.json`` giving each row's
key, CRC-32 and frame. ``key`` is the SHA-256 of the file's bytes, the bytes of a ``.seg`` label
file beside it (if any), and the settings. The default cache is ``$PRIMKIT_CACHE`` or
``~/.cache/primkit/prepared``.
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import shutil
import sys
import warnings
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import geometry, io, parallel

__all__ = [
    "PrepareSettings",
    "PreparedShape",
    "prepare",
    "prepare_file",
    "find_shape_files",
    "shape_name",
    "shape_names",
    "input_files",
    "split_files",
    "default_cache_dir",
    "PreparedCollection",
    "prepare_collection",
    "CacheSegment",
    "CACHE_FORMAT",
    "compact_by_default",
]

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


def _labels_path(path: Path) -> Path | None:
    """The ``.seg`` file that goes with a mesh: ``<stem>.seg`` beside it, or COSEG's ``../gt/<stem>.seg``."""
    for cand in (path.with_suffix(".seg"), path.parent.parent / "gt" / (path.stem + ".seg")):
        if cand.is_file():
            return cand
    return None


def prepare_file(path, settings: PrepareSettings = PrepareSettings()) -> PreparedShape:
    """Read and prepare one shape file; a ``.seg`` label file beside a mesh is used if present.

    Raises :class:`primkit.io.ShapeFileError` (one line, naming the file) when the file cannot be used.
    """
    path = Path(path)
    shape = io.read_shape(path)
    labels = None
    info = {}
    if isinstance(shape, io.Mesh):
        seg = _labels_path(path)
        if seg is not None:
            try:
                labels = io.read_labels(seg, face_count=len(shape.faces))
                info["labels"] = str(seg)
            except io.ShapeFileError as exc:
                # labels are for the commands that evaluate or train on them: a stale .seg beside a
                # mesh must not keep the mesh from being abstracted; it is prepared without labels
                warnings.warn(f"{exc} (prepared without labels)", stacklevel=2)
                info["labels_error"] = str(exc)
    try:
        prepared = prepare(shape, settings, face_labels=labels, name=shape_name(path), source=str(path))
    except (ValueError, RuntimeError) as exc:
        raise io.ShapeFileError(path, f"cannot prepare: {exc}") from exc
    if info:
        prepared = PreparedShape(**{**prepared.__dict__, "info": info})
    return prepared


def find_shape_files(folder) -> list[Path]:
    """Shape files under ``folder`` (recursively, sorted), by suffix (see :func:`primkit.io.is_shape_file`).

    Symbolically linked folders are searched too (each folder once, so a link back up is not a
    loop); the hidden temporaries a killed write leaves (:func:`primkit.io.is_temporary`) are not
    shapes. A file given by name is returned as it is. An empty list means no shape file."""
    folder = Path(folder)
    if folder.is_file():
        return [folder]
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such file or folder")
    found, searched = [], set()
    for root, dirs, files in os.walk(folder, followlinks=True):
        st = os.stat(root)
        if (st.st_dev, st.st_ino) in searched:  # reached again through a link
            dirs[:] = []
            continue
        searched.add((st.st_dev, st.st_ino))
        for name in files:
            p = Path(root) / name
            # a dangling link is kept: its error line names it
            if io.is_shape_file(p) and not io.is_temporary(p) and (p.is_file() or p.is_symlink()):
                found.append(p)
    return sorted(found)


def input_files(path) -> list[Path]:
    """The files read for the shape file ``path``: itself, the ``.seg`` labels that go with it
    (:func:`prepare_file`) and the ``.json`` attributes beside procedural shapes (``primkit
    generate``). Outputs are checked against these, so that no run writes over what it reads."""
    path = Path(path)
    out = [path]
    seg = _labels_path(path)
    if seg is not None:
        out += [seg, seg.with_suffix(".json")]
    out.append(path.with_suffix(".json"))
    return [p for p in dict.fromkeys(out) if os.path.lexists(p)]


#: file stems that say nothing about the shape (ShapeNet's ``<synset>/<id>/model.binvox``); the
#: folder's name is used instead
_GENERIC_STEMS = {"model", "model_normalized", "models", "mesh", "shape"}


def shape_name(path) -> str:
    """A shape's name from its path: the file's stem, or its folder's name when the stem is generic
    (``03001627/1a6f615e8b1b5ae4dbbc9440457e303e/model.binvox`` -> ``1a6f615e...``)."""
    path = Path(path)
    if path.stem.lower() in _GENERIC_STEMS and path.parent.name:
        return path.parent.name
    return path.stem


def shape_names(paths) -> list[str]:
    """One name per path, unique within ``paths``: :func:`shape_name`, except where several paths
    share it; those take the folders that tell them apart (``a/x.ply``, ``b/x.ply`` -> ``a-x``,
    ``b-x``), or their suffix when the folder is the same (``x.ply``, ``x.obj`` -> ``x-ply``,
    ``x-obj``), and a number when nothing else differs (the same file twice: ``x``, ``x-2``).

    Outputs are named after shapes, so two inputs never write the same output file; the names
    depend only on the paths, so a run and its re-run name everything alike."""
    paths = [Path(p) for p in paths]
    names = [shape_name(p) for p in paths]
    groups: dict = {}
    for i, name in enumerate(names):
        groups.setdefault(name, []).append(i)
    out = list(names)
    for name, members in groups.items():
        if len(members) < 2:
            continue
        # the folder above the one a generic stem (model.binvox) is named after
        anchors = [Path(os.path.abspath(paths[i])).parent for i in members]
        anchors = [a.parent if paths[i].stem.lower() in _GENERIC_STEMS else a for a, i in zip(anchors, members)]
        common = os.path.commonpath(anchors)
        for a, i in zip(anchors, members):
            out[i] = "-".join(Path(a).relative_to(common).parts + (name,))
        same: dict = {}
        for i in members:
            same.setdefault(out[i], []).append(i)
        for equal in same.values():
            if len({paths[i].suffix.lower() for i in equal}) > 1:
                for i in equal:
                    out[i] = f"{out[i]}-{paths[i].suffix[1:].lower()}"
    used, planned = set(), set(out)
    for i, name in enumerate(out):  # still equal (the same file twice), or equal to another shape's name
        if name in used:
            k = 2
            while f"{name}-{k}" in used or f"{name}-{k}" in planned:
                k += 1
            out[i] = f"{name}-{k}"
        used.add(out[i])
    return out


def split_files(files, hold_out_every: int) -> tuple[list, list]:
    """Split files deterministically into (training, held-out): sorted by path, the file of rank
    ``r`` is held out when ``r % hold_out_every == hold_out_every - 1``; ``0`` holds out nothing.

    The rule depends only on the sorted paths, so the held-out set can be recomputed from a model
    file's metadata (``primkit eval --split held-out``)."""
    files = sorted(Path(p) for p in files)
    if not hold_out_every:
        return files, []
    if hold_out_every < 2:
        raise ValueError(f"hold_out_every must be 0 or at least 2, got {hold_out_every}")
    train = [p for r, p in enumerate(files) if r % hold_out_every != hold_out_every - 1]
    held = [p for r, p in enumerate(files) if r % hold_out_every == hold_out_every - 1]
    return train, held


def default_cache_dir() -> Path:
    return Path(os.environ.get("PRIMKIT_CACHE", Path.home() / ".cache" / "primkit" / "prepared"))


def _cache_key(path: Path, settings: PrepareSettings) -> str:
    h = hashlib.sha256()
    h.update(path.read_bytes())
    seg = _labels_path(path) if path.suffix.lower() != ".binvox" else None
    if seg is not None:
        h.update(b"\0labels\0")
        h.update(seg.read_bytes())
    h.update(b"\0settings\0")
    h.update(settings.key().encode())
    return h.hexdigest()


#: the cache's layout and codes; bump when either changes. Its entries live in ``<cache>/v<CACHE_FORMAT>``
CACHE_FORMAT = 2
#: shapes per segment: a run that is killed keeps every whole segment it wrote
SEGMENT_SHAPES = 256
#: the arrays of a cache row, in the order of its checksum; ``solid`` and ``labels`` only where needed
_ROW_ARRAYS = ("occupancy", "near", "closest", "points")


def compact_by_default() -> bool:
    """Whether the cache stores compact codes unless told: the default; ``PRIMKIT_CACHE_CODES=exact``
    (or ``float32``) stores the exact float32 values instead."""
    return os.environ.get("PRIMKIT_CACHE_CODES", "compact").lower() not in ("exact", "float32")


def _encode_row(shape: PreparedShape, compact: bool) -> dict:
    """The cache's arrays of one shape: bits of the grids, the closest points coordinate-planar and
    the samples, as float32 or (``compact``) as the codes of :mod:`primkit.geometry.quantize`; the
    solid grid only where it differs from the occupancy (not for voxel grids), labels only where
    there are any; no face ids (nothing reads them)."""
    if compact:
        codes, near = geometry.encode_closest(shape.closest)
        row = {"occupancy": np.packbits(shape.occupancy), "near": near, "closest": codes,
               "points": geometry.encode_points(shape.points)}
    else:
        res = shape.resolution
        row = {"occupancy": np.packbits(shape.occupancy),
               "closest": np.ascontiguousarray(np.asarray(shape.closest, np.float32).reshape(res**3, 3).T),
               "points": np.ascontiguousarray(shape.points, np.float32)}
    if not np.array_equal(shape.solid, shape.occupancy):
        row["solid"] = np.packbits(shape.solid)
    if (shape.point_labels >= 0).any():
        row["labels"] = shape.point_labels.astype(np.int16)
    meta = {"frame": shape.frame.to_dict(), "kind": shape.kind, "info": shape.info}
    return {"arrays": row, "meta": meta}


def _row_crc(arrays: dict) -> int:
    crc = 0
    for name in _ROW_ARRAYS + ("solid", "labels"):
        if name in arrays:
            crc = zlib.crc32(np.ascontiguousarray(arrays[name]).data, crc)
    return crc


def _save_rows(path: Path, rows: list) -> None:
    """An ``.npy`` file of the rows stacked (what ``np.save(path, np.stack(rows))`` writes, byte for
    byte) without building the stacked array: the header for the whole shape, then each row."""
    first = np.asarray(rows[0])
    for r in rows:
        if r.shape != first.shape or r.dtype != first.dtype:
            raise ValueError(f"{path.name}: rows of {r.dtype} {r.shape} and {first.dtype} {first.shape}")
    header = {"descr": np.lib.format.dtype_to_descr(first.dtype), "fortran_order": False,
              "shape": (len(rows),) + first.shape}
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, header)
        for r in rows:
            fh.write(np.ascontiguousarray(r).data)


class CacheSegment:
    """A block of cached shapes: one ``.npy`` file per array (rows = shapes), memory-mapped, and an
    ``index.json`` (format, settings, each row's key, checksum, frame and kind).

    Nothing is read until asked for: a row is checked (CRC-32 of its bytes) by :meth:`verify` and
    decoded by :meth:`shape`; :meth:`gather` decodes a batch of rows for training. A segment built
    by :meth:`from_rows` lives in memory until :meth:`save` writes it.
    """

    def __init__(self, arrays: dict, rows: list, settings_key: str, resolution: int, samples: int, folder=None,
                 compact: bool = False):
        self.arrays, self.rows = arrays, rows
        self.settings_key, self.resolution, self.samples = settings_key, resolution, samples
        self.folder, self.compact = folder, compact

    def _shapes(self) -> dict:
        """Each array's row shape and dtype."""
        cells = self.resolution**3
        bits = ((cells + 7) // 8,)
        out = {"occupancy": (bits, np.uint8), "closest": ((3, cells), np.float32), "points": ((self.samples, 3), np.float32),
               "solid": (bits, np.uint8), "labels": ((self.samples,), np.int16)}
        if self.compact:
            out.update(near=(bits, np.uint8), closest=((3, cells), np.uint8), points=((self.samples,), np.uint32))
        return out

    def _row_arrays_names(self) -> tuple:
        return tuple(n for n in _ROW_ARRAYS if n != "near" or self.compact)

    @classmethod
    def open(cls, folder) -> "CacheSegment":
        """The segment written in ``folder``; raises (any exception) when it is not a whole one."""
        folder = Path(folder)
        index = json.loads((folder / "index.json").read_text())
        if index.get("format") != CACHE_FORMAT:
            raise ValueError(f"format {index.get('format')}, not {CACHE_FORMAT}")
        seg = cls({}, index["rows"], index["settings"], int(index["resolution"]), int(index["samples"]), folder,
                  compact={"compact": True, "float32": False}[index["codes"]])
        for name, (want, dtype) in seg._shapes().items():
            f = folder / f"{name}.npy"
            if name in ("solid", "labels") and not f.exists():
                continue
            a = np.load(f, mmap_mode="r", allow_pickle=False)
            count = len(seg.rows) if name in _ROW_ARRAYS else 1 + max(r.get(name, -1) for r in seg.rows)
            if a.shape != (count,) + want or a.dtype != dtype:
                raise ValueError(f"{f}: {a.dtype} {a.shape}, not {np.dtype(dtype)} {(count,) + want}")
            seg.arrays[name] = a
        return seg

    @staticmethod
    def _rows_and_lists(entries: list, compact: bool) -> tuple:
        """The index rows of ``entries`` (``(key, row)`` with rows of :func:`_encode_row`) and, per
        array, the list of its row arrays."""
        rows, extra = [], {"solid": [], "labels": []}
        for key, rec in entries:
            arrays = rec["arrays"]
            row = {"key": key, "crc": _row_crc(arrays), "meta": rec["meta"]}
            for opt in extra:
                if opt in arrays:
                    row[opt] = len(extra[opt])
                    extra[opt].append(arrays[opt])
            rows.append(row)
        names = [n for n in _ROW_ARRAYS if n != "near" or compact]
        lists = {name: [rec["arrays"][name] for _, rec in entries] for name in names}
        lists.update({name: items for name, items in extra.items() if items})
        return rows, lists

    @classmethod
    def from_rows(cls, settings: PrepareSettings, entries: list, compact: bool = False) -> "CacheSegment":
        """A segment in memory of ``entries``: ``(key, row)`` with rows of :func:`_encode_row`."""
        rows, lists = cls._rows_and_lists(entries, compact)
        arrays = {name: np.stack(items) for name, items in lists.items()}
        return cls(arrays, rows, settings.key(), settings.resolution, settings.samples, compact=compact)

    @classmethod
    def write(cls, root, settings: PrepareSettings, entries: list, compact: bool = False) -> "CacheSegment":
        """:meth:`from_rows` + :meth:`save` without the stacked copy: each array's rows are streamed
        to its ``.npy`` file. Stacking a segment of 256 float32 chairs (130 MB) cost as much as
        writing it (``benchmarks/bench_abstract_collection.py``). Returns the segment memory-mapped."""
        rows, lists = cls._rows_and_lists(entries, compact)
        return cls._write_folder(root, lists, rows, settings.key(), settings.resolution, settings.samples, compact)

    def save(self, root) -> "CacheSegment":
        """Write this segment under ``root`` (a hidden folder renamed into place: a killed write
        leaves no partial segment) and return it opened from there, memory-mapped."""
        rows = {name: list(values) for name, values in self.arrays.items()}  # views of the rows
        return self._write_folder(root, rows, self.rows, self.settings_key, self.resolution, self.samples, self.compact)

    @classmethod
    def _write_folder(cls, root, arrays: dict, rows: list, settings_key: str, resolution: int, samples: int,
                      compact: bool) -> "CacheSegment":
        """``arrays``: name -> the list of its (equal) row arrays, streamed to ``<name>.npy``."""
        root = Path(root)
        # named by its keys and a random tag: unique, so that two runs writing the same shapes at
        # once (shards, a re-run after a kill) each keep theirs, and a repair never meets the
        # damaged segment it replaces
        token = secrets.token_hex(4)
        name = f"{hashlib.sha256(chr(10).join(r['key'] for r in rows).encode()).hexdigest()[:16]}-{token}"
        final = root / name
        tmp = root / f".{name}.{token}.tmp"
        tmp.mkdir(parents=True)
        try:
            for array, values in arrays.items():
                _save_rows(tmp / f"{array}.npy", values)
            index = {"format": CACHE_FORMAT, "codes": "compact" if compact else "float32",
                     "settings": settings_key, "resolution": resolution, "samples": samples, "rows": rows}
            (tmp / "index.json").write_text(json.dumps(index))
            os.rename(tmp, final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return CacheSegment.open(final)

    def __len__(self) -> int:
        return len(self.rows)

    def keys(self) -> list:
        return [r["key"] for r in self.rows]

    def row_arrays(self, j: int) -> dict:
        r = self.rows[j]
        out = {name: self.arrays[name][j] for name in self._row_arrays_names()}
        for name in ("solid", "labels"):
            if r.get(name, -1) >= 0:
                out[name] = self.arrays[name][r[name]]
        return out

    def verify(self, j: int) -> bool:
        """Whether row ``j`` reads back with its checksum (the bytes as written)."""
        try:
            return _row_crc(self.row_arrays(j)) == self.rows[j]["crc"]
        except (OSError, ValueError, IndexError, KeyError, TypeError):
            return False

    def shape(self, j: int, name: str = "", source: str = "") -> PreparedShape:
        """Row ``j`` decoded to a :class:`PreparedShape` (``point_faces`` are -1: not stored)."""
        a, r, res = self.row_arrays(j), self.rows[j], self.resolution
        grid = (res, res, res)
        occupancy = np.unpackbits(a["occupancy"])[: res**3].reshape(grid).astype(bool)
        solid = np.unpackbits(a["solid"])[: res**3].reshape(grid).astype(bool) if "solid" in a else occupancy.copy()
        labels = np.asarray(a["labels"], np.int32) if "labels" in a else np.full(self.samples, -1, np.int32)
        meta = r["meta"]
        if self.compact:
            closest, points = geometry.decode_closest(a["closest"], a["near"], res), geometry.decode_points(a["points"])
        else:
            closest, points = np.ascontiguousarray(np.asarray(a["closest"]).T).reshape(res, res, res, 3), np.array(a["points"])
        return PreparedShape(
            name=name, occupancy=occupancy, solid=solid, closest=closest,
            points=points, point_faces=np.full(self.samples, -1, np.int32),
            point_labels=labels, frame=geometry.CanonicalFrame.from_dict(meta["frame"]), source=source,
            kind=meta["kind"], info=meta.get("info", {}))

    def gather(self, rows, pick) -> tuple:
        """The arrays of several rows for a batch: occupancy (b, R, R, R) bool, the closest
        points as stored (b, 3, R^3), float32 or codes (uint8) with their near bits (b, R^3 / 8)
        uint8 (for :func:`primkit.geometry.decode_closest`, or its torch twin in training; None
        for float32), and the samples ``pick`` ((b, k) row numbers) of each row, (b, k, 3) float32."""
        res = self.resolution
        rows = np.asarray(rows)
        occ = np.unpackbits(self.arrays["occupancy"][rows], axis=1)[:, : res**3].reshape(-1, res, res, res).view(bool)
        points = self.arrays["points"][rows]
        if self.compact:
            pts = geometry.decode_points(np.take_along_axis(points, np.asarray(pick), 1))
            return occ, self.arrays["closest"][rows], self.arrays["near"][rows], pts
        pts = np.take_along_axis(points, np.asarray(pick)[..., None], 1)
        return occ, self.arrays["closest"][rows], None, pts


def _old_cache_entries(cache: Path) -> int:
    """Entries of the first cache format (``<cache>/<xx>/<key>.npz``) under ``cache``."""
    count = 0
    try:
        for sub in cache.iterdir():
            if len(sub.name) == 2 and sub.is_dir():
                count += sum(1 for f in sub.iterdir() if f.suffix == ".npz")
    except OSError:
        pass
    return count


class _CacheIndex:
    """The segments of a cache folder for one settings and codes: key -> (segment, row)."""

    def __init__(self, root: Path, settings: PrepareSettings, compact: bool):
        self.root = root
        self.where: dict = {}
        self.damaged = 0
        #: keys stored with these settings in the other codes (float32 against compact): not read,
        #: since neither kind's values are the other's (:func:`compact_by_default`)
        self.other_codes: set = set()
        key = settings.key()
        try:
            folders = sorted(p for p in root.iterdir() if not p.name.startswith(".") and p.is_dir())
        except OSError:
            folders = []
        for folder in folders:
            try:
                seg = CacheSegment.open(folder)
            except Exception:  # noqa: BLE001 - whatever is wrong with it, it holds no usable entry
                # segments are renamed into place whole, so a visible one that does not open is
                # damaged for good: removed, and its shapes are misses
                self.damaged += 1
                shutil.rmtree(folder, ignore_errors=True)
                continue
            if seg.settings_key != key:
                continue
            if seg.compact != compact:
                self.other_codes.update(seg.keys())
                continue
            for j, k in enumerate(seg.keys()):
                self.where.setdefault(k, []).append((seg, j))

    def find(self, key: str):
        """A verified (segment, row) for ``key``, or None; a key whose every copy fails its
        checksum counts as damaged (prepared again into a new segment, which then wins)."""
        candidates = self.where.get(key, ())
        for seg, j in candidates:
            if seg.verify(j):
                return seg, j
        self.damaged += bool(candidates)
        return None


def _key_job(args) -> tuple:
    path, settings = args
    try:
        return path, _cache_key(Path(path), settings), None
    except OSError as exc:
        return path, None, f"{path}: unreadable ({exc.strerror or exc})"


def _prepare_row(args) -> tuple:
    """Worker: ``(path, key, row or None, error or None)``; a bad file must not stop a batch."""
    path, settings, key, compact = args
    try:
        prepared = prepare_file(path, settings)
    except io.ShapeFileError as exc:
        return path, key, None, str(exc)
    except Exception as exc:  # noqa: BLE001
        return path, key, None, f"{path}: cannot prepare ({type(exc).__name__}: {exc})"
    return path, key, _encode_row(prepared, compact), None


@dataclass
class PreparedCollection:
    """The prepared shapes of a folder, in a stable (sorted) order, decoded on access.

    Attributes
    ----------
    paths : list of Path
        Source files that prepared successfully.
    entries : list of (CacheSegment, int)
        Where each shape is, aligned with ``paths``: a segment's row (a segment kept in memory
        where the cache could not be written).
    errors : list of str
        One line per file that could not be used.
    settings : PrepareSettings
    names : list of str, optional
        The shapes' names, aligned with ``paths``: :func:`shape_names` over every file given (so
        that two files called ``x`` get different names); :func:`shape_name` of each path when None.
    """

    paths: list
    entries: list
    errors: list
    settings: PrepareSettings
    names: list | None = None

    def __len__(self) -> int:
        return len(self.entries)

    def name(self, i: int) -> str:
        return self.names[i] if self.names is not None else shape_name(self.paths[i])

    def __getitem__(self, i: int) -> PreparedShape:
        # the cache is keyed by content, so two files with the same bytes share an entry: the name
        # and source always come from this collection's path
        seg, j = self.entries[i]
        return seg.shape(j, self.name(i), str(self.paths[i]))

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def point_labels(self, i: int) -> np.ndarray:
        """(n,) int32 part labels of shape ``i``'s samples (-1 where none), without decoding the rest."""
        seg, j = self.entries[i]
        row = seg.rows[j].get("labels", -1)
        return np.asarray(seg.arrays["labels"][row], np.int32) if row >= 0 else np.full(seg.samples, -1, np.int32)

    def gather(self, index, pick) -> tuple:
        """The arrays of the shapes ``index`` for a training batch (:meth:`CacheSegment.gather`),
        read from their segments' memory-mapped rows and nothing else: occupancy (b, R, R, R)
        bool, closest points (b, 3, R^3) as stored (float32, or uint8 codes with near bits
        (b, R^3 / 8), else None), and the samples ``pick`` ((b, k) row numbers), (b, k, 3) float32."""
        index = np.asarray(index)
        pick = np.asarray(pick)
        res = self.settings.resolution
        cells = res**3
        compact = self.entries[index[0]][0].compact if len(index) else False
        occ = np.empty((len(index), res, res, res), bool)
        codes = np.empty((len(index), 3, cells), np.uint8 if compact else np.float32)
        near = np.empty((len(index), (cells + 7) // 8), np.uint8) if compact else None
        pts = np.empty(pick.shape + (3,), np.float32)
        groups: dict = {}
        for b, i in enumerate(index):
            groups.setdefault(id(self.entries[i][0]), []).append(b)
        for members in groups.values():
            seg = self.entries[index[members[0]]][0]
            rows = [self.entries[index[b]][1] for b in members]
            o, c, n, p = seg.gather(rows, pick[members])
            occ[members], codes[members], pts[members] = o, c, p
            if near is not None:
                near[members] = n
        return occ, codes, near, pts


def _one_thread_worker(parent: int | None = None) -> None:
    """Worker-process initialiser: native thread pools (OpenMP, BLAS, torch) on one thread, and
    the worker ends with its parent (:func:`primkit.parallel.die_with_parent`)."""
    parallel.die_with_parent(parent)
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["PRIMKIT_THREADS_AUTO"] = "1"
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)
    except ImportError:  # pragma: no cover
        pass
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def parallel_map(func, jobs, *, workers: int | None = None, progress: bool = True, desc: str = "", unit: str = "shape",
                 executor=None):
    """``func`` over ``jobs`` in worker processes, results in job order, with a progress bar.

    ``workers``: processes (by default the cores free, :func:`primkit.parallel.free_cores`: a core
    another process keeps busy is not counted); 1, or a single job, runs in this process. Each
    worker runs its native libraries (OpenMP, BLAS) on one thread, so that the processes do not
    compete for the cores. ``func`` must be a module-level function and should return its errors
    rather than raise. Processes are forked on Linux (fast, and safe here: workers run
    NumPy/Open3D/libigl code only).

    ``executor``: any object with a ``concurrent.futures.Executor``'s ``map`` (a Dask client's
    ``get_executor()``, :func:`primkit.parallel.executor_from`) runs the jobs there instead.

    Why not joblib (installed with scikit-learn): its process backend, loky, spawns fresh
    interpreters instead of forking, so every run pays their start-up and imports (preparing 12
    procedural chairs on 2 workers, alternating in one run: loky 10.7-11.6 s cold against 4.4-6.5 s
    for this fork pool; 2.4 s only when loky's workers are reused across calls), keeps its workers
    alive for minutes after the run, which the SIGTERM and parent-death handling here would have to
    chase, and sets only the thread-count variables where ``_one_thread_worker`` also tells primkit's
    own thread policy. ``executor=`` remains the way to run elsewhere (Dask, Ray).
    """
    from tqdm.auto import tqdm

    jobs = list(jobs)
    workers = workers or (parallel.free_cores() if len(jobs) > 1 else 1)
    bar = tqdm(total=len(jobs), desc=desc, unit=unit, disable=not progress, file=sys.stderr)
    try:
        if executor is not None and jobs:
            for res in executor.map(func, jobs):
                yield res
                bar.update()
        elif workers == 1 or len(jobs) <= 1:
            for job in jobs:
                yield func(job)
                bar.update()
        else:
            import multiprocessing as mp

            ctx = mp.get_context("fork") if sys.platform.startswith("linux") else None
            chunk = max(1, min(64, len(jobs) // (workers * 8) or 1))
            # SIGTERM stops the run as Ctrl-C does; on either the workers are ended at once (and a
            # parent killed outright takes them with it: die_with_parent)
            with parallel.sigterm_as_interrupt(), \
                    ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx,
                                        initializer=_one_thread_worker, initargs=(os.getpid(),)) as pool:
                try:
                    for res in pool.map(func, jobs, chunksize=chunk):
                        yield res
                        bar.update()
                except BaseException:
                    parallel.terminate_pool(pool)
                    raise
    finally:
        bar.close()


def prepare_collection(
    files_or_folder,
    settings: PrepareSettings = PrepareSettings(),
    *,
    cache_dir=None,
    workers: int | None = None,
    progress: bool = True,
    compact: bool | None = None,
    executor=None,
    shard=None,
) -> PreparedCollection:
    """Prepare every shape file of a folder (or a list of files) through the cache, in parallel.

    Files that cannot be used are reported in ``errors`` (one line each, naming the file) and the
    rest go on. Files already in the cache (same bytes, same settings) are not prepared again.

    The cache (``<cache>/v2``, :data:`CACHE_FORMAT`) holds segments of up to
    :data:`SEGMENT_SHAPES` shapes, memory-mapped when read, so that a collection of any size opens
    at once and training can hold only its batch in memory. ``compact`` (default: yes,
    unless ``PRIMKIT_CACHE_CODES=exact``, which stores float32 values) stores the codes of
    :mod:`primkit.geometry.quantize`: a quarter of the first format's bytes, within the accuracy
    declared there. Every entry is checked before it is trusted (its CRC-32); a
    damaged one is a miss, prepared again and said once. A cache that cannot be written keeps the
    shapes in memory (said once). Entries of the first format are not read (said once), nor
    entries of the other codes kind (said once; both kinds then stay in the cache).

    Parameters
    ----------
    files_or_folder : path or list of paths
    workers : int, optional
        Processes to use; all cores by default. ``1`` prepares in this process.
    progress : bool
        Show a progress bar (tqdm, on stderr).
    executor : optional
        Where to prepare the shapes the cache lacks: an executor (anything with
        ``concurrent.futures.Executor.map``) or an address for :func:`primkit.parallel.executor_from`
        (a Dask scheduler ``tcp://HOST:PORT``, ``ray``). The workers need primkit and the files,
        not the cache: prepared rows come back here and are written by this process.
    shard : (k, n) or primkit.parallel.Selection, optional
        Only shard k of n of the files (:func:`primkit.parallel.shard_indices`: every n-th of the
        list, from the k-th); names are given over all the files, so the shards of one
        collection name their shapes as one run would.
    """
    from concurrent.futures import ThreadPoolExecutor

    if isinstance(files_or_folder, (str, os.PathLike)):
        files = find_shape_files(files_or_folder)
    else:
        files = [Path(p) for p in files_or_folder]
    all_names = shape_names(files)
    keep = parallel.shard_indices(len(files), shard)
    files, all_names = [files[i] for i in keep], [all_names[i] for i in keep]
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    root = cache / f"v{CACHE_FORMAT}"
    old = _old_cache_entries(cache)
    if old:
        print(f"primkit: cache: {cache} holds {old} entr{'y' if old == 1 else 'ies'} of an older format, not read: "
              f"shapes are prepared again into {root} (delete {cache}/?? to free the space)", file=sys.stderr)
    compact = compact_by_default() if compact is None else bool(compact)
    index = _CacheIndex(root, settings, compact)
    # keys: the bytes of every file hashed, in threads (reading and hashlib release the GIL)
    with ThreadPoolExecutor(max_workers=4) as pool:
        keyed = list(pool.map(_key_job, [(str(p), settings) for p in files]))
    entries: dict = {}
    errors: dict = {}
    misses: dict = {}  # key -> the paths with those bytes (prepared once)
    for path, key, error in keyed:
        if error is not None:
            errors[path] = error
            continue
        found = index.find(key)
        if found is not None:
            entries[path] = found
        else:
            misses.setdefault(key, []).append(path)
    unwritable = None
    pending: list = []

    def flush():
        nonlocal unwritable
        if not pending:
            return
        entries_ = [(key, rec) for _, key, rec in pending]
        segment = None
        if unwritable is None:
            try:
                segment = CacheSegment.write(root, settings, entries_, compact)
            except OSError as exc:  # read-only, full, not a folder: the shapes stay in memory
                unwritable = exc.strerror or str(exc)
        if segment is None:
            segment = CacheSegment.from_rows(settings, entries_, compact)
        for j, (_, key, _) in enumerate(pending):
            for path in misses[key]:
                entries[path] = (segment, j)
        pending.clear()

    jobs = [(paths[0], settings, key, compact) for key, paths in misses.items()]
    with parallel.executor_from(executor) as pool:
        for path, key, rec, error in parallel_map(_prepare_row, jobs, workers=workers, progress=progress,
                                                  desc="preparing", unit="shape", executor=pool):
            if error is not None:
                # files of the same bytes are prepared once; each is reported under its own name
                for other in misses[key]:
                    errors[other] = other + error[len(path):] if error.startswith(path) else f"{other}: {error}"
                continue
            pending.append((path, key, rec))
            if len(pending) >= SEGMENT_SHAPES:
                flush()
    flush()
    if index.damaged:
        print(f"primkit: cache: {index.damaged} damaged entr{'y' if index.damaged == 1 else 'ies'} in {root} "
              "(truncated or not an entry) prepared again", file=sys.stderr)
    other = sum(key in index.other_codes for key in misses)
    if other:
        kinds = ("float32 values (PRIMKIT_CACHE_CODES=exact)", "compact codes") if compact else \
                ("compact codes", "float32 values (PRIMKIT_CACHE_CODES=exact)")
        print(f"primkit: cache: {other} shape{'' if other == 1 else 's'} in {root} stored as {kinds[0]} prepared again "
              f"as {kinds[1]}, this run's kind", file=sys.stderr)
    if unwritable:
        print(f"primkit: cache: {root} cannot be written ({unwritable}): shapes prepared in memory", file=sys.stderr)
    paths, found, errs, names = [], [], [], []
    for p, name in zip(files, all_names):
        if str(p) in errors:
            errs.append(errors[str(p)])
        else:
            paths.append(p)
            found.append(entries[str(p)])
            names.append(name)
    return PreparedCollection(paths, found, errs, settings, names)

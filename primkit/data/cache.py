"""The cache of prepared shapes: segments of memory-mapped rows keyed by each file's content and the
preparation settings (layout in :mod:`primkit.data`'s docstring)."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import secrets
import shutil
import stat
import zlib
from pathlib import Path

import numpy as np

from .. import geometry
from .files import labels_path
from .preparation import PreparedShape, PrepareSettings


def default_cache_dir() -> Path:
    """``$PRIMKIT_CACHE``, else ``~/.cache/primkit/prepared``. A ``PRIMKIT_CACHE`` that is set but
    empty (it put the cache in the working folder, read as input shapes by the next run) or that
    names something other than a folder is a one-line ``ValueError`` naming the variable."""
    value = os.environ.get("PRIMKIT_CACHE")
    if value is None:
        return Path.home() / ".cache" / "primkit" / "prepared"
    if not value.strip():
        raise ValueError("PRIMKIT_CACHE is set but empty: set it to a folder for the cache of prepared shapes, "
                         "or unset it for ~/.cache/primkit/prepared")
    path = Path(value)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return path  # made when the first shape is stored
    except OSError as exc:
        raise ValueError(f"PRIMKIT_CACHE={value}: cannot be used ({exc.strerror})") from None
    if not stat.S_ISDIR(st.st_mode):
        raise ValueError(f"PRIMKIT_CACHE={value}: {_kind(st.st_mode)}, not a folder")
    return path


class CacheFileError(ValueError):
    """A file of the cache that is not what the cache wrote (``"<path>: <reason>"``, one line)."""


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISDIR, "a folder"),
                       (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "a regular file" if stat.S_ISREG(mode) else "not a regular file"


def _regular(path: Path) -> Path:
    """``path`` when it is a regular file itself (not a link to one); else :class:`CacheFileError`.
    Checked before any open: opening a FIFO blocks until someone writes to it, a device may never
    end, and a link may lead out of the cache."""
    mode = os.lstat(path).st_mode
    if not stat.S_ISREG(mode):
        raise CacheFileError(f"{path}: {_kind(mode)}, not a regular file")
    return path


def cache_key(path: Path, settings: PrepareSettings) -> str:
    h = hashlib.sha256()
    h.update(path.read_bytes())
    seg = labels_path(path) if path.suffix.lower() != ".binvox" else None
    if seg is not None:
        h.update(b"\0labels\0")
        h.update(seg.read_bytes())
    h.update(b"\0settings\0")
    h.update(settings.key().encode())
    return h.hexdigest()


#: the cache's layout and codes; bump when either changes. Its entries live in ``<cache>/v<CACHE_FORMAT>``
#: (3: each row's checksum covers its metadata, its frame included, as well as its arrays)
CACHE_FORMAT = 3
#: shapes per segment: a run that is killed keeps every whole segment it wrote
SEGMENT_SHAPES = 256
#: the arrays of a cache row, in the order of its checksum; ``solid`` and ``labels`` only where needed
_ROW_ARRAYS = ("occupancy", "near", "closest", "points")


def compact_by_default() -> bool:
    """Whether the cache stores compact codes unless told: the default; ``PRIMKIT_CACHE_CODES=exact``
    (or ``float32``) stores the exact float32 values instead."""
    return os.environ.get("PRIMKIT_CACHE_CODES", "compact").lower() not in ("exact", "float32")


def encode_row(shape: PreparedShape, compact: bool) -> dict:
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


def _row_crc(arrays: dict, meta: dict) -> int:
    """CRC-32 of a row's arrays and of its metadata (frame, kind, info: everything that changes
    what is read back), the metadata as canonical JSON."""
    crc = 0
    for name in _ROW_ARRAYS + ("solid", "labels"):
        if name in arrays:
            crc = zlib.crc32(np.ascontiguousarray(arrays[name]).data, crc)
    return zlib.crc32(json.dumps(meta, sort_keys=True, allow_nan=False).encode(), crc)


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
        index = json.loads(_regular(folder / "index.json").read_text())
        if index.get("format") != CACHE_FORMAT:
            raise ValueError(f"format {index.get('format')}, not {CACHE_FORMAT}")
        seg = cls({}, index["rows"], index["settings"], int(index["resolution"]), int(index["samples"]), folder,
                  compact={"compact": True, "float32": False}[index["codes"]])
        for name, (want, dtype) in seg._shapes().items():
            f = folder / f"{name}.npy"
            if name in ("solid", "labels") and not os.path.lexists(f):
                continue
            a = np.load(_regular(f), mmap_mode="r", allow_pickle=False)
            count = len(seg.rows) if name in _ROW_ARRAYS else 1 + max(r.get(name, -1) for r in seg.rows)
            if a.shape != (count,) + want or a.dtype != dtype:
                raise ValueError(f"{f}: {a.dtype} {a.shape}, not {np.dtype(dtype)} {(count,) + want}")
            seg.arrays[name] = a
        return seg

    @staticmethod
    def _rows_and_lists(entries: list, compact: bool) -> tuple:
        """The index rows of ``entries`` (``(key, row)`` with rows of :func:`encode_row`) and, per
        array, the list of its row arrays."""
        rows, extra = [], {"solid": [], "labels": []}
        for key, rec in entries:
            arrays = rec["arrays"]
            meta = json.loads(json.dumps(rec["meta"], allow_nan=False))  # as read back from index.json
            row = {"key": key, "crc": _row_crc(arrays, meta), "meta": meta}
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
        """A segment in memory of ``entries``: ``(key, row)`` with rows of :func:`encode_row`."""
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
            return _row_crc(self.row_arrays(j), self.rows[j]["meta"]) == self.rows[j]["crc"]
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


def old_cache_entries(cache: Path) -> int:
    """Entries of older cache formats under ``cache``: the first's (``<cache>/<xx>/<key>.npz``)
    and the segments of ``<cache>/v2``."""
    count = 0
    try:
        for sub in cache.iterdir():
            if len(sub.name) == 2 and sub.is_dir() and not sub.is_symlink():
                count += sum(1 for f in sub.iterdir() if f.suffix == ".npz")
            elif sub.name == "v2" and sub.is_dir() and not sub.is_symlink():
                count += sum(1 for f in sub.iterdir() if not f.name.startswith("."))
    except OSError:
        pass
    return count


class CacheIndex:
    """The segments of a cache folder for one settings and codes: key -> (segment, row)."""

    def __init__(self, root: Path, settings: PrepareSettings, compact: bool):
        self.root = root
        self.where: dict = {}
        self.damaged = 0
        #: why the first damaged segment was refused (one line), or None
        self.reason = None
        #: keys stored with these settings in the other codes (float32 against compact): not read,
        #: since neither kind's values are the other's (:func:`compact_by_default`)
        self.other_codes: set = set()
        key = settings.key()
        try:
            folders = sorted(p for p in root.iterdir() if not p.name.startswith("."))
        except OSError:
            folders = []
        for folder in folders:
            try:  # lstat: a segment is a folder the cache made, never a link to one
                mode = os.lstat(folder).st_mode
            except OSError:
                continue
            if not stat.S_ISDIR(mode) and not stat.S_ISLNK(mode):
                continue  # not a segment (the cache writes folders only); nothing is read from it
            try:
                if stat.S_ISLNK(mode):
                    raise CacheFileError(f"{folder}: a symbolic link, not a segment folder")
                seg = CacheSegment.open(folder)
            except Exception as exc:  # noqa: BLE001 - whatever is wrong with it, it holds no usable entry
                # segments are renamed into place whole, so a visible one that does not open is
                # damaged for good: removed, and its shapes are misses
                self.damaged += 1
                if self.reason is None:
                    self.reason = str(exc).splitlines()[0] if isinstance(exc, CacheFileError) else \
                        f"{folder.name}: {type(exc).__name__}"
                if stat.S_ISLNK(mode):
                    with contextlib.suppress(OSError):
                        os.unlink(folder)  # the link only, never what it points to
                else:
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

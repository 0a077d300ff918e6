"""A collection: every shape file of a folder prepared through the cache, in parallel
(:func:`prepare_collection`, :class:`PreparedCollection`)."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import io, parallel
from . import cache as _cache
from .cache import CACHE_FORMAT, CacheSegment, CacheIndex, cache_key, encode_row, old_cache_entries, \
    compact_by_default, default_cache_dir
from .files import find_shape_files, prepare_file, shape_name, shape_names
from .plan import RunPlan
from .preparation import PreparedShape, PrepareSettings

_logger = logging.getLogger(__name__)

def _key_job(args) -> tuple:
    path, settings = args
    try:
        return path, cache_key(Path(path), settings), None
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
    return path, key, encode_row(prepared, compact), None


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


def prepare_collection(
    files_or_folder,
    settings: PrepareSettings = PrepareSettings(),
    *,
    cache_dir=None,
    workers: int | None = None,
    progress: bool = False,
    compact: bool | None = None,
    executor=None,
    shard=None,
) -> PreparedCollection:
    """Prepare every shape file of a folder (or a list of files) through the cache, in parallel.

    Files that cannot be used are reported in ``errors`` (one line each, naming the file) and the
    rest go on. Files already in the cache (same bytes, same settings) are not prepared again.

    The cache (``<cache>/v3``, :data:`CACHE_FORMAT`) holds segments of up to
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
    files_or_folder : path, list of paths, or RunPlan
        A :class:`primkit.data.RunPlan` gives its files, their names and what it does of them
        (its ``selection``: the shard less what a cut run finished).
    workers : int, optional
        Processes to use; all cores by default. ``1`` prepares in this process.
    progress : bool
        Show a progress bar (tqdm, on stderr); off by default.

    Notes on the cache (an older format, damaged entries, the other codes, a cache that cannot be
    written) are WARNING records of the ``primkit.data.collection`` logger.
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

    if isinstance(files_or_folder, RunPlan):  # a planned run: its files, names and what it does of them
        files, all_names = list(files_or_folder.files), list(files_or_folder.names)
        shard = files_or_folder.selection if shard is None else shard
    else:
        if isinstance(files_or_folder, (str, os.PathLike)):
            files = find_shape_files(files_or_folder)
        else:
            files = [Path(p) for p in files_or_folder]
        all_names = shape_names(files)
    keep = parallel.shard_indices(len(files), shard)
    files, all_names = [files[i] for i in keep], [all_names[i] for i in keep]
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    root = cache / f"v{CACHE_FORMAT}"
    old = old_cache_entries(cache)
    if old:
        _logger.warning(f"cache: {cache} holds {old} entr{'y' if old == 1 else 'ies'} of an older format, not read: "
                        f"shapes are prepared again into {root} (delete {cache}/?? to free the space)")
    compact = compact_by_default() if compact is None else bool(compact)
    index = CacheIndex(root, settings, compact)
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
        for path, key, rec, error in parallel.parallel_map(_prepare_row, jobs, workers=workers, progress=progress,
                                                  desc="preparing", unit="shape", executor=pool):
            if error is not None:
                # files of the same bytes are prepared once; each is reported under its own name
                for other in misses[key]:
                    errors[other] = other + error[len(path):] if error.startswith(path) else f"{other}: {error}"
                continue
            pending.append((path, key, rec))
            if len(pending) >= _cache.SEGMENT_SHAPES:
                flush()
    flush()
    if index.damaged:
        why = index.reason or "truncated, edited or not an entry"
        _logger.warning(f"cache: {index.damaged} damaged entr{'y' if index.damaged == 1 else 'ies'} in {root} "
                        f"({why}) prepared again")
    other = sum(key in index.other_codes for key in misses)
    if other:
        kinds = ("float32 values (PRIMKIT_CACHE_CODES=exact)", "compact codes") if compact else \
                ("compact codes", "float32 values (PRIMKIT_CACHE_CODES=exact)")
        _logger.warning(f"cache: {other} shape{'' if other == 1 else 's'} in {root} stored as {kinds[0]} prepared "
                        f"again as {kinds[1]}, this run's kind")
    if unwritable:
        _logger.warning(f"cache: {root} cannot be written ({unwritable}): shapes prepared in memory")
    paths, found, errs, names = [], [], [], []
    for p, name in zip(files, all_names):
        if str(p) in errors:
            errs.append(errors[str(p)])
        else:
            paths.append(p)
            found.append(entries[str(p)])
            names.append(name)
    return PreparedCollection(paths, found, errs, settings, names)

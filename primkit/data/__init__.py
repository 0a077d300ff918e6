"""Prepared shapes and collections: from files to the arrays the abstractor learns from.

:func:`prepare` turns one mesh, point cloud or voxel grid into a :class:`PreparedShape` in the
canonical frame. :func:`prepare_collection` does it for a whole folder, in parallel, through a cache
keyed by each file's content *and* the preparation settings, so an edited file or a changed setting
is prepared again and nothing stale is read. The torch ``Dataset`` on top lives in
:mod:`primkit.model.training` (torch stays in the model and training code).

Cache layout (:data:`CACHE_FORMAT` 3): ``<cache>/v3/<segment>/`` folders of up to
:data:`SEGMENT_SHAPES` shapes each, one ``.npy`` file per array with a row per shape (compact codes,
:mod:`primkit.geometry.quantize`; memory-mapped when read) and an ``index.json`` giving each row's
key, frame and CRC-32 (of its arrays and its metadata, the frame included). ``key`` is the SHA-256
of the file's bytes, the bytes of a ``.seg`` label file beside it (if any), and the settings. Only
regular files are read from the cache (a FIFO, a device or a link there is a damaged segment). The
default cache is ``$PRIMKIT_CACHE`` (an empty one is an error) or ``~/.cache/primkit/prepared``.

The package, by concept (each module imports only the ones listed after it; ``setup.cfg``'s
import-linter contract checks it):

* :mod:`~primkit.data.collection`: a folder prepared through the cache, in parallel;
* :mod:`~primkit.data.plan`: a run over a collection planned once (files, names, shard, what is
  done, the outputs to check);
* :mod:`~primkit.data.cache`: the cache's segments and keys;
* :mod:`~primkit.data.files`: input files, the files read with each, their names, the split;
* :mod:`~primkit.data.preparation`: one shape's preparation.

The process pool the collection runs on is :func:`primkit.parallel.parallel_map`.
"""

from __future__ import annotations

from .cache import CACHE_FORMAT, SEGMENT_SHAPES, CacheSegment, compact_by_default, default_cache_dir
from .collection import PreparedCollection, prepare_collection
from .plan import RunPlan, collect_files, plan_run
from .files import find_shape_files, input_files, prepare_file, shape_name, shape_names, split_files
from .preparation import PREPARATION_VERSION, PreparedShape, PrepareSettings, prepare

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
    "RunPlan",
    "plan_run",
    "collect_files",
]

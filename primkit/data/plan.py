"""A run over a collection, planned once before any work (:func:`plan_run`, :class:`RunPlan`).

The plan says which files the run reads, the unique name each shape's outputs take
(:func:`~primkit.data.files.shape_names` over the whole collection, so the shards of one
collection name their outputs as one run would), which of them this run does (its shard, less what
a cut run already finished with ``skip_done``), and every file it will write, checked before any
work (:meth:`RunPlan.check`). The library functions that run over a collection take it in place of
their inputs: :func:`primkit.data.prepare_collection`, :func:`primkit.model.abstraction.abstract_shapes`,
:meth:`primkit.segmentation.Segmenter.segment_files` / :meth:`~primkit.segmentation.Segmenter.run`,
:func:`primkit.report.build_report`.

>>> plan = plan_run(["chairs/"], "out/", outputs=(".cuboids.json", ".cuboids.ply"), shard="2/4",
...                 skip_done=True)                                      # doctest: +SKIP
>>> plan.check(overwrite=False)     # before any work: nothing is overwritten, nothing read is written
>>> abstract_shapes(plan, "chair")  # only what is left of shard 2 of 4    # doctest: +SKIP
"""

from __future__ import annotations

import functools
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from .. import io, parallel
from .files import find_shape_files, input_files, shape_name, shape_names

__all__ = ["RunPlan", "plan_run", "collect_files"]

_logger = logging.getLogger(__name__)


def collect_files(inputs) -> list[Path]:
    """The shape files of ``inputs`` (files as given, folders searched recursively,
    :func:`~primkit.data.files.find_shape_files`), in order. A missing input, or a folder with no
    shape file in it, is a one-line error (``FileNotFoundError``) before any work."""
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    files = []
    for item in inputs:
        found = find_shape_files(item)
        if not found:
            suffixes = " ".join(dict.fromkeys(io.MESH_SUFFIXES + io.POINT_SUFFIXES + io.VOXEL_SUFFIXES))
            raise FileNotFoundError(f"{item}: no shape files in this folder (searched recursively for {suffixes})")
        files.extend(found)
    return files


@dataclass(frozen=True)
class RunPlan:
    """What a run over a collection reads, does and writes, decided before it starts.

    Attributes
    ----------
    files : list of Path
        Every shape file of the collection, in order (the whole collection, not only this shard).
    names : list of str
        The unique name of each file's outputs, aligned with ``files``.
    todo : list of int
        The positions in ``files`` this run does: its shard, less what a cut run finished.
    done : list of int
        The positions of its shard a cut run already finished (``skip_done``), left as they are.
    shard : (k, n) or None
        The shard (1-based ``k``), None for the whole collection.
    folder : Path or None
        Where the shapes' outputs go.
    outputs : dict of int -> list of Path
        Each position's output files (``todo`` and ``done``).
    extra : list of Path
        The run's other outputs (summaries, a picture, an evaluation).
    reads : list of Path
        Every file the run reads besides the shapes' (models, label folders' files): nothing it
        writes may be one of them, nor one of the shapes' files (:meth:`check`).
    leftovers : list of Path
        What a cut run left of the inputs it did not finish: removed by :meth:`check`, then redone.
    skip_done : bool
        Whether the plan left out what a cut run finished (``done``, possibly empty).
    refused : dict of int -> str
        Positions of the shard left out because an output's name is too long for the file system
        of its folder, each with its one-line error naming the input (:attr:`errors`); the rest of
        the run goes on.
    """

    files: list
    names: list
    todo: list
    done: list = field(default_factory=list)
    shard: tuple | None = None
    folder: Path | None = None
    outputs: dict = field(default_factory=dict)
    extra: list = field(default_factory=list)
    reads: list = field(default_factory=list)
    leftovers: list = field(default_factory=list)
    skip_done: bool = False
    refused: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.todo)

    @property
    def todo_files(self) -> list:
        return [self.files[i] for i in self.todo]

    @property
    def todo_names(self) -> list:
        return [self.names[i] for i in self.todo]

    @property
    def errors(self) -> list:
        """One line per input the plan refused (:attr:`refused`), in input order."""
        return [self.refused[i] for i in sorted(self.refused)]

    @property
    def selection(self):
        """The ``shard`` argument that selects ``todo`` (:func:`primkit.parallel.shard_indices`):
        the shard itself, or a :class:`primkit.parallel.Selection` when some of it is done or refused."""
        if self.skip_done or self.refused:
            return parallel.Selection(self.todo)
        return self.shard

    def written(self) -> list:
        """Every file the run may write (the outputs of ``todo``, then ``extra``)."""
        return [p for i in self.todo for p in self.outputs.get(i, ())] + [p for p in self.extra if p is not None]

    def read(self) -> list:
        """Every file the run reads: the shapes' files with the labels and attributes read with them
        (:func:`~primkit.data.files.input_files`), and ``reads``."""
        out = [p for f in self.files for p in input_files(f)]
        for item in self.reads:
            if item is None:
                continue
            item = Path(item)
            out.extend(sorted(item.iterdir()) if item.is_dir() else [item])
        return out

    def check(self, overwrite: bool = False) -> list:
        """Before any work: remove the ``leftovers`` of a cut run (redone), then check that every
        output can be written, is no input, and replaces nothing unless ``overwrite``
        (:func:`primkit.io.check_outputs`). Returns the outputs."""
        for path in self.leftovers:
            if path.is_file():
                path.unlink()
        return io.check_outputs(self.written(), inputs=self.read(), overwrite=overwrite)


def _say_shared_names(files, names) -> None:
    plain = [shape_name(p) for p in files]
    for shared in dict.fromkeys(n for n, m in zip(plain, names) if n != m):
        items = [(p, m) for p, n, m in zip(files, plain, names) if n == shared]
        _logger.info(f"{len(items)} inputs are named {shared} ({', '.join(str(p) for p, _ in items)}); "
                 f"their outputs are named {', '.join(m for _, m in items)}")


def plan_run(inputs, folder=None, *, outputs=(), extra=(), reads=(), shard=None, skip_done: bool = False,
             finished=None, limit: int | None = None) -> RunPlan:
    """Plan a run over the shape files of ``inputs``.

    Parameters
    ----------
    inputs : path or list of paths
        Shape files or folders (searched recursively, :func:`collect_files`); a missing input or
        an empty folder is a one-line ``FileNotFoundError``.
    folder : path, optional
        The output folder.
    outputs : sequence of str, or callable
        Each shape's outputs in ``folder``: suffixes added to its name (``(".cuboids.json",
        ".cuboids.ply")``), or ``outputs(name, path) -> list of Path``.
    extra, reads : lists of paths
        The run's other outputs (None entries skipped), and the files it reads besides the shapes
        (a model file, a folder of labels: its files).
    shard : (k, n), ``"K/N"``, ``"auto"`` or None
        Only the k-th of n shards (:func:`primkit.parallel.parse_shard`, :func:`primkit.parallel.shard_indices`).
    skip_done : bool
        Leave out the shard's inputs a cut run finished: by default those whose every output
        exists (``finished(name, outputs) -> bool`` decides otherwise). What it left of the
        others becomes ``leftovers``, removed by :meth:`RunPlan.check` and redone.
    limit : int, optional
        Only the first ``limit`` files of the collection.
    """
    files = collect_files(inputs)
    if limit:
        files = files[:limit]
    names = shape_names(files)
    _say_shared_names(files, names)
    if isinstance(shard, str):
        shard = parallel.parse_shard(shard)
    keep = parallel.shard_indices(len(files), shard)
    folder = None if folder is None else Path(folder)
    if callable(outputs):
        made = {i: [Path(p) for p in outputs(names[i], files[i])] for i in keep}
    else:
        made = {i: [folder / f"{names[i]}{suffix}" for suffix in outputs] for i in keep} if folder is not None else {}
    refused = _names_too_long(files, made)
    keep = [i for i in keep if i not in refused]
    todo, done, leftovers = list(keep), [], []
    if skip_done:
        finished = finished or (lambda name, paths: all(p.is_file() for p in paths))
        todo = [i for i in keep if not finished(names[i], made.get(i, []))]
        done = sorted(set(keep) - set(todo))
        leftovers = [p for i in todo for p in made.get(i, []) if p.is_file()]
        _logger.info(f"--skip-done: {len(done)} of {len(keep)} input(s) already done")
    return RunPlan(files=files, names=names, todo=todo, done=done, shard=shard, folder=folder, outputs=made,
                   extra=[Path(p) for p in extra if p is not None], reads=list(reads), leftovers=leftovers,
                   skip_done=skip_done, refused=refused)


def _names_too_long(files, made) -> dict:
    """``{position: error}`` for the inputs one of whose outputs has a name longer than its folder's
    file system allows (``NAME_MAX``, 255 bytes on most): that input is one error, not a stopped run."""
    refused = {}
    for i, paths in made.items():
        for path in paths:
            size, limit = len(os.fsencode(path.name)), _name_max(str(path.parent))
            if size > limit:
                refused[i] = (f"{files[i]}: its output's name is too long for the file system ({path.name[:40]}... "
                              f"is {size} bytes, at most {limit} in {path.parent}); rename the input")
                break
    return refused


@functools.lru_cache(maxsize=64)
def _name_max(folder: str) -> int:
    """The longest file name (bytes) the file system of ``folder`` (or of its nearest existing
    ancestor) allows; 255 where the system does not say."""
    while folder and not os.path.isdir(folder) and os.path.dirname(folder) != folder:
        folder = os.path.dirname(folder)
    try:
        return int(os.pathconf(folder or ".", "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255

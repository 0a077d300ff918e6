"""Co-segmenting collections: abstract shape files with a model, then label each file's elements
(a mesh's faces, a voxel grid's voxels, a point cloud's points) by their primitives (a graph cut
by default, or each to its nearest), in parallel processes."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import io, parallel
from ..parallel import parallel_map
from ..model.abstraction import abstract, abstract_shapes, load_model
from .labeller import (Labeller, LabellerSettings, frame_features, grid_elements, label_elements, mesh_elements,
                       point_elements, read_labeller)
from . import graphcut
from .meshes import Segmentation, segment_mesh
from .points import PointSegmentation, segment_points
from .voxels import VoxelSegmentation, segment_voxels

__all__ = ["Segmenter", "segment", "apply_labeller", "shape_elements", "fit_labeller", "write_summary", "read_summary", "summary_header"]


def _segment_file(job):
    """Worker: read one shape file and project it onto its cuboids: (segmentation, None) or (None, error).

    Meshes get a :class:`Segmentation` (faces), voxel grids a :class:`VoxelSegmentation` (voxels),
    point clouds a :class:`PointSegmentation` (points).
    """
    path, cuboids, name, names, labeller, result, *rest = job
    how = rest[0] if rest else None  # the labelling (graphcut.Labelling or None)
    try:
        shape = io.read_shape(path)
        if isinstance(shape, io.VoxelGrid):
            seg = segment_voxels(shape, cuboids, name=name, source=str(path), part_names=names, labelling=how)
        elif isinstance(shape, io.PointCloud):
            seg = segment_points(shape, cuboids, name=name, source=str(path), part_names=names, labelling=how)
        elif isinstance(shape, io.Mesh):
            seg = segment_mesh(shape.vertices, shape.faces, cuboids, name=name, source=str(path), part_names=names,
                               labelling=how)
        else:
            raise io.ShapeFileError(path, f"a {type(shape).__name__} has no faces or voxels to label")
        return (seg if labeller is None else apply_labeller(seg, labeller, result)), None
    except (io.ShapeFileError, ValueError) as exc:
        return None, str(exc).splitlines()[0]


def shape_elements(seg, frame):
    """What a labeller reads of a segmented shape (:class:`primkit.segmentation.labeller.Elements`,
    canonical frame; ``frame`` its abstraction's :class:`primkit.geometry.CanonicalFrame`), and for a
    voxel grid the occupied voxels' indices (None otherwise)."""
    if isinstance(seg, VoxelSegmentation):
        return grid_elements(seg.grid, frame)
    if isinstance(seg, PointSegmentation):
        return point_elements(seg.points, frame), None
    return mesh_elements(seg.vertices, seg.faces, frame), None


def apply_labeller(seg, labeller: Labeller, result):
    """``seg`` with each element named by ``labeller`` (``named``, ``label_names``); ``result`` is
    its :class:`primkit.model.abstractor.AbstractionResult` (the canonical cuboids and the frame)."""
    elements, index = shape_elements(seg, result.frame)
    codes = label_elements(labeller, elements, result.canonical)
    if index is not None:
        named = np.full(seg.labels.shape, -1, np.int64)
        named[tuple(index.T)] = codes
        codes = named
    return replace(seg, named=codes, label_names=list(labeller.names))


def fit_labeller(labelled, names, parts: int, *, settings=None, seed=0, **options) -> Labeller:
    """Learn a labeller from segmented, labelled shapes.

    labelled : iterable of ``(segmentation, abstraction result, labels)``: a mesh's, voxel grid's
        or point cloud's segmentation (:mod:`primkit.segmentation`), its
        :class:`~primkit.model.abstractor.AbstractionResult`, and one label per element (per face;
        per occupied voxel in ``np.argwhere`` order; per point), indices into ``names``, -1 none.
    Other options are :meth:`primkit.segmentation.labeller.Labeller.fit`'s.
    """
    settings = settings or LabellerSettings()
    shapes = []
    for seg, result, y in labelled:
        elements, _ = shape_elements(seg, result.frame)
        X = frame_features(elements.points, result.canonical, elements.normals, settings, elements.context)
        shapes.append((X, np.asarray(y, np.int64)))
    return Labeller.fit(shapes, names, parts, settings=settings, seed=seed, **options)


class Segmenter:
    """Co-segment collections of meshes and voxel grids with a trained abstractor.

    Parameters
    ----------
    model : str, Path or Abstractor
        A model file or a bundled model's name (``"chair"``).
    up, front, align
        The inputs' axes when known, and how orientations are found
        (:func:`primkit.model.abstraction.abstract_shapes`: by default +Y up unless the collection
        clearly lies on a side, and the front searched).
    refine, existence_threshold, prune_threshold
        Passed to :meth:`primkit.model.abstractor.Abstractor.predict`.
    adapt : None, int or AdaptConfig
        Adapt the model to each run's inputs first, without labels
        (:func:`primkit.model.abstraction.abstract_shapes`'s ``adapt``; experimental).
    labeller : "auto", None or Labeller
        Names each element (``named`` on the segmentations; ``--semantic``): ``"auto"`` takes the
        model file's labeller when it has one (:func:`primkit.segmentation.labeller.read_labeller`),
        None names by part index only.
    labelling : None, str or graphcut.Labelling
        How elements get their index: ``"nearest"`` (each to its nearest cuboid) or ``"graphcut"``
        (:mod:`primkit.segmentation.graphcut`); a ``Labelling`` also sets the smoothness. None:
        the graph cut.

    Examples
    --------
    >>> seg = Segmenter("chair")                                   # doctest: +SKIP
    >>> results, errors = seg.segment_files(["chairs/"])            # doctest: +SKIP
    >>> results[0].face_labels                                      # doctest: +SKIP
    """

    def __init__(self, model, *, up: str | None = None, front: str | None = None, align=None, refine: int = 0,
                 existence_threshold: float = 0.5, prune_threshold: float | None = 0.6, adapt=None,
                 labeller="auto", labelling=None):
        self.abstractor = load_model(model)
        if isinstance(labeller, str) and labeller == "auto":
            labeller = None if not isinstance(model, (str, Path)) else read_labeller(_model_path(model))
        self.labeller = labeller
        self.labelling = graphcut.as_labelling(labelling)
        self.up, self.front = up, front
        self.predict_options = {"align": align, "refine": refine, "existence_threshold": existence_threshold,
                                "prune_threshold": prune_threshold, "adapt": adapt}

    @property
    def part_names(self) -> list:
        return self.abstractor.part_names

    def abstract_files(self, paths, *, cache_dir=None, workers=None, progress=False, executor=None, shard=None):
        """Abstractions of shape files: ``(results, errors)`` (:func:`primkit.model.abstraction.abstract_shapes`;
        ``executor`` prepares there, ``shard`` abstracts only that shard of the files)."""
        out = abstract_shapes(paths, self.abstractor, up=self.up, front=self.front, cache=cache_dir, workers=workers,
                              progress=progress, executor=executor, shard=shard, **self.predict_options)
        return out.results, out.errors

    def segment_files(self, paths, *, cache_dir=None, workers=None, progress=False, executor=None, shard=None):
        """Abstract and co-segment shape files.

        Returns ``(segmentations, errors)``: one :class:`Segmentation` (meshes),
        :class:`VoxelSegmentation` (voxel grids) or :class:`PointSegmentation` (point clouds) per usable file, in input order, and one line per
        file that could not be used (the batch goes on).

        ``executor``: an executor (anything with ``concurrent.futures.Executor.map``) or an
        address for :func:`primkit.parallel.executor_from` (a Dask scheduler, ``ray``): each file
        is prepared there and read and labelled there; the segmentations come back here (the
        network runs here, batched). ``shard=(k, n)``: only shard k of n of the files
        (:func:`primkit.parallel.shard_indices`), named as one run over all of them names them.
        """
        with parallel.executor_from(executor) as pool:  # one connection for both steps
            results, errors = self.abstract_files(paths, cache_dir=cache_dir, workers=workers, progress=progress,
                                                  executor=pool, shard=shard)
            return self.segment_results(results, workers=workers, progress=progress, errors=errors, executor=pool)

    def segment_results(self, results, *, workers=None, progress=False, errors=(), executor=None):
        """Co-segment the source files of abstraction results (in parallel processes, or on ``executor``)."""
        jobs = [(r.source, r.cuboids, r.name, self.part_names, self.labeller, r, self.labelling) for r in results]
        segs, errors = [], list(errors)
        with parallel.executor_from(executor) as pool:
            for seg, error in parallel_map(_segment_file, jobs, workers=workers, progress=progress, desc="segmenting",
                                           executor=pool):
                if error is not None:
                    errors.append(error)
                else:
                    segs.append(seg)
        return segs, errors


def _model_path(model):
    from ..model.bundled import resolve_model

    return resolve_model(model)


def segment(shape, model="chair", *, labelling=None, **options) -> Segmentation | VoxelSegmentation | PointSegmentation:
    """Co-segment one mesh, voxel grid or point cloud: a path, an :class:`primkit.io.Mesh`,
    :class:`~primkit.io.VoxelGrid` or :class:`~primkit.io.PointCloud`, ``(vertices, faces)``,
    ``(n, 3)`` points, or a trimesh, pyvista or Open3D mesh or cloud
    (:func:`primkit.model.abstraction.abstract`; ``options`` are its own: ``up``, ``front``,
    ``align``, ``refine``, ...; ``labeller`` and ``labelling`` as :class:`Segmenter`'s).

    >>> seg = primkit.segment("chair.off", model="chair")          # doctest: +SKIP
    >>> seg.face_labels                                           # doctest: +SKIP
    """
    abstractor = load_model(model)
    labeller = options.pop("labeller", "auto")
    if isinstance(labeller, str) and labeller == "auto":
        labeller = None if not isinstance(model, (str, Path)) else read_labeller(_model_path(model))
    a = abstract(shape, abstractor, **options)
    if isinstance(a.given, io.VoxelGrid) or (a.given is None and a.prepared.kind == "voxels"):
        grid = a.given if a.given is not None else io.read_voxels(a.source)
        seg = segment_voxels(grid, a.cuboids, name=a.name, source=a.source, part_names=abstractor.part_names,
                             labelling=labelling)
    elif isinstance(a.given, io.PointCloud) or (a.given is None and a.prepared.kind == "points"):
        cloud = a.given if a.given is not None else io.read_points(a.source)
        seg = segment_points(cloud, a.cuboids, name=a.name, source=a.source, part_names=abstractor.part_names,
                             labelling=labelling)
    else:
        mesh = a.mesh
        seg = segment_mesh(mesh.vertices, mesh.faces, a.cuboids, name=a.name, source=a.source,
                           part_names=abstractor.part_names, labelling=labelling)
    return seg if labeller is None else apply_labeller(seg, labeller, a.result)


def summary_header(kind: str, part_names) -> list[str]:
    """The columns of a summary (:func:`write_summary`) of shapes of ``kind`` (``"mesh"``,
    ``"voxels"`` or ``"points"``) segmented by a model with these part names."""
    element = {"mesh": "faces", "voxels": "voxels", "points": "points"}[kind]
    unit = "area" if kind == "mesh" else element
    return ["shape", element, "parts_present", f"{unit}_total"] + [f"{unit}_{k}_{n}" for k, n in enumerate(part_names)]


def read_summary(path) -> tuple[list[str], dict[str, list[str]]]:
    """A summary written by :func:`write_summary`: its header and its rows by shape name (the row
    without the name). An absent or unreadable file reads as no columns and no rows."""
    try:
        with open(path, newline="", encoding="utf-8", errors="surrogateescape") as fh:  # names as written
            table = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error):
        return [], {}
    if not table:
        return [], {}
    return table[0], {row[0]: row[1:] for row in table[1:] if row}


def write_summary(segmentations, path, *, overwrite: bool = False, keep=None, order=None) -> Path:
    """One CSV row per shape: its elements, the parts present (indices holding any), and how much
    of the shape each part index holds, with the same columns for the whole collection.

    Meshes (:class:`Segmentation`): ``faces``, then surface areas (``area_total``,
    ``area_<k>_<name>``). Voxel grids (:class:`VoxelSegmentation`): ``voxels``, then voxel counts
    (``voxels_<k>_<name>``). Point clouds (:class:`PointSegmentation`): ``points``, then point
    counts. One kind per file.

    ``keep``: rows of an earlier summary of the same columns (:func:`read_summary`), written with
    these (``primkit segment --skip-done``: the shapes it left as they were); ``order``: shape
    names in the order the rows are written (by default the kept rows, then the new ones).
    """
    if not segmentations:
        raise ValueError("no segmentations to summarise")
    kinds = {type(s) for s in segmentations}
    if len(kinds) > 1:
        raise ValueError("write meshes, voxel grids and point clouds into separate summaries")
    voxels = isinstance(segmentations[0], (VoxelSegmentation, PointSegmentation))  # counted, not measured
    names = segmentations[0].part_names
    count = segmentations[0].cuboids.count
    kind = {VoxelSegmentation: "voxels", PointSegmentation: "points"}.get(type(segmentations[0]), "mesh")
    header = summary_header(kind, names[:count])
    rows = dict(keep or {})
    for s in segmentations:
        amounts = s.part_sizes() if voxels else s.part_areas()
        elements = len(s.points) if kind == "points" else int(np.count_nonzero(s.labels >= 0)) if voxels \
            else len(s.faces)
        present = " ".join(str(k) for k in np.flatnonzero(amounts > 0))
        rows[s.name] = [elements, present, f"{amounts.sum():.6g}"] + [f"{a:.6g}" for a in amounts]
    if order is not None:
        position = {name: i for i, name in enumerate(order)}
        rows = dict(sorted(rows.items(), key=lambda item: position.get(item[0], len(position))))
    with io.atomic_output(path, overwrite=overwrite) as tmp:
        # a name from a file name that is not UTF-8 keeps its bytes (surrogateescape), as the file's
        with open(tmp, "w", newline="", encoding="utf-8", errors="surrogateescape") as fh:
            writer = csv.writer(fh)
            writer.writerow(header)
            for name, row in rows.items():
                writer.writerow([name] + row)
    return Path(path)

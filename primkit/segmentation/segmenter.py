"""Co-segmenting collections: abstract shape files with a model, then label each file's elements
(a mesh's faces, a voxel grid's voxels, a point cloud's points) by their primitives (a graph cut
by default, or each to its nearest), in parallel processes."""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import io, parallel
from ..parallel import parallel_map
from ..model.abstraction import abstract, abstract_shapes, load_model
from .labeller import (Labeller, LabellerSettings, element_features, grid_elements, label_elements,
                       mesh_elements, point_elements, read_labeller)
from . import evaluation, graphcut, outputs
from .meshes import Segmentation, SegmentationFiles, segment_mesh
from .meshlabels import face_graph
from .points import PointSegmentation, segment_points
from .voxels import VoxelSegmentation, segment_voxels

__all__ = ["Segmenter", "SegmentationRun", "segment", "apply_labeller", "shape_elements", "fit_labeller",
           "resolve_labeller"]


def _segment_file(job):
    """Worker: read one shape file and project it onto its cuboids: (segmentation, None) or (None, error).

    Meshes get a :class:`Segmentation` (faces), voxel grids a :class:`VoxelSegmentation` (voxels),
    point clouds a :class:`PointSegmentation` (points).
    """
    path, cuboids, name, names, labeller, result, *rest = job
    how = rest[0] if rest else None  # the labelling (graphcut.Labelling or None)
    graph = None
    try:
        shape = io.read_shape(path)
        if isinstance(shape, io.VoxelGrid):
            seg = segment_voxels(shape, cuboids, name=name, source=str(path), part_names=names, labelling=how)
        elif isinstance(shape, io.PointCloud):
            seg = segment_points(shape, cuboids, name=name, source=str(path), part_names=names, labelling=how)
        elif isinstance(shape, io.Mesh):
            graph = _face_graph(shape, labeller)
            seg = segment_mesh(shape.vertices, shape.faces, cuboids, name=name, source=str(path), part_names=names,
                               labelling=how, graph=graph)
        else:
            raise io.ShapeFileError(path, f"a {type(shape).__name__} has no faces or voxels to label")
        return (seg if labeller is None else apply_labeller(seg, labeller, result, graph=graph)), None
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


def _face_graph(mesh, labeller):
    """A mesh's face adjacency (:func:`~primkit.segmentation.meshlabels.face_graph`) when a labeller
    will cut over it too: built once, for the part-index cut and the labeller's; None otherwise."""
    return face_graph(mesh.vertices, mesh.faces) if labeller is not None and len(mesh.faces) else None


def apply_labeller(seg, labeller: Labeller, result, *, graph=None):
    """``seg`` with each element named by ``labeller`` (``named``, ``label_names``); ``result`` is
    its :class:`primkit.model.abstractor.AbstractionResult` (the canonical cuboids and the frame).
    ``graph``: a mesh's :func:`~primkit.segmentation.meshlabels.face_graph` when it is already built
    (the part-index cut's, :func:`~primkit.segmentation.segment_mesh`'s ``graph``); None: built here."""
    elements, index = shape_elements(seg, result.frame)
    codes = label_elements(labeller, elements, result.canonical, graph=graph)
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
        X = element_features(elements, result.canonical, settings)  # as the labeller reads them
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
        self.model = model
        self.abstractor = load_model(model)
        self.labeller = resolve_labeller(model, labeller)
        self.labelling = graphcut.as_labelling(labelling)
        self.up, self.front = up, front
        self.predict_options = {"align": align, "refine": refine, "existence_threshold": existence_threshold,
                                "prune_threshold": prune_threshold, "adapt": adapt}

    @property
    def part_names(self) -> list:
        return self.abstractor.part_names

    def plan(self, inputs, folder, *, shard=None, skip_done: bool = False, semantic: bool = False, ground_truth=(),
             ground_truth_names=None, picture=None, overwrite: bool = False):
        """The plan of a :meth:`run` over the shape files of ``inputs`` into ``folder``
        (:func:`primkit.segmentation.outputs.plan_segmentation`), with the reads (the model file,
        the ``ground_truth`` folders) whose files nothing may overwrite.

        ``ground_truth`` (folders of ``.seg`` files or voxel label archives; ``ground_truth_names``
        what their values mean, :func:`~primkit.segmentation.evaluation.ground_truth_sources`) and
        ``picture`` need the whole collection: refused (ValueError) with ``shard`` or ``skip_done``."""
        sources = evaluation.ground_truth_sources(ground_truth, ground_truth_names)
        shard = parallel.parse_shard(shard) if isinstance(shard, str) else shard
        if shard is not None and sources:
            raise ValueError("--gt evaluates the whole collection (the paper's mapping is fitted over every shape): "
                             "not with --shard")
        if shard is not None and picture:
            raise ValueError("--png draws the whole collection: not with --shard")
        if skip_done and (sources or picture):
            raise ValueError(f"{'--gt evaluates' if sources else '--png draws'} the whole collection: not with --skip-done")
        folder = Path(folder)
        codes = outputs.label_codes_text(self.part_names, self.labeller) if semantic else None
        model = _model_path(self.model) if isinstance(self.model, (str, Path)) else None
        evaluations = [folder / name for name in outputs.EVALUATIONS.values()] if sources else []
        return outputs.plan_segmentation(inputs, folder, self.part_names, shard=shard, skip_done=skip_done, codes=codes,
                                         evaluations=evaluations, picture=picture, overwrite=overwrite,
                                         reads=[model, *(f for f, _ in sources)])

    def run(self, inputs, folder=None, *, shard=None, skip_done: bool = False, semantic: bool = False, ground_truth=(),
            ground_truth_names=None, mean_over=None, picture=None, overwrite: bool = False, cache_dir=None,
            workers=None, executor=None, progress: bool = False):
        """Co-segment a collection into ``folder`` and write every output: each shape's labels,
        ``.parts.ply`` and ``.cuboids.json`` (last), the summaries (a shard's own; with ``skip_done``
        rewritten with the rows of what was done), ``labels.csv`` (``semantic``), the ``picture``,
        and the evaluations against ``ground_truth``. ``inputs``: files or folders, planned here
        (:meth:`plan`, with ``shard``, ``skip_done``...), or a plan made by :meth:`plan`. The outputs
        are checked before any work (:meth:`primkit.data.RunPlan.check`). Returns a
        :class:`SegmentationRun` (nothing done when the plan has nothing to do)."""
        from ..data import RunPlan
        from ..model.abstraction import CardMismatchWarning

        plan = inputs if isinstance(inputs, RunPlan) else self.plan(
            inputs, folder, shard=shard, skip_done=skip_done, semantic=semantic, ground_truth=ground_truth,
            ground_truth_names=ground_truth_names, picture=picture, overwrite=overwrite)
        if not plan.todo:
            return SegmentationRun(segmentations=[], errors=plan.errors, plan=plan)
        ground_truth = evaluation.ground_truth_sources(ground_truth, ground_truth_names)
        plan.check(overwrite)
        folder = plan.folder
        with parallel.executor_from(executor) as pool, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CardMismatchWarning)
            results, errors = self.abstract_files(plan, cache_dir=cache_dir, workers=workers, progress=progress,
                                                  executor=pool)  # segment_files' two steps, keeping the results
            segs, errors = self.segment_results(results, workers=workers, progress=progress, errors=errors,
                                                executor=pool)
        run = SegmentationRun(segmentations=segs, errors=list(errors), plan=plan)  # the plan's refusals with them
        for w in caught:  # the model-card warning kept for the caller (and the summary); the others as they came
            if issubclass(w.category, CardMismatchWarning):
                run.mismatch = str(w.message)
            else:
                warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        if not segs:
            return run
        for s in segs:
            run.written[s.name] = s.save(folder, semantic=semantic, overwrite=overwrite)
        kinds = {"mesh": [], "voxels": [], "points": []}
        for s in segs:
            kinds["voxels" if isinstance(s, VoxelSegmentation) else "points" if isinstance(s, PointSegmentation)
                  else "mesh"].append(s)
        kept = _kept_rows(plan, self.part_names)
        order = [plan.names[i] for i in sorted(plan.todo + plan.done)]
        for kind, group in kinds.items():
            if group:
                path = folder / outputs.summary_name(kind, plan.shard)
                outputs.write_summary(group, path, overwrite=overwrite or plan.skip_done,
                                      keep=kept.get(kind), order=order)
                run.summaries.append(path)
        labels = folder / "labels.csv"
        if labels in plan.extra:
            codes = outputs.label_codes_text(self.part_names, self.labeller)
            if not outputs.written_before(labels, codes, plan.shard is not None, overwrite):  # meanwhile
                with io.atomic_output(labels, overwrite=overwrite) as tmp:
                    Path(tmp).write_text(codes)
        from ..model.cuboids_file import write_cuboids_file

        frames = {r.name: r.frame for r in results}
        for s in segs:  # the schema of every <name>.cuboids.json, without abstract's alignment record: how
            # `auto` decided the up axis depends on the batch, and a --skip-done rerun must write the same bytes
            write_cuboids_file(folder / f"{s.name}.cuboids.json", s.cuboids, name=s.name, source=s.source,
                               canonical_frame=frames[s.name], model=self.abstractor.model or None,
                               part_names=s.part_names or None, overwrite=overwrite)
        if picture:
            run.picture = outputs.write_picture(segs, picture, semantic=semantic)
        if ground_truth and kinds["mesh"]:
            run.evaluation, failed = evaluation.evaluate_meshes_against(kinds["mesh"], ground_truth, self.part_names)
            run.errors += failed
            if run.evaluation is not None:
                run.evaluation_path = _write_json(folder / outputs.EVALUATIONS["meshes"], run.evaluation.to_dict(),
                                                  overwrite)
        if ground_truth and kinds["voxels"]:
            run.voxel_evaluation, failed = evaluation.evaluate_grids_against(
                kinds["voxels"], ground_truth, self.abstractor.parts, self.part_names, labeller=self.labeller,
                mean_over=mean_over)
            run.errors += failed
            if run.voxel_evaluation is not None:
                run.voxel_evaluation_path = _write_json(folder / outputs.EVALUATIONS["voxels"], run.voxel_evaluation.to_dict(),
                                                        overwrite)
        if ground_truth:
            run.unevaluated_clouds = len(kinds["points"])
        return run

    def abstract_files(self, paths, *, cache_dir=None, workers=None, progress=False, executor=None, shard=None):
        """Abstractions of shape files: ``(results, errors)`` (:func:`primkit.model.abstraction.abstract_shapes`;
        ``executor`` prepares there, ``shard`` abstracts only that shard of the files)."""
        out = abstract_shapes(paths, self.abstractor, up=self.up, front=self.front, cache=cache_dir, workers=workers,
                              progress=progress, executor=executor, shard=shard, **self.predict_options)
        return out.results, out.errors

    def segment_files(self, paths, *, cache_dir=None, workers=None, progress=False, executor=None, shard=None):
        """Abstract and co-segment shape files (or a :class:`primkit.data.RunPlan`'s: what it does of them).

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


@dataclass
class SegmentationRun:
    """What :meth:`Segmenter.run` did.

    Attributes
    ----------
    segmentations : list
        One segmentation per shape segmented (:class:`Segmentation`, :class:`VoxelSegmentation` or
        :class:`PointSegmentation`), in input order.
    errors : list of str
        One line per input that could not be used (or had no ground truth).
    written : dict of str to SegmentationFiles
        Each shape's files by name (:meth:`Segmentation.save`'s).
    summaries : list of Path
    picture : Path or None
    evaluation, voxel_evaluation : SegmentationEvaluation, VoxelEvaluation or None
        The reports of :func:`~primkit.segmentation.evaluation.evaluate` and
        :func:`~primkit.segmentation.evaluation.evaluate_voxels`, written to ``evaluation_path``
        and ``voxel_evaluation_path``.
    unevaluated_clouds : int
        Point clouds left out of the evaluation (their ground truth would be per point).
    mismatch : str or None
        The model-card warning (:class:`primkit.model.abstraction.CardMismatchWarning`), when given.
    plan : primkit.data.RunPlan
        What the run was to do (its shard, what a cut run had finished).
    """

    segmentations: list
    errors: list
    plan: object = None
    written: dict[str, SegmentationFiles] = field(default_factory=dict)
    summaries: list = field(default_factory=list)
    picture: Path | None = None
    evaluation: evaluation.SegmentationEvaluation | None = None
    evaluation_path: Path | None = None
    voxel_evaluation: evaluation.VoxelEvaluation | None = None
    voxel_evaluation_path: Path | None = None
    unevaluated_clouds: int = 0
    mismatch: str | None = None


def _kept_rows(plan, part_names) -> dict:
    """The summary rows of what a cut run finished (``plan.done``), by kind: ``{kind: {name: row}}``."""
    kept: dict = {}
    tables: dict = {}
    for i in plan.done:
        kind = outputs.shape_kind(plan.files[i])
        if kind not in tables:
            header, rows = outputs.read_summary(plan.folder / outputs.summary_name(kind, plan.shard))
            tables[kind] = rows if header == outputs.summary_header(kind, part_names) else {}
        if plan.names[i] in tables[kind]:
            kept.setdefault(kind, {})[plan.names[i]] = tables[kind][plan.names[i]]
    return kept


def _write_json(path, report, overwrite) -> Path:
    with io.atomic_output(path, overwrite=overwrite) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1))
    return Path(path)


def _model_path(model):
    from ..model.bundled import resolve_model

    return resolve_model(model)


def resolve_labeller(model, labeller="auto"):
    """The labeller to name elements with: ``labeller`` itself (a
    :class:`~primkit.segmentation.labeller.Labeller`, or None: none), or for ``"auto"`` the one in
    ``model``'s file (a path or a bundled model's name; :func:`~primkit.segmentation.labeller.read_labeller`),
    None when the file has none or ``model`` is an object rather than a file."""
    if not (isinstance(labeller, str) and labeller == "auto"):
        return labeller
    return read_labeller(_model_path(model)) if isinstance(model, (str, Path)) else None


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
    labeller = resolve_labeller(model, options.pop("labeller", "auto"))
    a = abstract(shape, abstractor, **options)
    graph = None
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
        graph = _face_graph(mesh, labeller)
        seg = segment_mesh(mesh.vertices, mesh.faces, a.cuboids, name=a.name, source=a.source,
                           part_names=abstractor.part_names, labelling=labelling, graph=graph)
    return seg if labeller is None else apply_labeller(seg, labeller, a.result, graph=graph)

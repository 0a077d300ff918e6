"""The one way in: shapes as the user has them (files, folders, meshes, arrays) -> prepared shapes
with their abstractions.

:func:`abstract_shapes` is what every command, the report, the demo and the viewers call;
:func:`abstract` is the one-shape form (``primkit.abstract(mesh, model="chair")``), and
:func:`load_model` the model alone (``primkit.load_model("chair")``), for scripts that predict
many times (:meth:`Abstractor.predict`).

Inputs, each one of:

* a path: a shape file (mesh, point cloud or binvox grid, :func:`primkit.io.read_shape`) or a
  folder of them (searched recursively, sorted); prepared through the cache, in parallel;
* a :class:`primkit.io.Mesh`, :class:`~primkit.io.PointCloud` or :class:`~primkit.io.VoxelGrid`;
* ``(vertices, faces)``: ``(n, 3) float`` and ``(f, 3) int``; or ``(n, 3) float`` points; or an
  ``(R, R, R) bool`` voxel grid; NumPy arrays, lists or torch tensors;
* a ``trimesh.Trimesh`` / ``trimesh.PointCloud``, a ``pyvista.PolyData`` (any VTK surface), or an
  Open3D ``TriangleMesh`` / ``PointCloud``.

Shapes given in memory are prepared here (no cache); their names are ``shape<i>`` unless ``names``
says otherwise. Every shape is checked before a compiled kernel sees it (dtypes, shapes, face
indices, finite coordinates, emptiness; vertices no face references are left out, with a warning:
``docs/faults.md``).
"""

from __future__ import annotations

import functools
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import data, io, parallel
from ..io.objects import from_pyvista, mesh_from_o3d, points_from_o3d
from . import orientation
from .abstractor import MIN_EXTENT, AbstractionResult, Abstractor

__all__ = ["Abstraction", "Abstractions", "as_shape", "abstract_shapes", "abstract", "load_model",
           "CardMismatchWarning", "CARD_LOSS_RATIO", "CARD_CHECK_Z", "CARD_CHECK_RATIO", "CARD_PARTS_RATIO",
           "CARD_PARTS_GAP", "CARD_PARTS_SHAPES", "FitReference",
           "fit_reference"]

#: For a model file without a ``fit_reference`` (below): how far above its card's final training
#: loss (coverage + consistency) the median fit loss on the inputs may be before
#: :func:`abstract_shapes` warns. Measured first on 10 shapes each (fit losses at 1000 points): a
#: wrong category's median 3.0-28.9 times. The bundled chair model's own held-out chairs sit at
#: 1.76 times its card, a third of them single shapes above 2.5: hence the reference.
CARD_LOSS_RATIO = 2.5
#: With a ``fit_reference`` (the median and spread of the log fit loss over held-out shapes of the
#: model's own kind, stored in the model file): warn when the inputs' median log loss lies more
#: than this many standard errors of a median of that many shapes above the reference's (one-sided
#: 1%, the reference's spread taken as the inputs' own)
CARD_CHECK_Z = 2.33
#: and their median loss is at least this many times the reference's (a large batch may be
#: significantly, yet harmlessly, a little worse).
CARD_CHECK_RATIO = 1.5
#: The parts in use: warn when the median number of parts the model keeps on the inputs is under
#: this fraction of the mean its training ended with (``training.final.parts`` in the model file).
#: The fit loss alone misses a category whose shapes a model covers with fewer, larger boxes: the
#: chair model fits four-legged animals about as well as chairs (median loss 1.1 times the
#: reference on 10 animals, 1.4 on 16), but keeps a median of 3.5 of its parts on 16 animals and 4
#: on 24 airplanes, against 8 on 24 held-out ShapeNet chairs (its training ended at 9.5; of 437
#: PartNet test and validation chairs 2 keep 4 parts, none fewer). The median must also be at least
#: :data:`CARD_PARTS_GAP` parts under, over at least :data:`CARD_PARTS_SHAPES` shapes: a model that
#: ends its training with few parts varies as much (the table model, 3.3 at its end, keeps 1 part
#: on 25 of 80 held-out tables, 5 on 24), and 2 of 80 held-out chairs keep 4 parts or fewer.
CARD_PARTS_RATIO = 0.5
CARD_PARTS_GAP = 3.0
CARD_PARTS_SHAPES = 3


class CardMismatchWarning(UserWarning):
    """The model explains the inputs far worse than the data it was trained on (wrong category,
    wrong scale or frame): its labels and parts mean little there."""


@dataclass(frozen=True, eq=False)
class Abstraction:
    """One shape as the user gave it, with its :class:`AbstractionResult` (``result``): the
    cuboids, and the shape's own geometry on demand.

    Attributes
    ----------
    result : AbstractionResult
        The cuboids in the input's frame (``cuboids``) and in the network's canonical frame
        (``canonical``), with the frame, the alignment and the refinement.
    given : io.Mesh, io.PointCloud, io.VoxelGrid or None
        The shape as given in memory; None for a file (read again on demand, see :attr:`mesh`).

    A shape from a file keeps no arrays: :attr:`prepared` reads it back from the preparation cache
    each time it is asked for, so that abstracting 10,000 shapes does not hold 5 GB of grids.
    """

    result: AbstractionResult
    given: object = None
    collection: object = None  # data.PreparedCollection holding the prepared shape, for files
    index: int = -1
    shape: object = None  # data.PreparedShape, for shapes given in memory

    @property
    def name(self) -> str:
        return self.result.name

    @property
    def source(self) -> str:
        return self.result.source

    @property
    def cuboids(self):
        """:class:`primkit.primitives.Cuboids` in the input's frame."""
        return self.result.cuboids

    @property
    def canonical(self):
        """:class:`primkit.primitives.Cuboids` in the network's canonical frame."""
        return self.result.canonical

    @property
    def prepared(self) -> data.PreparedShape:
        """The prepared shape as given to the model (before any ``align`` turn)."""
        return self.shape if self.shape is not None else self.collection[self.index]

    def canonical_shape(self) -> data.PreparedShape:
        """The prepared shape in the frame of :attr:`canonical` (turned when ``align`` chose an orientation)."""
        return self.result.canonical_shape(self.prepared)

    @functools.cached_property
    def mesh(self) -> io.Mesh:
        """The input's surface in its own frame: the mesh given, or the file read again.

        Raises :class:`primkit.io.ShapeFileError` for point clouds and voxel grids (no faces)."""
        if isinstance(self.given, io.Mesh):
            return self.given
        if self.given is not None:
            raise io.ShapeFileError(self.name, f"a {type(self.given).__name__} has no faces")
        return io.read_mesh(self.source)

    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float: :attr:`mesh`'s vertices, input frame."""
        return self.mesh.vertices

    @property
    def faces(self) -> np.ndarray:
        """(f, 3) int: :attr:`mesh`'s faces."""
        return self.mesh.faces

    def canonical_vertices(self) -> np.ndarray:
        """(n, 3) float: the mesh in the frame of :attr:`canonical`."""
        return self.result.frame.to_canonical(self.vertices)


@dataclass(frozen=True, eq=False)
class Abstractions:
    """What :func:`abstract_shapes` returns for a batch: the usable shapes (:class:`Abstraction`) in
    input order, one line per input that could not be used (the batch goes on), and the model that
    abstracted them with its model-card check."""

    shapes: list
    errors: list
    model: Abstractor
    #: the model's median fit loss on the inputs over its reference's (its card's final training loss
    #: where the model file has no ``fit_reference``), and the warning said (None: fine)
    card_ratio: float | None = None
    card_warning: str | None = None
    #: the fit losses the check read (coverage + consistency at 1000 points; a refined shape's loss
    #: before refinement; shapes left with no part are not checked): not aligned with ``shapes``
    fit_losses: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.shapes)

    def __iter__(self):
        return iter(self.shapes)

    def __getitem__(self, i):
        return self.shapes[i]

    @property
    def results(self) -> list:
        """The :class:`AbstractionResult` of every shape."""
        return [s.result for s in self.shapes]


def load_model(model="chair", device: str | None = None) -> Abstractor:
    """A volume model: a bundled model's name, a model file's path, or an :class:`Abstractor` (returned as is)."""
    return model if isinstance(model, Abstractor) else Abstractor.load(model, device)


def _is_array_like(obj) -> bool:
    return isinstance(obj, (np.ndarray, list)) or _is_tensor(obj)


def _is_tensor(obj) -> bool:
    return type(obj).__module__.split(".")[0] == "torch" and hasattr(obj, "detach")


def as_shape(obj):
    """One input as a primkit value: :class:`io.Mesh`, :class:`io.PointCloud` or :class:`io.VoxelGrid`.

    Takes the in-memory forms listed in the module notes (not paths). Raises TypeError naming the
    accepted forms for anything else, ValueError for arrays of the wrong shape.
    """
    if isinstance(obj, (io.Mesh, io.PointCloud, io.VoxelGrid)):
        return obj
    package = type(obj).__module__.split(".")[0]
    if package == "trimesh":
        if type(obj).__name__ == "Scene":
            obj = obj.to_geometry()
        if hasattr(obj, "faces") and len(obj.faces):
            return io.Mesh(obj.vertices, obj.faces)
        return io.PointCloud(obj.vertices)
    if package == "open3d":
        if type(obj).__name__ == "TriangleMesh":
            m = mesh_from_o3d(obj)
            return io.Mesh(m.vertices, m.faces)
        if type(obj).__name__ == "PointCloud":
            return io.PointCloud(points_from_o3d(obj)[0])
    if package in ("pyvista", "vtkmodules", "vtk"):
        vertices, faces = from_pyvista(obj)
        return io.Mesh(vertices, faces) if len(faces) else io.PointCloud(vertices)
    if isinstance(obj, tuple) and len(obj) == 2:
        return io.Mesh(*(x.detach().cpu().numpy() if _is_tensor(x) else x for x in obj))
    if _is_array_like(obj):
        a = obj.detach().cpu().numpy() if _is_tensor(obj) else np.asarray(obj)
        if a.ndim == 3:
            if a.dtype != bool:
                raise TypeError(f"a voxel grid must be (R, R, R) bool, got dtype {a.dtype}")
            return io.VoxelGrid(a, np.zeros(3), 1.0)
        return io.PointCloud(a)
    raise TypeError(f"cannot abstract a {type(obj).__name__}: give a path, an io.Mesh / PointCloud / VoxelGrid, "
                    "(vertices, faces), (n, 3) points, or a trimesh, pyvista or Open3D mesh or point cloud")


def _inputs(inputs) -> list:
    """``inputs`` as a list: one path or shape alone, or a list / tuple of them ((v, f) stays one shape)."""
    if isinstance(inputs, (str, os.PathLike)) or not isinstance(inputs, (list, tuple)):
        return [inputs]
    if isinstance(inputs, tuple) and len(inputs) == 2 and all(_is_array_like(x) for x in inputs):
        return [inputs]  # (vertices, faces)
    first = inputs[0] if isinstance(inputs, list) and inputs else None
    if isinstance(first, (list, tuple)) and first and all(isinstance(x, (int, float, np.number)) for x in first):
        return [inputs]  # a nested list of points (a list of shapes, [(vertices, faces)] included, is not)
    return list(inputs)


def abstract_shapes(
    inputs,
    model="chair",
    *,
    up: str | None = None,
    front: str | None = None,
    align: str | None = None,
    refine: int = 0,
    existence_threshold: float = 0.5,
    prune_threshold: float | None = 0.6,
    min_extent: float | None = MIN_EXTENT,
    adapt=None,
    settings: data.PrepareSettings | None = None,
    names=None,
    cache=None,
    workers: int | None = None,
    progress: bool = False,
    executor=None,
    shard=None,
    batch_size: int = 128,
) -> Abstractions:
    """Prepare and abstract shapes, in input order.

    Parameters
    ----------
    inputs : one input or a list of them (see the module notes); folders expand to their files.
        A :class:`primkit.data.RunPlan` gives its files and what it does of them (``shard`` then unused).
    model : a bundled model's name, a model file's path, or an :class:`Abstractor`.
    up, front : the inputs' up and front axes (``"+y"``, ``"-z"``, ...), when known. Undeclared
        (None or ``"auto"``), the shapes are taken as +Y up and their front is searched.
    align : how each shape's orientation is found (:data:`primkit.model.orientation.ALIGN_MODES`).
        By default it follows what was declared (:func:`primkit.model.orientation.resolve_align`):
        nothing declared -> ``"auto"`` (+Y up unless a shape is clearly lying down, the front
        searched among the 4 turns about the up axis, so the COSEG chairs' +Z front and
        ShapeNet's +X front both work without flags, and a symmetric stool is never laid on its
        side); ``up`` declared -> ``"front"``; both declared -> ``"none"``. What was chosen is
        recorded in each result's ``alignment``.
    refine, existence_threshold, prune_threshold, min_extent
        As :meth:`Abstractor.predict` (``refine=N`` runs N gradient steps per shape; parts whose
        longest side is under ``min_extent`` of the shape's size, or that are nearest to none of
        its surface samples, are not present).
    adapt : None, True, int or :class:`primkit.model.adaptation.AdaptConfig`
        Adapt the model to these inputs first, without labels (:func:`primkit.model.adaptation.adapt`;
        an int is the number of steps, True (or ``"auto"``) the default settings, whose steps follow
        the inputs' count: :func:`~primkit.model.adaptation.default_steps`); the shapes are
        then abstracted by the adapted model, which ``Abstractions.model`` holds. Experimental; the
        shapes are read from the cache at each batch, so memory does not grow with their number.
    settings : data.PrepareSettings, optional
        How to prepare (resolution, samples, axes); default the model's.
    names : one name per in-memory shape (default ``shape<i>``, ``i`` its position in ``inputs``).
    cache, workers, progress : the preparation cache folder, processes and progress bars (tqdm,
        on stderr; off by default).
    executor, shard : where files are prepared, and which shard of them is abstracted
        (:func:`primkit.data.prepare_collection`'s); shapes given as arrays are never sharded.
    batch_size : shapes read from the cache and abstracted at once.

    Returns
    -------
    Abstractions
        ``shapes`` (one :class:`Abstraction` per usable input, in input order), ``errors`` (one
        line per unusable input, naming it) and ``model``.
    """
    from tqdm.auto import tqdm  # tqdm: imported when the progress bar is drawn

    refused = []
    if isinstance(inputs, data.RunPlan):  # a planned run: its files, named by it, what it does of them
        inputs, shard, refused = list(inputs.files), inputs.selection, inputs.errors
    abstractor = load_model(model)
    mode = orientation.resolve_align(align, up, front)
    axes = {k: v for k, v in (("up", up), ("front", front)) if v not in (None, "auto")}
    if "up" in axes and "front" not in axes:
        axes["front"] = orientation.default_front(axes["up"])
    settings = replace(settings or abstractor.settings, **axes)
    if settings.resolution != abstractor.resolution:
        raise ValueError(f"settings.resolution is {settings.resolution} but the model reads {abstractor.resolution}^3")
    options = {"align": None if mode == "none" else mode, "refine": refine,
               "existence_threshold": existence_threshold, "prune_threshold": prune_threshold,
               "min_extent": min_extent}
    items = _inputs(inputs)
    files, memory, errors = [], [], list(refused)
    order = []  # ("file", position in files) or ("memory", position in memory), in input order
    for i, item in enumerate(items):
        if isinstance(item, (str, os.PathLike)):
            try:
                found = data.find_shape_files(item)
            except FileNotFoundError as exc:
                errors.append(str(exc))
                continue
            if not found:
                errors.append(f"{item}: no shape files in this folder")
            for p in found:
                order.append(("file", len(files)))
                files.append(p)
        else:
            name = names[len(memory)] if names is not None else f"shape{i}"
            try:
                # the values are checked here (io.values) and in data.prepare (io.values.usable_shape)
                shape = as_shape(item)
                prepared = data.prepare(shape, settings, name=name)
            except TypeError as exc:  # not a shape at all, or the wrong dtype: the caller's mistake
                raise TypeError(f"{name}: {exc}") from None
            except (ValueError, RuntimeError) as exc:
                errors.append(f"{name}: cannot prepare: {exc}")
                continue
            order.append(("memory", len(memory)))
            memory.append((shape, prepared))
    coll = data.prepare_collection(files, settings, cache_dir=cache, workers=workers, progress=progress,
                                   executor=executor, shard=shard) if files else None
    if coll is not None:
        errors = list(coll.errors) + errors
        usable = {str(p): j for j, p in enumerate(coll.paths)}
        order = [(kind, usable.get(str(files[k])) if kind == "file" else k) for kind, k in order]
        order = [(kind, k) for kind, k in order if k is not None]
    if adapt:
        from .adaptation import AdaptConfig, ShapeSequence, adapt as adapt_model

        config = (adapt if isinstance(adapt, AdaptConfig)
                  else AdaptConfig() if adapt is True or adapt == "auto" else AdaptConfig(steps=int(adapt)))
        everything = ShapeSequence(len(order), lambda i: coll[order[i][1]] if order[i][0] == "file"
                                   else memory[order[i][1]][1])  # read from the cache at each batch
        named = str(model) if isinstance(model, (str, os.PathLike)) else None
        if everything:
            with parallel.torch_threads(parallel.choose_threads(interval=0.05)):
                abstractor = adapt_model(abstractor, everything, config, parent_name=named, progress=progress)
    shapes, fit, parts = [], [], []
    # torch on the cores free (an explicit setting wins), the caller's thread count back afterwards
    with parallel.torch_threads(parallel.choose_threads(interval=0.05)), \
            tqdm(total=len(order), desc="abstracting", unit="shape", disable=not progress or len(order) <= batch_size) as bar:
        for start in range(0, len(order), batch_size):
            chunk = order[start : start + batch_size]
            prepared = [coll[k] if kind == "file" else memory[k][1] for kind, k in chunk]
            predicted = abstractor.predict(prepared, **options)
            fit.extend(_fit_losses(predicted, prepared))
            parts.extend(int(np.count_nonzero(r.cuboids.existence)) for r in predicted)
            for (kind, k), result in zip(chunk, predicted):
                if kind == "file":
                    shapes.append(Abstraction(result, collection=coll, index=k))
                else:
                    shapes.append(Abstraction(result, given=memory[k][0], shape=memory[k][1]))
            bar.update(len(chunk))
    ratio, warning = _card_check(abstractor, fit, parts)
    return Abstractions(shapes, errors, abstractor, ratio, warning, [float(v) for v in fit])


def _fit_losses(results, prepared) -> list:
    """Each shape's fit loss (coverage + consistency, :func:`primkit.model.fitting.fit_losses`) on
    its abstraction, in the frame the network saw; a cheap estimate (1000 points)."""
    from .fitting import fit_losses

    # the network's own fit: a refined shape's loss before refinement (fit_losses too), and a shape
    # left with no part (a high existence threshold) says nothing of the model
    refined = [r.refinement.loss_before for r in results if r.refinement is not None]
    pairs = [(r, p) for r, p in zip(results, prepared) if r.refinement is None and r.canonical.existence.any()]
    if not pairs:
        return refined
    shapes = [r.canonical_shape(p) for r, p in pairs]
    return refined + list(fit_losses([r.canonical for r, _ in pairs], shapes, points=1000,
                                     samples_per_cuboid=96).total)


@dataclass(frozen=True)
class FitReference:
    """How well a model fits held-out shapes of its own kind, stored in its file as
    ``fit_reference`` (:meth:`to_dict`) for :func:`abstract_shapes`' check: the median fit loss,
    the standard deviation of the log fit loss, how many shapes, and what they were."""

    median: float
    log_spread: float
    shapes: int
    data: str

    def to_dict(self) -> dict:
        return {"median": float(self.median), "log_spread": float(self.log_spread), "shapes": int(self.shapes),
                "data": str(self.data)}


def fit_reference(losses, data: str) -> FitReference:
    """The :class:`FitReference` of ``losses`` (:attr:`Abstractions.fit_losses` of held-out shapes
    of the model's own kind, at least 2); ``data`` says what they were."""
    logs = np.log(np.maximum(np.asarray(losses, float), 1e-12))
    if logs.ndim != 1 or len(logs) < 2 or not np.isfinite(logs).all():
        raise ValueError("a fit reference needs at least 2 finite fit losses")
    return FitReference(float(np.exp(np.median(logs))), float(np.std(logs, ddof=1)), int(len(logs)), str(data))


def _card_check(abstractor, losses, parts=()) -> tuple:
    """``(median loss / the reference's, warning or None)``; the warning is issued once (stderr).
    Against the model file's ``fit_reference`` when it has one (a test of the median, so that a
    few shapes of the model's own kind do not set it off), else its card's final training loss;
    then the parts in use against those of its training (:data:`CARD_PARTS_RATIO`)."""
    ratio, warning = _card_fit_check(abstractor, losses)
    if warning is None and parts:
        warning = _card_parts_check(abstractor, parts)
    if warning is not None:
        warning += ": a different category, scale or frame? Its parts and labels may mean little here"
        warnings.warn(warning, CardMismatchWarning, stacklevel=3)
    return ratio, warning


def _card_parts_check(abstractor, parts):
    """The warning (without its advice) when the median count of ``parts`` in use is under
    :data:`CARD_PARTS_RATIO` of the model's training's final mean and :data:`CARD_PARTS_GAP` under
    it, over :data:`CARD_PARTS_SHAPES` shapes or more; else None."""
    final = (abstractor.metadata.get("training") or {}).get("final") or {}
    try:
        trained = float(final["parts"])
    except (KeyError, TypeError, ValueError):
        return None
    median = float(np.median(parts))
    if not (len(parts) >= CARD_PARTS_SHAPES and np.isfinite(trained) and median < CARD_PARTS_RATIO * trained
            and trained - median >= CARD_PARTS_GAP):
        return None
    return (f"the model keeps a median of {median:g} of its parts on these {len(parts)} shape(s), against "
            f"{trained:.1f} at the end of its training")


def _card_fit_check(abstractor, losses) -> tuple:
    """``(ratio, warning without its advice, or None)`` of the fit-loss check."""
    reference = abstractor.metadata.get("fit_reference")
    if not losses:
        return None, None
    losses = np.maximum(np.asarray(losses, float), 1e-12)
    median = float(np.median(losses))
    if reference is not None:
        ratio = median / reference["median"]
        error = np.sqrt(np.pi / 2) * reference["log_spread"] / np.sqrt(len(losses))  # the median's standard error
        if not (ratio > CARD_CHECK_RATIO and np.log(ratio) > CARD_CHECK_Z * error):
            return ratio, None
        against = f"median loss {median:.2g} against {reference['median']:.2g} on {reference['shapes']} held-out shapes"
        warning = f"the model fits these {len(losses)} shape(s) {ratio:.1f} times worse than shapes of its own kind ({against})"
    else:
        final = (abstractor.metadata.get("training") or {}).get("final") or {}
        try:
            card = float(final["coverage"]) + float(final["consistency"])
        except (KeyError, TypeError, ValueError):
            return None, None
        if not card > 0:
            return None, None
        ratio = median / card
        if not ratio > CARD_LOSS_RATIO:
            return ratio, None
        warning = (f"the model fits these {len(losses)} shape(s) {ratio:.1f} times worse than its training data "
                   f"(median loss {median:.2g} against {card:.2g} on its card)")
    return ratio, warning


def abstract(shape, model="chair", **options) -> Abstraction:
    """Abstract one shape (a path to one file, a mesh, arrays; see the module notes).

    ``options`` are :func:`abstract_shapes`'s. Raises :class:`primkit.io.ShapeFileError` (one line,
    naming the file) when the shape cannot be used.

    >>> a = primkit.abstract((vertices, faces), model="chair")     # doctest: +SKIP
    >>> a.cuboids                                                  # doctest: +SKIP
    """
    if isinstance(shape, (str, os.PathLike)) and Path(shape).is_dir():
        raise ValueError(f"{shape}: a folder; abstract one shape, or use abstract_shapes for collections")
    options.setdefault("progress", False)
    options.setdefault("workers", 1)  # one shape: no process pool
    out = abstract_shapes(shape, model, **options)
    if not out.shapes:
        reason = out.errors[0] if out.errors else f"{shape}: not usable"
        raise io.ShapeFileError(*reason.split(": ", 1)) if ": " in reason else io.ShapeFileError(shape, reason)
    return out.shapes[0]

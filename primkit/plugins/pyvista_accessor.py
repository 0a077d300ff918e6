"""``dataset.primkit``: primkit as a pyvista accessor.

Installing primkit declares the ``pyvista.accessors`` entry point ``primkit`` (``setup.cfg``), so
pyvista (0.48 or later: the first with ``register_dataset_accessor`` and that entry-point group)
imports this module the first time ``.primkit`` is asked of any dataset, without the user
importing primkit; the ``pyvista.readers`` entry points (:mod:`primkit.plugins.pyvista_readers`)
let ``pv.read`` open ``.off``, ``.binvox``, ``.xyz`` and ``.npy`` the same way::

    import pyvista as pv
    chair = pv.read("chair.off")
    parts = chair.primkit.segment(model="chair")       # a copy with cell_data["part"]
    parts["part"]                                      # (f,) int, the part index of each face
    parts.plot()                                       # primkit's colours (active "part_rgb")
    pl = pv.Plotter()
    pl.add_mesh(parts, scalars="part", cmap=parts.primkit.lookup_table(), preference="cell")   # the same
    boxes = chair.primkit.cuboids(model="chair")       # pyvista.MultiBlock, one block per part
    a = chair.primkit.abstract(model="chair")          # primkit.model.abstraction.Abstraction

On a ``PolyData`` (or any dataset: its surface is taken) with faces, :meth:`PrimkitAccessor.segment`
labels faces (``cell_data["part"]``) and vertices (``point_data["part"]``); on one with points only
(a point cloud) it labels points (``point_data["part"]``); on an ``ImageData`` with
``cell_data["occupancy"]`` (a ``.binvox`` grid, see :mod:`~primkit.plugins.pyvista_readers`) it
abstracts the voxel grid and labels voxels (``cell_data["part"]``, -1 for empty ones). Beside the
``part`` of the elements labelled (faces, voxels, or a cloud's points) is ``part_rgb`` ((.., 3)
uint8, primkit's colour of each part, :func:`primkit.viz.palette.part_colors`; grey where ``part``
is -1), the copy's only active scalars, so ``plot()`` with no arguments draws primkit's colours
(pyvista takes an array whose name ends in ``_rgb`` as colours). A surface's ``point_data["part"]``
(each vertex) has no colour array beside it and is not active: ``scalars="part_rgb"`` then names
one array only, and colours interpolated between vertices never blur a part's border. For
``scalars="part"`` with :func:`lookup_table` pass ``preference="cell"`` (pyvista prefers point
data, and point labels interpolated through a table draw stripes of other parts' colours along
every border). A quad or polygon surface comes back triangulated (a ``part`` per triangle),
which a ``UserWarning`` says. The copy also carries ``field_data["part_names"]`` (one per slot) and
``field_data["primkit_cuboids"]`` (the cuboids as primkit's schema-versioned JSON, so they survive
``save("x.vtp")``); :meth:`cuboids` of a segmented copy reads them back without running the
model again.

On a ``MultiBlock`` (a collection), every method does the same for each block, in one batch
(the network reads all shapes at once), and returns a ``MultiBlock`` with the blocks' names.
"""

from __future__ import annotations

import json
import os
import warnings

import numpy as np

from ..primitives import Cuboids
from ..viz.backend import pyvista_module
from ..viz.interop import from_pyvista, to_pyvista_blocks
from ..viz.palette import part_colors
from .common import Labelled, label_shapes, model_key
from .pyvista_readers import voxels_from_pyvista

__all__ = ["PrimkitAccessor", "PrimkitBlocksAccessor", "segmented_copy", "lookup_table", "ACCESSOR", "PARAMETERS"]

#: The accessor's name: ``dataset.primkit``.
ACCESSOR = "primkit"
CUBOIDS_FIELD = "primkit_cuboids"
#: The colour of an element with no part (``part`` -1).
NO_PART = (200, 200, 200)

pv = pyvista_module()


def _surface(dataset):
    """A PolyData for any dataset: itself, or its outer surface."""
    return dataset if isinstance(dataset, pv.PolyData) else dataset.extract_surface()


def _as_input(dataset):
    """What primkit abstracts: a voxel grid, ``(vertices, faces)`` for a surface, ``(n, 3)`` points
    for a cloud."""
    grid = voxels_from_pyvista(dataset)
    if grid is not None:
        return grid
    poly = _surface(dataset)
    vertices, faces = from_pyvista(poly)
    return (vertices, faces) if len(faces) else vertices


def _rgb(labels: np.ndarray, count: int) -> np.ndarray:
    table = np.vstack([part_colors(count), [NO_PART]]).astype(np.uint8)
    return table[np.where(labels < 0, count, labels)]


def _label(out, where: str, labels: np.ndarray, count: int, colours: bool = True) -> None:
    data = out.cell_data if where == "cell" else out.point_data
    data["part"] = labels.astype(np.int64)
    if colours:
        data["part_rgb"] = _rgb(labels, count)


def _finish(out, labelled: Labelled):
    if labelled.labels is not None:  # the model's labeller: a name per face, or per point of a cloud
        data = out.cell_data if labelled.face_labels is not None else out.point_data
        data["label"] = labelled.labels.astype(np.int64)
        out.field_data["label_names"] = np.array(labelled.label_names)
    out.field_data["part_names"] = np.array(labelled.part_names)
    out.field_data[CUBOIDS_FIELD] = np.array([json.dumps(labelled.cuboids.to_dict())])
    # "part_rgb" the only active scalars: pyvista's plot() looks at point data first (and so does
    # its fallback when the dataset's record of what is active is lost, e.g. after copy or save)
    out.GetPointData().SetActiveScalars(None)
    out.GetCellData().SetActiveScalars(None)
    out.set_active_scalars("part_rgb", preference="cell" if "part_rgb" in out.cell_data else "point")
    return out


def segmented_copy(dataset, labelled: Labelled):
    """A copy of ``dataset``'s surface (or of its voxel grid) with the part labels of ``labelled``
    (see the module notes)."""
    count = len(labelled.part_names)
    if labelled.voxel_labels is not None:
        out = dataset.copy()
        _label(out, "cell", labelled.voxel_labels.ravel(order="F"), count)  # VTK's cells: x fastest
        return _finish(out, labelled)
    poly = _surface(dataset)
    out = poly.copy()
    if labelled.face_labels is not None:
        if poly.n_cells and not poly.is_all_triangles:
            # from_pyvista labelled the triangulated surface: label the copy's own triangles
            out = out.triangulate()
            warnings.warn(f"the surface's {poly.n_cells} cells are not all triangles: the segmented copy is its "
                          f"triangulation, {out.n_cells} triangles with a part each", stacklevel=3)
        if out.n_cells != len(labelled.face_labels):
            raise ValueError(f"the surface has {out.n_cells} cells, {len(labelled.face_labels)} of them faces: part "
                             "labels are per face; keep the faces only first (e.g. remove its lines and vertices)")
        _label(out, "cell", labelled.face_labels, count)
    _label(out, "point", labelled.point_labels, count, colours=labelled.face_labels is None)
    return _finish(out, labelled)


def lookup_table(part_names):
    """A ``pyvista.LookupTable`` giving part index ``k`` primkit's colour of ``k`` (and -1 grey), for
    ``add_mesh(..., scalars="part", cmap=lookup_table(names))``; annotated with ``"k name"``."""
    count = len(part_names)
    lut = pv.LookupTable()
    lut.values = np.hstack([part_colors(count), np.full((count, 1), 255)]).astype(np.uint8)
    lut.scalar_range = (-0.5, count - 0.5)  # value k falls in entry k
    lut.below_range_color = NO_PART
    lut.annotations = {float(k): f"{k} {n}" for k, n in enumerate(part_names)}
    return lut


def _stored_cuboids(dataset) -> Cuboids | None:
    if CUBOIDS_FIELD not in dataset.field_data:
        return None
    return Cuboids.from_dict(json.loads(str(dataset.field_data[CUBOIDS_FIELD][0])))


def _options(up, front, align, refine, existence_threshold, prune_threshold, progress_bar) -> dict:
    return {"up": up, "front": front, "align": align, "refine": int(refine), "existence_threshold": existence_threshold,
            "prune_threshold": prune_threshold, "progress_bar": progress_bar}


def _digest(shape) -> str:
    """A digest of what is abstracted: the arrays' bytes, shapes and dtypes (a few ms for a large mesh)."""
    import hashlib

    h = hashlib.blake2b(digest_size=16)
    if isinstance(shape, tuple):
        arrays = shape
    elif hasattr(shape, "occupancy"):  # a voxel grid: its cells and where they are
        arrays = (shape.occupancy, shape.translate, np.float64(shape.scale))
    else:
        arrays = (shape,)
    for a in arrays:
        a = np.asarray(a)
        h.update(f"{a.shape}{a.dtype}".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


#: The parameters every method shares, written once and added to each method's docstring (help()).
PARAMETERS = """
        Parameters
        ----------
        model : str, path or primkit.model.abstractor.Abstractor, default "chair"
            A bundled model's name (``primkit models`` lists them), a model file, or a loaded model.
        up, front : str, optional
            The input's up and front axes (``"+y"``, ``"-z"``, ...) when known, e.g. ``up="+z"`` for
            Z-up data. Undeclared, the input is taken as +Y up and its front is searched.
        align : {"auto", "front", "any", "none"}, optional
            How the orientation is found; by default it follows what was declared (nothing ->
            ``"auto"``, ``up`` -> ``"front"``, both -> ``"none"``). See :func:`primkit.abstract`.
        refine : int, default 0
            Gradient steps on the shape's own losses after the network (100-200 fit the cuboids
            closer, about 0.4-1.3 s per 100 steps on one core).
        existence_threshold : float, default 0.5
            A part is present when its existence probability reaches this.
        prune_threshold : float or None, default 0.6
            A present cuboid lying this much inside the others is dropped; None keeps them all.
        progress_bar : bool, default False
            Draw a progress bar (tqdm): preparing and abstracting, then labelling each shape.
"""


@pv.register_dataset_accessor(ACCESSOR, pv.DataSet)
class PrimkitAccessor:
    """``dataset.primkit``: abstract and co-segment one pyvista dataset (see the module notes)."""

    def __init__(self, dataset):
        self._dataset = dataset
        self._last = None  # (key, model, Labelled) of the last run: cuboids() after segment() runs nothing

    def _labelled(self, model, options) -> Labelled:
        """The dataset abstracted and labelled, or the last answer when the model, the options and the
        dataset's contents are the same (pyvista keeps one accessor per dataset, so ``segment``,
        ``abstract`` and ``cuboids`` on one dataset share one abstraction)."""
        shape = _as_input(self._dataset)
        key = (model_key(model), {k: v for k, v in options.items() if k != "progress_bar"}, _digest(shape))
        if self._last is not None and self._last[0] == key and (isinstance(model, (str, os.PathLike)) or self._last[1] is model):
            return self._last[2]
        labelled = label_shapes([shape], model, **options)[0]
        self._last = (key, model, labelled)
        return labelled

    def abstract(self, model: str | os.PathLike = "chair", *, up: str | None = None, front: str | None = None,
                 align: str | None = None, refine: int = 0, existence_threshold: float = 0.5,
                 prune_threshold: float | None = 0.6, progress_bar: bool = False):
        """The abstraction of the dataset, a :class:`primkit.model.abstraction.Abstraction`
        (``.cuboids`` in the dataset's frame)."""
        options = _options(up, front, align, refine, existence_threshold, prune_threshold, progress_bar)
        return self._labelled(model, options).abstraction

    def segment(self, model: str | os.PathLike = "chair", *, up: str | None = None, front: str | None = None,
                align: str | None = None, refine: int = 0, existence_threshold: float = 0.5,
                prune_threshold: float | None = 0.6, progress_bar: bool = False):
        """A copy of the dataset's surface (or voxel grid) with ``part`` and ``part_rgb`` arrays and
        the cuboids in its field data (see the module notes); with a labeller in the model also
        ``cell_data["label"]`` (faces; ``point_data["label"]`` for a point cloud), indices into
        ``field_data["label_names"]``."""
        options = _options(up, front, align, refine, existence_threshold, prune_threshold, progress_bar)
        return segmented_copy(self._dataset, self._labelled(model, options))

    def cuboids(self, model: str | os.PathLike = "chair", *, edges: bool = False, up: str | None = None,
                front: str | None = None, align: str | None = None, refine: int = 0,
                existence_threshold: float = 0.5, prune_threshold: float | None = 0.6, progress_bar: bool = False):
        """The cuboids as a ``pyvista.MultiBlock``, one block per present part (``field_data["part"]``
        and ``["part_name"]``, ``cell_data["rgb"]`` its colour; solid, or the 12 edges with
        ``edges=True``).

        A copy made by :meth:`segment` gives back its own cuboids (no model run) unless other
        options are given; otherwise the dataset is abstracted with ``model``."""
        options = _options(up, front, align, refine, existence_threshold, prune_threshold, progress_bar)
        stored = _stored_cuboids(self._dataset)
        defaults = _options(None, None, None, 0, 0.5, 0.6, progress_bar)
        if stored is not None and options == defaults:
            names = [str(n) for n in self._dataset.field_data["part_names"]] if "part_names" in self._dataset.field_data \
                else None
            return to_pyvista_blocks(stored, names, edges=edges)
        labelled = self._labelled(model, options)
        return to_pyvista_blocks(labelled.cuboids, labelled.part_names, edges=edges)

    def lookup_table(self, part_names=None):
        """primkit's part colours as a ``pyvista.LookupTable`` for ``scalars="part"`` (see
        :func:`lookup_table`), for the dataset's ``field_data["part_names"]`` (a segmented copy)
        or the given names."""
        if part_names is None:
            if "part_names" not in self._dataset.field_data:
                raise ValueError("the dataset has no field_data['part_names']: segment it first, or give part_names")
            part_names = [str(n) for n in self._dataset.field_data["part_names"]]
        return lookup_table(part_names)


def _leaves(blocks, prefix=""):
    """(name, dataset) of every dataset in a MultiBlock, nested blocks flattened as ``outer/inner``."""
    for i in range(blocks.n_blocks):
        block, name = blocks[i], blocks.get_block_name(i) or f"block{i}"
        if block is None:
            continue
        if isinstance(block, pv.MultiBlock):
            yield from _leaves(block, f"{prefix}{name}/")
        else:
            yield f"{prefix}{name}", block


@pv.register_dataset_accessor(ACCESSOR, pv.MultiBlock)
class PrimkitBlocksAccessor:
    """``blocks.primkit``: the same for every dataset of a MultiBlock, in one batch."""

    def __init__(self, blocks):
        self._blocks = blocks

    def _labelled(self, model, options):
        leaves = list(_leaves(self._blocks))
        if not leaves:
            raise ValueError("the MultiBlock holds no dataset")
        names = [n for n, _ in leaves]
        return leaves, label_shapes([_as_input(d) for _, d in leaves], model, names=names, **options)

    def abstract(self, model: str | os.PathLike = "chair", *, up: str | None = None, front: str | None = None,
                 align: str | None = None, refine: int = 0, existence_threshold: float = 0.5,
                 prune_threshold: float | None = 0.6, progress_bar: bool = False) -> list:
        """One :class:`primkit.model.abstraction.Abstraction` per dataset, in block order."""
        options = _options(up, front, align, refine, existence_threshold, prune_threshold, progress_bar)
        return [x.abstraction for x in self._labelled(model, options)[1]]

    def segment(self, model: str | os.PathLike = "chair", *, up: str | None = None, front: str | None = None,
                align: str | None = None, refine: int = 0, existence_threshold: float = 0.5,
                prune_threshold: float | None = 0.6, progress_bar: bool = False):
        """A MultiBlock of segmented copies (:meth:`PrimkitAccessor.segment`), named like the
        blocks."""
        options = _options(up, front, align, refine, existence_threshold, prune_threshold, progress_bar)
        leaves, labelled = self._labelled(model, options)
        out = pv.MultiBlock()
        for (name, d), x in zip(leaves, labelled):
            out.append(segmented_copy(d, x), name)
        return out

    def cuboids(self, model: str | os.PathLike = "chair", *, edges: bool = False, up: str | None = None,
                front: str | None = None, align: str | None = None, refine: int = 0,
                existence_threshold: float = 0.5, prune_threshold: float | None = 0.6, progress_bar: bool = False):
        """A MultiBlock with one MultiBlock of cuboids per dataset (:meth:`PrimkitAccessor.cuboids`)."""
        options = _options(up, front, align, refine, existence_threshold, prune_threshold, progress_bar)
        leaves, labelled = self._labelled(model, options)
        out = pv.MultiBlock()
        for (name, _), x in zip(leaves, labelled):
            out.append(to_pyvista_blocks(x.cuboids, x.part_names, edges=edges), name)
        return out


for _cls in (PrimkitAccessor, PrimkitBlocksAccessor):
    for _name in ("abstract", "segment", "cuboids"):
        getattr(_cls, _name).__doc__ += PARAMETERS

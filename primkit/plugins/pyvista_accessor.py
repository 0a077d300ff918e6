"""``dataset.primkit``: primkit as a pyvista accessor.

Installing primkit declares the ``pyvista.accessors`` entry point ``primkit`` (``setup.cfg``), so
pyvista (0.48 or later) imports this module the first time ``.primkit`` is asked of any dataset,
without the user importing primkit::

    import pyvista as pv
    chair = pv.read("chair.ply")
    parts = chair.primkit.segment(model="chair")       # a copy with cell_data["part"]
    parts["part"]                                      # (f,) int, the part index of each face
    boxes = chair.primkit.cuboids(model="chair")       # pyvista.MultiBlock, one block per part
    a = chair.primkit.abstract(model="chair")          # primkit.model.abstraction.Abstraction

On a ``PolyData`` (or any dataset: its surface is taken) with faces, :meth:`PrimkitAccessor.segment`
labels faces (``cell_data["part"]``) and vertices (``point_data["part"]``); on one with points only
(a point cloud) it labels points (``point_data["part"]``). The copy also carries
``field_data["part_names"]`` (one per slot) and ``field_data["primkit_cuboids"]`` (the cuboids as
primkit's schema-versioned JSON, so they survive ``save("x.vtp")``); :meth:`cuboids` of a segmented
copy reads them back without running the model again.

On a ``MultiBlock`` (a collection), every method does the same for each block, in one batch
(the network reads all shapes at once), and returns a ``MultiBlock`` with the blocks' names.

``options`` of every method are those of :func:`primkit.abstract`: ``up``, ``front``, ``align``,
``refine``, ... (the inputs' axes: ``up="+z"`` for Z-up data).
"""

from __future__ import annotations

import json

import numpy as np

from ..primitives import Cuboids
from ..viz.backend import pyvista_module
from ..viz.interop import from_pyvista, to_pyvista_blocks
from .common import Labelled, label_shapes

__all__ = ["PrimkitAccessor", "PrimkitBlocksAccessor", "segmented_copy", "ACCESSOR"]

#: The accessor's name: ``dataset.primkit``.
ACCESSOR = "primkit"
CUBOIDS_FIELD = "primkit_cuboids"

pv = pyvista_module()


def _surface(dataset):
    """A PolyData for any dataset: itself, or its outer surface."""
    return dataset if isinstance(dataset, pv.PolyData) else dataset.extract_surface()


def _as_input(dataset):
    """What primkit abstracts: ``(vertices, faces)`` for a surface, ``(n, 3)`` points for a cloud."""
    poly = _surface(dataset)
    vertices, faces = from_pyvista(poly)
    return (vertices, faces) if len(faces) else vertices


def segmented_copy(dataset, labelled: Labelled):
    """A copy of ``dataset``'s surface with the part labels of ``labelled`` (see the module notes)."""
    poly = _surface(dataset)
    out = poly.copy()
    if labelled.face_labels is not None:
        if poly.n_cells and not poly.is_all_triangles:
            # from_pyvista labelled the triangulated surface: label the copy's own triangles
            out = out.triangulate()
        if out.n_cells != len(labelled.face_labels):
            raise ValueError(f"the surface has {out.n_cells} cells, {len(labelled.face_labels)} of them faces: part "
                             "labels are per face; keep the faces only first (e.g. remove its lines and vertices)")
        out.cell_data["part"] = labelled.face_labels.astype(np.int64)
        if labelled.labels is not None:  # the model's labeller: a name per face
            out.cell_data["label"] = labelled.labels.astype(np.int64)
    out.point_data["part"] = labelled.point_labels.astype(np.int64)
    if labelled.labels is not None:
        if labelled.face_labels is None:  # a point cloud: a name per point
            out.point_data["label"] = labelled.labels.astype(np.int64)
        out.field_data["label_names"] = np.array(labelled.label_names)
    out.field_data["part_names"] = np.array(labelled.part_names)
    out.field_data[CUBOIDS_FIELD] = np.array([json.dumps(labelled.cuboids.to_dict())])
    return out


def _stored_cuboids(dataset) -> Cuboids | None:
    if CUBOIDS_FIELD not in dataset.field_data:
        return None
    return Cuboids.from_dict(json.loads(str(dataset.field_data[CUBOIDS_FIELD][0])))


@pv.register_dataset_accessor(ACCESSOR, pv.DataSet)
class PrimkitAccessor:
    """``dataset.primkit``: abstract and co-segment one pyvista dataset (see the module notes)."""

    def __init__(self, dataset):
        self._dataset = dataset

    def abstract(self, model="chair", **options):
        """The abstraction of the dataset: :class:`primkit.model.abstraction.Abstraction`
        (``.cuboids`` in the dataset's frame)."""
        return label_shapes([_as_input(self._dataset)], model, **options)[0].abstraction

    def segment(self, model="chair", **options):
        """A copy of the dataset's surface with ``cell_data["part"]`` (faces) and ``point_data["part"]``
        (vertices, or the points of a point cloud), and the cuboids in its field data; with a
        labeller in the model also ``cell_data["label"]`` (faces; ``point_data["label"]`` for a
        point cloud), indices into ``field_data["label_names"]``."""
        return segmented_copy(self._dataset, label_shapes([_as_input(self._dataset)], model, **options)[0])

    def cuboids(self, model="chair", *, edges: bool = False, **options):
        """The cuboids as a ``pyvista.MultiBlock``, one block per present part (``field_data["part"]``
        and ``["part_name"]``; solid, or the 12 edges with ``edges=True``).

        A copy made by :meth:`segment` gives back its own cuboids (no model run); otherwise the
        dataset is abstracted with ``model``."""
        stored = _stored_cuboids(self._dataset)
        if stored is not None and not options:
            names = [str(n) for n in self._dataset.field_data["part_names"]] if "part_names" in self._dataset.field_data \
                else None
            return to_pyvista_blocks(stored, names, edges=edges)
        labelled = label_shapes([_as_input(self._dataset)], model, **options)[0]
        return to_pyvista_blocks(labelled.cuboids, labelled.part_names, edges=edges)


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

    def abstract(self, model="chair", **options) -> list:
        """One :class:`primkit.model.abstraction.Abstraction` per dataset, in block order."""
        return [x.abstraction for x in self._labelled(model, options)[1]]

    def segment(self, model="chair", **options):
        """A MultiBlock of segmented copies (:meth:`PrimkitAccessor.segment`), named like the blocks."""
        leaves, labelled = self._labelled(model, options)
        out = pv.MultiBlock()
        for (name, d), x in zip(leaves, labelled):
            out.append(segmented_copy(d, x), name)
        return out

    def cuboids(self, model="chair", *, edges: bool = False, **options):
        """A MultiBlock with one MultiBlock of cuboids per dataset (:meth:`PrimkitAccessor.cuboids`)."""
        leaves, labelled = self._labelled(model, options)
        out = pv.MultiBlock()
        for (name, _), x in zip(leaves, labelled):
            out.append(to_pyvista_blocks(x.cuboids, x.part_names, edges=edges), name)
        return out

"""What every plugin does: abstract shapes held in memory and co-segment them.

A mesh gets a part index per face (:func:`primkit.segmentation.segment_mesh`'s default labelling,
a graph cut, as ``primkit segment``) and per vertex; a point cloud a part index per point
(:func:`primkit.segmentation.segment_points`);
a voxel grid a part index per voxel (:func:`primkit.segmentation.label_voxels`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .. import io
from ..model.abstraction import Abstraction, abstract_shapes
from ..segmentation import label_voxels, point_labels, resolve_labeller, segment_mesh, segment_points, voxel_centres
from ..segmentation.meshlabels import face_graph

__all__ = ["Labelled", "label_shapes", "label_shape", "resolve_labeller", "model_key"]


@dataclass(frozen=True, eq=False)
class Labelled:
    """One shape co-segmented by its abstraction.

    Attributes
    ----------
    abstraction : primkit.model.abstraction.Abstraction
        The cuboids (``abstraction.cuboids``, the input's frame) and everything else about the fit.
    face_labels : (f,) int or None
        Part index of each face of a mesh; None for a point cloud.
    point_labels : (n,) int
        Part index of each vertex of a mesh, of each point of a cloud, or of each occupied voxel of
        a grid (in ``np.argwhere`` order).
    part_names : list of str
        The model's name of each part slot.
    voxel_labels : (R, R, R) int or None
        Part index of each voxel of a grid (``[x, y, z]``, -1 for empty voxels); None otherwise.
    labels : (f,) or (n,) int or None
        With a labeller in the model (:mod:`primkit.segmentation.labeller`): each face's (mesh) or
        point's (cloud) label, an index into ``label_names``; None without one (and for voxel grids).
    label_names : list of str or None

    -1 marks an element with no cuboid to go to (a shape with no part present).
    """

    abstraction: Abstraction
    face_labels: np.ndarray | None
    point_labels: np.ndarray
    part_names: list
    voxel_labels: np.ndarray | None = None
    labels: np.ndarray | None = None
    label_names: list | None = None

    @property
    def cuboids(self):
        """:class:`primkit.primitives.Cuboids` in the input's frame."""
        return self.abstraction.cuboids


def _labels(shape, cuboids, graph=None) -> tuple:
    if isinstance(shape, io.Mesh):
        if not cuboids.existence.any():
            return np.full(len(shape.faces), -1, np.int64), np.full(len(shape.vertices), -1, np.int64)
        # the labelling `primkit segment` uses by default (the graph cut), so the filter agrees with it
        return (segment_mesh(shape.vertices, shape.faces, cuboids, graph=graph).face_labels,
                point_labels(shape.vertices, cuboids))
    if isinstance(shape, io.PointCloud):
        if not cuboids.existence.any():
            return None, np.full(len(shape.points), -1, np.int64)
        return None, segment_points(shape, cuboids).labels
    if isinstance(shape, io.VoxelGrid):
        voxels = label_voxels(shape, cuboids) if cuboids.existence.any() else np.full(shape.occupancy.shape, -1, np.int64)
        return None, voxels[tuple(voxel_centres(shape)[1].T)], voxels
    raise TypeError(f"cannot label a {type(shape).__name__}: a mesh, a point cloud or a voxel grid")


def label_shapes(shapes, model="chair", *, names=None, progress_bar: bool = False, **options) -> list[Labelled]:
    """Abstract and co-segment shapes held in memory (any form :func:`primkit.model.abstraction.as_shape`
    takes: meshes, point clouds and voxel grids of primkit, trimesh, pyvista, Open3D, or arrays), in
    one batch.

    ``options`` are :func:`~primkit.model.abstraction.abstract_shapes`'s (``up``, ``front``,
    ``align``, ``refine``, ...). ``progress_bar`` draws a tqdm bar: one step for preparing and
    abstracting the batch, then one per shape labelled. Raises ValueError naming every shape that
    could not be used.
    """
    from tqdm.auto import tqdm

    options.setdefault("progress", False)
    options.setdefault("workers", 1)
    labeller = _labeller(model, options.pop("labeller", "auto"))
    shapes = list(shapes)
    names = list(names) if names is not None else [f"shape{i}" for i in range(len(shapes))]
    with tqdm(total=len(shapes) + 1, desc="primkit: abstracting", unit="step", disable=not progress_bar) as bar:
        out = abstract_shapes(shapes, model, names=names, **options)
        if out.errors:
            raise ValueError("; ".join(str(e) for e in out.errors))
        bar.update(1)
        bar.set_description("primkit: labelling")
        labelled = []
        for a in out:
            # a mesh's face adjacency, built once for the part-index cut and the labeller's cut
            graph = face_graph(a.given.vertices, a.given.faces) \
                if labeller is not None and isinstance(a.given, io.Mesh) and len(a.given.faces) else None
            face, point, *voxels = _labels(a.given, a.cuboids, graph)
            labelled.append(Labelled(a, face, point, list(out.model.part_names), voxels[0] if voxels else None,
                                     *_named(a, labeller, graph)))
            bar.update(1)
    return labelled


_labeller = resolve_labeller  # "auto": the model file's labeller (primkit.segmentation.resolve_labeller)


def _named(a: Abstraction, labeller, graph=None):
    """``(labels, label_names)`` of a shape's faces (mesh) or points (cloud), or ``(None, None)``."""
    if labeller is None or isinstance(a.given, io.VoxelGrid):
        return None, None
    from ..segmentation.labeller import label_elements, mesh_elements, point_elements

    shape = a.given
    if isinstance(shape, io.Mesh):
        elements = mesh_elements(shape.vertices, shape.faces, a.result.frame)
    else:
        elements = point_elements(shape.points, a.result.frame)
    return label_elements(labeller, elements, a.result.canonical, graph=graph), list(labeller.names)


def label_shape(shape, model="chair", *, name: str = "shape", **options) -> Labelled:
    """:func:`label_shapes` of one shape."""
    return label_shapes([shape], model, names=[name], **options)[0]


def model_key(model) -> tuple:
    """What names a model's answers between calls: a loaded model by identity (compare the objects
    too: an id can be reused), a file by its absolute path, size and modification time (a rewritten
    file is another model), a bundled name by itself."""
    if not isinstance(model, (str, os.PathLike)):
        return ("loaded", id(model))
    try:
        st = os.stat(model)
        return ("file", os.path.abspath(os.fspath(model)), st.st_size, st.st_mtime_ns)
    except OSError:
        return ("name", os.fspath(model))

"""Mirrored labelled shapes: twice the labelled data for a labeller, at learning time only.

Chairs, tables and airplanes are left-right symmetric: a labelled shape mirrored across its
canonical frame's left-right axis (Z: +Y up, +X front, :class:`primkit.geometry.CanonicalFrame`)
is another plausible labelled shape, its labels carried with its elements. The mirrored shape is
abstracted again (the network does not give a mirrored cuboid the slot of its twin, so mirroring
the cuboids would teach a frame the labeller never sees), and a labeller learns from both
(:func:`mirrored_shapes`, :func:`primkit.segmentation.selftrain.learn_labeller`; validation
figures in docs/labeller.md).
"""

from __future__ import annotations

import numpy as np

from .. import io

__all__ = ["mirror_plane", "mirror_shape", "mirrored_shapes"]


def mirror_plane(frame) -> tuple[np.ndarray, float]:
    """``(normal (3,), offset)``: the plane ``normal . x = offset`` in the input frame that the
    canonical frame ``frame`` maps to ``z = 0`` (its left-right middle)."""
    rotation, centre = np.asarray(frame.rotation, float), np.asarray(frame.centre, float)
    return rotation[2].copy(), float(centre[2])


def mirror_shape(shape, frame):
    """``(mirrored, order)``: ``shape`` (:class:`primkit.io.Mesh`, :class:`~primkit.io.VoxelGrid`
    or :class:`~primkit.io.PointCloud`, input frame) mirrored across :func:`mirror_plane`, and
    ``order (n,) int``: for each element of the mirrored shape (face; occupied voxel in
    ``np.argwhere`` order; point), the element of ``shape`` it is the mirror of, so that labels
    carry over as ``labels[order]``.

    A mesh keeps its faces in order (each one's vertex order reversed, so normals stay outward). A
    voxel grid is flipped along the grid axis nearest the plane's normal (a canonical frame of a
    grid turns it by quarter turns), about the grid's middle.
    """
    normal, offset = mirror_plane(frame)
    if isinstance(shape, io.VoxelGrid):
        axis = int(np.argmax(np.abs(normal)))
        occupancy = np.asarray(shape.occupancy, bool)
        where = np.full(occupancy.shape, -1, np.int64)
        index = np.argwhere(occupancy)
        where[tuple(index.T)] = np.arange(len(index))
        flipped = np.flip(occupancy, axis)
        order = np.flip(where, axis)[tuple(np.argwhere(flipped).T)]
        return io.VoxelGrid(np.ascontiguousarray(flipped), np.array(shape.translate, float), shape.scale), order

    def reflect(x, offset=offset):
        x = np.asarray(x, float)
        return x - 2.0 * np.outer(x @ normal - offset, normal)

    if isinstance(shape, io.Mesh):
        faces = np.asarray(shape.faces, np.int64)
        return io.Mesh(reflect(shape.vertices), np.ascontiguousarray(faces[:, ::-1])), np.arange(len(faces))
    if isinstance(shape, io.PointCloud):
        normals = None if shape.normals is None else reflect(shape.normals, 0.0)  # directions: no offset
        return io.PointCloud(reflect(shape.points), normals), np.arange(len(shape.points))
    raise TypeError(f"cannot mirror a {type(shape).__name__}")


def _shape_of(seg):
    """The shape a segmentation was made of (input frame)."""
    from .points import PointSegmentation
    from .voxels import VoxelSegmentation

    if isinstance(seg, VoxelSegmentation):
        return seg.grid
    if isinstance(seg, PointSegmentation):
        return io.PointCloud(np.asarray(seg.points, float))
    return io.Mesh(np.asarray(seg.vertices, float), np.asarray(seg.faces, np.int64))


def mirrored_shapes(labelled, segmenter, settings, *, progress: bool = False) -> list:
    """The mirrors of labelled shapes, abstracted again, as a labeller learns from them.

    ``labelled``: ``(segmentation, abstraction result, labels)`` as
    :func:`primkit.segmentation.segmenter.fit_labeller` takes them; ``segmenter``: the
    :class:`~primkit.segmentation.Segmenter` that abstracted them (its model and orientation
    options abstract the mirrors). Returns ``[(features (n, d), labels (n,))]``, one per mirror
    abstracted (a mirror that fails to abstract is left out)."""
    from .labeller import element_features, grid_elements, mesh_elements, point_elements

    labelled = list(labelled)
    mirrors, labels = [], []
    for seg, result, y in labelled:
        shape, order = mirror_shape(_shape_of(seg), result.frame)
        mirrors.append(shape)
        labels.append(np.asarray(y, np.int64)[order])
    results, _ = segmenter.abstract_files(mirrors, progress=progress)
    by_name = {r.name: r for r in results}
    out = []
    for k, (shape, y) in enumerate(zip(mirrors, labels)):
        r = by_name.get(f"shape{k}")  # abstract_shapes' name of the k-th shape given in memory
        if r is None:
            continue
        if isinstance(shape, io.VoxelGrid):
            elements, _ = grid_elements(shape, r.frame)
        elif isinstance(shape, io.Mesh):
            elements = mesh_elements(shape.vertices, shape.faces, r.frame)
        else:
            elements = point_elements(shape.points, r.frame)
        out.append((element_features(elements, r.canonical, settings), y))
    return out


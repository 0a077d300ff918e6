"""What every plugin does: abstract shapes held in memory and co-segment them.

A mesh gets a part index per face (the face-area rule of :func:`primkit.segmentation.face_labels`)
and per vertex; a point cloud a part index per point (:func:`primkit.segmentation.point_labels`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import io
from ..model.abstraction import Abstraction, abstract_shapes
from ..segmentation import face_labels, point_labels

__all__ = ["Labelled", "label_shapes", "label_shape"]


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
        Part index of each vertex of a mesh, or of each point of a cloud.
    part_names : list of str
        The model's name of each part slot.
    """

    abstraction: Abstraction
    face_labels: np.ndarray | None
    point_labels: np.ndarray
    part_names: list

    @property
    def cuboids(self):
        """:class:`primkit.primitives.Cuboids` in the input's frame."""
        return self.abstraction.cuboids


def _labels(shape, cuboids) -> tuple[np.ndarray | None, np.ndarray]:
    if isinstance(shape, io.Mesh):
        if not cuboids.existence.any():
            return np.full(len(shape.faces), -1, np.int64), np.full(len(shape.vertices), -1, np.int64)
        return face_labels(shape.vertices, shape.faces, cuboids), point_labels(shape.vertices, cuboids)
    if isinstance(shape, io.PointCloud):
        if not cuboids.existence.any():
            return None, np.full(len(shape.points), -1, np.int64)
        return None, point_labels(shape.points, cuboids)
    raise TypeError(f"cannot label a {type(shape).__name__}: a mesh or a point cloud")


def label_shapes(shapes, model="chair", *, names=None, **options) -> list[Labelled]:
    """Abstract and co-segment shapes held in memory (any form :func:`primkit.model.abstraction.as_shape`
    takes: meshes and point clouds of primkit, trimesh, pyvista, Open3D, or arrays), in one batch.

    ``options`` are :func:`~primkit.model.abstraction.abstract_shapes`'s (``up``, ``front``,
    ``align``, ``refine``, ...). Raises ValueError naming every shape that could not be used.
    """
    options.setdefault("progress", False)
    options.setdefault("workers", 1)
    shapes = list(shapes)
    names = list(names) if names is not None else [f"shape{i}" for i in range(len(shapes))]
    out = abstract_shapes(shapes, model, names=names, **options)
    if out.errors:
        raise ValueError("; ".join(str(e) for e in out.errors))
    return [Labelled(a, *_labels(a.given, a.cuboids), list(out.model.part_names)) for a in out]


def label_shape(shape, model="chair", *, name: str = "shape", **options) -> Labelled:
    """:func:`label_shapes` of one shape."""
    return label_shapes([shape], model, names=[name], **options)[0]

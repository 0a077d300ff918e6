"""Part names per element on segmented shapes: a labeller (:mod:`primkit.labelling`) reading a
voxel grid's voxels, a mesh's faces or a point cloud's points.

:func:`grid_elements`, :func:`mesh_elements` and :func:`point_elements` turn a shape into the
:class:`Elements` a labeller reads (canonical frame); :func:`label_elements` labels them (a mesh
over its surface, :mod:`primkit.segmentation.meshlabels`); :func:`names_by_index` names a shape's
part indices by the labels their elements carry. The labeller itself lives in
:mod:`primkit.labelling`; its names are re-exported here so that existing imports work.

Frames: points, normals and cuboids given to :meth:`primkit.labelling.labeller.Labeller.features`
are in the canonical frame (``AbstractionResult.canonical`` and
``AbstractionResult.frame.to_canonical``); the ``*_elements`` helpers take the input frame and a
frame, as the segmentations hold them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import primitives
# the labeller's names, where they were before primkit.labelling (existing imports work)
from ..labelling.features import (ABSENT, GRID_RADIUS, LabellerSettings, feature_count,  # noqa: F401
                                  frame_features, grid_knn, grid_local_shape, nearest_neighbours)
from ..labelling.labeller import (DESCRIPTION_KEYS, LABELLER_FORMAT, LABELLER_FORMAT_VERSION,  # noqa: F401
                                  LABELLER_KEY, LABELLER_PREFIX, LABELLER_REBUILD, POST_TOLERANCE, STORED, Labeller,
                                  decide, has_labeller, index_prior, nearest_index, read_labeller, write_labeller)
from ..labelling.smoothing import grid_neighbours, grid_normals, grid_sampling, sample_grid  # noqa: F401
from ..labelling.trees import EARLY_STOP, PACKED_LEAF, TreeEnsemble  # noqa: F401
from ..model.modelfile import ModelFileError  # noqa: F401

__all__ = [
    "LABELLER_FORMAT",
    "LABELLER_FORMAT_VERSION",
    "LABELLER_PREFIX",
    "TreeEnsemble",
    "LabellerSettings",
    "Labeller",
    "Elements",
    "frame_features",
    "decide",
    "grid_normals",
    "grid_neighbours",
    "grid_sampling",
    "grid_knn",
    "grid_local_shape",
    "grid_elements",
    "mesh_elements",
    "point_elements",
    "element_features",
    "label_elements",
    "write_labeller",
    "read_labeller",
    "has_labeller",
    "names_by_index",
]


# ---------------------------------------------------------------------------------------------
# Elements of the three kinds of shape, in the canonical frame
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Elements:
    """What a labeller reads of one shape, in the canonical frame.

    points : (n, 3) float, the elements (voxel centres, face centroids, points)
    normals : (n, 3) float or None, outward unit normals
    context : (c, 3) float or None, points spread evenly over the shape for the local shape
        (a mesh's surface samples; None: the elements themselves)
    neighbours : (n, k) int or None, each element's neighbourhood for smoothing (a grid's
        :func:`grid_neighbours`; None: its nearest elements)
    grid_index : (n, 3) int or None, a grid's voxel indices (for ``LabellerSettings.grid_sample``)
    context_faces : (c,) int or None, a mesh's context samples' faces (the face each lies on; with
        ``faces`` and ``vertices``, the mesh in the input frame, for
        :func:`primkit.segmentation.meshlabels.label_faces`)
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    context: np.ndarray | None = None
    neighbours: np.ndarray | None = None
    grid_index: np.ndarray | None = None
    context_faces: np.ndarray | None = None
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None


def _rotate(frame, vectors):
    return None if vectors is None else np.asarray(vectors, float) @ np.asarray(frame.rotation, float).T


def grid_elements(grid, frame) -> tuple[Elements, np.ndarray]:
    """A voxel grid's occupied voxels: ``(Elements, index (n, 3) int)`` (``np.argwhere`` order;
    normals from :func:`grid_normals`; ``frame`` the grid's :class:`primkit.geometry.CanonicalFrame`)."""
    occupancy = np.asarray(grid.occupancy, bool)
    index = np.argwhere(occupancy)
    centres = grid.translate + (index + 0.5) * (grid.scale / grid.resolution)
    normals = grid_normals(occupancy, index)  # index axes are the model axes (uniform scale)
    return Elements(frame.to_canonical(centres), _rotate(frame, normals),
                    neighbours=grid_neighbours(index, occupancy.shape), grid_index=index), index


def mesh_elements(vertices, faces, frame, samples: int = 20000, seed=0) -> Elements:
    """A mesh's faces: centroids, face normals, and ``samples`` area-uniform surface points
    (trimesh) as the context, all canonical."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
    context, where = trimesh.sample.sample_surface(mesh, samples, seed=seed) if len(faces) else (np.zeros((0, 3)), None)
    enough = len(context) >= 3
    return Elements(frame.to_canonical(mesh.triangles_center), _rotate(frame, mesh.face_normals),
                    frame.to_canonical(context) if enough else None,
                    context_faces=np.asarray(where, np.int64) if enough else None,
                    vertices=mesh.vertices, faces=mesh.faces)


def point_elements(points, frame, normals=None) -> Elements:
    """A point cloud's points (and normals when it has them), canonical."""
    return Elements(frame.to_canonical(points), _rotate(frame, normals))


def element_features(elements: Elements, canonical: primitives.Cuboids, settings: LabellerSettings) -> np.ndarray:
    """:func:`frame_features` of every element, as :meth:`Labeller.predict_proba` reads them (a voxel
    grid's local shape found on the grid, :func:`grid_local_shape`): what a labeller learns from."""
    shape = None
    if settings.neighbours and elements.context is None and elements.grid_index is not None and len(elements.points):
        index = np.asarray(elements.grid_index, np.int64)
        shape = grid_local_shape(elements.points, index, np.arange(len(index)), settings.neighbours,
                                 index.max(axis=0) + 1)
    return frame_features(elements.points, canonical, elements.normals, settings, elements.context, local_shape=shape)


def label_elements(labeller: Labeller, elements: Elements, canonical: primitives.Cuboids, *,
                   graph=None) -> np.ndarray:
    """``(n,) int``: each element's label (index into ``labeller.names``); -1 everywhere when no
    cuboid is present. A mesh's faces (elements with ``faces``) are labelled over the mesh's
    surface (:func:`primkit.segmentation.meshlabels.label_faces`; ``graph``: the mesh's
    :func:`~primkit.segmentation.meshlabels.face_graph` when it is already built), other elements
    by :meth:`Labeller.predict`."""
    if not canonical.existence.any():
        return np.full(len(elements.points), -1, np.int64)
    if elements.faces is not None and len(elements.points):  # a mesh: over its surface (meshlabels)
        from .meshlabels import label_faces

        return label_faces(labeller, elements, canonical, graph=graph)
    return labeller.predict(elements.points, canonical, elements.normals, elements.context, elements.neighbours,
                            elements.grid_index)



def names_by_index(named, index, parts: int, label_names, fallback) -> list:
    """Each part index's name on one shape: the label most of its elements carry.

    ``named`` : (n,) int, each element's label (an index into ``label_names``; negative: none);
    ``index`` : (n,) int, each element's part index (the nearest-cuboid rule); ``fallback`` : the
    model's name of each of the ``parts`` indices, kept where an index holds no labelled element.
    Ties go to the label listed first. A name then selects, on this shape, the cuboids that hold
    mostly elements of that label (``edit --scale arms=...``: the cuboids of the arms).
    """
    named, index = np.asarray(named, np.int64), np.asarray(index, np.int64)
    if named.shape != index.shape:
        raise ValueError(f"`named` and `index` differ in shape: {named.shape} and {index.shape}")
    keep = (named >= 0) & (index >= 0) & (index < parts)
    counts = np.zeros((parts, len(label_names)), np.int64)
    np.add.at(counts, (index[keep], named[keep]), 1)
    return [str(label_names[int(np.argmax(row))]) if row.any() else str(fallback[k]) for k, row in enumerate(counts)]

"""Co-segmentation of meshes and points: each surface element goes to its nearest primitive.

Because one network explains a whole category, primitive ``k`` is the same part on every shape,
and projecting a mesh onto its abstraction parses the whole collection consistently with no labels
given (Tulsiani et al. 2017, Sec. 5.1).

The rule
--------
A point goes to the present cuboid at the smallest distance (zero inside), ties (a point inside
several cuboids) to the larger cuboid, then to the lower index: :func:`primkit.primitives.assign_points`.

* :func:`point_labels` / :func:`vertex_labels`: the rule applied to points or mesh vertices.
* :func:`face_labels`: a face takes the index that holds most of its area. The area is measured
  with a fixed quadrature rather than random samples: one midpoint subdivision splits a triangle
  into four triangles of equal area, and the centroid of each votes for a quarter of the face's
  area; a tie (2-2 or all different) goes to the index of the face's centroid. This is the
  area-weighted vote of points on the face, deterministic and exact for faces that lie in one
  part, and it costs four point projections per face (a million faces in about a second).

Evaluation against ground-truth face labels: :mod:`primkit.segmentation.evaluation`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import io, primitives
from ..model import parts
from ..primitives.palette import part_colors
from . import graphcut
from .meshlabels import FaceGraph, face_graph

__all__ = [
    "point_labels",
    "vertex_labels",
    "face_labels",
    "Segmentation",
    "SegmentationFiles",
    "segment_mesh",
    "surface_face_labels",
    "semantic_codes",
]


def point_labels(points, cuboids: primitives.Cuboids) -> np.ndarray:
    """Primitive index of each point (nearest present cuboid, ties to the larger).

    points : (n, 3) float  ->  (n,) int
    """
    return primitives.assign_points(points, cuboids)


def vertex_labels(vertices, cuboids: primitives.Cuboids) -> np.ndarray:
    """Primitive index of each mesh vertex: :func:`point_labels` of the vertices.

    vertices : (n, 3) float  ->  (n,) int
    """
    return point_labels(vertices, cuboids)


# centroids of the four equal-area triangles of one midpoint subdivision, in barycentric
# coordinates, then the face's own centroid (the tie-breaker)
_QUADRATURE = np.array(
    [[4, 1, 1], [1, 4, 1], [1, 1, 4], [2, 2, 2], [2, 2, 2]], dtype=float
) / 6.0


def semantic_codes(labels, part_names, named=None, label_names=None) -> tuple[list, np.ndarray]:
    """``(names, codes)`` of elements (points, voxels) labelled ``labels`` (part indices, -1 none):
    the distinct names and each element's 1-based name code (-1 none). With a labeller's ``named``
    (indices into ``label_names``, -1 none) its names; else each index's name
    (:func:`primkit.model.parts.label_codes`, the same codes on every shape of a model)."""
    if named is not None:
        return list(label_names), np.where(named >= 0, named + 1, -1)
    return parts.label_codes(part_names)[0], parts.named_labels(labels, part_names)


def face_labels(vertices, faces, cuboids: primitives.Cuboids) -> np.ndarray:
    """Primitive index of each face: the index holding most of its area (see the module notes).

    vertices : (n, 3) float, faces : (f, 3) int  ->  (f,) int
    """
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"`faces` must be (f, 3) int, got shape {faces.shape}")
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    corners = vertices[faces]  # (f, 3, 3)
    points = np.einsum("qc,fcd->fqd", _QUADRATURE, corners).reshape(-1, 3)
    votes = point_labels(points, cuboids).reshape(len(faces), len(_QUADRATURE))
    quarters, centroid = votes[:, :4], votes[:, 4]
    # count of each quarter's label among the four quarters; a label wins with 3 or 4 votes, or
    # with 2 votes when the other two quarters disagree with each other (2-1-1)
    same = (quarters[:, :, None] == quarters[:, None, :]).sum(axis=2)
    best = np.argmax(same, axis=1)
    top = same[np.arange(len(faces)), best]
    winner = quarters[np.arange(len(faces)), best]
    distinct_pairs = (top == 2) & ((same == 2).sum(axis=1) == 4)  # 2-2 split
    tie = (top == 1) | distinct_pairs
    return np.where(tie, centroid, winner)


@dataclass(frozen=True)
class SegmentationFiles:
    """The files one segmentation's ``save`` wrote: its labels (``<name>.seg`` for a mesh,
    ``<name>.parts.npy`` for points, ``<name>.voxlabels.npy`` for a voxel grid) and the coloured
    ``<name>.parts.ply``."""

    labels: Path
    mesh: Path


@dataclass(frozen=True, eq=False)
class Segmentation:
    """The co-segmentation of one mesh by its abstraction.

    Attributes
    ----------
    name, source : str
    vertices : (n, 3) float
    faces : (f, 3) int
    face_labels : (f,) int
        Primitive index of each face.
    vertex_labels : (n,) int
        Primitive index of each vertex.
    cuboids : primitives.Cuboids
        The abstraction, in the mesh's frame.
    part_names : list of str
        The model's name of each index (``part<k>`` when unnamed).
    """

    name: str
    source: str
    vertices: np.ndarray
    faces: np.ndarray
    face_labels: np.ndarray
    vertex_labels: np.ndarray
    cuboids: primitives.Cuboids
    part_names: list = field(default_factory=list)
    #: with a labeller in the model (:mod:`primkit.segmentation.labeller`): each face's label, an
    #: index into ``label_names`` (-1: none), and the labeller's names; None without one
    named: np.ndarray | None = None
    label_names: list | None = None
    #: the number of faces of the source file when they were polygons that reading triangulated
    #: (``faces``, ``face_labels`` and the ``.seg`` then hold one entry per triangle, more than the
    #: file's faces), else None (:func:`primkit.io.declared_face_count`)
    polygons: int | None = None

    @property
    def face_areas(self) -> np.ndarray:
        """(f,) float"""
        return io.Mesh(self.vertices, self.faces).face_areas()

    def part_areas(self) -> np.ndarray:
        """Surface area assigned to each index: ``(m,) float`` (zero for parts holding no face)."""
        return np.bincount(self.face_labels, weights=self.face_areas, minlength=self.cuboids.count)

    def semantic_labels(self) -> tuple[list, np.ndarray]:
        """``(names, codes)``: the distinct part names and each face's 1-based name code
        (:func:`primkit.model.parts.label_codes`, the same codes on every shape of a model)."""
        if self.named is not None:  # the labeller's names, one per face
            return list(self.label_names), np.where(self.named >= 0, self.named + 1, -1)
        names, codes = parts.label_codes(self.part_names)
        return names, codes[self.face_labels]

    def save(self, folder, *, semantic: bool = False, overwrite: bool = False) -> SegmentationFiles:
        """Write ``<name>.seg`` (one label per face: the part index, or with ``semantic`` the
        1-based code of its name) and ``<name>.parts.ply`` (the mesh, faces coloured by part with
        the colour of :func:`primkit.viz.palette.part_colors`, the same on every shape).
        Returns the :class:`SegmentationFiles` written."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = SegmentationFiles(labels=folder / f"{self.name}.seg", mesh=folder / f"{self.name}.parts.ply")
        io.refuse_existing([paths.labels, paths.mesh], overwrite)
        if semantic:
            names, labels = self.semantic_labels()
            colors = part_colors(len(names) + 1)[labels]
        else:
            labels = self.face_labels
            colors = part_colors(self.cuboids.count)[labels]
        io.write_labels(paths.labels, labels, overwrite=overwrite)
        io.write_mesh(paths.mesh, self.vertices, self.faces, face_colors=colors, overwrite=overwrite)
        return paths


def surface_face_labels(vertices, faces, cuboids: primitives.Cuboids, *, smoothness: float | None = None,
                        graph: FaceGraph | None = None) -> np.ndarray:
    """Primitive index of each face by a graph cut over face adjacency, started from
    :func:`face_labels` (:mod:`primkit.segmentation.graphcut`; ``smoothness`` None: its default).

    vertices : (n, 3) float, faces : (f, 3) int  ->  (f,) int; ``graph``: the mesh's
    :func:`~primkit.segmentation.meshlabels.face_graph` when it is already built (None: built here).
    """
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    init = face_labels(vertices, faces, cuboids)
    weight = graphcut.Labelling("graphcut", smoothness).weight("mesh")  # None: the validated default
    if len(faces) == 0 or weight <= 0:
        return init
    samples = np.einsum("qc,fcd->fqd", _QUADRATURE[:4], vertices[faces])
    graph = face_graph(vertices, faces) if graph is None else graph
    return graphcut.graphcut_labels(samples, graph.edges, graph.contact, graph.mass, cuboids, init, weight)


def segment_mesh(vertices, faces, cuboids: primitives.Cuboids, *, name: str = "shape", source: str = "",
                 part_names=None, labelling=None, graph: FaceGraph | None = None) -> Segmentation:
    """Co-segment one mesh by its abstraction (cuboids in the mesh's frame).

    ``labelling``: ``"nearest"`` (:func:`face_labels`), ``"graphcut"`` (:func:`surface_face_labels`),
    a :class:`primkit.segmentation.graphcut.Labelling`, or None: the graph cut
    (:data:`primkit.segmentation.graphcut.DEFAULT_LABELLING`). ``graph``: the mesh's
    :func:`~primkit.segmentation.meshlabels.face_graph` when it is already built (a labeller's cut
    goes over the same one: :func:`primkit.segmentation.segmenter.apply_labeller`); None: built
    here when the graph cut needs it."""
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    names = list(part_names) if part_names is not None else parts.default_part_names(cuboids.count)
    how = graphcut.as_labelling(labelling)
    labels = (surface_face_labels(vertices, faces, cuboids, smoothness=how.smoothness, graph=graph)
              if how.method_for("mesh") == "graphcut" else face_labels(vertices, faces, cuboids))
    declared = io.declared_face_count(source) if source else None
    polygons = declared if declared is not None and 0 < declared < len(faces) else None
    return Segmentation(name, source, vertices, faces, labels, vertex_labels(vertices, cuboids), cuboids, names,
                        polygons=polygons)


# ---------------------------------------------------------------------------------------------

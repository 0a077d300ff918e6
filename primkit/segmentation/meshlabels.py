"""A labeller's names on a mesh's faces, decided over the mesh's own surface.

:meth:`primkit.segmentation.labeller.Labeller.predict` smooths its class probabilities over each
element's ``k`` nearest elements, which suits voxels and points (spread evenly) but not a mesh's
faces: their centroids crowd where the triangles are small and thin out where they are large, so
the same ``k`` nearest centroids cover a speck of one part and half of another. On a mesh
(:func:`primkit.segmentation.labeller.label_elements` with a mesh's elements) the labeller's
probabilities (its trees and index prior, :meth:`~primkit.segmentation.labeller.Labeller.classify`)
are instead

1. averaged over the surface within a fixed radius of each face, weighted by area
   (:func:`surface_weights`: the mesh's evenly spread surface samples, the labeller's context, say
   how much of each face lies near), ``settings.smooth`` times;
2. turned into labels by a Potts graph cut over the faces' edge adjacency, the solver of
   :mod:`primkit.segmentation.graphcut` (:func:`~primkit.segmentation.graphcut.alpha_expansion` on
   its :func:`~primkit.segmentation.graphcut.mesh_graph`), minimising

       E(l) = sum_f  mass_f * -log max(p_f(l), floor)  +  smoothness * sum_(f,g) contact_fg * [l_f != l_g]

   with ``mass_f`` the face's share of the area (the energy does not depend on the tessellation)
   and ``contact_fg`` the shared edge's length over the square root of the area, weighted down at
   concave creases: label boundaries move to where one part meets another;
3. the labeller's rare-label rule (``settings.min_share``, as
   :func:`~primkit.segmentation.labeller.decide`): a label the cut gives to fewer than that share
   of the faces is dropped and the cut run again without it;
4. the labeller's post-steps (:mod:`primkit.labelling.post`, those its file names), as
   :meth:`~primkit.segmentation.labeller.Labeller.predict` applies them to points (a chair's arms
   rule: the side region's share counted in faces, chosen on the meshes below over the share by
   area; the seat cut reads a voxel grid's layers and leaves faces alone).

The radius and the smoothness (:class:`MeshLabelling`) were chosen on meshes of PartNet
validation chairs and on procedural chairs, never on COSEG (``scripts/mesh_labeller_check.py``,
``docs/labeller.md``). ``smoothness`` 0 and ``radius`` 0 give back :meth:`Labeller.predict`'s
decision.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import graphcut

__all__ = ["MeshLabelling", "DEFAULT_MESH_LABELLING", "FaceGraph", "face_graph", "surface_weights", "surface_smooth",
           "face_unary", "cut_faces", "label_faces"]


@dataclass(frozen=True)
class MeshLabelling:
    """How a mesh's faces are labelled from a labeller's probabilities.

    radius : float
        The probabilities are averaged over the surface within this distance of each face
        (canonical frame: the bounding box's longest side 1; :func:`surface_weights`), as many
        times as the labeller's ``settings.smooth``; 0: over its ``smooth_neighbours`` nearest
        faces, as :meth:`~primkit.segmentation.labeller.Labeller.smooth` does elsewhere.
    smoothness : float
        Weight of the cut's boundary term (dimensionless, as :mod:`.graphcut`'s); 0: no cut, each
        face its most probable label.
    floor : float
        Probabilities below it count as it in ``-log p`` (one wrong tree does not forbid a label).
    """

    radius: float = 0.05
    smoothness: float = 0.1
    floor: float = 1e-3


#: What :func:`primkit.segmentation.labeller.label_elements` uses on meshes.
DEFAULT_MESH_LABELLING = MeshLabelling()


@dataclass(frozen=True, eq=False)
class FaceGraph:
    """A mesh's face adjacency (:func:`primkit.segmentation.graphcut.mesh_graph`).

    edges : (e, 2) int, pairs of faces sharing an edge (each pair once)
    contact : (e,) float >= 0, the cost of a label boundary across each pair
    mass : (f,) float, each face's share of the area (sums to 1)
    """

    edges: np.ndarray
    contact: np.ndarray
    mass: np.ndarray


def face_graph(vertices, faces) -> FaceGraph:
    """The :class:`FaceGraph` of a mesh: ``vertices (n, 3) float`` (any frame: the weights are
    scale-free), ``faces (f, 3) int``."""
    return FaceGraph(*graphcut.mesh_graph(vertices, faces))


def surface_weights(points, context, context_faces, radius: float):
    """``(f, f)`` sparse row-stochastic weights of an area-weighted mean over the surface within
    ``radius`` of each face: row ``i`` weighs face ``j`` by how many of the surface samples
    ``context`` (``(c, 3)`` float, spread evenly over the area; sample ``s`` lies on face
    ``context_faces[s]``, ``(c,) int``) lie on face ``j`` within ``radius`` of face ``i``'s
    centroid ``points[i]`` (``(f, 3)`` float, the same frame), plus 1 for face ``i`` itself (a face
    with no sample that near keeps its own).

    Why not the labeller's ``k`` nearest centroids: a fixed count of faces covers a different area
    wherever the triangles differ in size; a fixed radius over evenly spread samples covers the
    same area everywhere. Why not trimesh's or scipy's: neither has an area-weighted mean over
    faces within a radius (``cKDTree.sparse_distance_matrix`` does the search)."""
    from scipy import sparse
    from scipy.spatial import cKDTree

    points = np.asarray(points, float)
    n = len(points)
    if context is None or context_faces is None or not len(points) or radius <= 0:
        return sparse.identity(n, format="csr")
    pairs = cKDTree(points).sparse_distance_matrix(cKDTree(np.asarray(context, float)), radius,
                                                     output_type="ndarray")
    rows = np.concatenate([pairs["i"], np.arange(n)])
    cols = np.concatenate([np.asarray(context_faces, np.int64)[pairs["j"]], np.arange(n)])
    w = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))  # duplicates summed
    return sparse.diags(1.0 / np.asarray(w.sum(axis=1)).ravel()) @ w


def surface_smooth(proba, weights, rounds: int) -> np.ndarray:
    """``(f, k)``: ``proba`` averaged ``rounds`` times with :func:`surface_weights`."""
    proba = np.asarray(proba, float)
    for _ in range(rounds):
        proba = weights @ proba
    return proba


def face_unary(proba, mass, floor: float = 1e-3) -> np.ndarray:
    """``(f, k)``: each face's data cost, ``mass_f * -log max(p_f(l), floor)``."""
    proba = np.asarray(proba, float)
    mass = np.asarray(mass, float).reshape(-1)
    if proba.ndim != 2 or len(proba) != len(mass):
        raise ValueError(f"`proba` must be (f, k) float with one row per face ({len(mass)}), got {proba.shape}")
    return mass[:, None] * -np.log(np.maximum(proba, floor))


def cut_faces(proba, graph: FaceGraph, smoothness: float, *, floor: float = 1e-3, min_share: float = 0.0,
              allowed=None) -> np.ndarray:
    """``(f,) int``: the labels minimising the energy of the module notes (alpha-expansion from
    the most probable labels), then labels given to fewer than ``min_share`` of the faces dropped
    and the cut run again without them (once: what is left of at least two labels stays).
    ``allowed``: (k,) bool, the labels that may be given (None: all)."""
    proba = np.asarray(proba, float)
    k = proba.shape[1]
    allowed = np.ones(k, bool) if allowed is None else np.asarray(allowed, bool)
    keep = np.flatnonzero(allowed)  # the cut over the allowed labels only
    labels = keep[np.argmax(proba[:, keep], axis=1)] if len(proba) else np.zeros(0, np.int64)
    if smoothness > 0 and len(proba) and len(keep) > 1:
        unary = face_unary(proba[:, keep], graph.mass, floor)
        start = np.searchsorted(keep, labels)
        labels = keep[graphcut.alpha_expansion(unary, graph.edges, smoothness * graph.contact, init=start)]
    if min_share > 0 and len(labels):
        counts = np.bincount(labels, minlength=k)
        rare = (counts > 0) & (counts < min_share * len(labels))
        if rare.any() and not rare[counts > 0].all():
            return cut_faces(proba, graph, smoothness, floor=floor, min_share=0.0, allowed=allowed & ~rare)
    return labels.astype(np.int64)


def label_faces(labeller, elements, canonical, how: MeshLabelling | None = None,
                graph: FaceGraph | None = None) -> np.ndarray:
    """``(f,) int``: a mesh's face labels (indices into ``labeller.names``), by the module notes.

    ``elements``: the mesh's :class:`~primkit.segmentation.labeller.Elements` (canonical frame,
    from :func:`~primkit.segmentation.labeller.mesh_elements`: the faces, their surface samples
    and the samples' faces), ``canonical`` its canonical cuboids; ``how`` a :class:`MeshLabelling`
    (None: :data:`DEFAULT_MESH_LABELLING`); ``graph`` the mesh's :func:`face_graph` when it is
    already built (the part-index cut's, :func:`primkit.segmentation.segment_mesh`; None: built
    here from ``elements.vertices`` and ``elements.faces``).
    """
    how = DEFAULT_MESH_LABELLING if how is None else how
    X = labeller.features(elements.points, canonical, elements.normals, elements.context)
    proba = labeller.classify(X)
    if how.radius > 0 and elements.context_faces is not None:
        weights = surface_weights(elements.points, elements.context, elements.context_faces, how.radius)
        proba = surface_smooth(proba, weights, labeller.settings.smooth)
    else:
        proba = labeller.smooth(proba, elements.points)
    if graph is None:
        graph = face_graph(elements.vertices, elements.faces) if how.smoothness > 0 and elements.faces is not None \
            else FaceGraph(np.zeros((0, 2), np.int64), np.zeros(0), np.full(len(proba), 1.0 / max(len(proba), 1)))
    labels = cut_faces(proba, graph, how.smoothness, floor=how.floor, min_share=labeller.settings.min_share)
    # the labeller's post-steps (those that read faces: a chair's arms rule, its side region's share
    # counted in faces; by face area it vetoed the thin arms of procedural chairs, docs/labeller.md)
    return labeller.after(labels, proba, elements.points, elements.context)

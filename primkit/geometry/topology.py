"""Which faces of a triangle mesh touch: edge-sharing face pairs.

Written here rather than taken from trimesh (``trimesh.graph.face_adjacency``, whose rule it
follows: an edge joins two faces when exactly two faces use it): importing trimesh and the networkx
it pulls in cost about 1 s of each ``primkit segment`` run, which needs nothing else of it
(``benchmarks/bench_segment.py``, one shape from a cold start). ``tests/geometry/test_topology.py``
compares the pairs with trimesh's on meshes with open, non-manifold and degenerate edges.
"""

from __future__ import annotations

import numpy as np

__all__ = ["face_adjacency"]


def face_adjacency(faces) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of faces that share an edge, and that edge.

    Parameters
    ----------
    faces : (f, 3) int
        Vertex indices of triangles. Vertices are matched by index: merge coincident vertices
        first where a mesh repeats them.

    Returns
    -------
    pairs : (e, 2) int64
        Face indices, the smaller first, one row per edge used by exactly two distinct faces
        (edges of one face, boundary edges and edges of three or more faces give none), ordered by
        the shared edge.
    edges : (e, 2) int64
        The shared edge of each pair, its vertex indices ascending.
    """
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if not len(faces):
        return np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(len(faces), dtype=np.int64), 3)
    key = edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    key = key[order]
    start = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1])))
    count = np.diff(np.concatenate((start, [len(key)])))
    first = start[count == 2]
    a, b = owner[order[first]], owner[order[first + 1]]
    keep = a != b  # a face with a repeated vertex uses one edge twice
    pairs = np.sort(np.stack([a[keep], b[keep]], axis=1), axis=1)
    return pairs, edges[order[first[keep]]]

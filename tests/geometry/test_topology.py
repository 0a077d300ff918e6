"""primkit.geometry.face_adjacency against trimesh's face_adjacency (an independent implementation)."""

import numpy as np
import pytest
import trimesh

from primkit.geometry import face_adjacency


def _as_set(pairs, edges):
    return {(int(p[0]), int(p[1]), int(e[0]), int(e[1])) for p, e in zip(pairs, edges)}


def _trimesh(faces):
    pairs, edges = trimesh.graph.face_adjacency(faces=faces, return_edges=True)
    return _as_set(pairs, np.sort(edges, axis=1))


@pytest.mark.parametrize("seed", range(5))
def test_same_pairs_as_trimesh_on_soups(seed):
    # random faces over few vertices: open edges, edges of 3+ faces, repeated and degenerate faces
    rng = np.random.default_rng(seed)
    faces = rng.integers(0, 12, size=(60, 3))
    pairs, edges = face_adjacency(faces)
    assert _as_set(pairs, edges) == _trimesh(faces)
    assert len(pairs) == len(_as_set(pairs, edges))  # no pair twice
    assert np.all(pairs[:, 0] < pairs[:, 1]) and np.all(edges[:, 0] <= edges[:, 1])


def test_closed_mesh_every_edge_once():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    pairs, edges = face_adjacency(mesh.faces)
    assert len(pairs) == len(mesh.edges_unique)  # closed 2-manifold: every edge joins two faces
    assert _as_set(pairs, edges) == _trimesh(mesh.faces)
    for (f, g), e in zip(pairs[:50], edges[:50]):  # the edge is in both faces
        assert set(e) <= set(mesh.faces[f]) and set(e) <= set(mesh.faces[g])


def test_empty_and_single():
    assert face_adjacency(np.zeros((0, 3), int))[0].shape == (0, 2)
    assert face_adjacency([[0, 1, 2]])[0].shape == (0, 2)
    pairs, edges = face_adjacency([[0, 1, 2], [2, 1, 3]])
    assert pairs.tolist() == [[0, 1]] and edges.tolist() == [[1, 2]]

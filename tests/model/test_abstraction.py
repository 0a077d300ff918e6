"""The one way in: shapes as users have them (files, folders, meshes, arrays) to abstractions."""

import numpy as np
import pytest

import primkit
from primkit import io, synthetic
from primkit.model.abstraction import abstract_shapes, as_shape


def test_files_meshes_and_arrays_give_the_same_abstraction_in_input_order(tmp_path):
    path = synthetic.write_collection(tmp_path / "in", "chair", 1, seed=3)[0]
    mesh = io.read_mesh(path)
    out = abstract_shapes([tmp_path / "in", (mesh.vertices, mesh.faces), tmp_path / "missing.off", mesh], model="chair",
                          cache=tmp_path / "cache", workers=1, progress=False)
    assert [a.name for a in out] == ["chair_0000", "shape1", "shape3"]
    assert len(out.errors) == 1 and "missing.off" in out.errors[0]
    first = out[0]
    for other in out.shapes[1:]:  # the same mesh, from a file or from memory: the same cuboids
        # (parts grown to their surface samples follow the samples, which differ by up to 5e-4
        # between the routes: the file holds the vertices rounded)
        np.testing.assert_array_equal(other.cuboids.existence, first.cuboids.existence)
        np.testing.assert_allclose(other.cuboids.translations, first.cuboids.translations, atol=2e-3)
    assert first.mesh.faces.shape == mesh.faces.shape and first.prepared.occupancy.shape == (32, 32, 32)
    np.testing.assert_allclose(first.canonical_vertices(), first.result.frame.to_canonical(mesh.vertices))
    one = primkit.abstract(path, model=out.model, workers=1, cache=tmp_path / "cache")  # options pass through
    np.testing.assert_allclose(one.cuboids.translations, first.cuboids.translations, atol=1e-6)  # batch of 1, not 3
    with pytest.raises(io.ShapeFileError, match="missing.off"):
        primkit.abstract(tmp_path / "missing.off", model=out.model)


def test_inputs_are_read_as_primkit_values():
    v = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    assert isinstance(as_shape(v), io.PointCloud)
    assert isinstance(as_shape(np.zeros((8, 8, 8), bool)), io.VoxelGrid)
    with pytest.raises(TypeError, match="cannot abstract a dict"):
        as_shape({})


def test_a_list_holding_one_mesh_or_one_cloud_is_a_list_of_shapes():
    s = synthetic.generate("chair", 1, seed=2)[0]
    points = s.vertices[::2]
    one_mesh = abstract_shapes([(s.vertices, s.faces)], model="chair", progress=False)
    clouds = abstract_shapes([points, points + 0.1], model="chair", progress=False)
    nested = abstract_shapes(points.tolist(), model="chair", progress=False)  # a nested list of points: one cloud
    assert len(one_mesh) == 1 and isinstance(one_mesh[0].given, io.Mesh)
    assert len(clouds) == 2 and all(isinstance(a.given, io.PointCloud) for a in clouds)
    assert len(nested) == 1 and len(nested[0].given.points) == len(points)

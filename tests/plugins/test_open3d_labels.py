"""The Open3D attributes carry the labeller's names: ``triangle["label"]`` of a mesh and
``point["label"]`` of a cloud, checked against :func:`primkit.segmentation.labeller.label_elements`
called directly on the same procedural chair (the bundled chair model's labeller)."""

from __future__ import annotations

import numpy as np
import pytest

from primkit import synthetic
from primkit.model.abstraction import abstract
from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.viz.palette import UNLABELLED, label_colors

o3d = pytest.importorskip("open3d")
pk = pytest.importorskip("primkit.plugins.open3d_geometry")


@pytest.fixture(scope="module")
def chair():
    return synthetic.generate("chair", 1, seed=11)[0]


@pytest.fixture(scope="module")
def labeller():
    return lab.read_labeller(resolve_model("chair"))


def test_a_mesh_gets_a_label_per_face_as_the_labeller_gives(chair, labeller, tmp_path):
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(chair.vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(chair.faces.astype(np.int32))
    seg = pk.segment_geometry(mesh, model="chair")
    a = abstract((chair.vertices, chair.faces), "chair")
    want = lab.label_elements(labeller, lab.mesh_elements(chair.vertices, chair.faces, a.result.frame), a.result.canonical)
    got = seg.geometry.triangle["label"].numpy()
    assert got.shape == (len(chair.faces),) and np.array_equal(got, want)
    assert seg.label_names == ["back", "seat", "legs", "arms"]
    assert len(np.unique(got)) >= 3  # back, seat and legs at least: not a constant
    # the colours: the label palette, per face
    assert np.allclose(seg.label_colors() * 255, label_colors(4)[want])
    # the mask travels through Open3D's own selection
    seat = seg.geometry.select_faces_by_mask(o3d.core.Tensor(got == 1))
    assert len(seat.triangle.indices) == int((want == 1).sum()) and np.all(seat.triangle["label"].numpy() == 1)
    # and through primkit's PLY writer and reader
    back = pk.read(pk.write(tmp_path / "seg.ply", seg.geometry))
    assert np.array_equal(back.triangle["label"].numpy(), want)


def test_a_cloud_gets_a_label_per_point_and_none_without_a_labeller(chair, labeller):
    rng = np.random.default_rng(0)
    points = chair.vertices[rng.choice(len(chair.vertices), 1500)] + rng.normal(0, 1e-3, (1500, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    seg = pk.segment_geometry(pcd, model="chair")
    a = abstract(points, "chair")
    want = lab.label_elements(labeller, lab.point_elements(points, a.result.frame), a.result.canonical)
    got = seg.geometry.point["label"].numpy()
    assert got.shape == (len(points), 1) and np.array_equal(got[:, 0], want)
    plain = pk.segment_geometry(pcd, model="chair", labeller=None)
    assert "label" not in plain.geometry.point and plain.label_names is None and plain.label_colors() is None


def test_label_element_colors_greys_what_has_no_name():
    from primkit.viz.palette import label_element_colors

    got = label_element_colors(np.array([0, -1, 2]), 3)
    assert np.array_equal(got, np.vstack([label_colors(3)[0], UNLABELLED, label_colors(3)[2]]))
    with pytest.raises(ValueError, match="3 label names"):
        label_element_colors(np.array([3]), 3)

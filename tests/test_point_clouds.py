"""Point clouds end to end: .xyz / .npy / .ply clouds through embed, deform (of the points) and the
viewers, with the same one-line errors as meshes; each checked against the library on the same
points (and the identity deformation against the input itself)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from primkit import deformation, geometry, io, synthetic
from primkit.cli import main
from primkit.model.abstraction import abstract_shapes, load_model
from primkit.segmentation import point_labels


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """Four procedural chairs sampled to 3,000 points each, written as .xyz, .npy, .ply, .xyz."""
    root = tmp_path_factory.mktemp("clouds")
    (root / "in").mkdir()
    paths = []
    for i, (shape, suffix) in enumerate(zip(synthetic.generate("chair", 4, seed=21), (".xyz", ".npy", ".ply", ".xyz"))):
        points = geometry.sample_surface(shape.vertices, shape.faces, 3000, seed=i).points
        paths.append(io.write_points(root / "in" / f"cloud{i}{suffix}", points))
    return root, paths


def test_deforming_a_cloud_moves_its_points_as_the_library_does(clouds, tmp_path, capsys):
    root, paths = clouds
    out = tmp_path / "moved.xyz"
    assert main(["deform", str(paths[0]), str(paths[1]), "--model", "chair", "-o", str(out), "--workers", "1",
                 "--png", str(tmp_path / "d.png")]) == 0
    moved = io.read_points(out).points
    model = load_model("chair")
    a, b = abstract_shapes([paths[0], paths[1]], model, workers=1, progress=False)
    v = a.result.frame.to_canonical(io.read_points(paths[0]).points)
    want = a.result.frame.from_canonical(deformation.deform(v, a.result.canonical, b.result.canonical).vertices)
    np.testing.assert_allclose(moved, want, atol=1e-9)
    report = json.loads((tmp_path / "moved.json").read_text())
    assert report["kind"] == "points" and report["quality"]["chamfer_result_target"] < report["quality"]["chamfer_source_target"]
    from pictures import read_picture

    picture = read_picture(tmp_path / "d.png")  # source, target and result, each with its cuboids
    assert picture.blobs() >= 3 and 0.03 < picture.foreground_fraction < 0.8, (picture.blobs(), picture.foreground_fraction)
    # onto itself: every part keeps its place, the points stay
    same = tmp_path / "same.npy"
    assert main(["deform", str(paths[0]), str(paths[0]), "--model", "chair", "-o", str(same), "--workers", "1"]) == 0
    np.testing.assert_allclose(io.read_points(same).points, io.read_points(paths[0]).points, atol=1e-9)
    # a mesh suffix for a cloud: one line, naming the file
    capsys.readouterr()
    assert main(["deform", str(paths[0]), str(paths[1]), "--model", "chair", "-o", str(tmp_path / "m.obj"),
                 "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "m.obj: a deformed point cloud is written as" in err and not (tmp_path / "m.json").exists()


def test_embed_takes_clouds(clouds, tmp_path):
    root, paths = clouds
    assert main(["embed", str(root / "in"), "--model", "chair", "-o", str(tmp_path / "emb"), "--workers", "1"]) == 0
    names = (tmp_path / "emb").iterdir()
    assert any(p.suffix in (".npy", ".csv") for p in names)


def test_viewers_draw_clouds_as_points_coloured_by_part(clouds):
    from vtk.util.numpy_support import vtk_to_numpy

    from primkit.viewers import abstraction_viewer, collection_browser, common, deformation_viewer
    from primkit.viz.palette import part_colors

    root, paths = clouds
    model = load_model("chair")
    shapes = [common.drawable(a) for a in abstract_shapes(paths, model, workers=1, progress=False)]
    assert all(isinstance(s, common.PointShape) and s.faces.shape == (0, 3) for s in shapes)
    browser = collection_browser.collection_browser(shapes, model.part_names, mode="segmentation", off_screen=True,
                                                    window_size=(500, 400))
    for s, actor in zip(shapes, browser.actors["segmentation"]):
        poly = actor.GetMapper().GetInput()
        labels = point_labels(s.canonical_vertices(), s.result.canonical)
        assert poly.GetNumberOfPoints() == len(s.points)
        assert np.array_equal(vtk_to_numpy(poly.GetPointData().GetArray("rgb")), part_colors(20)[labels])
    browser.plotter.close()
    s = shapes[0]
    viewer = abstraction_viewer.abstraction_viewer(s.vertices, s.faces, s.cuboids, model.part_names, off_screen=True,
                                                   window_size=(400, 300))
    assert viewer.mesh_actor.GetMapper().GetInput().GetNumberOfPoints() == len(s.points)
    viewer.plotter.close()
    dv = deformation_viewer.deformation_viewer(shapes[0], shapes[1], model.part_names, off_screen=True,
                                               window_size=(600, 400))
    assert dv.result_poly.n_points == len(shapes[0].points)
    dv.plotter.close()

"""The Open3D viewer: its actions driven with a window that records what they ask of it, their effect
checked on the scene and the files; and once in Open3D's real window under Xvfb (skipped, with the
reason, without xvfb-run or a Vulkan driver; scripts/setup.sh installs both)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from primkit import io, synthetic
from primkit.model.abstraction import load_model
from primkit.model.cuboids_file import read_cuboids_file
from primkit.segmentation.meshes import surface_face_labels
from primkit.segmentation.points import segment_points
from primkit.viewers.open3d_viewer import open3d_viewer


@pytest.fixture(scope="module")
def model():
    return load_model("chair")


@pytest.fixture(scope="module")
def chair(tmp_path_factory):
    path = synthetic.write_collection(tmp_path_factory.mktemp("o3dview"), "chair", 1, seed=8)[0]
    return path, io.read_mesh(path)


def test_parts_toggle_refine_and_export(chair, model, tmp_path, recording_window):
    path, mesh = chair
    viewer = open3d_viewer((mesh.vertices, mesh.faces), model, name="c", refine_step=30, export_folder=tmp_path / "x")
    cub = viewer.segmentation.cuboids
    labels = surface_face_labels(mesh.vertices, mesh.faces, cub)  # the default labelling: the graph cut
    assert np.array_equal(viewer.segmentation.labelled.face_labels, labels)
    names = {g["name"]: g for g in viewer.geometries()}
    for k in cub.present:
        assert {f"cuboids {k}", f"cuboids {k} edges"} <= set(names)
        assert names[f"cuboids {k} edges"]["geometry"].line.indices.shape[0] == 12  # a box shows its 12 edges
    for k in np.unique(labels):  # part k's surface is exactly the faces labelled k
        assert len(names[f"surface {k}"]["geometry"].triangle.indices) == int((labels == k).sum())
    assert [a for a, _ in viewer.actions()][-4:] == ["surface", "cuboids", "refine +30", "export"]

    w = recording_window()
    k = int(cub.present[0])
    assert viewer.toggle_part(w, k) is False
    assert {n for n, v in w.shown.items() if not v} == {n for n in names if n.split()[1] == str(k)}
    assert viewer.toggle_part(w, k) is True and all(w.shown.values())
    assert viewer.toggle_cuboids(w) is False
    assert {n for n, v in w.shown.items() if not v} == {n for n in names if n.startswith("cuboids")}
    viewer.toggle_cuboids(w)

    before = cub.translations.copy()
    assert viewer.refine(w) == 30 and viewer.refine(w) == 60
    assert set(w.removed) == set(names) and viewer.segmentation.labelled.abstraction.result.refinement is not None
    assert not np.allclose(viewer.segmentation.cuboids.translations[cub.present], before[cub.present])

    written = viewer.export(w)
    saved = read_cuboids_file(written.cuboids)
    np.testing.assert_allclose(saved.cuboids.translations, viewer.segmentation.cuboids.translations)
    assert saved.frame == "input" and saved.canonical_frame is not None and saved.extra["refinement"]["steps"] == 60
    assert np.array_equal(io.read_labels(written.labels), viewer.segmentation.labelled.face_labels)
    assert io.read_mesh(written.parts).faces.shape == mesh.faces.shape
    paths = [written.cuboids, written.labels, written.parts]
    stamp = {p: p.stat().st_mtime_ns for p in paths}
    assert viewer.export(w) is None and "exists: nothing written" in w.boxes[-1][1]  # never over a file
    assert {p: p.stat().st_mtime_ns for p in paths} == stamp


def test_point_cloud_in_the_viewer(chair, model, tmp_path, recording_window):
    _, mesh = chair
    points = mesh.vertices[::2]
    viewer = open3d_viewer(points, model, name="cloud", export_folder=tmp_path)
    labels = segment_points(io.PointCloud(points), viewer.segmentation.cuboids).labels  # the default labelling
    for g in viewer.geometries():
        if g["name"].startswith("surface"):
            k = int(g["name"].split()[1])
            assert len(g["geometry"].point.positions) == int((labels == k).sum())
    written = viewer.export(recording_window())
    assert np.array_equal(np.load(written.labels), labels)
    assert written.parts.suffix == ".ply" and len(io.read_points(written.parts).points) == len(points)


def _vulkan() -> bool:
    return any(Path(d).glob("libvulkan.so*") for d in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib"))


@pytest.mark.skipif(shutil.which("xvfb-run") is None or not _vulkan(),
                    reason="xvfb-run or a Vulkan driver missing (scripts/setup.sh installs xvfb, libvulkan1 and "
                           "mesa-vulkan-drivers)")
@pytest.mark.integration  # Open3D's window under Xvfb
def test_the_real_open3d_window_draws_the_parts_and_runs_its_actions(chair, tmp_path):
    path, _ = chair
    code = f"""
import json, sys
import numpy as np
from PIL import Image
from primkit import io
from primkit.cli import main
from primkit.viewers.open3d_viewer import open3d_viewer
assert main(["view", "open3d", {str(path)!r}, "--model", "chair", "--png", {str(tmp_path / 'shot.png')!r},
             "--size", "640x480"]) == 0
mesh = io.read_mesh({str(path)!r})
viewer = open3d_viewer((mesh.vertices, mesh.faces), "chair", name="c")
app, w = viewer.window(width=640, height=480)
for _ in range(3):
    app.run_one_tick()
k = int(viewer.segmentation.cuboids.present[0])
viewer.toggle_part(w, k)
hidden = [n for n in ("surface " + str(k), "cuboids " + str(k)) if n in [g["name"] for g in viewer.geometries()]]
out = {{"hidden": [w.get_geometry(n).is_visible for n in hidden],
       "others": [w.get_geometry(g["name"]).is_visible for g in viewer.geometries() if g["name"].split()[1] != str(k)]}}
w.close()
app.run_one_tick()
print(json.dumps(out))
"""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW")}
    out = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", sys.executable, "-c", code],
                         capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["hidden"] and not any(got["hidden"]) and all(got["others"])
    from PIL import Image

    from primkit.viz.palette import part_colors

    img = np.asarray(Image.open(tmp_path / "shot.png").convert("RGB")).astype(int)
    hue = img / np.maximum(img.sum(-1, keepdims=True), 1)
    colours = part_colors(20)[[16, 18]].astype(int)  # the seat and back of the bundled chair model
    ref = colours / colours.sum(-1, keepdims=True)
    close = (np.abs(hue[:, :, None] - ref[None, None]).sum(-1) < 0.06) & (np.ptp(img, axis=-1) > 40)[..., None]
    assert (close.sum(axis=(0, 1)) > 200).all(), close.sum(axis=(0, 1))

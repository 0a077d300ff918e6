"""Open3D: the ``part`` attribute through ``o3d.t.io`` write-and-read, per format (the table in
:mod:`primkit.plugins.open3d_geometry`), primkit's writer and reader where Open3D drops it, and
``primkit view open3d --png`` with no display (Open3D's ``OffscreenRenderer``)."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

from primkit import io, synthetic
from primkit.plugins import open3d_geometry as pk

o3d = pytest.importorskip("open3d")

MESH_FORMATS = (".npz", ".ply", ".obj", ".off", ".stl", ".glb")
CLOUD_FORMATS = (".ply", ".pcd", ".npz", ".xyz", ".pts")


@pytest.fixture(scope="module")
def segmented(tmp_path_factory):
    """A chair segmented as a tensor mesh, and its vertices segmented as a tensor point cloud."""
    path = synthetic.write_collection(tmp_path_factory.mktemp("o3d"), "chair", 1, seed=11)[0]
    mesh = io.read_mesh(path)
    seg = pk.segment_all([o3d.t.io.read_triangle_mesh(str(path)),
                          o3d.t.geometry.PointCloud(o3d.core.Tensor(mesh.vertices[::2].astype(np.float32)))], "chair")
    return seg[0], seg[1], path


def _part(attributes):
    return attributes["part"].numpy().reshape(-1) if "part" in attributes else None


def _o3d_round_trip(geometry, path):
    if type(geometry).__name__ == "TriangleMesh":
        assert o3d.t.io.write_triangle_mesh(str(path), geometry)
        return o3d.t.io.read_triangle_mesh(str(path))
    assert o3d.t.io.write_point_cloud(str(path), geometry)
    return o3d.t.io.read_point_cloud(str(path))


@pytest.mark.parametrize("suffix", MESH_FORMATS)
def test_a_segmented_mesh_through_o3d_t_io(segmented, suffix, tmp_path):
    seg = segmented[0]
    faces = seg.labelled.face_labels
    back = _o3d_round_trip(seg.geometry, tmp_path / f"m{suffix}")  # never raises (1-D vertex part used to, on .npz)
    kept = _part(back.triangle)
    if suffix in pk.KEEPS_PART["TriangleMesh"]:
        assert np.array_equal(kept, faces)
    else:
        assert kept is None  # Open3D drops it: what the module notes say, measured here
    # primkit's writer: the same file type, part kept through primkit's reader, or a one-line warning
    out = tmp_path / f"pk{suffix}"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pk.write(out, seg.geometry)
    again = pk.read(out)
    if suffix in (".npz", ".ply"):
        assert not caught
        assert np.array_equal(_part(again.triangle), faces)
        assert np.array_equal(_part(again.vertex), seg.labelled.point_labels)
        assert np.array_equal(again.triangle.indices.numpy(), seg.geometry.triangle.indices.numpy())
    else:
        assert len(caught) == 1 and str(caught[0].message).count("\n") == 0
        assert f"pk{suffix}" in str(caught[0].message) and "keeps no 'part'" in str(caught[0].message)
    if suffix == ".ply":  # Open3D's own reader still reads primkit's PLY (positions, colours)
        plain = o3d.t.io.read_triangle_mesh(str(out))
        np.testing.assert_allclose(plain.vertex.positions.numpy(), seg.geometry.vertex.positions.numpy())
        np.testing.assert_allclose(plain.vertex.colors.numpy(), seg.geometry.vertex["colors"].numpy(), atol=1 / 255)


@pytest.mark.parametrize("suffix", CLOUD_FORMATS)
def test_a_segmented_point_cloud_through_o3d_t_io(segmented, suffix, tmp_path):
    seg = segmented[1]
    assert tuple(seg.geometry.point["part"].shape) == (len(seg.labelled.point_labels), 1)
    back = _o3d_round_trip(seg.geometry, tmp_path / f"c{suffix}")
    kept = _part(back.point)
    if suffix in pk.KEEPS_PART["PointCloud"]:
        assert np.array_equal(kept, seg.labelled.point_labels)
    else:
        assert kept is None
        with pytest.warns(UserWarning, match="keeps no 'part'"):
            pk.write(tmp_path / f"pk{suffix}", seg.geometry)


def test_write_refuses_to_overwrite_and_legacy_geometry(segmented, tmp_path):
    seg = segmented[0]
    pk.write(tmp_path / "a.npz", seg.geometry)
    pk.write(tmp_path / "a.ply", seg.geometry)  # primkit's own PLY writer
    for name in ("a.npz", "a.ply"):  # a library caller is told the library's word, not the command's
        with pytest.raises(FileExistsError, match=r"exists \(pass overwrite=True to replace it\)") as caught:
            pk.write(tmp_path / name, seg.geometry)
        assert "--force" not in str(caught.value)
        pk.write(tmp_path / name, seg.geometry, overwrite=True)
    with pytest.raises(TypeError, match="tensor TriangleMesh or PointCloud"):
        pk.write(tmp_path / "b.ply", seg.geometry.to_legacy())


@pytest.mark.integration  # a CLI process rendering with Open3D
def test_view_open3d_png_with_no_display(segmented, tmp_path):
    """``primkit view open3d --png`` with DISPLAY unset: Open3D's OffscreenRenderer draws the parts in
    primkit's colours."""
    from PIL import Image

    from primkit.viz.palette import part_colors

    seg, _, path = segmented
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    code = ("import sys; from primkit.cli import main; "
            f"sys.exit(main(['view', 'open3d', {str(path)!r}, '--model', 'chair', '--png', {str(tmp_path / 'p.png')!r}, "
            "'--size', '480x360']))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    img = np.asarray(Image.open(tmp_path / "p.png").convert("RGB")).astype(int)
    assert img.shape == (360, 480, 3)
    assert (img[0] == 255).all() and (img[:, 0] == 255).all()  # white background, nothing at the border
    hue = img / np.maximum(img.sum(-1, keepdims=True), 1)
    labels = seg.labelled.face_labels
    biggest = np.bincount(labels[labels >= 0]).argsort()[::-1][:2]  # the two largest parts are seen
    colours = part_colors(20)[biggest].astype(int)
    ref = colours / colours.sum(-1, keepdims=True)
    close = (np.abs(hue[:, :, None] - ref[None, None]).sum(-1) < 0.06) & (np.ptp(img, axis=-1) > 40)[..., None]
    assert (close.sum(axis=(0, 1)) > 200).all(), close.sum(axis=(0, 1))

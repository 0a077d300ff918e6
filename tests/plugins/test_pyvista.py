"""pyvista meets primkit with no ``import primkit``: ``pv.read`` of ``.off``, ``.binvox``, ``.xyz`` and
``.npy`` (the ``pyvista.readers`` entry points) and ``.primkit`` (``pyvista.accessors``), from a wheel
built from this checkout; the accessor's typed options, progress bar and colours."""

from __future__ import annotations

import inspect
import json
import re
from pathlib import Path

import numpy as np
import pytest
from wheel_env import run as _run

from primkit import io, synthetic
from primkit.plugins import pyvista_readers
from primkit.plugins.common import label_shape
from primkit.segmentation import voxel_centres
from primkit.viz.palette import part_colors

CHAIR = "coseg_chairs/chairs_101-120/shapes/101.off"
VOXELS = "standalone_meshes/chair.binvox"


@pytest.fixture(scope="module")
def wheel_python(wheel_env):
    """The session's fresh environment holding the wheel of this checkout (``tests/conftest.py``)."""
    return wheel_env / "bin" / "python", wheel_env


@pytest.mark.shared
@pytest.mark.integration  # a wheel built and installed into a fresh virtual environment, as tests/test_wheel.py
def test_pv_read_off_and_binvox_and_segment_from_the_wheel_without_import(shared_data, wheel_python, tmp_path):
    python, env = wheel_python
    cloud = tmp_path / "chair.xyz"
    mesh = io.read_mesh(shared_data / CHAIR)
    np.savetxt(cloud, mesh.vertices[::7])
    np.save(tmp_path / "chair.npy", mesh.vertices[::7])
    code = """if True:
        import json, sys, pyvista as pv
        chair = pv.read(sys.argv[1]); grid = pv.read(sys.argv[2])
        xyz, npy = pv.read(sys.argv[3]), pv.read(sys.argv[4])
        read_only = "torch" not in sys.modules and "primkit.model" not in sys.modules
        parts = chair.primkit.segment(model="chair")
        voxels = grid.primkit.segment(model="chair")
        import primkit
        print(json.dumps({"read_only": read_only, "file": primkit.__file__,
                          "points": chair.points.tolist(), "faces": chair.regular_faces.tolist(),
                          "part": parts["part"].tolist(), "dims": list(grid.dimensions),
                          "occupancy": grid["occupancy"].tolist(), "voxel_part": voxels["part"].tolist(),
                          "xyz": xyz.points.tolist(), "npy": npy.n_points}))
    """
    got = json.loads(_run([python, "-c", code, shared_data / CHAIR, shared_data / VOXELS, cloud, tmp_path / "chair.npy"],
                          cwd=tmp_path).strip().splitlines()[-1])
    assert Path(got["file"]).is_relative_to(env)  # primkit came from the wheel
    assert got["read_only"]  # reading a file imports neither primkit's model nor torch
    np.testing.assert_array_equal(got["points"], mesh.vertices)  # pv.read gives what primkit reads
    np.testing.assert_array_equal(got["faces"], mesh.faces)
    expected = label_shape((mesh.vertices, mesh.faces), "chair")
    assert np.array_equal(got["part"], expected.face_labels)  # the accessor gives primkit's labels
    grid = io.read_voxels(shared_data / VOXELS)
    assert got["dims"] == [grid.resolution + 1] * 3
    assert np.array_equal(np.asarray(got["occupancy"]).reshape((grid.resolution,) * 3, order="F"), grid.occupancy)
    voxel_expected = label_shape(grid, "chair").voxel_labels
    assert np.array_equal(np.asarray(got["voxel_part"]).reshape(voxel_expected.shape, order="F"), voxel_expected)
    np.testing.assert_allclose(got["xyz"], mesh.vertices[::7], atol=1e-12)
    assert got["npy"] == len(mesh.vertices[::7])


@pytest.mark.shared
def test_the_binvox_image_puts_each_voxel_where_primkit_does(shared_data):
    grid = io.read_voxels(shared_data / VOXELS)
    image = pyvista_readers.read_binvox(shared_data / VOXELS)
    filled = image.extract_cells(np.flatnonzero(image["occupancy"]))
    centres, _ = voxel_centres(grid)
    got = np.asarray(filled.cell_centers().points)
    order = lambda a: a[np.lexsort(np.round(a, 6).T)]  # noqa: E731
    np.testing.assert_allclose(order(got), order(centres), atol=1e-9)  # brute force: every filled cell's centre
    back = pyvista_readers.voxels_from_pyvista(image)
    assert np.array_equal(back.occupancy, grid.occupancy) and np.allclose(back.translate, grid.translate)
    assert back.scale == pytest.approx(grid.scale)
    with pytest.raises(TypeError, match="takes no options"):
        pyvista_readers.read_off(shared_data / CHAIR, foo=1)
    with pytest.raises(io.ShapeFileError, match="chair.binvox"):
        pyvista_readers.read_off(shared_data / VOXELS)


def test_the_accessor_lists_its_options_typed_and_documented():
    from primkit.plugins.pyvista_accessor import PrimkitAccessor, PrimkitBlocksAccessor

    wanted = {"up": "str | None", "front": "str | None", "align": "str | None", "refine": "int",
              "existence_threshold": "float", "prune_threshold": "float | None", "progress_bar": "bool"}
    for cls in (PrimkitAccessor, PrimkitBlocksAccessor):
        for name in ("abstract", "segment", "cuboids"):
            method = getattr(cls, name)
            params = inspect.signature(method).parameters
            assert {k: params[k].annotation for k in wanted} == wanted, (cls, name)
            assert all(params[k].kind is inspect.Parameter.KEYWORD_ONLY for k in wanted)
            assert not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
            documented = set(re.findall(r"^ +(\w+(?:, \w+)*) : ", method.__doc__, re.M))
            assert set(wanted) <= {k for line in documented for k in line.split(", ")}, (cls, name)


def test_segmented_copies_carry_primkits_colours_and_a_progress_bar(tmp_path, capsys):
    import pyvista as pv

    path = synthetic.write_collection(tmp_path, "chair", 1, seed=3)[0]
    poly = pv.read(path)
    seg = poly.primkit.segment(model="chair", progress_bar=True)
    assert "primkit: labelling" in capsys.readouterr().err  # tqdm writes to stderr
    names = list(seg.field_data["part_names"])
    palette = part_colors(len(names))
    assert seg.cell_data.active_scalars_name == "part_rgb"
    assert np.array_equal(seg.cell_data["part_rgb"], palette[seg.cell_data["part"]])
    # the only active scalars, and the only array of that name: plot() and scalars="part_rgb" (which
    # pyvista looks up in point data first) both draw the faces' colours
    assert seg.point_data.active_scalars_name is None and "part_rgb" not in seg.point_data
    assert seg.copy().active_scalars_name == "part_rgb"
    cloud = pv.PolyData(seg.points).primkit.segment(model="chair")
    assert cloud.point_data.active_scalars_name == "part_rgb"
    assert np.array_equal(cloud.point_data["part_rgb"], palette[cloud.point_data["part"]])
    lut = seg.primkit.lookup_table()
    for k in range(len(names)):  # the lookup table sends part k to primkit's colour of k
        assert np.allclose(np.array(lut.map_value(k)[:3]) * 255, palette[k], atol=0.6)
    assert np.allclose(np.array(lut.map_value(-1)[:3]) * 255, 200, atol=0.6)

    # scalars="part" with the table draws the very picture the rgb colours draw
    images = []
    for kwargs in ({"scalars": "part", "cmap": lut}, {"scalars": "part_rgb"}):
        pl = pv.Plotter(off_screen=True, window_size=(200, 200))
        pl.add_mesh(seg, preference="cell", show_scalar_bar=False, lighting=False, **kwargs)
        pl.camera_position = "xy"
        images.append(pl.screenshot(return_img=True).astype(int))
        pl.close()
    drawn = (np.abs(images[1] - 255).sum(-1) > 30).mean()
    assert drawn > 0.05 and np.abs(images[0] - images[1]).max() <= 2


def test_a_quad_surface_comes_back_triangulated_with_a_warning(tmp_path):
    import pyvista as pv

    quads = pv.Box(level=4)  # 6 * 25 quads
    assert not quads.is_all_triangles
    with pytest.warns(UserWarning, match=r"150 cells are not all triangles: .*300 triangles"):
        seg = quads.primkit.segment(model="chair")
    assert seg.n_cells == 300 and len(seg.cell_data["part"]) == 300


def test_the_reader_entry_points_name_functions_of_this_checkout():
    """setup.cfg's ``pyvista.readers`` entry points name functions that exist here (a rename that
    forgets setup.cfg fails here, not only after a reinstall)."""
    import configparser
    import importlib

    cfg = configparser.ConfigParser()
    cfg.read(Path(__file__).resolve().parents[2] / "setup.cfg")
    entries = [line.split("=", 1) for line in cfg["options.entry_points"]["pyvista.readers"].strip().splitlines()]
    assert {suffix.strip() for suffix, _ in entries} == {"off", "binvox", "xyz", "npy"}
    for _, target in entries:
        module, name = target.strip().split(":")
        assert callable(getattr(importlib.import_module(module), name)), target


def test_segment_abstract_and_cuboids_on_one_dataset_share_one_run(tmp_path, monkeypatch):
    import pyvista as pv

    from primkit.plugins import pyvista_accessor

    calls = []
    real = pyvista_accessor.label_shapes
    monkeypatch.setattr(pyvista_accessor, "label_shapes", lambda *a, **k: calls.append(k) or real(*a, **k))
    path = synthetic.write_collection(tmp_path, "chair", 1, seed=4)[0]
    poly = pv.read(path)
    seg = poly.primkit.segment(model="chair")
    boxes = poly.primkit.cuboids(model="chair")
    a = poly.primkit.abstract(model="chair", progress_bar=True)  # the bar does not change the answer
    assert len(calls) == 1
    assert boxes.n_blocks == len(a.cuboids.present)  # the same abstraction's parts
    assert set(np.unique(seg.cell_data["part"])) <= set(a.cuboids.present.tolist())
    poly.primkit.cuboids(model="chair", refine=5)  # other options: a new run
    assert len(calls) == 2
    poly.points[:, 1] *= 1.5  # new contents (in place): a new run, not the stale answer
    poly.primkit.abstract(model="chair", refine=5)
    assert len(calls) == 3

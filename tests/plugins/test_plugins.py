"""The plugins: pyvista's accessor (found through its entry point), the VTK filter and its ParaView
face, Open3D's tensor geometry. Each is checked against primkit's own functions on the same shape
(the labels of :func:`primkit.segmentation.segment_mesh` / ``segment_points`` for the same cuboids),
and the three against each other."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
import types

import numpy as np
import pytest

from primkit import io, synthetic
from primkit.model.abstraction import abstract, load_model
from primkit.segmentation import point_labels, segment_mesh, segment_points


@pytest.fixture(scope="module")
def model():
    return load_model("chair")


@pytest.fixture(scope="module")
def chair_file(tmp_path_factory):
    return synthetic.write_collection(tmp_path_factory.mktemp("plugins"), "chair", 2, seed=7)


@pytest.fixture(scope="module")
def expected(chair_file, model):
    """primkit's own answer for the first chair: its cuboids and face labels."""
    mesh = io.read_mesh(chair_file[0])
    a = abstract((mesh.vertices, mesh.faces), model)
    return mesh, a.cuboids, segment_mesh(mesh.vertices, mesh.faces, a.cuboids).face_labels


# ---------------------------------------------------------------------------------------------
# pyvista
# ---------------------------------------------------------------------------------------------


@pytest.mark.integration  # a fresh interpreter
def test_the_accessor_is_found_through_its_entry_point_without_importing_primkit(chair_file):
    code = ("import sys, pyvista as pv; m = pv.read(sys.argv[1]); before = 'primkit' in sys.modules; "
            "s = m.primkit.segment(model='chair'); import json; "
            "print(json.dumps({'before': before, 'part': s['part'].tolist(), 'faces': m.n_cells}))")
    env = {**os.environ, "VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow"}
    out = subprocess.run([sys.executable, "-c", code, str(chair_file[0])], capture_output=True, text=True, env=env,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["before"] is False and len(got["part"]) == got["faces"]


def test_accessor_segment_abstract_and_cuboids_agree_with_primkit(chair_file, expected, model, tmp_path):
    import pyvista as pv

    mesh, cuboids, labels = expected
    poly = pv.read(chair_file[0])
    seg = poly.primkit.segment(model=model)
    assert seg is not poly and "part" not in poly.cell_data  # a copy; the input is left alone
    assert np.array_equal(seg.cell_data["part"], labels)
    assert np.array_equal(seg.point_data["part"], point_labels(mesh.vertices, cuboids))
    assert list(seg.field_data["part_names"]) == model.part_names
    a = poly.primkit.abstract(model=model)
    np.testing.assert_allclose(a.cuboids.translations, cuboids.translations, atol=1e-6)

    blocks = poly.primkit.cuboids(model=model)
    assert blocks.keys() == [f"{k} {model.part_names[k]}" for k in cuboids.present]
    for k, b in zip(cuboids.present, blocks):
        assert b.field_data["part"].tolist() == [k] and np.allclose(b.volume, cuboids.volumes[k])
    # the segmented copy carries its cuboids, through a file too
    seg.save(tmp_path / "seg.vtp")
    again = pv.read(tmp_path / "seg.vtp").primkit.cuboids()
    assert again.keys() == blocks.keys()
    assert all(np.allclose(x.points, y.points) for x, y in zip(again, blocks))


@pytest.mark.integration  # three kinds of dataset segmented: seconds, left to the default suite
def test_accessor_on_point_clouds_quads_and_multiblocks(chair_file, expected, model):
    import pyvista as pv

    mesh, cuboids, labels = expected
    cloud = pv.PolyData(mesh.vertices[::2])
    got = cloud.primkit.segment(model=model)
    a = abstract(mesh.vertices[::2], model)
    assert np.array_equal(got.point_data["part"], segment_points(io.PointCloud(mesh.vertices[::2]), a.cuboids).labels)
    assert "part" not in got.cell_data

    box = pv.Box(level=2)  # quads: labelled on its triangles, which a warning says
    with pytest.warns(UserWarning, match="not all triangles"):
        seg = box.primkit.segment(model=model)
    assert seg.is_all_triangles and seg.n_cells == 2 * box.n_cells and len(seg.cell_data["part"]) == seg.n_cells

    both = pv.MultiBlock({"first": pv.read(chair_file[0]), "second": pv.read(chair_file[1])})
    out = both.primkit.segment(model=model)
    assert out.keys() == ["first", "second"] and np.array_equal(out["first"]["part"], labels)
    alone = pv.read(chair_file[1]).primkit.segment(model=model)
    assert np.array_equal(out["second"]["part"], alone["part"])  # a batch gives what one at a time gives
    assert [len(c) for c in both.primkit.cuboids(model=model)] == [len(cuboids.present), alone.primkit.cuboids().n_blocks]


# ---------------------------------------------------------------------------------------------
# VTK and ParaView
# ---------------------------------------------------------------------------------------------


@pytest.mark.integration  # a VTK pipeline re-run: seconds, left to the default suite
def test_vtk_filter_in_a_pipeline_follows_its_input(chair_file, expected, model):
    import pyvista as pv
    from vtkmodules.vtkCommonTransforms import vtkTransform
    from vtkmodules.vtkFiltersGeneral import vtkTransformFilter
    from vtkmodules.vtkIOPLY import vtkPLYReader

    from primkit.plugins.vtk_filter import PrimkitSegmentation

    _, cuboids, labels = expected
    reader = vtkPLYReader()
    reader.SetFileName(str(chair_file[0]))
    move = vtkTransform()
    moved = vtkTransformFilter()
    moved.SetTransform(move)
    moved.SetInputConnection(reader.GetOutputPort())
    f = PrimkitSegmentation(Model="chair")
    f.SetInputConnection(moved.GetOutputPort())
    f.Update()
    parts, boxes = pv.wrap(f.GetOutputDataObject(0)), pv.wrap(f.GetOutputDataObject(1))
    assert np.array_equal(parts.cell_data["part"], labels)
    assert boxes.n_cells == 12 * len(cuboids.present)
    assert sorted(set(boxes.cell_data["part"])) == cuboids.present.tolist()
    before = boxes.points.copy()

    move.Translate(2.0, 0.0, -1.0)  # the input changes: the filter runs again on the next update
    f.Update()
    parts2, boxes2 = pv.wrap(f.GetOutputDataObject(0)), pv.wrap(f.GetOutputDataObject(1))
    np.testing.assert_allclose(boxes2.points, before + [2.0, 0.0, -1.0], atol=1e-4)  # the cuboids moved with it
    assert np.array_equal(parts2.cell_data["part"], labels)
    assert f.GetUp() == "auto" and f.GetFront() == "auto" and f.GetRefineSteps() == 0
    with pytest.raises(ValueError, match="one of"):
        f.SetUp("up")


def test_vtk_filter_reports_bad_input_in_one_line(capfd, caplog):
    from vtkmodules.vtkCommonDataModel import vtkPolyData

    from primkit.plugins.vtk_filter import PrimkitSegmentation

    f = PrimkitSegmentation()
    f.SetInputDataObject(0, vtkPolyData())  # nothing in it
    f.Update()
    err = capfd.readouterr().err + caplog.text  # VTK's output window (pyvista routes it to logging)
    assert "primkit segmentation: shape0: cannot prepare" in err and "Traceback" not in err
    assert f.GetOutputDataObject(0).GetNumberOfCells() == 0


def test_vtk_filter_says_why_a_bad_model_fails(capfd, caplog):
    from vtkmodules.vtkFiltersSources import vtkSphereSource

    from primkit.plugins.vtk_filter import PrimkitSegmentation

    sphere = vtkSphereSource()
    f = PrimkitSegmentation(Model="nosuchmodel")
    f.SetInputConnection(sphere.GetOutputPort())
    f.Update()
    err = capfd.readouterr().err + caplog.text
    why = "primkit segmentation: nosuchmodel: no such model file, and not a bundled model"
    assert why in err and f.last_error.startswith(why) and "\n" not in f.last_error
    assert f.GetOutputDataObject(0).GetNumberOfCells() == 0


def test_the_paraview_plugin_file_declares_a_proxy_and_imports_nothing_of_primkit(monkeypatch):
    """ParaView loads the file by path with its decorators importable; a recording stand-in for
    ``paraview.util.vtkAlgorithm`` checks what the file declares (the real ParaView: test_paraview.py)."""
    calls = []

    class Recorder:
        def __init__(self, kind):
            self.kind = kind

        def __getattr__(self, name):
            def decorator(*args, **kwargs):
                def apply(target):
                    calls.append((self.kind, name, kwargs, getattr(target, "__name__", "")))
                    return target
                return apply
            return decorator

    fake = types.ModuleType("paraview.util.vtkAlgorithm")
    for kind in ("smproxy", "smproperty", "smdomain", "smhint"):
        setattr(fake, kind, Recorder(kind))
    monkeypatch.setitem(sys.modules, "paraview", types.ModuleType("paraview"))
    monkeypatch.setitem(sys.modules, "paraview.util", types.ModuleType("paraview.util"))
    monkeypatch.setitem(sys.modules, "paraview.util.vtkAlgorithm", fake)
    from primkit import plugins

    path = os.path.join(os.path.dirname(plugins.__file__), "paraview_plugin.py")
    spec = importlib.util.spec_from_file_location("paraview_plugin", path)
    plugin = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(plugin)
    source = open(path).read()
    assert not re.search(r"^\s*(from|import) (primkit|pyvista|vtk)\b", source, re.M)  # ParaView's VTK only
    proxies = [c for c in calls if c[:2] == ("smproxy", "filter")]
    assert proxies and proxies[0][2]["name"] == "PrimkitSegmentation" and proxies[0][3] == "PrimkitSegmentation"
    properties = {c[2]["name"]: c for c in calls if c[0] == "smproperty" and c[1] != "input"}
    assert set(properties) == {"Model", "RefineSteps", "Up", "Front", "Align", "Python"}
    assert properties["Model"][2]["default_values"] == "chair" and properties["RefineSteps"][1] == "intvector"
    assert ("smdomain", "datatype") in {c[:2] for c in calls}
    assert plugin.PrimkitSegmentation().GetNumberOfOutputPorts() == 2


def _plugin_module():
    from primkit import plugins

    path = os.path.join(os.path.dirname(plugins.__file__), "paraview_plugin.py")
    spec = importlib.util.spec_from_file_location("paraview_plugin_kept", path)
    plugin = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(plugin)  # on pip's VTK here: the decorators are inert (ParaView itself: test_paraview.py)
    return plugin


@pytest.mark.integration  # a worker process
def test_the_paraview_plugin_keeps_one_worker_between_applies(chair_file, expected, tmp_path):
    import pyvista as pv

    plugin = _plugin_module()
    try:
        f = plugin.PrimkitSegmentation()
        f.SetInputDataObject(0, pv.read(chair_file[0]))
        f.Update()
        labels = expected[2]
        first = np.asarray(pv.wrap(f.GetOutputDataObject(0)).cell_data["part"])
        assert np.array_equal(first, labels)  # the labels of primkit's own segment_mesh
        (w,) = plugin._WORKERS.values()
        pid = w.proc.pid
        other = synthetic.write_collection(tmp_path, "chair", 1, seed=11)[0]
        f.SetInputDataObject(0, pv.read(other))
        f.Update()
        want = segment_mesh(*_mesh_arrays(other), abstract(io.read_mesh(other), load_model("chair")).cuboids).face_labels
        assert np.array_equal(np.asarray(pv.wrap(f.GetOutputDataObject(0)).cell_data["part"]), want)
        assert list(plugin._WORKERS.values()) == [w] and w.proc.pid == pid and w.alive()  # the same process served both
        w.proc.kill()  # a worker that died is started again at the next apply
        w.proc.wait()
        f.SetInputDataObject(0, pv.read(chair_file[0]))
        f.Modified()
        f.Update()
        assert np.array_equal(np.asarray(pv.wrap(f.GetOutputDataObject(0)).cell_data["part"]), labels)
        assert plugin._WORKERS and next(iter(plugin._WORKERS.values())).proc.pid != pid
    finally:
        plugin.close_workers()
    assert not plugin._WORKERS


def test_the_paraview_worker_answers_requests_in_one_process(tmp_path, monkeypatch):
    from primkit.model import abstraction
    from primkit.plugins import paraview_worker

    mesh = io.read_mesh(synthetic.write_collection(tmp_path, "chair", 1, seed=5)[0])
    given = tmp_path / "in.npz"
    np.savez(given, points=mesh.vertices, faces=mesh.faces, options=np.array(json.dumps({"model": "chair"})))
    (tmp_path / "bad.npz").write_bytes(b"PK not a zip")
    requests = [json.dumps({"in": str(given), "out": str(tmp_path / "a.npz")}), "not json",
                json.dumps({"in": str(tmp_path / "bad.npz"), "out": str(tmp_path / "b.npz")}),
                json.dumps({"in": str(given), "out": str(tmp_path / "c.npz")})]
    loads = []
    real = abstraction.load_model
    monkeypatch.setattr(abstraction, "load_model", lambda *a, **k: loads.append(a) or real(*a, **k))
    replies = __import__("io").StringIO()
    assert paraview_worker.serve(iter(line + "\n" for line in requests), replies) == 0
    answers = [json.loads(line) for line in replies.getvalue().splitlines()]
    assert [a["status"] for a in answers] == [0, 2, 2, 0]
    assert answers[1]["error"].startswith("primkit segmentation: bad request") and "\n" not in answers[2]["error"]
    with np.load(tmp_path / "a.npz") as a, np.load(tmp_path / "c.npz") as c:
        assert np.array_equal(a["face_labels"], c["face_labels"]) and len(a["face_labels"]) == len(mesh.faces)
    assert not (tmp_path / "b.npz").exists()
    assert [a for a in loads if isinstance(a[0], str)] == [("chair",)]  # two answers, one model read from its file


def _mesh_arrays(path):
    m = io.read_mesh(path)
    return m.vertices, m.faces


# ---------------------------------------------------------------------------------------------
# Open3D
# ---------------------------------------------------------------------------------------------


def test_open3d_tensor_mesh_carries_part_through_select_faces_by_mask(chair_file, expected, model):
    import open3d as o3d

    from primkit.plugins import open3d_geometry

    mesh, cuboids, labels = expected
    for given in (o3d.t.io.read_triangle_mesh(str(chair_file[0])), o3d.io.read_triangle_mesh(str(chair_file[0]))):
        seg = open3d_geometry.segment_geometry(given, model=model)
        part = seg.geometry.triangle["part"].numpy()
        assert np.array_equal(part, labels)
        seat = int(np.bincount(labels).argmax())
        kept = seg.geometry.select_faces_by_mask(seg.geometry.triangle["part"] == seat)
        assert len(kept.triangle["part"]) == int((labels == seat).sum())
        assert set(kept.triangle["part"].numpy().tolist()) == {seat}
        assert np.array_equal(seg.cuboid_mesh.triangle["part"].numpy(), np.repeat(cuboids.present, 12))
        assert np.array_equal(seg.cuboid_edges.line["part"].numpy(), np.repeat(cuboids.present, 12))

    points = mesh.vertices[::3]
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(points.astype(np.float32)))
    seg = open3d_geometry.segment_geometry(cloud, model=model)
    a = abstract(points.astype(np.float32).astype(float), model)
    assert np.array_equal(seg.geometry.point["part"].numpy()[:, 0], segment_points(io.PointCloud(points), a.cuboids).labels)
    with pytest.raises(TypeError, match="TriangleMesh or PointCloud"):
        open3d_geometry.segment_geometry(o3d.geometry.LineSet(), model=model)

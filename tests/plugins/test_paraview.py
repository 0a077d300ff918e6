"""The ParaView plugin in a real ParaView (``pvpython``, and the GUI's own Python under Xvfb) on a
COSEG chair: its ``part`` labels must be those ``primkit segment`` writes for the same file.

ParaView is not on PyPI: ``scripts/setup.sh`` installs Debian's (``paraview``, ``python3-paraview``,
5.11 on VTK 9.2). Without ``pvpython`` these tests skip."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import primkit.plugins
from primkit import io

PLUGIN = Path(primkit.plugins.__file__).with_name("paraview_plugin.py")
CHAIR = "coseg_chairs/chairs_101-120/shapes/101.off"

# Run in ParaView's Python: load the plugin, apply the filter, save what comes out. It checks that
# neither primkit nor pip's VTK / pyvista were imported into ParaView's process.
SCRIPT = textwrap.dedent("""
    import inspect, json, sys
    {shim}
    from paraview.simple import LoadPlugin, OpenDataFile
    from paraview import servermanager
    from vtkmodules.vtkCommonCore import vtkVersion
    from vtkmodules.util.numpy_support import vtk_to_numpy
    import numpy as np
    LoadPlugin({plugin!r}, ns=globals())
    seg = PrimkitSegmentation(Input=OpenDataFile({data!r}), Model="chair")
    seg.UpdatePipeline()
    parts, boxes = servermanager.Fetch(seg, idx=0), servermanager.Fetch(seg, idx=1)
    names = parts.GetFieldData().GetAbstractArray("part_names")
    np.savez({out!r}, face=vtk_to_numpy(parts.GetCellData().GetArray("part")),
             vertex=vtk_to_numpy(parts.GetPointData().GetArray("part")),
             rgb=vtk_to_numpy(parts.GetCellData().GetArray("rgb")),
             box_part=vtk_to_numpy(boxes.GetCellData().GetArray("part")),
             names=np.array([names.GetValue(i) for i in range(names.GetNumberOfValues())]))
    with open({info!r}, "w") as fh:
        json.dump({{"vtk": vtkVersion.GetVTKVersion(), "python": sys.version.split()[0],
                   "foreign": sorted(m for m in sys.modules if m.split(".")[0] in ("primkit", "pyvista"))}}, fh)
    {end}
""")


@pytest.fixture(scope="module")
def pvpython():
    path = shutil.which("pvpython")
    if path is None:
        pytest.skip("pvpython not found (scripts/setup.sh installs Debian's paraview and python3-paraview)")
    return path


@pytest.fixture(scope="module")
def paraview_gui():
    paraview, xvfb = shutil.which("paraview"), shutil.which("xvfb-run")
    if paraview is None or xvfb is None:
        pytest.skip("the ParaView GUI or xvfb-run not found (scripts/setup.sh installs both)")
    return paraview, xvfb


@pytest.fixture(scope="module")
def chair(shared_data, tmp_path_factory):
    """The COSEG chair as PLY (ParaView reads no OFF), and ``primkit segment``'s labels for that file."""
    from primkit.cli import main

    folder = tmp_path_factory.mktemp("paraview")
    mesh = io.read_mesh(shared_data / CHAIR)
    ply = folder / "chair.ply"
    io.write_mesh(ply, mesh.vertices, mesh.faces)
    assert main(["segment", str(ply), "-o", str(folder / "seg"), "--model", "chair", "--workers", "1",
                 "--cache", str(folder / "cache")]) == 0
    labels = io.read_labels(folder / "seg" / "chair.seg")
    cuboids = json.loads((folder / "seg" / "chair.cuboids.json").read_text())
    return ply, labels, cuboids


def _environment() -> dict:
    # ParaView's process sees none of primkit's paths; the worker runs in this Python
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PRIMKIT_PYTHON"] = sys.executable
    return env


def _check(got_file, info_file, chair):
    ply, labels, cuboids = chair
    info = json.loads(Path(info_file).read_text())
    assert info["foreign"] == [], info  # nothing of primkit or pyvista inside ParaView
    got = np.load(got_file)
    assert np.array_equal(got["face"], labels)  # the same labels as `primkit segment`
    mesh = io.read_mesh(ply)
    assert len(got["vertex"]) == len(mesh.vertices)
    from primkit.viz.palette import part_colors

    assert np.array_equal(got["rgb"], part_colors(len(got["names"]))[labels])
    present = [p["index"] for p in cuboids["parts"] if p["present"]]
    assert sorted(set(got["box_part"].tolist())) == present and len(got["box_part"]) == 12 * len(present)
    return info


@pytest.mark.integration  # a pvpython process
@pytest.mark.shared
def test_pvpython_loads_the_plugin_and_gives_primkit_segments_labels(pvpython, chair, tmp_path):
    script = tmp_path / "run.py"
    script.write_text(SCRIPT.format(
        shim="if not hasattr(inspect, 'getargspec'): inspect.getargspec = inspect.getfullargspec",
        plugin=str(PLUGIN), data=str(chair[0]), out=str(tmp_path / "got.npz"), info=str(tmp_path / "info.json"),
        end=""))
    run = subprocess.run([pvpython, "--force-offscreen-rendering", str(script)], capture_output=True, text=True,
                         env=_environment(), timeout=600)
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    _check(tmp_path / "got.npz", tmp_path / "info.json", chair)


@pytest.mark.integration  # the ParaView GUI under xvfb
@pytest.mark.shared
def test_the_paraview_gui_loads_the_plugin_after_its_startup_script(paraview_gui, chair, tmp_path):
    """The GUI's route: ``paraview --script=<plugin file>`` (which puts back inspect.getargspec), then
    the plugin loaded by path. The script below runs the plugin file as ``--script`` runs it (as
    ``__main__``, no ``__file__``), then loads it through ``LoadPlugin``: the same
    ``vtkSMPluginManager::LoadLocalPlugin`` that *Tools > Manage Plugins > Load New* calls."""
    paraview, xvfb = paraview_gui
    script = tmp_path / "gui.py"
    startup = f"exec(compile(open({str(PLUGIN)!r}).read(), {str(PLUGIN)!r}, 'exec'), {{'__name__': '__main__'}})"
    script.write_text(SCRIPT.format(shim=startup, plugin=str(PLUGIN), data=str(chair[0]), out=str(tmp_path / "got.npz"),
                                    info=str(tmp_path / "info.json"), end="import os; os._exit(0)"))
    run = subprocess.run([xvfb, "-a", paraview, f"--script={script}"], capture_output=True, text=True,
                         env=_environment(), timeout=600)
    assert (tmp_path / "info.json").is_file(), (run.stdout + run.stderr)[-3000:]
    _check(tmp_path / "got.npz", tmp_path / "info.json", chair)

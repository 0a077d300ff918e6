"""Every Python block of ``docs/plugins.md`` runs as written, and every picture a documented line
draws shows primkit's colours: each is compared with the same meshes drawn with
``scalars="part_rgb", rgb=True`` (:mod:`doc_pictures` captures both off screen).

The pyvista block runs in a folder holding a procedural chair as ``chair.off`` and its voxels as
``chair.binvox``; the ``pvpython`` block runs in ParaView's own Python (skipped without it) with the
plugin's real path in place of ``/path/to/...``. The ``sh`` block starts the ParaView GUI, which
``tests/plugins/test_paraview.py`` drives by the same route under Xvfb.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import primkit.plugins

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "plugins.md"
HARNESS = Path(__file__).with_name("doc_pictures.py")
PLUGIN = Path(primkit.plugins.__file__).with_name("paraview_plugin.py")
BLOCKS = re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S)
PYVISTA = [b for b in BLOCKS if "import pyvista" in b]
PVPYTHON = [b for b in BLOCKS if "paraview.simple" in b]
#: a documented line draws a picture when it plots or adds a mesh to a plotter
DRAWS = re.compile(r"\.plot\(|\.add_mesh\(")


def test_the_doc_has_the_blocks_this_file_runs():
    assert len(PYVISTA) == 1 and len(PVPYTHON) == 1 and len(BLOCKS) == 2, "a new block: run it here too"
    assert DRAWS.search(PYVISTA[0])


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    from primkit import io, synthetic
    from primkit.data import prepare

    root = tmp_path_factory.mktemp("plugins-doc")
    shape = synthetic.generate("chair", 1, seed=0)[0]
    io.write_mesh(root / "chair.off", shape.vertices, shape.faces)
    io.write_mesh(root / "chair.ply", shape.vertices, shape.faces)
    grid = prepare(io.Mesh(shape.vertices, shape.faces), name="chair").occupancy
    io.write_voxels(root / "chair.binvox", io.VoxelGrid(np.asarray(grid, bool), np.zeros(3), 1.0))
    return root


def _environment(tmp_path) -> dict:
    env = {**os.environ, "VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow", "PRIMKIT_CACHE": str(tmp_path / "cache")}
    env.pop("DISPLAY", None)
    return env


def _differs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a.astype(int) - b.astype(int)).max(axis=-1) > 3


@pytest.mark.integration  # a fresh interpreter loading torch and VTK, rendering through EGL
def test_every_documented_pyvista_picture_shows_primkits_colours(folder, tmp_path):
    block = tmp_path / "block.py"
    block.write_text(PYVISTA[0])
    out = subprocess.run([sys.executable, str(HARNESS), str(block), str(tmp_path / "pictures")], cwd=folder,
                         capture_output=True, text=True, env=_environment(tmp_path), timeout=900)
    assert out.returncode == 0, f"{out.stdout[-2000:]}\n{out.stderr[-3000:]}"
    pictures = [np.load(p) for p in sorted((tmp_path / "pictures").glob("*.npz"), key=lambda p: int(p.stem))]
    drawing = [i + 1 for i, line in enumerate(PYVISTA[0].splitlines()) if DRAWS.search(line.split("#")[0])]
    assert sorted(int(p["line"]) for p in pictures) == drawing, "a drawing line drew no picture (or one too many)"
    for p in pictures:
        doc, ref, source = p["doc"], p["ref"], str(p["source"])
        background = ref[0, 0]
        drawn = np.abs(ref.astype(int) - background).max(axis=-1) > 3
        assert drawn.mean() > 0.05, source  # the chair fills part of the window
        # the same picture: a pixel or two may differ at the edge of the window's corner widget
        assert _differs(doc, ref)[drawn].mean() < 0.002, f"{source}: not primkit's colours"


def test_the_comparison_catches_the_stripes_of_point_labels(tmp_path):
    """The picture the docs once promised, ``scalars="part"`` with the lookup table and pyvista's
    default preference (the point labels interpolated through the table), fails the comparison
    above; with ``preference="cell"`` it passes."""
    import pyvista as pv

    from primkit import synthetic

    path = synthetic.write_collection(tmp_path, "chair", 1, seed=3)[0]
    parts = pv.read(path).primkit.segment(model="chair")

    def draw(**kwargs):
        pl = pv.Plotter(off_screen=True, window_size=(300, 300))
        pl.add_mesh(parts, show_scalar_bar=False, **kwargs)
        pl.camera_position = "xy"
        image = pl.screenshot(return_img=True)
        pl.close()
        return image

    ref = draw(scalars="part_rgb", rgb=True)
    drawn = np.abs(ref.astype(int) - ref[0, 0]).max(axis=-1) > 3
    lut = parts.primkit.lookup_table()
    assert _differs(draw(scalars="part", cmap=lut), ref)[drawn].mean() > 0.01
    assert _differs(draw(scalars="part", cmap=lut, preference="cell"), ref)[drawn].mean() < 0.002
    assert _differs(draw(), ref)[drawn].mean() < 0.002  # plot()'s choice: the active scalars


@pytest.mark.integration  # ParaView's Python, with primkit's worker in a process of its own
def test_the_pvpython_block_runs_in_paraview(folder, tmp_path):
    pvpython = shutil.which("pvpython")
    if pvpython is None:
        pytest.skip("pvpython not found (scripts/setup.sh installs Debian's paraview and python3-paraview)")
    code = re.sub(r'"/path/to/[^"]*paraview_plugin\.py"', repr(str(PLUGIN)), PVPYTHON[0])
    assert str(PLUGIN) in code
    code += "\nseg.UpdatePipeline()\nfrom paraview import servermanager\n" \
            "print('faces', servermanager.Fetch(seg).GetCellData().GetArray('part').GetNumberOfTuples())\n"
    script = tmp_path / "block.py"
    script.write_text(code)
    env = {k: v for k, v in _environment(tmp_path).items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PRIMKIT_PYTHON"] = sys.executable
    out = subprocess.run([pvpython, "--force-offscreen-rendering", str(script)], cwd=folder, capture_output=True,
                         text=True, env=env, timeout=900)
    assert out.returncode == 0, (out.stdout + out.stderr)[-3000:]
    from primkit import io

    faces = len(io.read_mesh(folder / "chair.ply").faces)
    assert f"faces {faces}" in out.stdout, out.stdout[-2000:]

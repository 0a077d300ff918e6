"""The README's integration examples run as written: every ``python`` block of its section "In
pyvista, VTK, ParaView and Open3D", each as a script of its own in a folder holding a procedural
``chair.ply`` (and ``cloud.xyz``, points sampled from it)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
SECTION = "## In pyvista, VTK, ParaView and Open3D"


def _blocks() -> list[str]:
    text = README.read_text()
    start = text.index(SECTION)
    end = text.index("\n## ", start + len(SECTION))
    return re.findall(r"```python\n(.*?)```", text[start:end], re.S)


BLOCKS = _blocks()


def test_the_section_shows_each_integration():
    joined = "\n".join(BLOCKS)
    for needle in (".primkit.segment(", "PrimkitSegmentation", "open3d_geometry.segment("):
        assert needle in joined, needle


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    from primkit import geometry, io, synthetic

    root = tmp_path_factory.mktemp("readme")
    shape = synthetic.generate("chair", 1, seed=0)[0]
    io.write_mesh(root / "chair.ply", shape.vertices, shape.faces)
    np.savetxt(root / "cloud.xyz", geometry.sample_surface(shape.vertices, shape.faces, 2000, seed=0).points)
    return root


@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_readme_block_runs(code, folder, tmp_path):
    env = {**os.environ, "VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow", "PRIMKIT_CACHE": str(tmp_path / "cache")}
    env.pop("DISPLAY", None)
    out = subprocess.run([sys.executable, "-c", code], cwd=folder, capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, f"{code}\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}"

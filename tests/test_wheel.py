"""primkit as a user installs it: a wheel built from this checkout, installed into a fresh virtual
environment with no checkout on the path. The viewers draw a picture (``primkit view abstraction
... --png``) and a script abstracts a mesh through ``primkit.abstract``.

The environment is :mod:`wheel_env`'s (no dependencies installed, this environment's
site-packages seen through a ``.pth`` file); every command runs from a temporary folder, and the
test checks where primkit was imported from."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from wheel_env import ROOT
from wheel_env import run as _run

pytestmark = pytest.mark.integration  # a wheel built and installed into a fresh virtual environment

@pytest.fixture(scope="module")
def fresh_env(wheel_env, tmp_path_factory):
    """The session's wheel environment (``tests/conftest.py``) and a folder for this module's work."""
    return wheel_env, tmp_path_factory.mktemp("wheel-work")


def test_the_wheel_carries_the_viewers_and_the_library(fresh_env):
    from primkit import synthetic

    env, root = fresh_env
    work = root / "work"
    (work / "in").mkdir(parents=True)
    shape = synthetic.write_collection(work / "in", "chair", 1, seed=4)[0]
    where = _run([env / "bin" / "python", "-c", "import primkit; print(primkit.__file__)"], cwd=work).strip()
    assert Path(where).is_relative_to(env) and not Path(where).is_relative_to(ROOT), where

    _run([env / "bin" / "primkit", "view", "abstraction", shape, "--model", "chair", "--png", "out.png",
          "--cache", work / "cache", "--workers", "1"], cwd=work)
    from pictures import read_picture

    shown = read_picture(work / "out.png").part_colours_shown({16, 18})  # the seat and back cuboids
    assert min(shown.values()) > 300, shown  # measured from the checkout: 2,061 and 827 pixels

    code = ("import json, primkit; m = primkit.read_shape('in/chair_0000.ply'); "
            "a = primkit.abstract((m.vertices, m.faces), model='chair'); "
            "print(json.dumps({'file': primkit.__file__, 'parts': int(a.cuboids.existence.sum()), 'slots': a.cuboids.count}))")
    got = json.loads(_run([env / "bin" / "python", "-c", code], cwd=work).strip().splitlines()[-1])
    assert Path(got["file"]).is_relative_to(env)
    assert got["slots"] == 20 and got["parts"] >= 3


def test_the_wheel_registers_the_pyvista_accessor(fresh_env):
    """``pv.read(chair).primkit.segment(model="chair")`` with no ``import primkit``: pyvista finds the
    accessor through the wheel's ``pyvista.accessors`` entry point and imports primkit from the wheel."""
    from primkit import synthetic

    env, root = fresh_env
    work = root / "work-accessor"
    work.mkdir()
    shape = synthetic.write_collection(work, "chair", 1, seed=6)[0]
    code = ("import json, sys, pyvista as pv; chair = pv.read(sys.argv[1]); before = 'primkit' in sys.modules; "
            "parts = chair.primkit.segment(model='chair'); import primkit; "
            "print(json.dumps({'before': before, 'file': primkit.__file__, 'faces': chair.n_cells, "
            "'part': parts['part'].tolist(), 'cuboids': chair.primkit.cuboids(model='chair').n_blocks}))")
    got = json.loads(_run([env / "bin" / "python", "-c", code, shape], cwd=work).strip().splitlines()[-1])
    assert got["before"] is False and Path(got["file"]).is_relative_to(env)
    assert len(got["part"]) == got["faces"] and got["cuboids"] >= 3
    assert set(got["part"]) <= set(range(20)) and len(set(got["part"])) >= 3

"""A fresh virtual environment holding the wheel of this checkout, for the tests that use primkit as
a user installs it (``tests/test_wheel.py``, ``tests/plugins/test_pyvista.py``).

To stay fast the wheel is built and installed without dependencies (``--no-deps
--no-build-isolation``) and the fresh environment sees the dependencies already installed here
through a ``.pth`` file naming this environment's site-packages. A folder added by a ``.pth`` file
has its own ``.pth`` files ignored, so this environment's editable install of the checkout stays
off the path."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(args, cwd, timeout=600) -> str:
    """Run a command without DISPLAY or PYTHONPATH (so the checkout cannot leak in); its stdout."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "PYTHONPATH")}
    env.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    out = subprocess.run([str(a) for a in args], capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout)
    assert out.returncode == 0, f"{args[0]} failed:\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}"
    return out.stdout


def fresh_environment(root: Path) -> Path:
    """Build the checkout's wheel under ``root`` and install it into a new environment there;
    returns the environment's folder (its Python is ``env/bin/python``)."""
    # built from a copy, so that no stale build/ of the checkout can slip old modules into the wheel
    source = root / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".git", ".venv", "build", "dist", "*.egg-info", "__pycache__",
                                                               ".pytest_cache", ".primkit-cache", "out", "tests", "docs"))
    run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "--disable-pip-version-check",
         "-w", root / "dist", source], cwd=root)
    env = root / "env"
    run([sys.executable, "-m", "venv", "--without-pip", env], cwd=root)
    python = env / "bin" / "python"
    run([sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps", "--no-build-isolation",
         "--disable-pip-version-check", next((root / "dist").glob("primkit-*.whl"))], cwd=root)
    site = Path(run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=root).strip())
    (site / "primkit-test-dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return env

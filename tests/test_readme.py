"""The README says what is true and stays short: its first commands are the two the project
promises, every ``primkit`` command it names exists (and every command is named), it has at most
220 lines and no dates, commit hashes or issue numbers (those belong in ``docs/`` and git), and
its Python blocks run as written: the section "Library" and every block of "In pyvista, VTK,
ParaView and Open3D", each as a script of its own in a folder holding a procedural ``chair.ply``
(and ``cloud.xyz``, points sampled from it)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
TEXT = README.read_text()
SECTIONS = ("## Library", "## In pyvista, VTK, ParaView and Open3D")
FIRST_COMMANDS = (
    "bash scripts/setup.sh && .venv/bin/primkit demo",
    "bash scripts/setup.sh && .venv/bin/python -m pytest -q",
)


def _section(title: str) -> str:
    start = TEXT.index(title)
    end = TEXT.find("\n## ", start + len(title))
    return TEXT[start:] if end < 0 else TEXT[start:end]


def _blocks() -> list[str]:
    return [code for title in SECTIONS for code in re.findall(r"```python\n(.*?)```", _section(title), re.S)]


BLOCKS = _blocks()


def test_readme_is_short():
    lines = TEXT.splitlines()
    assert len(lines) <= 220, f"README.md has {len(lines)} lines (at most 220; results go to docs/results.md)"


def test_readme_has_no_dates_hashes_or_issue_numbers():
    patterns = {
        "a date": r"\b(19|20)\d\d-\d\d-\d\d\b",
        "a commit hash": r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b",
        "an issue number": r"\bissues? #?\d+",
        "a load average": r"\bload (average )?\d",
    }
    for what, pattern in patterns.items():
        found = re.search(pattern, TEXT, re.I)
        assert found is None, f"README.md holds {what}: {found.group(0)!r}"


def test_a_line_with_a_hash_or_date_would_be_caught():
    # the patterns above can fail: they catch what they are meant to catch
    assert re.search(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b", "as of 7f3df5b")
    assert not re.search(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b", "defaced 1234567 chairs")
    assert re.search(r"\b(19|20)\d\d-\d\d-\d\d\b", "on 2026-12-03")


def test_readme_starts_with_the_two_commands():
    first_block = re.search(r"```bash\n(.*?)```", TEXT, re.S).group(1)
    commands = [line.split("#")[0].strip() for line in first_block.splitlines() if line.strip()]
    assert commands == list(FIRST_COMMANDS)
    assert (ROOT / "scripts" / "setup.sh").is_file()
    text = (ROOT / "scripts" / "setup.sh").read_text()
    assert ".venv" in text and "constraints.txt" in text


def test_every_command_the_readme_names_exists_and_every_command_is_named():
    from primkit.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    commands = set(sub.choices)
    bash = "\n".join(re.findall(r"```bash\n(.*?)```", TEXT, re.S))
    named = set(re.findall(r"^primkit ([a-z][a-z-]*)", bash, re.M)) | set(re.findall(r"`primkit ([a-z][a-z-]*)", TEXT))
    assert named <= commands, f"the README names commands that do not exist: {sorted(named - commands)}"
    assert commands <= named, f"commands the README does not name: {sorted(commands - named)}"
    view = sub.choices["view"]
    viewers = set(next(a for a in view._actions if a.__class__.__name__ == "_SubParsersAction").choices)
    line = re.search(r"^primkit view ([a-z0-9|]+)", bash, re.M).group(1)
    assert set(line.split("|")) == viewers


def test_the_links_point_at_files():
    for link in re.findall(r"\]\(((?:docs|examples)/[^)#]+)\)", TEXT):
        assert (ROOT / link).exists(), link


def test_the_sections_show_the_library_and_each_integration():
    joined = "\n".join(BLOCKS)
    for needle in ("primkit.abstract(", "primkit.segment(", ".primkit.segment(", "PrimkitSegmentation",
                   "open3d_geometry.segment_geometry("):
        assert needle in joined, needle


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    from primkit import geometry, io, synthetic

    root = tmp_path_factory.mktemp("readme")
    shape = synthetic.generate("chair", 1, seed=0)[0]
    io.write_mesh(root / "chair.ply", shape.vertices, shape.faces)
    np.savetxt(root / "cloud.xyz", geometry.sample_surface(shape.vertices, shape.faces, 2000, seed=0).points)
    return root


@pytest.mark.integration  # each block a fresh interpreter loading torch, VTK or Open3D: 13-19 s
@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_readme_block_runs(code, folder, tmp_path):
    env = {**os.environ, "VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow", "PRIMKIT_CACHE": str(tmp_path / "cache")}
    env.pop("DISPLAY", None)
    out = subprocess.run([sys.executable, "-c", code], cwd=folder, capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, f"{code}\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}"

"""The API reference builds from the docstrings (Sphinx: autodoc, autosummary, napoleon; docs/conf.py)
with warnings as errors, and a reference to a primkit name that does not exist fails the build.

The full build imports every module and takes about a minute, so it is marked ``integration``; the
check that a broken reference fails builds one small page, in a Sphinx process of its own (also
``integration``: the fast loop leaves subprocesses out)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("sphinx", reason="sphinx is in the dev extra: pip install -e '.[dev]'")

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _build(source: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(source), str(out)],
                          capture_output=True, text=True, timeout=900)


@pytest.mark.integration
def test_api_reference_builds_without_warnings(tmp_path):
    source = tmp_path / "docs"  # a copy: autosummary writes the generated pages into its source folder
    shutil.copytree(DOCS, source, ignore=shutil.ignore_patterns("_build", "api", "images"))
    out = _build(source, tmp_path / "html")
    assert out.returncode == 0, out.stderr[-4000:]
    pages = tmp_path / "html" / "api"
    assert (tmp_path / "html" / "index.html").is_file()
    for module, name in (("primkit.segmentation.meshes", "face_labels"), ("primkit.primitives.cuboids", "Cuboids"),
                         ("primkit.model.abstraction", "abstract_shapes"), ("primkit.embedding", "PartDescriptor")):
        page = pages / f"{module}.html"
        assert page.is_file(), f"no page for {module}"
        assert f'id="{module}.{name}"' in page.read_text(), f"{module}.{name} is not documented"


def _small_site(tmp_path, body: str) -> Path:
    source = tmp_path / "docs"
    source.mkdir(parents=True)
    shutil.copy(DOCS / "conf.py", source / "conf.py")
    (source / "index.rst").write_text("Page\n====\n\n" + body + "\n")
    return source


@pytest.mark.integration  # a Sphinx build in a subprocess
def test_a_reference_to_a_name_that_does_not_exist_fails_the_build(tmp_path):
    # through a re-export, relative to the module, and a private module: these names exist
    good = _small_site(tmp_path / "good", ".. py:currentmodule:: primkit.segmentation\n\n"
                       ":class:`primkit.io.Mesh`, :func:`face_labels`, :mod:`primkit.geometry._mesh_kernels`.")
    out = _build(good, tmp_path / "good-html")
    assert out.returncode == 0, out.stderr[-3000:]
    bad = _small_site(tmp_path / "bad", "See :func:`primkit.segmentation.no_such_function`.")
    out = _build(bad, tmp_path / "bad-html")
    assert out.returncode != 0
    assert "primkit.segmentation.no_such_function" in out.stderr

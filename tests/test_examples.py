"""Every script in examples/ runs as a user would run it: ``python examples/X.py OUTPUT_FOLDER``,
exits 0, and writes what it says it writes: each example has a check of its outputs below (the
numbers it prints, its files, what its pictures show), with bounds from one measured run."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pictures import read_picture

pytestmark = pytest.mark.integration  # each example as a user runs it, in a fresh interpreter

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


def test_there_are_examples():
    assert len(EXAMPLES) >= 4


@pytest.mark.parametrize("script", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs(script, tmp_path):
    env = {**os.environ, "VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow", "PRIMKIT_CACHE": str(tmp_path / "cache")}
    env.pop("DISPLAY", None)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, str(script), str(out)], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, f"{script.name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    assert out.is_dir() and any(out.iterdir()), f"{script.name} wrote nothing into {out}"
    CHECKS[script.stem](out, proc.stdout)


def _number(pattern: str, text: str) -> float:
    found = re.search(pattern, text)
    assert found, f"{pattern!r} not in the output:\n{text[-2000:]}"
    return float(found.group(1))


def _deform_chair(out: Path, stdout: str) -> None:
    """Measured: Chamfer-L1 to the target 0.0415 -> 0.0306, 0.27% flipped, height 1.000 -> 1.124."""
    from primkit import io, synthetic

    quality = json.loads((out / "quality.json").read_text())
    d = quality["deform"]
    assert d["chamfer_result_target"] < 0.9 * d["chamfer_source_target"] and d["flipped"] < 0.01, d
    low, high = quality["height"]
    assert 1.08 < high / low < 1.3  # legs 30% longer raise the chair; seat and back are carried up
    source = synthetic.generate("chair", 2, seed=5)[0]
    for name in ("deformed.off", "longer_legs.off"):
        mesh = io.read_mesh(out / name)
        assert np.array_equal(mesh.faces, source.faces) and not np.allclose(mesh.vertices, source.vertices)
    assert read_picture(out / "deform.png").blobs() >= 4  # source, target, deformed, legs +30%


def _embed_chairs(out: Path, stdout: str) -> None:
    """Measured: has_arms agreement 0.93 on all parts (chance 0.72), 0.70 on back and seat alone;
    Spearman(distance to the most upright chair, tilt) 0.98."""
    chance = _number(r"chance agreement .* = ([0-9.]+)", stdout)
    every = _number(r"all +nearest neighbour agrees on has_arms: ([0-9.]+)", stdout)
    back_seat = _number(r"back_seat +nearest neighbour agrees on has_arms: ([0-9.]+)", stdout)
    assert every > chance + 0.1 and back_seat < every  # arms decide the neighbours only when compared
    assert _number(r"Spearman\(distance to the most upright chair, tilt\) = ([-0-9.]+)", stdout) > 0.85
    for name in ("map_all", "map_back_seat", "map_back_tilt"):
        assert read_picture(out / f"{name}.png").blobs() >= 5, name  # thumbnails on the map (some touch)


def _image_abstraction(out: Path, stdout: str) -> None:
    """Measured: distillation loss 0.734 -> 0.070; 8 parts; azimuth 33 (true 46), elevation 19 (20)."""
    first = _number(r"distillation loss ([0-9.]+) ->", stdout)
    last = _number(r"distillation loss [0-9.]+ -> ([0-9.]+)", stdout)
    assert last < 0.5 * first
    cuboids = json.loads((out / "chair.cuboids.json").read_text())
    assert 3 <= sum(bool(p.get("present", True)) for p in cuboids["parts"]) <= 20
    assert (out / "tiny-image-model.safetensors").stat().st_size > 0
    picture = read_picture(out / "chair.overlay.png").rgb  # the picture, and beside it the cuboids over it
    half = picture.shape[1] // 2
    left, right = picture[:, :half - 4].astype(int), picture[:, picture.shape[1] - (half - 4):].astype(int)
    assert np.mean(np.abs(left - right).max(axis=-1) > 30) > 0.01  # the cuboids are drawn


def _interop_open3d(out: Path, stdout: str) -> None:
    """Measured: the seat's and the back's colours (indices 16, 18) on 7,700-27,000 pixels of each picture."""
    from primkit import io

    assert len(io.read_points(out / "samples.ply").points) == 5000
    for name in ("open3d.png", "pyvista.png"):
        shown = read_picture(out / name).part_colours_shown({16, 18})
        assert min(shown.values()) > 1000, (name, shown)


def _segment_chairs(out: Path, stdout: str) -> None:
    """Measured: 92.7% of the surface right (collection majority), mean IoU 0.64."""
    from primkit import io

    assert _number(r"collection-majority +accuracy ([0-9.]+)%", stdout) > 85
    assert _number(r"model-names +accuracy ([0-9.]+)%", stdout) > 85
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 1 + 6
    for i in range(6):
        faces = io.read_mesh(out / "chairs" / f"chair_{i:04d}.ply").faces
        assert len(io.read_labels(out / "segmented" / f"chair_{i:04d}.seg")) == len(faces)


CHECKS = {"deform_chair": _deform_chair, "embed_chairs": _embed_chairs, "image_abstraction": _image_abstraction,
          "interop_open3d": _interop_open3d, "segment_chairs": _segment_chairs}


def test_every_example_has_a_check_of_its_outputs():
    assert sorted(CHECKS) == sorted(p.stem for p in EXAMPLES)

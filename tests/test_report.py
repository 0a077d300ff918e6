"""The HTML report: built through the CLI on procedural chairs, its files and numbers checked, and
loaded in a real headless browser (Debian's chromium; skipped with the reason when it is missing,
scripts/setup.sh installs it)."""

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from primkit import synthetic
from primkit.cli import main

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    synthetic.write_collection(root / "in", "chair", 4, seed=11)
    out = root / "out"
    assert main(["report", str(root / "in"), "--model", "chair", "-o", str(out), "--cache", str(root / "cache")]) == 0
    return out


def _scene(page: str) -> dict:
    m = re.search(r'<script id="data" type="application/json">(.*?)</script>', page, re.S)
    return json.loads(m.group(1))


def test_report_files_and_numbers(report_dir):
    page = (report_dir / "index.html").read_text()
    for src in re.findall(r'src="([^"]+)"', page):
        assert (report_dir / src).is_file(), src
    assert "http://" not in page and "https://" not in page  # nothing fetched at view time
    summary = json.loads((report_dir / "report.json").read_text())
    assert summary["notes"] == {} and len(summary["shapes"]) == 4
    for s in summary["shapes"]:
        assert s["scores"]["parts"] == len(s["parts"])
        d = [n["distance"] for n in s["neighbors"]]
        assert d == sorted(d) and s["name"] not in [n["name"] for n in s["neighbors"]]
    scene = _scene(page)
    assert len(scene["shapes"]) == 4 and len(scene["colors"]) == 20
    for s, info in zip(scene["shapes"], summary["shapes"]):
        v, f = np.reshape(s["v"], (-1, 3)), np.reshape(s["f"], (-1, 3))
        assert f.min() >= 0 and f.max() < len(v) and len(s["label"]) == len(f)
        assert set(s["label"]) <= set(info["parts"])  # faces take present parts only
        assert sorted(s["part"]) == sorted(info["parts"]) and len(s["corners"]) == 24 * len(s["part"])
        assert np.abs(v).max() <= 0.5 + 1e-3  # canonical frame: inside the unit cube


def test_report_refuses_to_overwrite_and_degrades_with_two_shapes(tmp_path, report_dir):
    assert main(["report", str(report_dir.parent / "in"), "--model", "chair", "-o", str(report_dir),
                 "--cache", str(report_dir.parent / "cache")]) == 2
    synthetic.write_collection(tmp_path / "in", "chair", 2, seed=12)
    from primkit.report import build_report

    report, errors = build_report(sorted((tmp_path / "in").glob("*.ply")), "chair", tmp_path / "out",
                                  cache_dir=tmp_path / "cache", progress=False)
    assert errors == [] and "similarity" in report.notes and "3 shapes" in report.notes["similarity"]
    page = report.path.read_text()
    assert "similarity map not drawn" in page and "deformation.png" in page


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (scripts/setup.sh installs it: apt-get install chromium)")
def test_report_loads_in_headless_chromium(report_dir, tmp_path):
    shot = tmp_path / "shot.png"
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-logging=stderr", "--v=0",
           f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1200,900", "--virtual-time-budget=5000",
           f"--screenshot={shot}", (report_dir / "index.html").as_uri()]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    console = [line for line in out.stderr.splitlines() if ":CONSOLE" in line]
    assert any("primkit report ready: 4 shapes" in line for line in console), out.stderr[-2000:]
    bad = [line for line in console if ":ERROR:" in line or ":WARNING:" in line or "Uncaught" in line]
    assert not bad, bad
    from PIL import Image

    from primkit.viz.palette import part_colors

    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    # the page shows the shapes: thumbnails and the 3D scene carry part colours (shaded, so match loosely)
    summary = json.loads((report_dir / "report.json").read_text())
    used = sorted({k for s in summary["shapes"] for k in s["parts"]})
    colours = part_colors(20)[used].astype(int)
    hue = img / np.maximum(img.sum(-1, keepdims=True), 1)
    ref = colours / np.maximum(colours.sum(-1, keepdims=True), 1)
    close = np.abs(hue[:, :, None, :] - ref[None, None]).sum(-1).min(-1) < 0.03
    saturated = np.ptp(img, axis=-1) > 40
    assert (close & saturated).mean() > 0.005
    # and the DOM says the viewer ran
    dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'p2'}",
                          "--virtual-time-budget=5000", "--dump-dom", (report_dir / "index.html").as_uri()],
                         capture_output=True, text=True, timeout=180)
    assert 'data-ready="1"' in dom.stdout and re.search(r'id="status">\d+ polygons', dom.stdout)

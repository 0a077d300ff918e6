"""The report as a page for a paper's supplement, checked in headless Chromium at 1280 x 900 on 12
shapes (the 10 shared COSEG chairs and 2 procedural ones; 12 procedural chairs without the shared
data): one self-contained file under 8 MB, a grid of shape cards whose first screen shows six and
whose twelve fit in two screens, 320-px pictures, a t-SNE map with every name printed and a hover
title, each metric defined where it is shown, the colours explained once, and a print stylesheet
that shows every picture of every card. The screenshots are saved beside the report (looked at
when the page changed: ``first-screen.png``, ``print.png``)."""

from __future__ import annotations

import base64
import html
import json
import re
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from chromium import CHROMIUM, load_page
from primkit import synthetic
from primkit.cli import main
from primkit.report import METRICS, THUMB

pytestmark = [pytest.mark.integration,  # the whole chain on 12 shapes, then headless Chromium
              pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (scripts/setup.sh installs it)")]

COSEG = ("coseg_chairs/chairs_101-120/shapes", "coseg_chairs/large_chairs/shapes")
#: ../shared/data beside the checkout (tests/conftest.py's place; "from conftest import" finds whichever
#: conftest module was imported first, tests/viewers/conftest.py in a whole run)
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
WIDTH, HEIGHT = 1280, 900


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    root = tmp_path_factory.mktemp("page")
    inputs = [str(SHARED / c) for c in COSEG if (SHARED / c).is_dir()]
    count = 12 - sum(len(list(Path(c).glob("*.off"))) for c in inputs)
    synthetic.write_collection(root / "procedural", "chair", count, seed=3)
    out = root / "out"
    assert main(["report", *inputs, str(root / "procedural"), "--model", "chair", "-o", str(out),
                 "--cache", str(root / "cache"), "-q"]) == 0
    return out


CARDS = ("JSON.stringify(Array.from(document.querySelectorAll('.card')).map(c => "
         "{const r = c.getBoundingClientRect(); return [r.top + scrollY, r.bottom + scrollY];}))")
IMAGES = ("JSON.stringify(Array.from(document.querySelectorAll('.card img')).map(i => "
          "[i.naturalWidth, i.naturalHeight, i.src.slice(0, 23), getComputedStyle(i).display, i.getBoundingClientRect().width]))")


def test_one_self_contained_file_under_8_mb(report):
    assert sorted(p.name for p in report.iterdir()) == ["index.html", "report.json"]
    page = (report / "index.html").read_text()
    size = (report / "index.html").stat().st_size
    assert size < 8e6, f"{size / 1e6:.2f} MB"
    markup = re.sub(r"<script\b.*?</script>", "", page, flags=re.S)
    assert not re.search(r'(src|href)="(?!data:|#)', markup), "a file or address the page would fetch"
    pictures = re.findall(r'src="data:image/webp;base64,([^"]+)"', markup)
    assert len(pictures) >= 12 * 4 + 1  # four per card (names: the chair model's labeller) and the deformation
    for data in pictures[:8]:
        image = Image.open(BytesIO(base64.b64decode(data)))
        assert image.format == "WEBP" and min(image.size) >= THUMB


def test_the_first_screen_shows_six_cards_and_two_screens_hold_twelve(report):
    got = load_page(report / "index.html", width=WIDTH, height=HEIGHT, evaluate=[CARDS, IMAGES])
    (report.parent / "first-screen.png").write_bytes(got.screenshot)
    assert got.ready_ms is not None and not got.problems(), got.problems()
    assert got.requests and all(u.startswith(("file:", "data:")) for u in got.requests), got.requests
    cards = json.loads(got.values[CARDS])
    assert len(cards) == 12
    assert sum(bottom <= HEIGHT for _, bottom in cards) >= 6, cards
    assert max(bottom for _, bottom in cards) <= 2 * HEIGHT, cards
    images = json.loads(got.values[IMAGES])
    shown = [i for i in images if i[3] != "none"]
    assert len(shown) == 12 and all(w >= THUMB and h >= THUMB and drawn >= THUMB for w, h, _, _, drawn in shown)
    assert all(src.startswith("data:image/webp") for *_, src, _, _ in [(i[0], i[1], i[2], i[3], i[4]) for i in images])
    # the screenshot shows the cards' pictures: six blocks of colour in the first screen
    shot = np.asarray(Image.open(BytesIO(got.screenshot)).convert("RGB")).astype(int)
    coloured = np.ptp(shot, axis=-1) > 40
    for top, bottom in cards[:6]:
        assert coloured[int(top):int(min(bottom, HEIGHT))].sum() > 2000


def test_the_map_prints_every_name_and_titles_it(report):
    page = (report / "index.html").read_text()
    summary = json.loads((report / "report.json").read_text())
    names = [s["name"] for s in summary["shapes"]]
    svg = re.search(r'<svg class="map".*?</svg>', page, re.S).group(0)
    printed = re.findall(r"<text x=[^>]*><title>[^<]*</title>([^<]*)</text>", svg)
    assert sorted(printed) == sorted(names)
    titles = re.findall(r"<title>([^<]*)</title>", svg)
    assert all(any(t.startswith(f"{n} (nearest: ") for t in titles) for n in names)
    assert "t-SNE 1" in svg and "t-SNE 2" in svg and len(re.findall(r"<image ", svg)) == 12


def test_each_metric_is_defined_where_it_is_shown(report):
    page = (report / "index.html").read_text()
    for name, meaning in METRICS.items():
        assert f'<abbr title="{html.escape(meaning)}">{name}</abbr>' in page  # on every card, hovered
        assert page.count(f"<dt>{name}</dt><dd>{html.escape(meaning)}</dd>") == 2  # under the cards, over the table
    cards = page[page.index('<section id="shapes">'):page.index('<section id="colours">')]
    assert cards.count('<abbr title="' + html.escape(METRICS["coverage"])) == 12 and "<dt>consistency</dt>" in cards


def test_the_colours_are_explained_once(report):
    page = (report / "index.html").read_text()
    colours = page[page.index('<section id="colours">'):page.index('<section id="similarity">')]
    assert "One colour per part index" in colours and "the names, not to part indices" in colours
    assert page.count("One colour per part index") == 1 and "16 seat" in colours


def test_the_print_stylesheet_shows_every_picture_and_leaves_the_scene_out(report):
    scene = "getComputedStyle(document.getElementById('scene-section')).display"
    got = load_page(report / "index.html", width=WIDTH, height=HEIGHT, media="print", evaluate=[IMAGES, scene])
    (report.parent / "print.png").write_bytes(got.screenshot)
    assert not got.problems(), got.problems()
    images = json.loads(got.values[IMAGES])
    assert len(images) == 12 * 4 and all(i[3] == "block" for i in images)
    assert got.values[scene] == "none"

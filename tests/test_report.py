"""The HTML report: built through the CLI on procedural chairs, its files and numbers checked, and
loaded in a real headless browser (Debian's chromium, driven through the DevTools protocol by
``tests/chromium.py``; skipped with the reason when it is missing, scripts/setup.sh installs it)."""

import html
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from primkit import synthetic
from primkit.cli import main
from primkit.viz import web

from chromium import CHROMIUM, load_page

pytestmark = pytest.mark.integration  # the whole chain, then headless Chromium

needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (scripts/setup.sh installs it: "
                                    "apt-get install chromium)")


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    synthetic.write_collection(root / "in", "chair", 4, seed=11)
    out = root / "out"
    assert main(["report", str(root / "in"), "--model", "chair", "-o", str(out), "--cache", str(root / "cache"),
                 "--images"]) == 0
    return out


@pytest.fixture(scope="module")
def report_by_part(report_dir):
    """The same shapes' report without the model's labeller: the 3D scene coloured by part index."""
    from primkit.report import build_report

    out = report_dir.parent / "by-part"
    build_report(sorted((report_dir.parent / "in").glob("*.ply")), "chair", out, cache_dir=report_dir.parent / "cache",
                 labeller=None)
    return out


#: the page drawn, then scrolled to its 3D scene (below the cards): the screenshots are of the viewport
SCENE_READY = ("document.body && document.body.dataset.ready === '1' && "
               "(document.getElementById('scene').scrollIntoView(), true)")


def _scene(page: str) -> dict:
    m = re.search(r'<script id="scene-data" type="application/json">(.*?)</script>', page, re.S)
    return json.loads(m.group(1))


def test_report_files_and_numbers(report_dir):
    page = (report_dir / "index.html").read_text()
    markup = re.sub(r"<script\b.*?</script>", "", page, flags=re.S)  # the page's own elements
    sources = re.findall(r'(?:src|href)="(data:[^"]{0,30})', markup)
    assert len(sources) >= 4 * 4 and all(src.startswith("data:image/webp;base64,") for src in sources)  # inlined
    assert not re.search(r'src="(?!data:)', markup)
    # with --images, each picture also as a PNG beside the page (which needs none of them)
    assert sorted(p.name for p in (report_dir / "images").iterdir()) == sorted(
        ["deformation.png"] + [f"{i:03d}.{k}.png" for i in range(4) for k in ("mesh", "cuboids", "segmentation", "names")])
    # nothing fetched at view time: no remote src/href; the browser test checks every request
    assert not re.search(r'(src|href)\s*=\s*["\']?(https?:)?//', markup)
    assert "Plotly.newPlot" in page and "plotly.js v" in page  # the library is inlined
    summary = json.loads((report_dir / "report.json").read_text())
    assert summary["notes"] == {} and len(summary["shapes"]) == 4
    for s in summary["shapes"]:
        assert s["scores"]["parts"] == len(s["parts"])
        d = [n["distance"] for n in s["neighbors"]]
        assert d == sorted(d) and s["name"] not in [n["name"] for n in s["neighbors"]]
    scene = _scene(page)
    shape_at, cuboid_at, _ = web.scene_offsets(4)
    for i, info in enumerate(summary["shapes"]):
        traces = [t for t in scene["data"] if t.get("meta", {}).get("shape") == i]
        surface = [t for t in traces if t["meta"]["kind"] == "surface"]
        cuboids = [t for t in traces if t["meta"]["kind"] == "cuboid"]
        edges = [t for t in traces if t["meta"]["kind"] == "edges"]
        # with the chair model's labeller the surface goes by name, every face once (decimated: at most 3000 and a few)
        assert all(0 <= t["meta"]["label"] < len(summary["label_names"]) for t in surface)
        assert {summary["label_names"][t["meta"]["label"]] for t in surface} <= set(info["labels"])
        assert len({t["meta"]["label"] for t in surface}) == len(surface) and 1000 < sum(len(t["i"]) for t in surface) < 3100
        assert sorted(t["meta"]["part"] for t in cuboids) == sorted(info["parts"])
        assert sorted(t["meta"]["part"] for t in edges) == sorted(info["parts"])
        for t in surface + cuboids:
            v = np.stack([np.asarray(t[a]) for a in "xyz"], 1).astype(float)
            f = np.stack([np.asarray(t[a]) for a in "ijk"], 1)
            assert f.min() >= 0 and f.max() < len(v)
            where = shape_at[i] if t["meta"]["kind"] == "surface" else cuboid_at[i]
            assert np.abs(v - where).max() <= 0.5 + 1e-3 or t["meta"]["kind"] == "cuboid"  # canonical frame
            if t["meta"]["kind"] == "cuboid":
                assert len(f) == 12 and len(v) == 8
        for t in edges:  # a cuboid shows its 12 edges: 12 segments, each two corners and a gap
            assert len(t["x"]) == 36 and t["x"][2::3] == [None] * 12
    names = [t for t in scene["data"] if t.get("meta", {}).get("kind") == "names"][0]
    assert names["text"] == [s["name"] for s in summary["shapes"]]



def test_each_shape_is_deformed_onto_its_nearest_other_shape(report_dir):
    summary = json.loads((report_dir / "report.json").read_text())
    pairs = summary["deformation"]["pairs"]
    assert [p["source"] for p in pairs] == [s["name"] for s in summary["shapes"]]
    for p, s in zip(pairs, summary["shapes"]):
        assert p["target"] != p["source"] and p["target"] == s["neighbors"][0]["name"]
        assert p["distance"] == pytest.approx(s["neighbors"][0]["distance"])
        assert 0.0 <= p["quality"]["flipped"] < 0.05
    page = (report_dir / "index.html").read_text()
    assert "nearest other shape" in page and "least like it" not in page


def test_partners_against_brute_force():
    from primkit.report import partners

    rng = np.random.default_rng(4)
    X = rng.normal(size=(9, 5))
    X[7] = X[2]  # an exact copy: each is the other's partner at distance 0, never itself
    D = np.linalg.norm(X[:, None] - X[None], axis=-1)
    got = partners(D)
    for i in range(len(X)):
        others = [j for j in range(len(X)) if j != i]
        assert got[i] == min(others, key=lambda j: (D[i, j], j))
    assert got[2] == 7 and got[7] == 2
    with pytest.raises(ValueError, match="s >= 2"):
        partners(np.zeros((1, 1)))


def test_inline_json_cannot_end_its_script():
    hostile = {"name": "<!--<script></script><b>&\u2028\u2029", "x": np.array([0.25, -1.5])}
    text = web.figure_json(hostile)
    assert json.loads(text) == {"name": hostile["name"], "x": [0.25, -1.5]}
    assert not set("<>/\u2028\u2029") & set(text)


def test_report_refuses_to_overwrite_and_degrades_with_two_shapes(tmp_path, report_dir):
    assert main(["report", str(report_dir.parent / "in"), "--model", "chair", "-o", str(report_dir),
                 "--cache", str(report_dir.parent / "cache")]) == 2
    synthetic.write_collection(tmp_path / "in", "chair", 2, seed=12)
    from primkit.report import build_report

    report, errors = build_report(sorted((tmp_path / "in").glob("*.ply")), "chair", tmp_path / "out",
                                  cache_dir=tmp_path / "cache", progress=False)
    assert errors == [] and "similarity" in report.notes and "3 shapes" in report.notes["similarity"]
    page = report.path.read_text()
    assert "similarity map not drawn" in page and 'alt="deformation"' in page
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["index.html", "report.json"]  # one page, no images/


def _colour_counts(img: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """For each colour, the number of saturated pixels of ``img`` whose chromaticity is that
    colour's (shading scales a colour's brightness, not its chromaticity)."""
    img = img.astype(int)
    hue = img / np.maximum(img.sum(-1, keepdims=True), 1)
    ref = colours / np.maximum(colours.sum(-1, keepdims=True), 1)
    close = np.abs(hue[:, :, None, :] - ref[None, None]).sum(-1) < 0.03
    saturated = (np.ptp(img, axis=-1) > 20)[..., None]
    return (close & saturated).sum(axis=(0, 1))


def test_without_a_labeller_the_scene_goes_by_part(report_by_part):
    summary = json.loads((report_by_part / "report.json").read_text())
    assert "label_names" not in summary and all("labels" not in s for s in summary["shapes"])
    surface = [t for t in _scene((report_by_part / "index.html").read_text())["data"]
               if t.get("meta", {}).get("kind") == "surface"]
    for i, info in enumerate(summary["shapes"]):
        assert {t["meta"]["part"] for t in surface if t["meta"]["shape"] == i} <= set(info["parts"])  # present parts only


@needs_chromium
def test_report_loads_in_headless_chromium(report_by_part):
    """The report of a model without a labeller: its scene's surfaces in the parts' colours."""
    report_dir = report_by_part
    from io import BytesIO

    from PIL import Image

    from primkit.viz.palette import part_colors

    box = "JSON.stringify(document.getElementById('scene').getBoundingClientRect())"
    legend = "JSON.stringify(document.querySelector('#scene .legend').getBoundingClientRect())"
    got = load_page(report_dir / "index.html", ready=SCENE_READY, width=1200, height=1100, evaluate=[box, legend])
    assert got.ready_ms is not None, got.console
    assert any("primkit report ready: 4 shapes" in text for _, text in got.console)
    assert not got.problems(), got.problems()
    assert "in the colours of its parts" in got.dom
    assert got.requests and all(u.startswith(("file:", "data:", "blob:")) for u in got.requests), got.requests
    assert re.search(r'id="status">\d+ traces, \d+ triangles', got.dom)
    # the 3D scene (its legend's swatches left out) shows every part in use in its own colour
    img = np.array(Image.open(BytesIO(got.screenshot)).convert("RGB"))
    lg = json.loads(got.values[legend])
    img[int(lg["top"]):int(lg["bottom"]) + 1, int(lg["left"]):int(lg["right"]) + 1] = 255
    rect = json.loads(got.values[box])
    scene = img[int(rect["top"]):int(rect["bottom"]), int(rect["left"]):int(rect["right"])]
    assert scene.shape[0] > 300 and scene.shape[1] > 600
    summary = json.loads((report_dir / "report.json").read_text())
    used = sorted({k for s in summary["shapes"] for k in s["parts"]})
    traces = _scene((report_dir / "index.html").read_text())["data"]
    assert {f"part{k}" for k in used} <= {t.get("legendgroup") for t in traces}  # every part in the legend
    # parts whose co-segmented surface has at least 100 triangles over the shapes show in their colour
    # (a present cuboid can be too thin, or hidden inside another, to label any surface or show)
    surface = {k: sum(len(t["i"]) for t in traces if t.get("legendgroup") == f"part{k}" and "surface of" in t.get("hovertemplate", ""))
               for k in used}
    colours = part_colors(20).astype(int)
    grey = colours.max(axis=1) - colours.min(axis=1) < 10  # tab20's two greys (14, 15): shading looks the same
    visible = [k for k in used if surface[k] >= 100 and not grey[k]]
    assert len(visible) >= 4, surface
    counts = _colour_counts(scene, colours[visible])
    assert (counts >= 40).all(), (dict(zip(visible, counts)), surface)


@needs_chromium
def test_a_hostile_shape_name_does_not_stop_the_scene(tmp_path):
    folder = tmp_path / "in"
    paths = synthetic.write_collection(folder, "chair", 3, seed=5)
    hostile = folder / "<!--<script>.ply"
    shutil.move(paths[0], hostile)
    out = tmp_path / "out"
    assert main(["report", str(folder), "--model", "chair", "-o", str(out), "--cache", str(tmp_path / "cache"),
                 "--workers", "1"]) == 0
    got = load_page(out / "index.html", screenshot=False)
    assert got.ready_ms is not None and not got.problems(), (got.console, got.exceptions)
    assert "&lt;!--&lt;script&gt;" in got.dom  # shown as text
    scene = _scene((out / "index.html").read_text())
    names = [t for t in scene["data"] if t.get("meta", {}).get("kind") == "names"][0]["text"]
    assert html.escape("<!--<script>") in names  # plotly decodes entities: the name is drawn as written


@needs_chromium
@pytest.mark.parametrize("width", [760, 1200])
def test_the_3d_scene_frames_every_shape_at_any_width(report_dir, width):
    """The plot's height follows its width so that no shape is cut off: the plot area's outer
    columns and rows are background (at 760 px, before, the first and last shapes were cut)."""
    from io import BytesIO

    from PIL import Image

    size = "JSON.stringify(Object.assign({top: document.getElementById('scene').getBoundingClientRect().top, " \
           "left: document.getElementById('scene').getBoundingClientRect().left}, document.getElementById('scene')._fullLayout._size))"
    got = load_page(report_dir / "index.html", ready=SCENE_READY, width=width, height=1100, evaluate=[size])
    assert got.ready_ms is not None and not got.problems(), got.problems()
    box = json.loads(got.values[size])
    img = np.array(Image.open(BytesIO(got.screenshot)).convert("RGB")).astype(int)
    top, left = int(round(box["top"] + box["t"])) + 1, int(round(box["left"])) + 1  # below the mode bar's strip
    area = img[top + 2 : top + int(box["h"]) - 2, left + 2 : left + int(box["w"]) - 2]
    ink = np.ptp(area, axis=-1) > 30  # coloured parts (the background and the grey text are not)
    rows, cols = np.nonzero(ink)
    assert len(rows) > 2000, "the scene is empty"
    assert cols.min() > 3 and cols.max() < area.shape[1] - 4, (cols.min(), cols.max(), area.shape)
    assert rows.max() < area.shape[0] - 4, (rows.max(), area.shape)
    # and the content fills the width (framed, not shrunk to a corner)
    assert cols.max() - cols.min() > 0.7 * area.shape[1]


def test_the_report_names_each_shape_with_the_models_labeller(report_dir):
    """The bundled chair model has a labeller: report.json's per-shape ``labels`` (the share of the
    surface each name holds) agree with label_elements called directly on each input mesh in its own
    frame, and each shape's ``names`` thumbnail shows the names in the label palette's colours."""
    from pictures import read_picture

    from primkit import io
    from primkit.model.abstraction import abstract
    from primkit.model.bundled import resolve_model
    from primkit.segmentation import labeller as lab
    from primkit.viz.palette import label_colors

    summary = json.loads((report_dir / "report.json").read_text())
    names = summary["label_names"]
    assert names == ["back", "seat", "legs", "arms"]
    labeller = lab.read_labeller(resolve_model("chair"))
    page = (report_dir / "index.html").read_text()
    assert "Names (the model's labeller" in page and "(parts, cuboids, mesh, names: click to switch" in page
    for i, s in enumerate(summary["shapes"]):
        mesh = io.read_mesh(s["source"])
        a = abstract((mesh.vertices, mesh.faces), "chair")
        named = lab.label_elements(labeller, lab.mesh_elements(mesh.vertices, mesh.faces, a.result.frame),
                                   a.result.canonical)
        area = mesh.face_areas()
        want = {n: area[named == j].sum() / area.sum() for j, n in enumerate(names) if (named == j).any()}
        assert set(s["labels"]) <= set(want) and abs(sum(s["labels"].values()) - 1) < 1e-6
        for n, share in want.items():
            assert abs(s["labels"].get(n, 0.0) - share) < 0.02, (s["name"], n, s["labels"], want)
        thumb = read_picture(report_dir / "images" / f"{i:03d}.names.png")
        for j, n in enumerate(names):
            if want.get(n, 0) >= 0.05:
                assert thumb.colour_pixels(label_colors(4)[j]) > 20, (s["name"], n)
        assert "names: " in page


@needs_chromium
def test_the_3d_scene_shows_each_surface_by_name(report_dir):
    """With the chair model's labeller, the scene's surfaces are drawn in the names' colours (the
    thumbnails by name's): with the cuboids hidden (Plotly.restyle, before the screenshot), every
    name on at least 100 of the scene's triangles shows in its colour, and no part colour that is
    not also a name's shows (the surfaces are not by part: the seat's and back's parts, 16 and 18,
    olive and teal, would); the legend lists the names first."""
    from io import BytesIO

    from PIL import Image

    from primkit.viz.palette import label_colors, part_colors

    summary = json.loads((report_dir / "report.json").read_text())
    names = summary["label_names"]
    traces = _scene((report_dir / "index.html").read_text())["data"]
    hide = [n for n, t in enumerate(traces) if t.get("meta", {}).get("kind") in ("cuboid", "edges")]
    assert hide
    ready = (SCENE_READY + " && (window.hid === undefined ? (window.hid = false, "
             f"Plotly.restyle(document.getElementById('scene'), {{visible: false}}, {json.dumps(hide)})"
             ".then(function(){ window.hid = true; }), false) : window.hid)")
    box = "JSON.stringify(document.getElementById('scene').getBoundingClientRect())"
    legend = "JSON.stringify(document.querySelector('#scene .legend').getBoundingClientRect())"
    entries = "JSON.stringify(Array.from(document.querySelectorAll('#scene .legendtext')).map(e => e.textContent))"
    got = load_page(report_dir / "index.html", ready=ready, width=1200, height=1100, evaluate=[box, legend, entries])
    assert got.ready_ms is not None and not got.problems(), (got.console, got.problems())
    assert "in its names (the model's labeller" in got.dom
    shown = json.loads(got.values[entries])
    triangles = {j: sum(len(t["i"]) for t in traces if t.get("meta", {}).get("kind") == "surface"
                        and t["meta"]["label"] == j) for j in range(len(names))}
    assert [n for n in shown if n in names] == [n for j, n in enumerate(names) if triangles[j]]  # names first, in order
    assert shown[:sum(1 for j in triangles if triangles[j])] == [n for j, n in enumerate(names) if triangles[j]]
    img = np.array(Image.open(BytesIO(got.screenshot)).convert("RGB"))
    lg = json.loads(got.values[legend])
    img[int(lg["top"]):int(lg["bottom"]) + 1, int(lg["left"]):int(lg["right"]) + 1] = 255
    rect = json.loads(got.values[box])
    scene = img[int(rect["top"]):int(rect["bottom"]), int(rect["left"]):int(rect["right"])]
    big = [j for j in triangles if triangles[j] >= 100]
    assert len(big) >= 3, triangles
    counts = _colour_counts(scene, label_colors(len(names))[big].astype(int))
    assert (counts >= 40).all(), dict(zip(big, counts))
    # tab20's pairs 0-7 are the names' colours (tab10) and their light tints, which a name's edges
    # blended with the white background also take; the other part colours must not show
    parts = part_colors(20).astype(int)
    others = [k for k in range(2 * len(names), 20) if np.ptp(parts[k]) >= 10]
    assert (_colour_counts(scene, parts[others]) < 40).all(), dict(zip(others, _colour_counts(scene, parts[others])))

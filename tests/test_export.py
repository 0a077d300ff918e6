"""glTF scenes (primkit.export, ``primkit abstract --format glb``): read back with trimesh (nodes,
names, extras, materials, geometry against the inputs), and opened in headless Chromium by three.js's
GLTFLoader (the ``three`` package from the npm registry, installed at test time into pytest's cache
folder, outside the package; skipped with the reason when chromium, npm or the registry is missing)."""

import http.server
import json
import os
import shutil
import subprocess
import threading
from functools import partial
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest

from primkit import synthetic
from primkit.cli import main
from primkit.export import CUBOID_OPACITY, glb_scene, part_node_name, write_glb
from primkit.primitives import Cuboids
from primkit.viz.palette import part_colors

from chromium import CHROMIUM, load_page

THREE = "0.187.0"  # three.js from the npm registry (MIT); pinned so the test sees one loader


def _two_boxes():
    """Two separate boxes as one mesh, and the two cuboids that are exactly those boxes (slots 1 and 3 of 4)."""
    import trimesh

    a = trimesh.creation.box(extents=[0.4, 0.2, 0.6])
    b = trimesh.creation.box(extents=[0.2, 0.8, 0.2])
    b.apply_translation([0.0, 0.6, 0.0])
    v = np.vstack([a.vertices, b.vertices])
    f = np.vstack([a.faces, b.faces + len(a.vertices)])
    z = np.array([[0.05, 0.05, 0.05], [0.2, 0.1, 0.3], [0.05, 0.05, 0.05], [0.1, 0.4, 0.1]])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    t = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.6, 0.0]])
    cub = Cuboids(z, q, t, np.array([False, True, False, True]), probabilities=np.array([0.1, 0.9, 0.2, 0.75]))
    return v, f, cub, len(a.faces)


def _edge(scene, node):
    parent = scene.graph.transforms.parents[node]
    return parent, scene.graph.transforms.edge_data[(parent, node)].get("metadata", {})


def test_glb_read_back_by_trimesh(tmp_path):
    import trimesh

    v, f, cub, na = _two_boxes()
    names = ["part0", "seat", "part2", "back"]
    path = write_glb(tmp_path / "boxes.glb", cub, names, v, f, source="boxes.off")
    scene = trimesh.load(path)
    parent, root = _edge(scene, "boxes")
    assert root["primkit_glb"] == 1 and root["frame"] == "input" and root["parts"] == [1, 3]
    assert root["part_names"] == names and root["source"] == "boxes.off"
    parts = {n for n in scene.graph.nodes if n != scene.graph.base_frame and "existence_probability" in _edge(scene, n)[1]}
    assert parts == {"1 seat", "3 back"} == {part_node_name(k, names[k]) for k in cub.present}
    for k, faces in ((1, na), (3, len(f) - na)):
        node = part_node_name(k, names[k])
        parent, extras = _edge(scene, node)
        assert parent == "boxes" and extras == {"part_index": k, "part_name": names[k],
                                                "existence_probability": pytest.approx(cub.probabilities[k])}
        # the surface: exactly this box's faces (face_labels on separate boxes is unambiguous), in place
        surf = scene.geometry[scene.graph[f"{node} surface"][1]]
        assert _edge(scene, f"{node} surface") == (node, {"part_index": k, "kind": "surface", "faces": faces})
        mine = f[:na] if k == 1 else f[na:]
        assert len(surf.faces) == faces
        assert np.allclose(np.sort(surf.vertices, axis=0), np.sort(v[np.unique(mine)], axis=0), atol=1e-6)
        assert np.allclose(scene.graph[f"{node} surface"][0], np.eye(4))
        # the cuboid: its 8 corners, and its parameters in the extras
        box = scene.geometry[scene.graph[f"{node} cuboid"][1]]
        cv, _, cpart = cub.to_mesh()
        corners = cv[np.repeat(np.arange(len(cv) // 8), 8) == list(cub.present).index(k)]
        assert np.allclose(np.sort(box.vertices, axis=0), np.sort(corners, axis=0), atol=1e-6)
        _, cx = _edge(scene, f"{node} cuboid")
        assert np.allclose(cx["half_extents"], cub.half_extents[k]) and np.allclose(cx["translation"], cub.translations[k])
        # materials: the part's colour; the cuboid's translucent
        srgb = part_colors(4)[k] / 255.0  # glTF's factors are linear: decode sRGB (closed form, 8-bit stored)
        linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
        assert np.abs(surf.visual.material.baseColorFactor[:3] / 255.0 - linear).max() <= 0.5 / 255 + 1e-9
        assert np.array_equal(box.visual.material.baseColorFactor[:3], surf.visual.material.baseColorFactor[:3])
        assert box.visual.material.baseColorFactor[3] == round(255 * CUBOID_OPACITY)
        assert box.visual.material.alphaMode == "BLEND"


def test_glb_cuboids_only_and_unlabelled_faces(tmp_path):
    import trimesh

    v, f, cub, na = _two_boxes()
    labels = np.full(len(f), -1)
    labels[:na] = 1
    labels[na : na + 2] = 0  # a part that is not present: unlabelled too
    scene = glb_scene(cub, None, v, f, labels=labels, name="x")
    assert "unlabelled surface" in scene.graph.nodes and "3 part3 surface" not in scene.graph.nodes
    assert _edge(scene, "unlabelled surface") == ("x", {"part_index": -1, "kind": "surface", "faces": len(f) - na})
    assert len(scene.geometry["unlabelled surface"].faces) == len(f) - na
    alone = trimesh.load(write_glb(tmp_path / "c.glb", cub))  # no surface: the cuboids alone
    assert {n for n in alone.graph.nodes if n.endswith(" surface")} == set()
    assert {"1 part1 cuboid", "3 part3 cuboid"} <= set(alone.graph.nodes)
    with pytest.raises(FileExistsError, match="exists"):
        write_glb(tmp_path / "c.glb", cub)
    with pytest.raises(ValueError, match="part_names"):
        glb_scene(cub, ["a", "b"])


@pytest.fixture(scope="module")
def glb_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("glb")
    synthetic.write_collection(root / "in", "chair", 2, seed=8)
    out = root / "out"
    assert main(["abstract", str(root / "in"), "--model", "chair", "--format", "glb", "-o", str(out),
                 "--cache", str(root / "cache"), "--workers", "1"]) == 0
    return out


def test_abstract_format_glb(glb_dir, capsys):
    import trimesh

    glbs = sorted(glb_dir.glob("*.glb"))
    assert [p.name for p in glbs] == ["chair_0000.glb", "chair_0001.glb"]
    assert sorted(p.name for p in glb_dir.iterdir()) == ["chair_0000.cuboids.json", "chair_0000.glb",
                                                         "chair_0001.cuboids.json", "chair_0001.glb"]
    for p in glbs:
        record = json.loads(p.with_suffix("").with_suffix(".cuboids.json").read_text())
        scene = trimesh.load(p)
        present = [part["index"] for part in record["parts"] if part["present"]]
        _, root = _edge(scene, p.stem)
        names = root["part_names"]
        nodes = sorted((_edge(scene, n)[1]["part_index"], n) for n in scene.graph.nodes
                       if n != scene.graph.base_frame and "existence_probability" in _edge(scene, n)[1])
        assert [k for k, _ in nodes] == root["parts"] and all(n == part_node_name(k, names[k]) for k, n in nodes)
        assert present == root["parts"]  # the JSON and the scene agree
        probability = {part["index"]: part["probability"] for part in record["parts"]}
        for k, n in nodes:
            assert _edge(scene, n)[1]["existence_probability"] == pytest.approx(probability[k])
        assert "seat" in {names[k] for k, _ in nodes}
    # nothing overwritten without --force; with it, written again
    before = {p: p.stat().st_mtime_ns for p in glb_dir.iterdir()}
    src = glb_dir.parent / "in"
    assert main(["abstract", str(src), "--model", "chair", "--format", "glb", "-o", str(glb_dir),
                 "--cache", str(glb_dir.parent / "cache"), "--workers", "1"]) == 2
    assert "exists" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in glb_dir.iterdir()} == before
    # --skip-done counts a shape done when its JSON and its .glb exist
    assert main(["abstract", str(src), "--model", "chair", "--format", "glb", "-o", str(glb_dir), "--skip-done",
                 "--cache", str(glb_dir.parent / "cache"), "--workers", "1"]) == 0
    assert "2 of 2 input(s) already done" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in glb_dir.iterdir()} == before


@pytest.fixture(scope="session")
def three_js(request, tmp_path_factory):
    """The ``three`` package from the npm registry, installed once into pytest's cache folder (a
    temporary folder when pytest runs without its cache, ``-p no:cacheprovider``)."""
    if CHROMIUM is None:
        pytest.skip("chromium not installed (scripts/setup.sh installs it: apt-get install chromium)")
    npm = shutil.which("npm")
    if npm is None:
        pytest.skip("npm not installed (apt-get install npm): three.js comes from the npm registry")
    cache = getattr(request.config, "cache", None)
    folder = Path(cache.mkdir(f"npm-three-{THREE}") if cache is not None else tmp_path_factory.mktemp(f"npm-three-{THREE}"))
    package = folder / "node_modules" / "three"
    if not (package / "package.json").is_file():
        try:
            done = subprocess.run([npm, "install", "--prefix", str(folder), "--no-audit", "--no-fund", "--ignore-scripts",
                                   f"three@{THREE}"], capture_output=True, text=True, timeout=300)
        except subprocess.TimeoutExpired:
            pytest.skip("npm install three timed out (no registry?)")
        if done.returncode != 0 or not (package / "package.json").is_file():
            pytest.skip(f"npm install three@{THREE} failed (offline?): {done.stderr.strip()[-200:]}")
    return package


_PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>glb</title><link rel="icon" href="data:,">
<script type="importmap">{"imports": {"three": "./three/build/three.module.js", "three/addons/": "./three/examples/jsm/"}}</script>
<style>body{margin:0;background:#fff} #info{position:absolute;top:4px;left:6px;font:13px sans-serif}</style>
</head><body data-ready="0"><div id="info">loading</div>
<script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
const W = innerWidth, H = innerHeight;
const renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
renderer.setSize(W, H);
renderer.setClearColor(0xffffff);
document.body.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.add(new THREE.AmbientLight(0xffffff, 0.75));
const sun = new THREE.DirectionalLight(0xffffff, 0.6);
sun.position.set(2, 3, 4);
scene.add(sun);
const isPart = (o) => o.userData && ("existence_probability" in o.userData);
new GLTFLoader().load("model.glb", (gltf) => {
  scene.add(gltf.scene);
  const box = new THREE.Box3().setFromObject(gltf.scene);
  const size = box.getSize(new THREE.Vector3()).length(), centre = box.getCenter(new THREE.Vector3());
  const camera = new THREE.PerspectiveCamera(35, W / H, size / 100, size * 10);
  camera.position.copy(centre).add(new THREE.Vector3(1.6, 0.9, 1.2).normalize().multiplyScalar(size * 1.5));
  camera.lookAt(centre);
  camera.updateMatrixWorld();
  renderer.render(scene, camera);
  const ray = new THREE.Raycaster();
  // what a click at (x, y) selects: the part nodes along the ray, nearest first
  const pick = (x, y) => {
    ray.setFromCamera(new THREE.Vector2(x / W * 2 - 1, 1 - y / H * 2), camera);
    return ray.intersectObjects(gltf.scene.children, true).map((h) => {
      let o = h.object;
      while (o && !isPart(o)) o = o.parent;
      return o ? o.name : null;
    });
  };
  renderer.domElement.addEventListener("click", (e) => {
    const hit = pick(e.clientX, e.clientY)[0];
    document.getElementById("info").textContent = hit ? "selected " + hit : "nothing selected";
  });
  // for each part node: click on the centre of its largest triangle that faces the camera
  const parts = [];
  gltf.scene.traverse((o) => { if (isPart(o)) parts.push(o); });
  const report = parts.map((p) => {
    let best = null, area = 0;
    p.traverse((m) => {
      if (!m.isMesh) return;
      const pos = m.geometry.attributes.position, idx = m.geometry.index;
      for (let t = 0; t < idx.count; t += 3) {
        const a = new THREE.Vector3().fromBufferAttribute(pos, idx.getX(t)).applyMatrix4(m.matrixWorld);
        const b = new THREE.Vector3().fromBufferAttribute(pos, idx.getX(t + 1)).applyMatrix4(m.matrixWorld);
        const c = new THREE.Vector3().fromBufferAttribute(pos, idx.getX(t + 2)).applyMatrix4(m.matrixWorld);
        const tri = new THREE.Triangle(a, b, c), mid = tri.getMidpoint(new THREE.Vector3());
        const facing = tri.getNormal(new THREE.Vector3()).dot(camera.position.clone().sub(mid)) > 0;
        const s = tri.getArea();  // one-sided surfaces are picked from the front only, as they are drawn
        if (s > area && (facing || m.material.side === THREE.DoubleSide)) { area = s; best = mid; }
      }
    });
    let picked = [];
    if (best) {
      const q = best.clone().project(camera);
      picked = pick((q.x + 1) / 2 * W, (1 - q.y) / 2 * H);
    }
    return {name: p.name, part_index: p.userData.part_index, part_name: p.userData.part_name,
            existence_probability: p.userData.existence_probability, area: area,
            children: p.children.map((c) => c.name), selectable: picked.includes(p.name)};
  });
  window.primkitParts = report;
  document.getElementById("info").textContent = report.length + " parts";
  console.log("glb ready: " + report.length + " parts");
  document.body.dataset.ready = "1";
}, undefined, (e) => console.error("GLTFLoader: " + e));
</script></body></html>
"""


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.mark.integration  # three.js in a node process
def test_glb_opens_in_three_js_with_one_selectable_node_per_part(glb_dir, three_js, tmp_path):
    from PIL import Image

    import trimesh

    site = tmp_path / "site"
    site.mkdir()
    os.symlink(three_js, site / "three")
    glb = glb_dir / "chair_0000.glb"
    shutil.copy(glb, site / "model.glb")
    (site / "index.html").write_text(_PAGE)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), partial(_Quiet, directory=str(site)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/index.html"
        got = load_page(url, width=900, height=700, evaluate=["JSON.stringify(window.primkitParts)"])
    finally:
        server.shutdown()
        server.server_close()
    assert got.ready_ms is not None, (got.console, got.exceptions)
    assert not got.problems(), got.problems()
    assert all(u.startswith(f"http://127.0.0.1:{server.server_address[1]}/") for u in got.requests), got.requests
    shown = json.loads(got.values["JSON.stringify(window.primkitParts)"])
    scene = trimesh.load(glb)
    _, root = _edge(scene, "chair_0000")
    names = root["part_names"]
    # one node per present part, named "<index> <name>" (three.js's loader writes spaces in node
    # names as underscores), its extras in userData
    assert sorted(p["part_index"] for p in shown) == root["parts"]
    for p in shown:
        k = p["part_index"]
        assert p["name"] == part_node_name(k, names[k]).replace(" ", "_") and p["part_name"] == names[k]
        assert 0.5 < p["existence_probability"] <= 1.0
        assert f"{p['name']}_cuboid" in p["children"]
    # every part with visible geometry can be clicked (its largest triangle, seen from the camera)
    visible = [p for p in shown if p["area"] > 1e-8]
    assert len(visible) >= 4 and all(p["selectable"] for p in visible), [(p["name"], p["selectable"]) for p in visible]
    # the picture: not blank, and the parts in their colours
    Path(tmp_path / "three.png").write_bytes(got.screenshot)
    img = np.array(Image.open(BytesIO(got.screenshot)).convert("RGB")).astype(int)
    ink = np.ptp(img, axis=-1) > 30
    assert ink.mean() > 0.02, ink.mean()
    hue = img / np.maximum(img.sum(-1, keepdims=True), 1)
    colours = part_colors(len(names)).astype(int)
    seen = []
    for k in root["parts"]:
        c = colours[k]
        if np.ptp(c) < 10:
            continue  # tab20's greys: shading cannot tell them apart
        close = (np.abs(hue - c / max(c.sum(), 1)).sum(-1) < 0.03) & ink
        seen.append(int(close.sum()))
    assert sum(n >= 30 for n in seen) >= 3, seen

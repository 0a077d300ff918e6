"""A static HTML report of a collection's abstractions: ``primkit report FOLDER --model M -o report/``.

The report folder holds ``index.html``, ``report.json`` (the same numbers, for machines) and
``images/``. The page shows, for every shape, thumbnails of the shape, its cuboids and its
co-segmentation (one colour per part index on every shape, :func:`primkit.viz.palette.part_colors`,
drawn with the camera convention of :mod:`primkit.viz.render` at one fixed scale so they line up); the
similarity map (t-SNE of :class:`primkit.embedding.PartDescriptor`) with each shape's nearest
neighbours; one deformation transfer (the first shape onto the shape least like it); a table of
metrics (:func:`primkit.metrics.score`, with its convention sentence); and an interactive 3D scene.

The 3D scene works offline and in any browser: the page carries its own small viewer, a canvas 2D
painter's-algorithm renderer of a few thousand triangles (the meshes are decimated for it with
Open3D's quadric decimation), with the data inlined as JSON. Why not pyvista's ``export_html``:
it needs trame (not a dependency of primkit) and its page loads its JavaScript at view time; a
WebGL page would need a GL context, which headless browsers on CPU-only machines provide only
through a deprecated software fallback that logs warnings. The canvas viewer needs neither.

Each section degrades on its own: a missing piece (a map needs 3 shapes; the deformation needs
two; a module that fails) is replaced by a one-line note on the page and in ``report.json``, and
the rest is still written.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import deformation, embedding, io
from .geometry import voxel_boundary_mesh
from .segmentation import face_labels
from .viz.interop import mesh_from_o3d, mesh_to_o3d
from .viz.palette import part_colors
from .viz.camera import CANONICAL_RADIUS
from .viz.render import cuboid_layer, mesh_layer, segmentation_layer, ThumbnailRenderer, Tile, write_png
from .model.abstractor import Abstractor
from .model.abstraction import abstract_shapes
from .metrics import score

__all__ = ["ReportShape", "Report", "build_report", "write_report", "scene_data", "VIEWER_JS"]

THUMB = 160  # thumbnail size in pixels
SCENE_FACES = 1500  # triangles per shape in the interactive scene


@dataclass
class ReportShape:
    """One shape of the report, in the network's canonical frame (upright, front +X, longest side 1).

    vertices : (n, 3) float; faces : (f, 3) int; cuboids : Cuboids; labels : (f,) int, the
    co-segmentation (primitive index per face); scores : primkit.metrics.AbstractionScores or None.
    """

    name: str
    source: str
    vertices: np.ndarray
    faces: np.ndarray
    cuboids: object
    labels: np.ndarray
    scores: object = None


@dataclass
class Report:
    """What :func:`write_report` wrote: the page, and a note per section that could not be made."""

    path: Path
    shapes: int
    notes: dict = field(default_factory=dict)


def _canonical_mesh(a):
    """The shape's mesh in the frame of its abstraction's canonical frame (input cuboids brought along).

    Meshes are read again from their file; voxel grids and point clouds are drawn as the boundary
    of the occupancy grid the network read."""
    result = a.result
    cub = result.cuboids.transformed(result.frame.matrix)
    try:
        mesh = a.mesh
        return result.frame.to_canonical(mesh.vertices), mesh.faces, cub
    except (io.ShapeFileError, ValueError, OSError):
        v, f = voxel_boundary_mesh(np.asarray(a.prepared.occupancy, bool))
        if result.alignment is not None:  # the grid was read turned; turn it back
            v = v @ np.asarray(result.alignment["rotation"], float)
        return v, f, cub


def _face_labels(vertices, faces, cuboids) -> np.ndarray:
    if not cuboids.existence.any():
        return np.full(len(faces), -1, np.int64)

    return face_labels(vertices, faces, cuboids)


def _decimate(vertices, faces, labels, target: int):
    """At most about ``target`` triangles (Open3D quadric decimation); each kept face takes the
    label of the nearest original face centroid."""
    if len(faces) <= target:
        return vertices, faces, labels
    from scipy.spatial import cKDTree

    small = mesh_from_o3d(mesh_to_o3d(vertices, faces).simplify_quadric_decimation(target))
    if len(small.faces) == 0:
        return vertices, faces, labels
    _, nearest = cKDTree(vertices[faces].mean(1)).query(small.vertices[small.faces].mean(1))
    return small.vertices, small.faces, labels[nearest]


def scene_data(shapes, part_count: int, faces_per_shape: int = SCENE_FACES) -> dict:
    """The JSON the page's viewer draws: per shape its decimated mesh (vertices rounded to 1e-4),
    face labels, and its present cuboids as 8 corners each (:meth:`Cuboids.to_mesh` order)."""
    out = {"colors": part_colors(part_count).tolist(), "shapes": []}
    for s in shapes:
        v, f, lab = _decimate(s.vertices, s.faces, s.labels, faces_per_shape)
        cv, _, cpart = s.cuboids.to_mesh()
        out["shapes"].append({
            "name": s.name,
            "v": np.round(v, 4).ravel().tolist(), "f": np.asarray(f, int).ravel().tolist(),
            "label": np.asarray(lab, int).tolist(),
            "corners": np.round(cv, 4).ravel().tolist(), "part": cpart[::12].astype(int).tolist(),
        })
    return out


def _thumbnails(shapes, folder: Path, overwrite: bool, progress: bool) -> dict:
    from tqdm import tqdm

    frame = np.array([[-0.5] * 3, [0.5] * 3])
    paths = {}
    with ThumbnailRenderer(size=THUMB, radius=CANONICAL_RADIUS) as thumbs:
        for i, s in enumerate(tqdm(shapes, desc="thumbnails", unit="shape", disable=not progress)):
            layers = {"mesh": [mesh_layer(s.vertices, s.faces)]}
            if s.cuboids.existence.any():
                layers["cuboids"] = [cuboid_layer(s.cuboids)]
                layers["segmentation"] = [segmentation_layer(s.vertices, s.faces, s.labels, s.cuboids.count)]
            for kind, layer in layers.items():
                p = folder / f"{i:03d}.{kind}.png"
                thumbs.render(Tile("", layer, frame=frame), p, overwrite=overwrite)
                paths[(i, kind)] = p
    return paths


def _similarity(shapes, results, part_names, folder: Path, thumbs: dict, overwrite: bool) -> dict:
    from PIL import Image

    if len(shapes) < 3:
        raise ValueError(f"a similarity map needs at least 3 shapes, got {len(shapes)}")
    X = embedding.PartDescriptor(part_names=part_names).fit_transform(results)
    k = min(3, len(shapes) - 1)
    near = embedding.nearest_neighbors(X, k=k)
    coords = embedding.tsne_map(X, random_state=0)
    images = [np.asarray(Image.open(thumbs[(i, "cuboids")]).convert("RGB")) if (i, "cuboids") in thumbs else None
              for i in range(len(shapes))]
    path = folder / "similarity.png"
    io.refuse_existing(path, overwrite)
    embedding.draw_map(coords, images, path, title="t-SNE of the part descriptors (all parts)", zoom=0.45)
    D = embedding.descriptor_distances(X)
    return {"map": path, "coords": coords, "neighbors": near, "distances": D}


def _deformation(shapes, similarity, folder: Path, overwrite: bool) -> dict:
    if len(shapes) < 2:
        raise ValueError("a deformation needs two shapes")
    src = 0
    if similarity is not None:
        tgt = int(np.argmax(similarity["distances"][src]))
    else:
        tgt = 1
    a, b = shapes[src], shapes[tgt]
    d = deformation.deform(a.vertices, a.cuboids, b.cuboids, faces=a.faces)
    tiles = [Tile(f"source {a.name[:14]}", [segmentation_layer(a.vertices, a.faces, a.labels, a.cuboids.count)]),
             Tile(f"target {b.name[:14]}", [segmentation_layer(b.vertices, b.faces, b.labels, b.cuboids.count)]),
             Tile("result", [mesh_layer(d.vertices, a.faces)])]
    path = write_png(folder / "deformation.png", tiles, columns=3, tile=220, overwrite=overwrite,
                     radius=float(np.sqrt(3) / 2))
    return {"path": path, "source": a.name, "target": b.name,
            "paired": list(map(int, d.transfer.paired)), "quality": d.quality(a.faces)}


def build_report(paths, model, output, *, refine: int = 0, align=None, overwrite: bool = False, settings=None,
                 model_label: str | None = None,
                 cache_dir=None, workers=None, progress: bool = True) -> tuple[Report, list]:
    """Abstract, segment, embed and deform the shapes of ``paths`` with ``model`` and write the report.

    ``settings``: :class:`primkit.data.PrepareSettings` (the inputs' axes); default the model's.
    Returns ``(report, errors)``; ``errors`` has one line per unusable input (the rest goes on).
    """
    out = abstract_shapes(paths, model, settings=settings, align=align, refine=refine, cache=cache_dir, workers=workers,
                          progress=progress)
    if not out.shapes:
        raise ValueError("no usable shapes for the report")
    shapes = []
    for a in out:
        v, f, cub = _canonical_mesh(a)
        shapes.append(ReportShape(a.name, str(a.source), v, f, cub, _face_labels(v, f, cub),
                                  score(a.canonical, a.canonical_shape())))
    meta = {"model": model_label or (str(model) if not isinstance(model, Abstractor) else "given"), "refine": refine,
            "align": align or "none"}
    report = write_report(output, shapes, out.results, out.model.part_names, overwrite=overwrite, progress=progress,
                          meta=meta)
    return report, [str(e) for e in out.errors]


def write_report(output, shapes, results, part_names, *, overwrite: bool = False, progress: bool = True,
                 meta=None) -> Report:
    """Write ``index.html``, ``report.json`` and ``images/`` into ``output`` for shapes already
    abstracted (:class:`ReportShape`, with the :class:`~primkit.model.abstractor.AbstractionResult` s)."""
    out = Path(output)
    page = out / "index.html"
    io.refuse_existing(page, overwrite)
    images = out / "images"
    images.mkdir(parents=True, exist_ok=True)
    notes = {}
    thumbs = _thumbnails(shapes, images, overwrite, progress)
    similarity = deform = None
    try:
        similarity = _similarity(shapes, results, part_names, images, thumbs, overwrite)
    except FileExistsError:
        raise
    except Exception as exc:  # noqa: BLE001 - one section missing must not lose the report
        notes["similarity"] = f"similarity map not drawn: {type(exc).__name__}: {exc}"
    try:
        deform = _deformation(shapes, similarity, images, overwrite)
    except FileExistsError:
        raise
    except Exception as exc:  # noqa: BLE001
        notes["deformation"] = f"deformation not drawn: {type(exc).__name__}: {exc}"
    count = results[0].canonical.count if results else 20
    scene = scene_data(shapes, count)
    summary = _summary_json(shapes, part_names, similarity, deform, notes, meta or {})
    with io.atomic_output(out / "report.json", overwrite=overwrite) as tmp:
        Path(tmp).write_text(json.dumps(summary, indent=1))
    text = _page(shapes, part_names, thumbs, similarity, deform, notes, scene, out, meta or {})
    with io.atomic_output(page, overwrite=overwrite) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return Report(page, len(shapes), notes)


def _summary_json(shapes, part_names, similarity, deform, notes, meta) -> dict:
    d = {"meta": meta, "notes": notes, "part_names": list(part_names), "shapes": []}
    for i, s in enumerate(shapes):
        e = {"name": s.name, "source": s.source, "parts": s.cuboids.present.tolist()}
        if s.scores is not None:
            e["scores"] = s.scores.to_dict()
        if similarity is not None:
            nb = similarity["neighbors"]
            e["neighbors"] = [{"name": shapes[j].name, "distance": float(x)} for j, x in zip(nb.indices[i], nb.distances[i])]
            e["map"] = similarity["coords"][i].tolist()
        d["shapes"].append(e)
    if deform is not None:
        d["deformation"] = {k: (str(v) if isinstance(v, Path) else v) for k, v in deform.items()}
    return d


def _fmt(x) -> str:
    return "&ndash;" if x is None or not np.isfinite(x) else f"{x:.4f}"


def _page(shapes, part_names, thumbs, similarity, deform, notes, scene, out: Path, meta) -> str:
    esc = html.escape
    rel = lambda p: esc(str(Path(p).relative_to(out)))  # noqa: E731
    cards = []
    for i, s in enumerate(shapes):
        imgs = "".join(f'<figure><img src="{rel(thumbs[(i, k)])}" alt="{k} of {esc(s.name)}" width="{THUMB}" '
                       f'height="{THUMB}"><figcaption>{k}</figcaption></figure>'
                       for k in ("mesh", "cuboids", "segmentation") if (i, k) in thumbs)
        parts = ", ".join(f"{k} {esc(part_names[k])}" for k in s.cuboids.present)
        nearest = ""
        if similarity is not None:
            nb = similarity["neighbors"]
            nearest = "<br>nearest: " + ", ".join(f"{esc(shapes[j].name)} ({x:.2f})" for j, x in zip(nb.indices[i], nb.distances[i]))
        cards.append(f'<div class="card"><h3>{esc(s.name)}</h3><div class="row">{imgs}</div>'
                     f'<p>{len(s.cuboids.present)} parts: {parts}{nearest}</p></div>')
    rows = []
    conv = ""
    for s in shapes:
        sc = s.scores
        if sc is None:
            continue
        conv = sc.convention
        rows.append(f"<tr><td>{esc(s.name)}</td><td>{sc.parts}</td><td>{_fmt(sc.chamfer)}</td><td>{_fmt(sc.iou)}</td>"
                    f"<td>{_fmt(sc.coverage)}</td><td>{_fmt(sc.consistency)}</td></tr>")
    if rows:
        vals = np.array([[s.scores.parts, s.scores.chamfer, s.scores.iou, s.scores.coverage, s.scores.consistency]
                         for s in shapes if s.scores is not None], float)
        mean = vals.mean(0)
        rows.append(f"<tr class='mean'><td>mean</td><td>{mean[0]:.1f}</td>" + "".join(f"<td>{_fmt(x)}</td>" for x in mean[1:])
                    + "</tr>")
    present = np.array([s.cuboids.existence for s in shapes]).mean(0)
    usage = "".join(f"<tr><td>{k}</td><td>{esc(part_names[k])}</td><td><span class='sw' style='background:rgb"
                    f"{tuple(scene['colors'][k])}'></span></td><td>{present[k]:.0%}</td></tr>"
                    for k in np.flatnonzero(present))
    sim = (f'<img src="{rel(similarity["map"])}" alt="similarity map" class="map">' if similarity is not None
           else f"<p class='note'>{esc(notes.get('similarity', ''))}</p>")
    if deform is not None:
        q = deform["quality"]
        dfm = (f'<img src="{rel(deform["path"])}" alt="deformation" class="wide"><p>{esc(deform["source"])} deformed '
               f'onto the parts of {esc(deform["target"])} (the shape least like it); {len(deform["paired"])} parts paired '
               f'by index; flipped triangles {q["flipped"]:.2%}.</p>')
    else:
        dfm = f"<p class='note'>{esc(notes.get('deformation', ''))}</p>"
    data = json.dumps(scene, separators=(",", ":")).replace("</", "<\\/")
    return _TEMPLATE.format(
        title=f"primkit report: {len(shapes)} shapes", meta=esc(json.dumps(meta)), cards="".join(cards),
        rows="".join(rows), convention=esc(conv), usage=usage, similarity=sim, deformation=dfm, data=data,
        js=VIEWER_JS, options="".join(f'<option value="{i}">{esc(s.name)}</option>' for i, s in enumerate(shapes)))


_TEMPLATE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body{{font-family:sans-serif;margin:1.5em;color:#222}} h2{{border-bottom:1px solid #ccc}}
.cards{{display:flex;flex-wrap:wrap;gap:12px}} .card{{border:1px solid #ddd;padding:6px;width:{w}px}}
.card h3{{margin:0 0 4px 0;font-size:14px}} .card p{{font-size:12px;margin:4px 0}}
.row{{display:flex}} figure{{margin:0}} figcaption{{font-size:11px;text-align:center;color:#666}}
table{{border-collapse:collapse;font-size:13px}} td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}
td:first-child{{text-align:left}} tr.mean{{font-weight:bold}} .sw{{display:inline-block;width:14px;height:14px}}
img.map{{max-width:900px;width:100%}} img.wide{{max-width:700px}} .note{{color:#a33}}
#scene{{border:1px solid #ccc;background:#fff;cursor:grab}}
</style></head><body data-ready="0">
<h1>{title}</h1>
<p>Made by primkit (Tulsiani et al., CVPR 2017): one network explains the whole collection, so
primitive <i>k</i> is the same part on every shape and has the same colour everywhere. Shapes are
drawn in the model's canonical frame (upright, front +X), all at one scale. Settings: <code>{meta}</code></p>
<h2>Interactive 3D scene</h2>
<p><select id="pick"><option value="-1">all shapes (grid)</option>{options}</select>
<label><input type="checkbox" id="mesh" checked> mesh (segmentation colours)</label>
<label><input type="checkbox" id="cubes" checked> cuboids</label> &mdash; drag to turn, wheel to zoom.
<span id="status"></span></p>
<canvas id="scene" width="900" height="560"></canvas>
<h2>Shapes: mesh, cuboids, co-segmentation</h2>
<div class="cards">{cards}</div>
<h2>Similarity map</h2>{similarity}
<h2>Deformation</h2>{deformation}
<h2>Metrics</h2>
<table><tr><th>shape</th><th>parts</th><th>Chamfer</th><th>IoU</th><th>coverage</th><th>consistency</th></tr>{rows}</table>
<p>{convention}</p>
<h3>Parts in use</h3>
<table><tr><th>index</th><th>name</th><th>colour</th><th>present on</th></tr>{usage}</table>
<script id="data" type="application/json">{data}</script>
<script>{js}</script>
</body></html>
""".replace("{w}", str(3 * THUMB + 14))

#: The page's own viewer: orthographic projection, back-to-front triangles on a 2D canvas,
#: Lambert shading; no library, no network.
VIEWER_JS = r"""
(function(){
"use strict";
const D = JSON.parse(document.getElementById("data").textContent);
const cv = document.getElementById("scene"), ctx = cv.getContext("2d");
const pick = document.getElementById("pick"), meshBox = document.getElementById("mesh"), cubeBox = document.getElementById("cubes");
const QUADS = [[1,3,7,5],[0,4,6,2],[2,6,7,3],[0,1,5,4],[4,5,7,6],[0,2,3,1]];
let yaw = -0.75, pitch = 0.45, zoom = 1.0, drag = null;
function grey(){ return [200,200,200]; }
function colour(k){ return k >= 0 && k < D.colors.length ? D.colors[k] : grey(); }
function triangles(sel){
  const out = [], n = D.shapes.length, cols = Math.ceil(Math.sqrt(n * 1.5));
  const list = sel < 0 ? D.shapes.map((s, i) => i) : [sel];
  list.forEach((i, pos) => {
    const s = D.shapes[i], ox = sel < 0 ? (pos % cols) * 1.3 : 0, oy = sel < 0 ? -Math.floor(pos / cols) * 1.3 : 0;
    const P = (arr, j) => [arr[3*j] + ox, arr[3*j+1] + oy, arr[3*j+2]];
    if (meshBox.checked && (sel >= 0 || !cubeBox.checked)) {
      for (let t = 0; t < s.f.length / 3; t++)
        out.push({p: [P(s.v, s.f[3*t]), P(s.v, s.f[3*t+1]), P(s.v, s.f[3*t+2])], c: colour(s.label[t]), a: 1});
    }
    if (cubeBox.checked) {
      for (let b = 0; b < s.part.length; b++) {
        for (const q of QUADS) {
          const c = q.map(j => P(s.corners, 8*b + j));
          out.push({p: [c[0], c[1], c[2], c[3]], c: colour(s.part[b]), a: sel >= 0 && meshBox.checked ? 0.45 : 1, edge: true});
        }
      }
    }
  });
  return {tris: out, cols: cols, rows: Math.ceil(list.length / cols), grid: sel < 0};
}
function draw(){
  const sel = parseInt(pick.value, 10), scene = triangles(sel), T = scene.tris;
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  let cx = 0, cy0 = 0;
  if (scene.grid) { cx = (Math.min(scene.cols, D.shapes.length) - 1) * 0.65; cy0 = -(scene.rows - 1) * 0.65; }
  const rot = (p) => { const x = p[0] - cx, y = p[1] - cy0, z = p[2];
    const x1 = cy * x + sy * z, z1 = -sy * x + cy * z; return [x1, cp * y - sp * z1, sp * y + cp * z1]; };
  const span = scene.grid ? 1.3 * Math.max(scene.cols, scene.rows) : 1.2;
  const s = zoom * Math.min(cv.width, cv.height) / span, W = cv.width / 2, H = cv.height / 2;
  const items = T.map(t => { const q = t.p.map(rot); let z = 0; q.forEach(v => z += v[2]); return {q: q, z: z / q.length, t: t}; });
  items.sort((a, b) => a.z - b.z);
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, cv.width, cv.height);
  for (const it of items) {
    const q = it.q, u = [q[1][0]-q[0][0], q[1][1]-q[0][1], q[1][2]-q[0][2]], v = [q[2][0]-q[0][0], q[2][1]-q[0][1], q[2][2]-q[0][2]];
    const nx = u[1]*v[2]-u[2]*v[1], ny = u[2]*v[0]-u[0]*v[2], nz = u[0]*v[1]-u[1]*v[0], len = Math.hypot(nx, ny, nz) || 1;
    const light = 0.35 + 0.65 * Math.abs((0.3 * nx + 0.5 * ny + 0.8 * nz) / len / Math.hypot(0.3, 0.5, 0.8));
    const c = it.t.c.map(x => Math.round(x * light));
    ctx.beginPath();
    q.forEach((p, k) => { const X = W + s * p[0], Y = H - s * p[1]; if (k) ctx.lineTo(X, Y); else ctx.moveTo(X, Y); });
    ctx.closePath();
    ctx.globalAlpha = it.t.a; ctx.fillStyle = "rgb(" + c.join(",") + ")"; ctx.fill();
    if (it.t.edge) { ctx.strokeStyle = "rgba(0,0,0,0.6)"; ctx.lineWidth = 0.7; ctx.stroke(); }
    else { ctx.strokeStyle = ctx.fillStyle; ctx.lineWidth = 0.5; ctx.stroke(); }
  }
  ctx.globalAlpha = 1;
  if (scene.grid) {
    ctx.fillStyle = "#000"; ctx.font = "11px sans-serif";
    D.shapes.forEach((sh, i) => { const p = rot([(i % scene.cols) * 1.3, -Math.floor(i / scene.cols) * 1.3 - 0.6, 0]);
      ctx.fillText(sh.name.slice(0, 18), W + s * p[0] - 25, H - s * p[1]); });
  }
  document.getElementById("status").textContent = T.length + " polygons";
}
cv.addEventListener("mousedown", e => { drag = [e.clientX, e.clientY]; });
window.addEventListener("mouseup", () => { drag = null; });
window.addEventListener("mousemove", e => { if (!drag) return;
  yaw += (e.clientX - drag[0]) * 0.01; pitch += (e.clientY - drag[1]) * 0.01; drag = [e.clientX, e.clientY]; draw(); });
cv.addEventListener("wheel", e => { e.preventDefault(); zoom *= Math.exp(-e.deltaY * 0.001); draw(); }, {passive: false});
[pick, meshBox, cubeBox].forEach(el => el.addEventListener("change", draw));
draw();
document.body.setAttribute("data-ready", "1");
console.log("primkit report ready: " + D.shapes.length + " shapes");
})();
"""

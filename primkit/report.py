"""A static HTML report of a collection's abstractions: ``primkit report FOLDER --model M -o report/``.

The report folder holds ``index.html``, one self-contained file (every picture inlined as a WebP
data URI, the 3D scene's library and data inline: it can be mailed alone and opens offline), and
``report.json`` (the same numbers, for machines); with ``images=True`` (``--images``) also each
picture as a PNG in ``images/`` for reuse. The page opens on a grid of shape cards, three to a
row at 1280 px (two screens for 12 shapes): each card one 320-px picture of the shape, switched
between its co-segmentation (one colour per part index on every shape,
:func:`primkit.viz.palette.part_colors`), its cuboids, its mesh and its names, drawn with the camera
convention of :mod:`primkit.viz.render` at one fixed scale so they line up, and its scores and
nearest neighbours. Then the colours explained, the similarity map (t-SNE of
:class:`primkit.embedding.PartDescriptor`, an SVG with each shape's name printed and a hover title);
deformation transfers (each shape onto its nearest other shape); a table of metrics
(:func:`primkit.metrics.score`, each defined beside it, with its convention sentence); and an
interactive 3D scene. A print stylesheet lays the cards two to a row with all their pictures and
leaves the interactive scene out.

When the model has a labeller (:mod:`primkit.segmentation.labeller`; the bundled chair model's
names ``back``, ``seat``, ``legs``, ``arms``), every face is also named on its own
(:func:`primkit.segmentation.labeller.label_elements`): each shape gets a fourth thumbnail coloured
by name (:func:`primkit.viz.palette.label_colors`, the colours of ``segment --semantic --png``),
its card the share of its surface each name holds, ``report.json`` the same shares (``labels``,
and ``label_names`` at the top), and the page a table of the names in use. Without a labeller
the report is as before.

The 3D scene is drawn by plotly.js (:mod:`primkit.viz.web`): each shape's co-segmented surface
beside its cuboids with their edges, a legend entry per part index that toggles that part on every
shape, and the camera convention of every primkit picture (with a labeller, the surface is coloured
by name instead, as the thumbnail by name, and the legend's names come first and toggle that name's
surface on every shape; the cuboids keep their part colours); the plot's height follows the page's
width so that every shape stays in view (:func:`_frame_scene`). The library (from the installed
``plotly`` package) and the data are inlined, so the page opens without a network; the data's JSON
is escaped so that no shape name can end its script element. The meshes are decimated for it with
Open3D's quadric decimation. (Until this page used plotly, a hand-written canvas painter drew the
scene; pyvista's ``export_html`` was not used because it needs trame and loads its JavaScript at
view time.)

Each section degrades on its own: a missing piece (a map needs 3 shapes; the deformation needs
two; a module that fails) is replaced by a one-line note on the page and in ``report.json``, and
the rest is still written.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import data, deformation, embedding, io
from .geometry import voxel_boundary_mesh
from .segmentation import face_labels, resolve_labeller
from .viz import web
from .viz.interop import mesh_from_o3d, mesh_to_o3d
from .viz.palette import label_colors, label_element_colors, part_colors
from .viz.camera import CANONICAL_RADIUS
from .viz.render import cuboid_layer, mesh_layer, render_tiles, segmentation_layer, ThumbnailRenderer, Tile, write_image
from .model.abstractor import Abstractor
from .model.abstraction import abstract_shapes
from .model.parts import default_part_names
from .metrics import score

__all__ = ["ReportShape", "Report", "build_report", "write_report", "page_scene_figure", "partners"]

THUMB = 320  # thumbnail size in pixels
MAP_THUMB = 80  # the similarity map's thumbnails, in pixels (cropped to the shapes)
#: WebP quality of the inlined pictures (flat-shaded renders: 12 chairs' 48 thumbnails take about 0.5 MB)
WEBP_QUALITY = 85
SCENE_FACES = 3000  # triangles per shape in the interactive scene
DEFORMED_SHAPES = 12  # shapes deformed onto their partners in the picture (one row each)


@dataclass
class ReportShape:
    """One shape of the report, in the network's canonical frame (upright, front +X, longest side 1).

    vertices : (n, 3) float; faces : (f, 3) int; cuboids : Cuboids; labels : (f,) int, the
    co-segmentation (primitive index per face); scores : primkit.metrics.AbstractionScores or None;
    named : (f,) int or None, each face's name with the model's labeller (an index into the
    report's ``label_names``, -1 none), None without one.
    """

    name: str
    source: str
    vertices: np.ndarray
    faces: np.ndarray
    cuboids: object
    labels: np.ndarray
    scores: object = None
    named: np.ndarray | None = None

    def label_shares(self, label_names) -> dict[str, float]:
        """``{name: share}``: the share of the surface (by area) each name holds, for the names
        present; empty without :attr:`named`."""
        if self.named is None or not len(self.faces):
            return {}
        v = np.asarray(self.vertices, float)[np.asarray(self.faces, np.int64)]
        area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
        keep = self.named >= 0
        amount = np.bincount(self.named[keep], weights=area[keep], minlength=len(label_names))
        total = max(float(area.sum()), 1e-300)
        return {str(n): float(a / total) for n, a in zip(label_names, amount) if a > 0}


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
            v = v @ np.asarray(result.alignment.rotation, float)
        return v, f, cub


def _named(labeller, vertices, faces, result):
    """``(f,) int``: each face of the shape's canonical mesh named by ``labeller`` (None: None)."""
    if labeller is None:
        return None
    from .geometry import CanonicalFrame
    from .segmentation.labeller import label_elements, mesh_elements

    identity = CanonicalFrame(np.eye(3), np.zeros(3), 1.0)  # the mesh is drawn in the canonical frame already
    return label_elements(labeller, mesh_elements(vertices, faces, identity), result.canonical)


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


def page_scene_figure(shapes, part_names, part_count: int, faces_per_shape: int = SCENE_FACES,
                      label_names=None) -> dict:
    """The plotly figure of the page's 3D scene (:func:`primkit.viz.web.scene_figure`): each
    :class:`ReportShape` decimated to about ``faces_per_shape`` triangles, with its cuboids and its
    surface coloured by part index, or with ``label_names`` (the model's labeller's) by name
    (:attr:`ReportShape.named`), as the thumbnails by name."""
    by_name = bool(label_names) and all(s.named is not None for s in shapes)
    items = []
    for s in shapes:
        v, f, lab = _decimate(s.vertices, s.faces, s.named if by_name else s.labels, faces_per_shape)
        items.append((s.name, v, f, lab, s.cuboids))
    names = list(part_names) + default_part_names(part_count)[len(part_names):]
    figure = web.scene_figure(items, names, count=part_count, label_names=list(label_names) if by_name else None)
    _frame_scene(figure)
    return figure


#: Half the height plotly's orthographic camera shows, in scene-box units, with the camera eye two
#: units from the centre as :func:`primkit.viz.web.scene_figure` puts it (measured: a report of 4
#: chairs drawn 600 px high shows 300 px per box unit, whatever the width).
_ORTHO_HALF_HEIGHT = 1.0


def _frame_scene(figure: dict, margin: float = 0.06) -> None:
    """Make the scene frame everything it holds at any page width, in place.

    plotly's orthographic camera shows a fixed height of the scene box (``2 * _ORTHO_HALF_HEIGHT``
    units) and a width in proportion to the plot's width / height, so a fixed height on a narrow
    page cut off the first and last shapes. Here the axis ranges are widened to every point (a
    cuboid can stick out of its cell), the box is scaled so that the content, seen along the
    camera, fills the height less ``margin``, and ``layout.meta["height_per_width"]`` is the
    plot's height / width at which it also fills the width: the page sets the plot's height from
    its width with it (:data:`_FIT_SCENE`, on load and on every resize).
    """
    from .viz.camera import CAMERA

    scene = figure["layout"]["scene"]
    pts = [np.stack([np.asarray(t["x"], float), np.asarray(t["y"], float), np.asarray(t["z"], float)], axis=1)
           for t in figure["data"] if t.get("type") in ("mesh3d", "scatter3d") and len(t.get("x", ()))]
    pts = np.concatenate(pts) if pts else np.zeros((1, 3))
    pts = pts[np.isfinite(pts).all(axis=1)]  # edge traces separate their lines with None (NaN)
    ranges = np.array([scene[f"{a}axis"]["range"] for a in "xyz"], float)
    lo, hi = np.minimum(ranges[:, 0], pts.min(axis=0)), np.maximum(ranges[:, 1], pts.max(axis=0))
    _, up, right = CAMERA.basis()
    rel = pts - (lo + hi) / 2  # plotly centres the camera on the middle of the box
    half_w = max(float(np.abs(rel @ right).max()), 1e-6)
    half_h = max(float(np.abs(rel @ up).max()), 1e-6)
    scale = _ORTHO_HALF_HEIGHT / (half_h * (1.0 + margin))  # box units per world unit
    for n, a in enumerate("xyz"):
        scene[f"{a}axis"]["range"] = [float(lo[n]), float(hi[n])]
    scene["aspectratio"] = dict(zip("xyz", map(float, scale * (hi - lo))))
    figure["layout"]["meta"] = {**figure["layout"].get("meta", {}), "height_per_width": half_h / half_w}
    # a strip above the plot for plotly's mode bar, and the legend from the plot's top (not over the bar)
    figure["layout"]["margin"] = {**figure["layout"].get("margin", {}), "t": 32}
    figure["layout"]["legend"] = {**figure["layout"].get("legend", {}), "y": 1.0, "yanchor": "top"}


def _thumbnails(shapes, progress: bool, label_names=None) -> dict:
    """``{(i, kind): (THUMB, THUMB, 3) uint8}``: each shape's pictures (:data:`_KINDS`)."""
    from tqdm import tqdm

    frame = np.array([[-0.5] * 3, [0.5] * 3])
    pictures = {}
    with ThumbnailRenderer(size=THUMB, radius=CANONICAL_RADIUS) as thumbs:
        for i, s in enumerate(tqdm(shapes, desc="thumbnails", unit="shape", disable=not progress)):
            layers = {"mesh": [mesh_layer(s.vertices, s.faces)]}
            if s.cuboids.existence.any():
                layers["cuboids"] = [cuboid_layer(s.cuboids)]
                layers["segmentation"] = [segmentation_layer(s.vertices, s.faces, s.labels, s.cuboids.count)]
            if s.named is not None and label_names:
                layers["names"] = [mesh_layer(s.vertices, s.faces, label_element_colors(s.named, len(label_names)))]
            for kind, layer in layers.items():
                pictures[(i, kind)] = thumbs.render(Tile("", layer, frame=frame))
    return pictures


def data_uri(image: np.ndarray, quality: int = WEBP_QUALITY) -> str:
    """A picture as a ``data:image/webp;base64,...`` URI (``image``: (h, w, 3) uint8)."""
    import base64
    from io import BytesIO

    from PIL import Image

    buffer = BytesIO()
    Image.fromarray(np.asarray(image, np.uint8)).save(buffer, format="WEBP", quality=quality, method=6)
    return "data:image/webp;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _similarity(shapes, results, part_names) -> dict:
    if len(shapes) < 3:
        raise ValueError(f"a similarity map needs at least 3 shapes, got {len(shapes)}")
    X = embedding.PartDescriptor(part_names=part_names).fit_transform(results)
    k = min(3, len(shapes) - 1)
    near = embedding.nearest_neighbors(X, k=k)
    coords = embedding.tsne_map(X, random_state=0)
    D = embedding.descriptor_distances(X)
    return {"coords": coords, "neighbors": near, "distances": D}


def partners(distances) -> np.ndarray:
    """Each shape's partner for the deformation: its nearest other shape, ``(s,) int``.

    ``distances`` is the ``(s, s)`` descriptor distance matrix; the diagonal is left out (a shape's
    partner is never itself, even when another shape is an exact copy at distance 0); ties go to
    the lower index."""
    D = np.array(distances, float)
    if D.ndim != 2 or D.shape[0] != D.shape[1] or len(D) < 2:
        raise ValueError(f"`distances` must be (s, s) float with s >= 2, got shape {D.shape}")
    np.fill_diagonal(D, np.inf)
    return np.argmin(D, axis=1)


def _deformation(shapes, similarity) -> dict:
    """Each of the first :data:`DEFORMED_SHAPES` shapes deformed onto its partner (:func:`partners`),
    one row each (source, partner, result in the source's part colours) in ``deformation.png``."""
    if len(shapes) < 2:
        raise ValueError("a deformation needs two shapes")
    if similarity is not None:
        partner = partners(similarity["distances"])
    else:  # no descriptor distances (fewer than 3 shapes): two shapes are each other's partner
        partner = np.array([1 - i if len(shapes) == 2 else (i + 1) % len(shapes) for i in range(len(shapes))])
    tiles, pairs = [], []
    for src in range(min(len(shapes), DEFORMED_SHAPES)):
        a, b = shapes[src], shapes[int(partner[src])]
        d = deformation.deform(a.vertices, a.cuboids, b.cuboids, faces=a.faces)
        q = d.quality(a.faces).to_dict()
        tiles += [Tile(f"{a.name[:16]}", [segmentation_layer(a.vertices, a.faces, a.labels, a.cuboids.count)]),
                  Tile(f"partner {b.name[:14]}", [segmentation_layer(b.vertices, b.faces, b.labels, b.cuboids.count)]),
                  Tile("deformed", [segmentation_layer(d.vertices, a.faces, a.labels, a.cuboids.count)])]
        pairs.append({"source": a.name, "target": b.name,
                      "distance": None if similarity is None else float(similarity["distances"][src, partner[src]]),
                      "paired": list(map(int, d.transfer.paired)), "quality": q})
    image = render_tiles(tiles, columns=6, tile=200, radius=float(np.sqrt(3) / 2))  # two shapes a row
    return {"image": image, "pairs": pairs, "shown": len(pairs), "shapes": len(shapes)}


#: the thumbnails of each shape (``names``: with a labeller only)
_KINDS = ("mesh", "cuboids", "segmentation", "names")


def report_outputs(output, count: int, images: bool = False) -> list[Path]:
    """Every file :func:`build_report` may write into ``output`` for ``count`` shapes (the
    pictures in ``images/`` only with ``images``)."""
    out = Path(output)
    files = [out / "index.html", out / "report.json"]
    if images:
        files += [out / "images" / "deformation.png"]
        files += [out / "images" / f"{i:03d}.{kind}.png" for i in range(count) for kind in _KINDS]
    return files


def build_report(paths, model, output, *, refine: int = 0, align=None, up=None, front=None, overwrite: bool = False,
                 settings=None, model_label: str | None = None,
                 cache_dir=None, workers=None, progress: bool = False, adapt=None,
                 labeller="auto", images: bool = False) -> tuple[Report, list]:
    """Abstract, segment, embed and deform the shapes of ``paths`` with ``model`` and write the report.

    ``settings``: :class:`primkit.data.PrepareSettings`; default the model's. ``up``, ``front``,
    ``align``: the inputs' axes when known, and how orientations are found, as
    :func:`primkit.model.abstraction.abstract_shapes`, as is ``adapt`` (experimental); ``progress``:
    tqdm bars on stderr (off by default). ``labeller``: ``"auto"`` takes the model file's labeller
    when it has one (a model given as an object has none), None names nothing, or a
    :class:`primkit.segmentation.labeller.Labeller`. ``images``: also write each picture as a PNG
    into ``images/`` (the page inlines them either way).
    Returns ``(report, errors)``; ``errors`` has one line per unusable input (the rest goes on).

    ``paths``: files or folders, or a :class:`primkit.data.RunPlan` (:func:`primkit.data.plan_run`),
    whose outputs here (:func:`report_outputs`) are checked before any work.
    """
    if isinstance(paths, data.RunPlan):  # a planned run: nothing overwritten without ``overwrite``, no input
        paths = replace(paths, folder=Path(output), extra=report_outputs(output, len(paths.files), images))
        paths.check(overwrite)
    out = abstract_shapes(paths, model, settings=settings, align=align, up=up, front=front, refine=refine,
                          cache=cache_dir, workers=workers, progress=progress, adapt=adapt)
    if not out.shapes:
        raise ValueError("no usable shapes for the report")
    labeller = resolve_labeller(model, labeller)
    shapes = []
    for a in out:
        v, f, cub = _canonical_mesh(a)
        shapes.append(ReportShape(a.name, str(a.source), v, f, cub, _face_labels(v, f, cub),
                                  score(a.canonical, a.canonical_shape()), _named(labeller, v, f, a.result)))
    meta = {"model": model_label or (str(model) if not isinstance(model, Abstractor) else "given"), "refine": refine,
            "align": align or "default"}
    report = write_report(output, shapes, out.results, out.model.part_names, overwrite=overwrite, progress=progress,
                          meta=meta, label_names=None if labeller is None else list(labeller.names), images=images)
    return report, [str(e) for e in out.errors]


def write_report(output, shapes, results, part_names, *, overwrite: bool = False, progress: bool = False,
                 meta=None, label_names=None, images: bool = False) -> Report:
    """Write ``index.html`` (self-contained) and ``report.json`` into ``output`` (and with
    ``images`` the pictures as PNGs in ``images/``) for shapes already abstracted
    (:class:`ReportShape`, with the :class:`~primkit.model.abstractor.AbstractionResult` s);
    ``label_names``: what the shapes' ``named`` index (the model's labeller's names), or None."""
    out = Path(output)
    page = out / "index.html"
    io.refuse_existing([page] + (report_outputs(out, len(shapes), True)[2:] if images else []), overwrite)
    out.mkdir(parents=True, exist_ok=True)
    notes = {}
    thumbs = _thumbnails(shapes, progress, label_names)
    similarity = deform = None
    try:
        similarity = _similarity(shapes, results, part_names)
    except Exception as exc:  # noqa: BLE001 - one section missing must not lose the report
        notes["similarity"] = f"similarity map not drawn: {type(exc).__name__}: {exc}"
    try:
        deform = _deformation(shapes, similarity)
    except Exception as exc:  # noqa: BLE001
        notes["deformation"] = f"deformation not drawn: {type(exc).__name__}: {exc}"
    if images:
        for (i, kind), image in thumbs.items():
            write_image(out / "images" / f"{i:03d}.{kind}.png", image, overwrite=overwrite)
        if deform is not None:
            deform["path"] = write_image(out / "images" / "deformation.png", deform["image"], overwrite=overwrite)
    count = results[0].canonical.count if results else 20
    scene = page_scene_figure(shapes, part_names, count, label_names=label_names)
    summary = _summary_json(shapes, part_names, similarity, deform, notes, meta or {}, label_names)
    with io.atomic_output(out / "report.json", overwrite=overwrite) as tmp:
        Path(tmp).write_text(json.dumps(summary, indent=1))
    text = _page(shapes, part_names, thumbs, similarity, deform, notes, scene, meta or {}, label_names)
    with io.atomic_output(page, overwrite=overwrite) as tmp:
        Path(tmp).write_text(text, encoding="utf-8", errors="surrogateescape")  # file names that are not UTF-8
    return Report(page, len(shapes), notes)


def _summary_json(shapes, part_names, similarity, deform, notes, meta, label_names=None) -> dict:
    d = {"meta": meta, "notes": notes, "part_names": list(part_names), "shapes": []}
    if label_names:
        d["label_names"] = list(label_names)
    for i, s in enumerate(shapes):
        e = {"name": s.name, "source": s.source, "parts": s.cuboids.present.tolist()}
        if label_names and s.named is not None:
            e["labels"] = s.label_shares(label_names)
        if s.scores is not None:
            e["scores"] = s.scores.to_dict()
        if similarity is not None:
            nb = similarity["neighbors"]
            e["neighbors"] = [{"name": shapes[j].name, "distance": float(x)} for j, x in zip(nb.indices[i], nb.distances[i])]
            e["map"] = similarity["coords"][i].tolist()
        d["shapes"].append(e)
    if deform is not None:
        d["deformation"] = {k: (str(v) if isinstance(v, Path) else v) for k, v in deform.items() if k != "image"}
    return d


def _fmt(x) -> str:
    return "&ndash;" if x is None or not np.isfinite(x) else f"{x:.4f}"


def _short(x) -> str:
    """Three significant digits (coverage and consistency are squared distances, often 1e-5)."""
    return "&ndash;" if x is None or not np.isfinite(x) else f"{x:.3g}"


#: What each score means, one sentence each, shown where the scores are (:mod:`primkit.metrics`)
METRICS = {
    "parts": "the number of cuboids present.",
    "IoU": "volume shared by the cuboids and the shape over the volume of either, on the canonical "
           "grid (1 is a perfect fit).",
    "Chamfer": "mean distance from surface samples of the cuboids to the shape's surface and back "
               "(0 is a perfect fit; in units of the shape's longest side).",
    "coverage": "mean squared distance from the shape's surface samples to the nearest cuboid (zero "
                "inside one): how much of the shape the cuboids leave out (lower is better).",
    "consistency": "area-weighted mean squared distance from the cuboids' surface samples to the "
                   "shape's surface: how far the cuboids reach past the shape (lower is better).",
}

#: the tabs of a card's picture, in their order (the first is shown first)
_VIEWS = (("segmentation", "parts"), ("cuboids", "cuboids"), ("mesh", "mesh"), ("names", "names"))


def _abbr(name: str) -> str:
    return f'<abbr title="{html.escape(METRICS[name])}">{html.escape(name)}</abbr>'


def _card(i, s, part_names, thumbs, uris, similarity, shapes, label_names) -> str:
    esc = html.escape
    views = [(kind, label) for kind, label in _VIEWS if (i, kind) in thumbs]
    tabs = "".join(f'<input type="radio" name="view{i}" id="view{i}-{kind}" aria-label="{label}"'
                   f'{" checked" if n == 0 else ""}>' for n, (kind, label) in enumerate(views))
    labels = "".join(f'<label for="view{i}-{kind}">{label}</label>' for kind, label in views)
    imgs = "".join(f'<img class="{kind}" src="{uris[(i, kind)]}" alt="{kind} of {esc(s.name)}" width="{THUMB}" '
                   f'height="{THUMB}" title="{esc(s.name)}: {label}">' for kind, label in views)
    parts = ", ".join(f"{k} {esc(part_names[k])}" for k in s.cuboids.present)
    lines = [f'<span title="{esc(parts)}">{len(s.cuboids.present)}</span> {_abbr("parts")}']
    sc = s.scores
    if sc is not None:
        lines[0] += f" &middot; {_abbr('IoU')} {_short(sc.iou)} &middot; {_abbr('Chamfer')} {_short(sc.chamfer)}"
        lines.append(f"{_abbr('coverage')} {_short(sc.coverage)} &middot; {_abbr('consistency')} {_short(sc.consistency)}")
    if label_names and s.named is not None:
        lines.append("names: " + ", ".join(f"{esc(n)} {x:.0%}" for n, x in s.label_shares(label_names).items()))
    if similarity is not None:
        nb = similarity["neighbors"]
        lines.append("nearest: " + ", ".join(f'<a href="#shape{j}">{esc(shapes[j].name)}</a> ({x:.2f})'
                                             for j, x in zip(nb.indices[i], nb.distances[i])))
    return (f'<article class="card" id="shape{i}"><div class="views">{tabs}<div class="tabs">{labels}</div>'
            f'<h3 title="{esc(s.source)}">{esc(s.name)}</h3><div class="imgs">{imgs}</div></div>'
            + "".join(f"<p>{line}</p>" for line in lines) + "</article>")


def _map_thumbnails(pictures: dict) -> dict:
    """``{i: data URI}``: the pictures cropped to the square that holds what any of them shows (one
    crop for all, so they keep one scale) and shrunk to twice :data:`MAP_THUMB` pixels."""
    from PIL import Image

    if not pictures:
        return {}
    ink = np.zeros(next(iter(pictures.values())).shape[:2], bool)
    for image in pictures.values():
        ink |= (np.asarray(image, int) < 250).any(axis=-1)
    rows, cols = np.nonzero(ink) if ink.any() else (np.array([0, ink.shape[0] - 1]), np.array([0, ink.shape[1] - 1]))
    side = int(max(rows.max() - rows.min(), cols.max() - cols.min())) + 5
    top = int(np.clip((rows.min() + rows.max() - side) // 2, 0, ink.shape[0] - side))
    left = int(np.clip((cols.min() + cols.max() - side) // 2, 0, ink.shape[1] - side))
    size = (2 * MAP_THUMB, 2 * MAP_THUMB)
    return {i: data_uri(np.asarray(Image.fromarray(np.asarray(image, np.uint8)[top:top + side, left:left + side])
                                   .resize(size, Image.LANCZOS))) for i, image in pictures.items()}


def _map_svg(coords, shapes, uris, neighbors, width: int = 960, height: int = 620) -> str:
    """The t-SNE map as inline SVG: each shape's cuboids at its position, its name printed under
    it, and a hover title (name, nearest shapes); a frame with the two t-SNE axes."""
    esc = html.escape
    pad, size = 56, MAP_THUMB
    xy = np.asarray(coords, float)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = np.where(hi - lo > 1e-12, hi - lo, 1.0)
    x = pad + size / 2 + (xy[:, 0] - lo[0]) / span[0] * (width - 2 * pad - size)
    y = height - pad - size / 2 - (xy[:, 1] - lo[1]) / span[1] * (height - 2 * pad - size - 14)
    pictures, labels = [], []  # the names drawn over every picture, so none hides one
    for i, s in enumerate(shapes):
        near = ", ".join(shapes[j].name for j in neighbors.indices[i])
        title = f"<title>{esc(s.name)} (nearest: {esc(near)})</title>"
        picture = (f'<image href="{uris[i]}" x="{x[i] - size / 2:.1f}" y="{y[i] - size / 2:.1f}" width="{size}" '
                   f'height="{size}"/>' if uris.get(i) else f'<circle cx="{x[i]:.1f}" cy="{y[i]:.1f}" r="5"/>')
        pictures.append(f'<a href="#shape{i}"><g class="pt">{title}{picture}</g></a>')
        labels.append(f'<a href="#shape{i}"><text x="{x[i]:.1f}" y="{y[i] + size / 2 + 4:.1f}">{title}{esc(s.name)}'
                      f'</text></a>')
    items = pictures + labels
    frame = (f'<rect x="{pad / 2}" y="{pad / 2}" width="{width - pad}" height="{height - pad}" class="frame"/>'
             f'<text class="axis" x="{width / 2}" y="{height - 8}">t-SNE 1</text>'
             f'<text class="axis" transform="translate(16 {height / 2}) rotate(-90)">t-SNE 2</text>')
    return (f'<svg class="map" viewBox="0 0 {width} {height}" width="{width}" height="{height}" role="img" '
            f'aria-label="t-SNE map of the shapes">{frame}{"".join(items)}</svg>')


def _colours(shapes, part_names, label_names) -> str:
    """The one explanation of the page's colours: each part index in use, and the labeller's names."""
    esc = html.escape
    present = np.array([s.cuboids.existence for s in shapes]).mean(0)
    colours = part_colors(len(present))
    sw = lambda c: f"<span class='sw' style='background:rgb{tuple(int(v) for v in c)}'></span>"  # noqa: E731
    parts = "".join(f"<li>{sw(colours[k])}{k} {esc(part_names[k])} <small>({present[k]:.0%} of the shapes)</small></li>"
                    for k in np.flatnonzero(present))
    text = ("<p>One colour per part index, the same on every shape, in the <b>parts</b> and <b>cuboids</b> "
            "pictures, the similarity map and the 3D scene: primitive <i>k</i> is the same part on every shape "
            "(matplotlib's tab20, colour <i>k</i>; indices sharing a name are separate slots).</p>"
            f"<ul class='legend'>{parts}</ul>")
    if label_names:
        text += ("<p>The <b>names</b> pictures (and the 3D scene's surfaces) colour each face by the name the "
                 "model's labeller gives it on its own, whichever cuboid it lies in; these colours belong to the "
                 "names, not to part indices:</p>")
    return text


def _page(shapes, part_names, thumbs, similarity, deform, notes, scene, meta, label_names=None) -> str:
    esc = html.escape
    uris = {key: data_uri(image) for key, image in thumbs.items()}
    cards = "".join(_card(i, s, part_names, thumbs, uris, similarity, shapes, label_names) for i, s in enumerate(shapes))
    rows = []
    conv = ""
    for s in shapes:
        sc = s.scores
        if sc is None:
            continue
        conv = sc.convention
        rows.append(f"<tr><td><a href='#shape{shapes.index(s)}'>{esc(s.name)}</a></td><td>{sc.parts}</td>"
                    f"<td>{_short(sc.iou)}</td><td>{_short(sc.chamfer)}</td><td>{_short(sc.coverage)}</td>"
                    f"<td>{_short(sc.consistency)}</td></tr>")
    if rows:
        vals = np.array([[s.scores.parts, s.scores.iou, s.scores.chamfer, s.scores.coverage, s.scores.consistency]
                         for s in shapes if s.scores is not None], float)
        mean = vals.mean(0)
        rows.append(f"<tr class='mean'><td>mean</td><td>{mean[0]:.1f}</td>" + "".join(f"<td>{_short(x)}</td>" for x in mean[1:])
                    + "</tr>")
    definitions = "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>" for k, v in METRICS.items())
    if similarity is not None:
        small = _map_thumbnails({i: thumbs[(i, "cuboids")] for i in range(len(shapes)) if (i, "cuboids") in thumbs})
        sim = ("<p>Each shape's cuboids at its place on a t-SNE map of the part descriptors (all parts: the size, "
               "position, orientation and presence of each, <code>primkit.embedding.PartDescriptor</code>): shapes "
               "close on the map have alike parts. t-SNE keeps neighbourhoods, not distances, so its axes have no "
               "units. Hover a shape for its nearest shapes; click it for its card.</p>"
               + _map_svg(similarity["coords"], shapes, small, similarity["neighbors"]))
    else:
        sim = f"<p class='note'>{esc(notes.get('similarity', ''))}</p>"
    if deform is not None:
        lines = "".join(f"<li>{esc(p['source'])} onto {esc(p['target'])}"
                        + ("" if p["distance"] is None else f" (distance {p['distance']:.2f})")
                        + f": {len(p['paired'])} parts paired by index, flipped triangles {p['quality']['flipped']:.2%}</li>"
                        for p in deform["pairs"])
        more = (f" The first {deform['shown']} of {deform['shapes']} shapes are shown." if deform["shown"] < deform["shapes"]
                else "")
        dfm = (f'<p>Each shape deformed onto the parts of its partner, its nearest other shape by the part '
               f'descriptors (the similarity map\'s distance), so that the transfer is between shapes alike: the shape, '
               f'its partner and the result, in the parts\' colours, two shapes a row.{more}</p>'
               f'<img src="{data_uri(deform["image"])}" alt="deformation" class="wide"><ul>{lines}</ul>')
    else:
        dfm = f"<p class='note'>{esc(notes.get('deformation', ''))}</p>"
    triangles = sum(len(t["i"]) for t in scene["data"] if t["type"] == "mesh3d")
    by_name = any("label" in t.get("meta", {}) for t in scene["data"])
    # the plot's height follows its width (see _frame_scene), so every shape stays in view
    ready = (_FIT_SCENE + 'fit().then(function(){ '
             'document.getElementById("status").textContent = gd.data.length + " traces, " + ' + json.dumps(triangles)
             + ' + " triangles"; document.body.setAttribute("data-ready", "1"); '
             f'console.log("primkit report ready: {len(shapes)} shapes"); }});')
    return _TEMPLATE.format(
        title=f"primkit report: {len(shapes)} shapes", meta=esc(json.dumps(meta)), cards=cards, thumb=THUMB,
        rows="".join(rows), convention=esc(conv), definitions=definitions, colours=_colours(shapes, part_names, label_names),
        names_table=_names_table(shapes, label_names), similarity=sim, deformation=dfm,
        views=", ".join(label for kind, label in _VIEWS if kind != "names" or label_names),
        scene_colours=("its names (the model's labeller, the colours of the pictures by name), beside its cuboids in "
                       "the colours of their parts" if by_name else "the colours of its parts, beside its cuboids"),
        toggle="a name or a part" if by_name else "a part",
        scene=web.figure_div(scene, "scene"), scene_script=web.figure_script("scene", ready=ready))


def _names_table(shapes, label_names) -> str:
    """The labeller's names in use: their colour, the shapes holding each, the mean share of the
    surface."""
    if not label_names:
        return ""
    shares = [s.label_shares(label_names) for s in shapes if s.named is not None]
    if not shares:
        return ""
    colours = label_colors(len(label_names))
    rows = "".join(f"<tr><td><span class='sw' style='background:rgb{tuple(int(c) for c in colours[j])}'></span>"
                   f"{html.escape(n)}</td><td>{np.mean([n in x for x in shares]):.0%}</td>"
                   f"<td>{np.mean([x.get(n, 0.0) for x in shares]):.0%}</td></tr>"
                   for j, n in enumerate(label_names))
    return ("<table><caption>Names (the model's labeller: each face named on its own)</caption>"
            "<tr><th>name</th><th>on shapes</th><th>mean share of the surface</th></tr>" + rows + "</table>")


#: JavaScript run once the scene is drawn (``gd`` the plot, ``F`` its figure): the plot area's height
#: set from its width by ``layout.meta.height_per_width`` (:func:`_frame_scene`), within 260-1000 px;
#: below 260 px the scene box shrinks instead, so the width stays in view and the legend beside it
#: keeps room. Again on every resize of the window.
_FIT_SCENE = (
    "const base = JSON.parse(JSON.stringify(gd.layout.scene.aspectratio)); "
    "const fit = function(){ "
    "const size = gd._fullLayout._size, want = size.w * F.layout.meta.height_per_width; "
    "const h = Math.min(1000, Math.max(260, want)), shrink = Math.min(1, want / h); "
    "const update = {height: Math.round(h + size.t + size.b)}; "
    "for (const a of ['x', 'y', 'z']) update['scene.aspectratio.' + a] = base[a] * shrink; "
    "return Plotly.relayout(gd, update); }; "
    "let pending = null; "
    "window.addEventListener('resize', function(){ clearTimeout(pending); pending = setTimeout(fit, 150); }); "
)

_TEMPLATE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
body{{font-family:system-ui,sans-serif;margin:10px 16px;color:#222;font-size:14px;line-height:1.35}}
h1{{font-size:18px;margin:0;display:inline-block;margin-right:24px}} h2{{font-size:17px;border-bottom:1px solid #ccc;margin:22px 0 8px}}
header p{{margin:2px 0 6px;white-space:nowrap;overflow:hidden;text-overflow:ellipsis}} nav{{display:inline-block}}
nav a{{margin-right:12px}} a{{color:#1f5fa8}}
.cards{{display:grid;grid-template-columns:repeat(auto-fill,minmax({thumb}px,1fr));gap:10px;max-width:1240px}}
.card{{border:1px solid #ddd;border-radius:4px;padding:3px 8px 4px;background:#fff}}
.card h3{{position:absolute;top:0;right:2px;max-width:45%;margin:0;font-size:14px;white-space:nowrap;overflow:hidden;
text-overflow:ellipsis;z-index:1}} .card p{{font-size:12px;margin:0;color:#333;white-space:nowrap;overflow:hidden;text-overflow:ellipsis}}
.views{{position:relative;width:{thumb}px;height:{thumb}px;margin:1px auto}}
.views input{{position:absolute;opacity:0;pointer-events:none}}
.tabs{{position:absolute;top:2px;left:2px;z-index:1;font-size:11px}}
.tabs label{{display:inline-block;padding:0 5px;margin-right:2px;border:1px solid #bbb;border-radius:3px;background:#f6f6f6;cursor:pointer}}
.imgs img{{display:none;width:{thumb}px;height:{thumb}px}}
.views input:nth-of-type(1):checked~.imgs img:nth-of-type(1),.views input:nth-of-type(2):checked~.imgs img:nth-of-type(2),
.views input:nth-of-type(3):checked~.imgs img:nth-of-type(3),.views input:nth-of-type(4):checked~.imgs img:nth-of-type(4){{display:block}}
.views input:nth-of-type(1):checked~.tabs label:nth-of-type(1),.views input:nth-of-type(2):checked~.tabs label:nth-of-type(2),
.views input:nth-of-type(3):checked~.tabs label:nth-of-type(3),.views input:nth-of-type(4):checked~.tabs label:nth-of-type(4){{background:#333;color:#fff}}
.views input:focus-visible~.tabs{{outline:2px solid #1f5fa8}}
abbr{{text-decoration:underline dotted;cursor:help}} dl.defs{{display:grid;grid-template-columns:max-content 1fr;gap:2px 12px;margin:6px 0}}
dl.defs dt{{font-weight:bold}} dl.defs dd{{margin:0}}
table{{border-collapse:collapse;font-size:13px}} td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}
td:first-child,th:first-child{{text-align:left}} tr.mean{{font-weight:bold}}
.sw{{display:inline-block;width:13px;height:13px;margin-right:5px;vertical-align:-2px;border:1px solid #0002}}
ul.legend{{columns:4 180px;list-style:none;padding:0;margin:4px 0}} ul.legend li{{break-inside:avoid}}
svg.map{{max-width:100%;height:auto;border:0;font-size:12px}} svg.map .frame{{fill:none;stroke:#bbb}}
svg.map text{{text-anchor:middle;fill:#222;paint-order:stroke;stroke:#fff;stroke-width:3px}} svg.map .axis{{fill:#666;font-size:13px}} svg.map a:hover text{{font-weight:bold}}
img.wide{{max-width:1200px;width:100%}} .note{{color:#a33}}
#scene{{border:1px solid #ccc;max-width:1240px}} code{{font-size:12px}}
@media print{{
  body{{margin:0;font-size:10pt}} nav,.tabs,.noprint,#scene-section{{display:none}}
  h2{{break-after:avoid}} .cards{{grid-template-columns:repeat(2,1fr);max-width:none}}
  .card{{break-inside:avoid;border-color:#999}} .views{{width:auto;height:auto}} .card h3{{position:static;max-width:none}}
  .imgs{{display:grid;grid-template-columns:repeat(4,1fr);gap:2px}} .imgs img{{display:block!important;width:100%;height:auto}}
  svg.map,img.wide{{break-inside:avoid}} a{{color:inherit;text-decoration:none}} abbr{{text-decoration:none}}
}}
</style></head><body data-ready="0">
<header><h1>{title}</h1><nav><a href="#colours">Colours</a><a href="#similarity">Similarity map</a><a
href="#deformation">Deformation</a><a href="#metrics">Metrics</a><a href="#scene-section">3D scene</a></nav>
<p>primkit (after Tulsiani et al., CVPR 2017): one network explains every shape with cuboids, so primitive <i>k</i>
is the same part everywhere, in <a href="#colours">one colour</a>. Canonical frame, one scale.</p></header>
<main>
<section id="shapes"><div class="cards">{cards}</div>
<p>Each card: the shape's pictures ({views}: click to switch; all four in print), its scores and its nearest
shapes by the part descriptors (distance). <span class="noprint">Hover a score's name for its definition;</span>
<a href="#metrics">Metrics</a> defines each.</p>
<dl class="defs">{definitions}</dl></section>
<section id="colours"><h2>Colours</h2>{colours}{names_table}</section>
<section id="similarity"><h2>Similarity map</h2>{similarity}</section>
<section id="deformation"><h2>Deformation</h2>{deformation}</section>
<section id="metrics"><h2>Metrics</h2>
<dl class="defs">{definitions}</dl>
<table><tr><th>shape</th><th>parts</th><th>IoU</th><th>Chamfer</th><th>coverage</th><th>consistency</th></tr>{rows}</table>
<p>{convention}. All scores in the canonical frame (longest side 1); coverage and consistency are the losses the
abstractor is trained on (squared distances). Settings: <code>{meta}</code>.</p></section>
<section id="scene-section"><h2>Interactive 3D scene</h2>
<p>Each shape's surface in {scene_colours}. Drag to turn, scroll to zoom,
click {toggle} in the legend to hide it on every shape. <span id="status"></span></p>
{scene}</section>
</main>
{scene_script}</body></html>
"""

"""What ``segment`` writes, and under which names: each shape's files (:func:`shape_outputs`), the
summaries of each kind of shape (:func:`summary_name`, :func:`write_summary`), the label codes
(``labels.csv``, :func:`label_codes_text`), and the plan of a segmentation run over a collection
(:func:`plan_segmentation`: the files, their names, the shard, what a cut run finished, the outputs).
"""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import data, io, parallel
from .meshes import Segmentation
from .points import PointSegmentation
from .voxels import VoxelSegmentation

__all__ = ["summary_header", "read_summary", "write_summary", "summary_name", "shape_kind", "shape_outputs",
           "label_codes_text", "written_before", "plan_segmentation", "write_picture", "legend_strip", "SUMMARIES",
           "EVALUATIONS"]

#: the summary file of each kind of shape
SUMMARIES = {"mesh": "summary.csv", "voxels": "summary-voxels.csv", "points": "summary-points.csv"}
#: the labels file of each kind of shape (after its name)
_LABEL_SUFFIXES = {"mesh": ".seg", "voxels": ".voxlabels.npy", "points": ".parts.npy"}


def summary_name(kind: str, shard) -> str:
    """The summary file of a kind of shape; a shard's own (``summary.shard-2-of-8.csv``: its shapes' rows)."""
    name = SUMMARIES[kind]
    return name if shard is None else name.replace(".csv", f".shard-{shard[0]}-of-{shard[1]}.csv")


def shape_kind(path) -> str:
    """``"mesh"``, ``"voxels"`` or ``"points"`` for a shape file, from its suffix (and for a PLY, from
    its header: a PLY without faces is a point cloud), without reading its geometry."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in io.VOXEL_SUFFIXES:
        return "voxels"
    if suffix in (".xyz", ".npy"):
        return "points"
    if suffix == ".ply":
        try:
            with open(path, "rb") as fh:
                for line in fh.read(1 << 16).split(b"\n"):
                    words = line.split()
                    if words[:2] == [b"element", b"face"] and len(words) > 2:
                        return "mesh" if words[2] != b"0" else "points"
                    if line.strip() == b"end_header":
                        return "points"
        except OSError:
            pass  # reported when it is read
    return "mesh"


def shape_outputs(out, name: str, kind: str) -> list[Path]:
    """A shape's three files, in the order they are written (its ``.cuboids.json`` last)."""
    out = Path(out)
    return [out / f"{name}{_LABEL_SUFFIXES[kind]}", out / f"{name}.parts.ply", out / f"{name}.cuboids.json"]


def label_codes_text(part_names, labeller=None) -> str:
    """``labels.csv``: the 1-based code of each of the model's part names (``--semantic``): its
    labeller's names when it has one, else the names of its part indices."""
    from ..model.parts import label_codes

    names = list(labeller.names) if labeller is not None else label_codes(part_names)[0]
    return "code,name\n" + "".join(f"{i + 1},{n}\n" for i, n in enumerate(names))


def written_before(path, codes: str, expected: bool, overwrite: bool) -> bool:
    """Whether ``labels.csv`` is there with these very codes, written by another shard of the run or
    by the run that ``skip_done`` goes on with (``expected``: they are the model's, the same for
    every shard: not a clash). Never otherwise, nor with ``overwrite``."""
    if not expected or overwrite:
        return False
    try:
        return Path(path).read_text() == codes
    except (OSError, UnicodeDecodeError):
        return False


def plan_segmentation(inputs, folder, part_names, *, shard=None, skip_done: bool = False, codes: str | None = None,
                      evaluations=(), picture=None, reads=(), overwrite: bool = False) -> data.RunPlan:
    """The plan of a segmentation run (:func:`primkit.data.plan_run`): per shape its labels (``.seg``;
    ``.voxlabels.npy`` for a voxel grid, ``.parts.npy`` for a point cloud), ``.parts.ply`` and
    ``.cuboids.json``; the summaries, ``labels.csv`` (``codes``, unless another shard or the cut run
    wrote these very codes), the ``evaluations`` and the ``picture``.

    ``skip_done``: done means its three files exist and its row is in this shard's summary of its
    kind, written by the same model (same columns, ``part_names``): a run is cut after the shapes'
    labels and meshes, before the summaries, or before the cuboids."""
    folder = Path(folder)
    shard = parallel.parse_shard(shard) if isinstance(shard, str) else shard
    kinds: dict = {}

    def outputs(name, path):
        kinds[name] = shape_kind(path)
        return shape_outputs(folder, name, kinds[name])

    summaries: dict = {}

    def finished(name, paths):
        kind = kinds[name]
        if kind not in summaries:
            header, rows = read_summary(folder / summary_name(kind, shard))
            summaries[kind] = rows if header == summary_header(kind, part_names) else {}
        return all(p.is_file() for p in paths) and name in summaries[kind]

    plan = data.plan_run(inputs, folder, outputs=outputs, shard=shard, skip_done=skip_done, finished=finished,
                         reads=reads)
    present = {kinds[plan.names[i]] for i in plan.todo}
    extra = [folder / summary_name(kind, shard) for kind in SUMMARIES if kind in present and not skip_done]
    if codes is not None and not written_before(folder / "labels.csv", codes, shard is not None or skip_done, overwrite):
        extra.append(folder / "labels.csv")
    extra += [Path(p) for p in evaluations] + ([io.check_suffix(picture, ".png", "a picture")] if picture is not None else [])
    return data.RunPlan(**{**plan.__dict__, "extra": extra})


def summary_header(kind: str, part_names) -> list[str]:
    """The columns of a summary (:func:`write_summary`) of shapes of ``kind`` (``"mesh"``,
    ``"voxels"`` or ``"points"``) segmented by a model with these part names."""
    element = {"mesh": "faces", "voxels": "voxels", "points": "points"}[kind]
    unit = "area" if kind == "mesh" else element
    return ["shape", element, "parts_present", f"{unit}_total"] + [f"{unit}_{k}_{n}" for k, n in enumerate(part_names)]


def read_summary(path) -> tuple[list[str], dict[str, list[str]]]:
    """A summary written by :func:`write_summary`: its header and its rows by shape name (the row
    without the name). An absent or unreadable file reads as no columns and no rows."""
    try:
        with open(path, newline="", encoding="utf-8", errors="surrogateescape") as fh:  # names as written
            table = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error):
        return [], {}
    if not table:
        return [], {}
    return table[0], {row[0]: row[1:] for row in table[1:] if row}


def write_summary(segmentations, path, *, overwrite: bool = False, keep=None, order=None) -> Path:
    """One CSV row per shape: its elements, the parts present (indices holding any), and how much
    of the shape each part index holds, with the same columns for the whole collection.

    Meshes (:class:`Segmentation`): ``faces``, then surface areas (``area_total``,
    ``area_<k>_<name>``). Voxel grids (:class:`VoxelSegmentation`): ``voxels``, then voxel counts
    (``voxels_<k>_<name>``). Point clouds (:class:`PointSegmentation`): ``points``, then point
    counts. One kind per file.

    ``keep``: rows of an earlier summary of the same columns (:func:`read_summary`), written with
    these (``primkit segment --skip-done``: the shapes it left as they were); ``order``: shape
    names in the order the rows are written (by default the kept rows, then the new ones).
    """
    if not segmentations:
        raise ValueError("no segmentations to summarise")
    kinds = {type(s) for s in segmentations}
    if len(kinds) > 1:
        raise ValueError("write meshes, voxel grids and point clouds into separate summaries")
    voxels = isinstance(segmentations[0], (VoxelSegmentation, PointSegmentation))  # counted, not measured
    names = segmentations[0].part_names
    count = segmentations[0].cuboids.count
    kind = {VoxelSegmentation: "voxels", PointSegmentation: "points"}.get(type(segmentations[0]), "mesh")
    header = summary_header(kind, names[:count])
    rows = dict(keep or {})
    for s in segmentations:
        amounts = s.part_sizes() if voxels else s.part_areas()
        elements = len(s.points) if kind == "points" else int(np.count_nonzero(s.labels >= 0)) if voxels \
            else len(s.faces)
        present = " ".join(str(k) for k in np.flatnonzero(amounts > 0))
        rows[s.name] = [elements, present, f"{amounts.sum():.6g}"] + [f"{a:.6g}" for a in amounts]
    if order is not None:
        position = {name: i for i, name in enumerate(order)}
        rows = dict(sorted(rows.items(), key=lambda item: position.get(item[0], len(position))))
    with io.atomic_output(path, overwrite=overwrite) as tmp:
        # a name from a file name that is not UTF-8 keeps its bytes (surrogateescape), as the file's
        with open(tmp, "w", newline="", encoding="utf-8", errors="surrogateescape") as fh:
            writer = csv.writer(fh)
            writer.writerow(header)
            for name, row in rows.items():
                writer.writerow([name] + row)
    return Path(path)


#: the evaluations a run writes into its folder: of meshes, and of voxel grids
EVALUATIONS = {"meshes": "evaluation.json", "voxels": "evaluation-voxels.json"}


def write_picture(segmentations, path, limit: int = 16, *, semantic: bool = False) -> Path:
    """Each shape beside its co-segmentation (a point cloud as points), the first ``limit`` shapes,
    into a PNG file.

    By default every element takes its part index's colour (:func:`primkit.viz.palette.part_colors`,
    the cuboids' colours). With ``semantic`` (``segment --semantic --png``) it takes its *name's*
    colour (:func:`primkit.viz.palette.label_colors`, by the name's code in ``labels.csv``: the
    labeller's name of each element when the model has one, else its part index's name; grey: no
    name), and a legend of the names runs under the tiles.
    """
    from ..viz.palette import UNLABELLED, label_colors, part_colors
    from ..viz.render import Tile, mesh_layer, points_layer, render_tiles

    names = None
    tiles = []
    for s in segmentations[:limit]:
        if semantic:
            names, codes = s.semantic_labels()
            table = np.vstack([label_colors(max(len(names), 1)), np.array([UNLABELLED], np.uint8)])
            index = np.where(codes > 0, codes - 1, -1)  # into names; -1: none (grey, the table's last row)
        else:
            index = s.face_labels if isinstance(s, Segmentation) else s.labels
            table = np.vstack([part_colors(s.cuboids.count), [[200, 200, 200]]]).astype(np.uint8)
        if isinstance(s, PointSegmentation):
            plain = points_layer(s.points, point_size=2.0)
            tiles += [Tile(s.name, [plain]), Tile("", [points_layer(s.points, table[index], point_size=2.0)],
                                                  frame=plain.bounds())]
            continue
        if isinstance(s, VoxelSegmentation):  # the voxels' surface split by name (or by index)
            v, f, labels = replace(s, labels=np.asarray(index, np.int64)).boundary_mesh()
        else:
            v, f, labels = s.vertices, s.faces, index
        plain = mesh_layer(v, f)
        tiles += [Tile(s.name, [plain]), Tile("", [mesh_layer(v, f, table[labels])], frame=plain.bounds())]
    image = render_tiles(tiles, columns=2 * min(4, max(1, len(tiles) // 2)), tile=260)
    if names:
        image = np.vstack([image, legend_strip(names, label_colors(len(names)), image.shape[1])])
    with io.atomic_output(path, overwrite=True) as tmp:
        from PIL import Image

        Image.fromarray(image).save(tmp, format="PNG", optimize=True)
    return Path(path)


def legend_strip(names, colors, width: int, height: int = 28) -> np.ndarray:
    """``(height, width, 3) uint8``: a white strip with a swatch (``colors`` (k, 3) uint8) and the
    name of each label, left to right (Pillow's default font), for the foot of a picture."""
    from PIL import Image, ImageDraw, ImageFont

    strip = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(strip)
    try:
        font = ImageFont.load_default(size=height // 2)
    except TypeError:  # Pillow before 10.1: the small bitmap font only
        font = ImageFont.load_default()
    x, box = 8, height - 10
    for name, colour in zip(names, np.asarray(colors, np.uint8)):
        draw.rectangle([x, 5, x + box, 5 + box], fill=tuple(int(c) for c in colour), outline=(0, 0, 0))
        draw.text((x + box + 6, height // 2), str(name), fill=(0, 0, 0), font=font, anchor="lm")
        x += box + 18 + int(draw.textlength(str(name), font=font))
    return np.asarray(strip)

"""A chair validation that predicts unseen shapes: real chairs grouped by structure, and procedural
stools, bar stools and swivel chairs, each group reported on its own. Choose models, recipes and
flags on these figures; never on the PartNet test part or the COSEG chairs.

Usage::

    python scripts/chair_validation.py [--model PATH] [--adapt [only]] [--json F] [--per-group N]

Every run uses ``primkit segment``'s default flags (no axes declared, no refinement, the graph cut).

**PartNet chairs.** The validation part of ``scripts/partnet_chairs.py``'s split (never its test
part), plus the chairs of ``../shared/data/partnet_chair_boxes`` with no back label (stools) that
lie in neither part of that split (the one in the test part stays out). They are segmented as one
collection; the paper's protocol maps each index to the label holding most of its voxels over all of
them (one mapping: an index means one part on every chair), and each group is scored with that
mapping. Groups are read from the PartNet voxel labels (:func:`chair_structure`, ``lab[x, y, z]``,
+y up; 0 back, 1 seat, 2 legs/base, 3 arm) and overlap:

* ``armchairs``: arm voxels present;
* ``pedestal``: a pedestal or base instead of legs (armchairs included; definition below);
* ``four-legged``: three or more separate legs, no arms;
* ``other base``: neither, no arms (runners, sleds, side panels, cantilevers);
* ``no back``: no back voxels (stools; in this group only).

The base (:func:`base_kind`) is read from the legs/base voxels between the floor (the lowest
occupied layer) and the seat's layer (the layer holding the most seat voxels), on the horizontal
layers of the middle half of that height (25% to 75%). On each layer the voxels are split into
8-connected blobs (seen from above) and the median count over the layers is taken. **Pedestal**:
one blob, whose centre lies within a third of the seat's size from the seat's centre along both
horizontal axes (the seat's size and centre: the bounding rectangle of its layer's seat voxels;
the median offset over the layers): a column, a cone, a box or a panel under the middle of the
seat. **Legs**: three blobs or more. **Other**: anything else (two blobs: runners, sleds, side
panels; one blob at the seat's edge: cantilevers; no legs/base voxels under the seat: sofas and
chairs whose seat reaches the floor). The middle layers are used rather than the floor because at
the floor a star base's casters are separate blobs and a four-legged chair's low stretchers join
its legs into one; between 25% and 75% of the height a stretcher takes a layer or two and the median
ignores it. ``--draw PNG`` draws chairs of each kind, to check the rule by eye.

Per group: chairs; mean per-chair IoU of back, seat and legs under the paper's protocol (1 when a
label is absent from both) and their mean; arm detection (a chair *has* arms when an index mapped
to arms holds a voxel): true and false positives, missed, F1 (none where no chair has arms); for chairs without a back label, the
share with no back index either; cuboids per chair.

**Procedural shapes** (:mod:`primkit.synthetic`, fixed seeds below, each group segmented as its own
collection, written as meshes): ``stools`` (:func:`primkit.synthetic.stool`: three or four legs or a
column on a round foot, low to bar height), ``bar stools`` (the same with legs of 0.68-0.80 against
a 0.32-0.46 seat), ``swivel chairs`` (:func:`primkit.synthetic.chair` with ``swivel=True``: a
column on a five-spoke star base). The model's back and seat indices are its stored names (``back``,
``seat``) when it names both; otherwise the indices the PartNet chairs' mapping gives those labels.
Per group: the share of shapes on which a back index holds a face, the share of the seat's area on
a seat index (mean over shapes), and cuboids per shape.

``--adapt``: every collection is segmented twice, as given and with ``primkit segment --adapt``
(the model adapted to that collection first, without labels); the adapted procedural runs read
indices through the adapted PartNet run's mapping when the model names no seat or back.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent))

from partnet_chairs import CHAIRS, PARTNET, score, segment_chairs, split  # noqa: E402

from primkit import data, io, synthetic  # noqa: E402
from primkit.segmentation import Segmenter  # noqa: E402

BACK, SEAT, LEGS, ARMS = 0, 1, 2, 3  # the PartNet voxel labels
MEAN_OVER = ("back", "seat", "legs")
PEDESTAL_OFFSET = 1 / 3  # a pedestal's centre: at most this share of the seat's size from the seat's centre
GROUPS = ("all", "armchairs", "pedestal", "four-legged", "other base", "no back")

#: The procedural groups: fixed seeds, so every model is measured on the same shapes.
PROCEDURAL_COUNT = 30
STOOL_SEED = 48_100  # synthetic.generate("stool", 30, seed=48_100)
BAR_STOOL_SEED = 48_200  # stool(48_200 + i, leg_length=0.68 + 0.12 * i / 29)
SWIVEL_SEED = 48_300  # chair(48_300 + i, swivel=True)


# ---------------------------------------------------------------------------------------------
# Structure from the PartNet voxel labels


@dataclass(frozen=True)
class ChairStructure:
    """What a chair is made of, read from its voxel labels: ``back`` and ``arms`` (any voxel of the
    label), ``base`` (:func:`base_kind`: ``"legs"``, ``"pedestal"`` or ``"other"``) and ``blobs``
    (the median number of legs/base blobs on the middle layers; 0 when there is nothing there)."""

    back: bool
    arms: bool
    base: str
    blobs: int


def base_kind(labels) -> tuple[str, int]:
    """``(kind, blobs)`` of a chair's base from its voxel labels (see the module notes).

    labels : (X, Y, Z) int, +Y up, -1 empty, 1 seat, 2 legs/base  ->  ("legs" | "pedestal" | "other", int)
    """
    labels = np.asarray(labels)
    if labels.ndim != 3:
        raise ValueError("`labels` must be (X, Y, Z) int")
    occupied = np.argwhere(labels >= 0)
    seat = np.argwhere(labels == SEAT)
    if not len(occupied) or not len(seat):
        return "other", 0
    floor = int(occupied[:, 1].min())
    level = int(np.argmax(np.bincount(seat[:, 1])))  # the seat's layer: the most seat voxels
    on_level = np.argwhere(labels[:, level, :] == SEAT)
    lo, hi = on_level.min(axis=0), on_level.max(axis=0) + 1
    centre, size = (lo + hi) / 2, hi - lo  # the seat seen from above: (x, z) voxel coordinates
    height = level - floor
    layers = [y for y in range(floor + int(np.floor(0.25 * height)), floor + int(np.ceil(0.75 * height)) + 1)
              if y < level]
    counts, offsets = [], []
    for y in layers:
        base = labels[:, y, :] == LEGS
        _, n = ndimage.label(base, structure=np.ones((3, 3), int))
        if n:
            counts.append(n)
        if n == 1:
            offsets.append(np.abs(np.argwhere(base).mean(axis=0) + 0.5 - centre) / size)
    if not counts:
        return "other", 0
    blobs = int(np.floor(np.median(counts)))
    if blobs >= 3:
        return "legs", blobs
    if blobs == 1 and offsets and np.all(np.median(offsets, axis=0) <= PEDESTAL_OFFSET):
        return "pedestal", blobs
    return "other", blobs


def chair_structure(labels) -> ChairStructure:
    """A chair's :class:`ChairStructure` from its PartNet voxel labels (``lab[x, y, z]``, +y up)."""
    labels = np.asarray(labels)
    kind, blobs = base_kind(labels)
    return ChairStructure(back=bool((labels == BACK).any()), arms=bool((labels == ARMS).any()), base=kind,
                          blobs=blobs)


def groups_of(structure: ChairStructure) -> list[str]:
    """The groups (:data:`GROUPS`) a chair belongs to."""
    out = ["all"]
    if not structure.back:  # stools: their own group only
        return out + ["no back"]
    if structure.arms:
        out.append("armchairs")
    if structure.base == "pedestal":
        out.append("pedestal")
    elif not structure.arms:
        out.append("four-legged" if structure.base == "legs" else "other base")
    return out


# ---------------------------------------------------------------------------------------------
# Figures per group


def _iou(p, t, label_count) -> np.ndarray:
    iou = np.ones(label_count)
    for lab in range(label_count):
        union = np.count_nonzero((p == lab) | (t == lab))
        if union:
            iou[lab] = np.count_nonzero((p == lab) & (t == lab)) / union
    return iou


def group_figures(assignments, truths, mapping, parts, labels) -> dict:
    """The figures of one group of chairs under one index-to-label ``mapping``.

    assignments, truths : lists of (v,) int, one per chair: the index and the label of each occupied voxel
    mapping : (m,) int, label of each index (-1: none); parts : (s,) int, cuboids per chair
    labels : the label names (``back``, ``seat``, ``legs``, ``arms``)
    """
    mapping = np.asarray(mapping)
    if not len(truths):
        return {"chairs": 0}
    count = len(labels)
    ious, has_p, has_t = [], [], []
    for a, t in zip(assignments, truths):
        p = np.where(mapping[a] >= 0, mapping[a], -2)  # an index mapped to no label is wrong everywhere
        ious.append(_iou(p, t, count))
        has_p.append([np.any(p == lab) for lab in range(count)])
        has_t.append([np.any(t == lab) for lab in range(count)])
    ious, has_p, has_t = np.array(ious), np.array(has_p), np.array(has_t)
    iou = {labels[i]: round(float(ious[:, i].mean()), 4) for i in range(count)}
    arm = labels.index("arms")
    tp = int(np.sum(has_p[:, arm] & has_t[:, arm]))
    fp = int(np.sum(has_p[:, arm] & ~has_t[:, arm]))
    fn = int(np.sum(~has_p[:, arm] & has_t[:, arm]))
    back = labels.index("back")
    no_back = ~has_t[:, back]
    return {
        "chairs": len(truths),
        "iou": iou,
        "mean_iou": round(float(np.mean([iou[k] for k in MEAN_OVER])), 4),
        "arms": {"with": int(has_t[:, arm].sum()), "true_positive": tp, "false_positive": fp, "missed": fn,
                 "f1": round(2 * tp / (2 * tp + fp + fn), 3) if has_t[:, arm].any() else None},
        "back_absent_kept_absent": (round(float(np.mean(~has_p[no_back, back])), 3) if no_back.any() else None),
        "without_back": int(no_back.sum()),
        "parts_mean": round(float(np.mean(parts)), 2),
    }


def partnet_groups(run, report, names_by_group) -> dict:
    """Per protocol of ``report`` (``score(run)``), per group: :func:`group_figures`."""
    segs = run.segmentations
    labels = [str(n).split("/")[0] for n in run.truths[0].names]
    occupied = [np.asarray(t.labels) >= 0 for t in run.truths]
    flat_a = [np.asarray(s.labels)[o] for s, o in zip(segs, occupied)]
    flat_t = [np.asarray(t.labels)[o] for t, o in zip(run.truths, occupied)]
    parts = np.array([int(np.count_nonzero(s.cuboids.existence)) for s in segs])
    position = {s.name: i for i, s in enumerate(segs)}
    out = {}
    for protocol, entry in report["protocols"].items():
        mapping = np.array([labels.index(v) if v is not None else -1 for _, v in
                            sorted(entry["mapping"].items(), key=lambda kv: int(kv[0]))])
        out[protocol] = {}
        for group, names in names_by_group.items():
            rows = [position[n] for n in names if n in position]
            out[protocol][group] = group_figures([flat_a[i] for i in rows], [flat_t[i] for i in rows], mapping,
                                                 parts[rows], labels)
        whole = out[protocol]["all"]["mean_iou"]
        if abs(whole - round(float(entry["mean_iou"]), 4)) > 1e-3:  # the same chairs and mapping: the same figure
            raise RuntimeError(f"group figures disagree with evaluate_voxels ({whole} vs {entry['mean_iou']})")
    return out


def partnet_files(per_group: int = 0):
    """``(files, structures, archive)``: the validation chairs and the no-back chairs outside the
    split's test part, with their :class:`ChairStructure` by name; ``per_group`` > 0 keeps at
    most that many chairs of each base kind and of the armchairs (the first by name)."""
    validation, test, archive = split()
    test_names = {data.shape_name(p) for p in test}
    files = list(validation)
    known = {data.shape_name(p) for p in validation} | test_names
    raw = np.load(PARTNET / "voxlabels.npz")
    manifest = (line.split(",") for line in (PARTNET / "MANIFEST.csv").read_text().splitlines()[1:])
    for name in sorted(row[0] for row in manifest if "back" not in row[3].split(";")):  # the stools
        if name not in known and not (raw[name] == BACK).any():
            path = CHAIRS / name / "model.binvox"
            if path.is_file():
                files.append(path)
    structures = {data.shape_name(p): chair_structure(raw[data.shape_name(p)]) for p in files}
    if per_group:
        kept, seen = [], {}
        for p in files:
            s = structures[data.shape_name(p)]
            key = "no back" if not s.back else "arms" if s.arms else s.base
            if seen.get(key, 0) < per_group:
                kept.append(p)
                seen[key] = seen.get(key, 0) + 1
        files = kept
    return files, structures, archive


# ---------------------------------------------------------------------------------------------
# Procedural shapes


def procedural_shapes() -> dict:
    """The procedural groups: ``{group: [LabelledShape]}`` (fixed seeds, :data:`PROCEDURAL_COUNT` each)."""
    n = PROCEDURAL_COUNT
    return {
        "stools": synthetic.generate("stool", n, seed=STOOL_SEED),
        "bar stools": [synthetic.stool(BAR_STOOL_SEED + i, leg_length=0.68 + 0.12 * i / (n - 1)) for i in range(n)],
        "swivel chairs": [synthetic.chair(SWIVEL_SEED + i, swivel=True) for i in range(n)],
    }


def index_roles(part_names, partnet_mapping) -> tuple[dict, str]:
    """``({"back": [indices], "seat": [indices]}, source)``: the model's stored names when it names
    both, else the PartNet chairs' collection-majority mapping (index as str -> label)."""
    named = {role: [k for k, n in enumerate(part_names) if str(n).lower() == role] for role in ("back", "seat")}
    if all(named.values()):
        return named, "the model's stored names"
    return ({role: sorted(int(k) for k, v in partnet_mapping.items() if v == role) for role in ("back", "seat")},
            "the PartNet validation chairs' collection-majority mapping")


def procedural_figures(segs, shapes, roles) -> dict:
    """Back index present, seat area on a seat index, cuboids: per shape and their means."""
    back, seat = np.array(roles["back"], int), np.array(roles["seat"], int)
    present, on_seat, parts = [], [], []
    for seg, shape in zip(segs, shapes):
        if len(seg.face_labels) != len(shape.faces):
            raise RuntimeError(f"{seg.name}: {len(seg.face_labels)} labels for {len(shape.faces)} faces")
        area = io.Mesh(shape.vertices, shape.faces).face_areas()
        is_seat = shape.face_labels == shape.part_names.index("seat")
        present.append(bool(np.isin(seg.face_labels, back).any()))
        on_seat.append(float(area[is_seat & np.isin(seg.face_labels, seat)].sum() / area[is_seat].sum()))
        parts.append(int(np.count_nonzero(seg.cuboids.existence)))
    return {"shapes": len(segs), "back_index_present": round(float(np.mean(present)), 3),
            "seat_on_seat_index": round(float(np.mean(on_seat)), 3),
            "seat_on_seat_index_min": round(float(np.min(on_seat)), 3),
            "parts_mean": round(float(np.mean(parts)), 2)}


def segment_procedural(model, shapes, *, adapt=None, workers=None):
    """Segment generated shapes as one collection of mesh files (default flags)."""
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i, shape in enumerate(shapes):
            paths.append(Path(tmp) / f"shape_{i:03d}.ply")
            io.write_mesh(paths[-1], shape.vertices, shape.faces)
        segs, errors = Segmenter(model, adapt=adapt).segment_files(paths, workers=workers)
    if errors:
        raise RuntimeError(f"procedural shapes failed: {errors}")
    return segs


# ---------------------------------------------------------------------------------------------


def run_once(model, files, structures, archive, shapes, *, adapt, workers) -> dict:
    t0 = time.perf_counter()
    run = segment_chairs(model, files, archive, workers=workers, adapt=adapt)
    report = score(run)
    names_by_group = {g: [n for n, s in structures.items() if g in groups_of(s)] for g in GROUPS}
    partnet = partnet_groups(run, report, names_by_group)
    roles, source = index_roles(run.segmenter.part_names, report["protocols"]["collection-majority"]["mapping"])
    procedural = {group: procedural_figures(segment_procedural(model, s, adapt=adapt, workers=workers), s, roles)
                  for group, s in shapes.items()}
    return {"adapt": bool(adapt), "partnet": partnet, "partnet_errors": run.errors,
            "mapping": report["protocols"]["collection-majority"]["mapping"],
            "procedural_indices": {"source": source, **roles}, "procedural": procedural,
            "seconds": round(time.perf_counter() - t0)}


def table_lines(result) -> list[str]:
    lines = ["| group | chairs | back | seat | legs | mean | arm F1 (TP/FP/missed) | back absent | parts |",
             "|---|---|---|---|---|---|---|---|---|"]
    for group, f in result["partnet"]["collection-majority"].items():
        if not f["chairs"]:
            continue
        arm = f["arms"]
        f1 = "—" if arm["f1"] is None else f"{arm['f1']:.2f}"
        absent = "—" if f["back_absent_kept_absent"] is None else f"{f['back_absent_kept_absent']:.2f}"
        lines.append(f"| {group} | {f['chairs']} | {f['iou']['back']:.3f} | {f['iou']['seat']:.3f} | "
                     f"{f['iou']['legs']:.3f} | {f['mean_iou']:.3f} | {f1} ({arm['true_positive']}/"
                     f"{arm['false_positive']}/{arm['missed']}) | {absent} | {f['parts_mean']:.1f} |")
    lines += ["", "| procedural | shapes | back index present | seat area on the seat index (min) | parts |",
              "|---|---|---|---|---|"]
    for group, f in result["procedural"].items():
        lines.append(f"| {group} | {f['shapes']} | {f['back_index_present']:.2f} | {f['seat_on_seat_index']:.3f} "
                     f"({f['seat_on_seat_index_min']:.2f}) | {f['parts_mean']:.1f} |")
    return lines


def draw(structures, path, per_kind: int = 6):
    """Chairs of each base kind: the side view of the labels and the middle layers' legs/base from above."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    raw = np.load(PARTNET / "voxlabels.npz")
    kinds = ("pedestal", "legs", "other")
    picked = {k: [n for n, s in sorted(structures.items()) if s.base == k][:per_kind] for k in kinds}
    fig, axes = plt.subplots(2 * len(kinds), per_kind, figsize=(2.2 * per_kind, 4.4 * len(kinds)))
    colours = np.array([[0.85, 0.2, 0.2], [0.2, 0.5, 0.85], [0.2, 0.7, 0.3], [0.9, 0.7, 0.1]])
    for r, kind in enumerate(kinds):
        for c in range(per_kind):
            side, top = axes[2 * r, c], axes[2 * r + 1, c]
            side.axis("off"), top.axis("off")
            if c >= len(picked[kind]):
                continue
            name = picked[kind][c]
            lab = raw[name]
            # side view (looking along -z): the nearest voxel's label, x across, y up
            image = np.ones(lab.shape[:2] + (3,))
            for z in range(lab.shape[2] - 1, -1, -1):
                hit = lab[:, :, z] >= 0
                image[hit] = colours[lab[:, :, z][hit]]
            side.imshow(np.transpose(image, (1, 0, 2)), origin="lower")
            side.set_title(f"{kind} ({structures[name].blobs}): {name[:8]}", fontsize=7)
            occupied, seat = np.argwhere(lab >= 0), np.argwhere(lab == SEAT)
            floor = occupied[:, 1].min()
            level = int(np.argmax(np.bincount(seat[:, 1]))) if len(seat) else floor
            y = floor + int(round(0.5 * (level - floor)))
            top.imshow((lab[:, y, :] == LEGS).T, origin="lower", cmap="Greens")
            if len(seat):  # the seat's centre as base_kind reads it
                on_level = np.argwhere(lab[:, level, :] == SEAT)
                top.plot(*((on_level.min(axis=0) + on_level.max(axis=0) + 1) / 2 - 0.5), "r+")
            top.set_title(f"legs/base at y={y} (mid-height)", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="chair", help="a model file or a bundled model's name (default: chair)")
    ap.add_argument("--adapt", nargs="?", const="both", choices=("both", "only"), default=None,
                    help="also segment every collection with --adapt (`--adapt only`: only with it)")
    ap.add_argument("--per-group", type=int, default=0, help="at most N PartNet chairs of each kind (default: all)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--json", type=Path, default=Path(__file__).with_suffix(".json"))
    ap.add_argument("--draw", type=Path, default=None, help="draw chairs of each base kind to this PNG and stop")
    args = ap.parse_args(argv)
    files, structures, archive = partnet_files(args.per_group)
    structures = {data.shape_name(p): structures[data.shape_name(p)] for p in files}
    if args.draw:
        draw(structures, args.draw)
        return 0
    shapes = procedural_shapes()
    counts = {g: sum(g in groups_of(s) for s in structures.values()) for g in GROUPS}
    report = {"model": str(args.model), "per_group": args.per_group, "partnet_chairs": len(files), "groups": counts,
              "structures": {n: asdict(s) for n, s in structures.items()}, "runs": []}
    for adapt in {None: [None], "both": [None, True], "only": [True]}[args.adapt]:
        result = run_once(args.model, files, structures, archive, shapes, adapt=adapt, workers=args.workers)
        report["runs"].append(result)
        print(f"{args.model}{' --adapt' if adapt else ''}: {len(files)} PartNet chairs ({result['seconds']} s)")
        print("\n".join(table_lines(result)))
        print()
    args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

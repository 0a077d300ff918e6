"""How often the default frame search (``align="auto"``) finds the upright frame, per category.

Usage (from the repository root, primkit importable)::

    python scripts/frame_check.py [--per-synset 40] [--columns 12] [--procedural 6]
                                  [--part choose|report|all] [--losses F.npz] [--json F] [--verify N]

Shapes with a known upright frame, each scored with its category's bundled model (chair, table,
airplane; there is no bundled animal model, so the four-legged animals are not covered):

* ShapeNetVox32 grids (``../shared/data/shapenetvox32``, +Y up, front +X), taken from each model's
  held-out files (never trained on): ``--per-synset`` spread over the sorted files, and every
  held-out chair and table whose base is a single central column (a pedestal, swivel or round
  table: found from the grid, :func:`base_kind`); the PartNet chairs without a back label (stools).
  The PartNet test part (``scripts/partnet_chairs.py``) is left out.
* the 10 COSEG chairs (+Y up, front +Z), reported only;
* the Princeton benchmark's chairs, tables and airplanes, in the upright frame established by
  eye for each mesh (:data:`PSB_FRAMES`; they come in every orientation);
* procedural shapes (:mod:`primkit.synthetic`): chairs, swivel chairs, stools on four legs, three
  legs and a column, rectangular and pedestal tables, airplanes (+Y up, front +X).

Each shape is scored once in its 24 candidate orientations, as the search scores it
(:meth:`primkit.model.abstractor.Abstractor._candidate_losses`). Turning a prepared shape is exact
(it is what preparing the turned file gives), and the shape turned by ``T`` and tried in candidate
``c`` is the shape tried in ``c T`` (:func:`primkit.model.orientation.compose_index`), so its 24
turns are judged from that one scoring, with the library's own choice
(:func:`primkit.model.orientation.choose_auto`): ``alone`` (a shape by itself, as one file) and as
a ``collection`` (every shape of a group turned the same way, the vote on: a folder of Z-up
exports); by the default rule and by the rule before mirror symmetry was read (``before``). The fit
losses are estimated from random samples, so the same shape scored in another turn gives losses
about 10% apart and near ties can go the other way: ``--verify N`` searches ``N`` shapes in every
turn for real and counts the turns whose up axis is judged differently. The part to choose on is
``choose`` (even positions of every sorted set: ShapeNet, Princeton and procedural shapes), the part
reported is ``report`` (odd positions, and the COSEG chairs, never chosen on).

A choice is upright when the up axis it takes is the shape's, and right when the front is too
(chairs and airplanes; tables have no front here). Results go to ``scripts/frame_check.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"

from primkit import data, io, synthetic  # noqa: E402
from primkit.model import orientation  # noqa: E402
from primkit.model.abstractor import Abstractor  # noqa: E402

SYNSETS = {"chair": "03001627", "table": "04379243", "airplane": "02691156"}
PSB_CATEGORIES = {"Chair": "chair", "Table": "table", "Airplane": "airplane"}

#: The upright frame of each Princeton mesh (input axes of up and front; front None where the shape
#: has none or it is not along an axis), established by looking at each mesh's three axis views.
PSB_FRAMES = {
    "Chair": {"101": ("+y", "-x"), "103": ("+y", "-x"), "105": ("+z", "-y"), "107": ("+y", None),  # 107: turned 45 deg
              "109": ("+y", "+z"), "111": ("+y", "-z"), "113": ("+y", "-x"), "115": ("+y", "-x"),
              "117": ("+y", "+z"), "119": ("+y", "+z")},
    "Table": {"141": ("-z", None), "143": ("+y", None), "145": ("+y", None), "147": ("+y", None), "149": ("+y", None),
              "151": ("+y", None), "153": ("+z", None), "155": ("+y", None), "157": ("+y", None), "159": ("+z", None)},
    "Airplane": {"61": ("+z", "-x"), "63": ("+y", "+z"), "65": ("+z", "-x"), "67": ("+z", "-x"), "69": ("+z", "-x"),
                 "71": ("+z", "-x"), "73": ("+z", "-x"), "75": ("+z", "-x"), "77": ("+y", "-z"), "79": ("+z", "-x")},
}


@dataclass
class Item:
    """One shape of the check: where it comes from and its upright frame (input axes)."""

    name: str
    model: str
    group: str
    part: str
    up: str
    front: str | None
    path: Path | None = None
    mesh: object = None
    shape: object = field(default=None, repr=False)


def base_kind(occupancy) -> str:
    """``"column"`` when an upright grid (+Y up, ``occupancy[x, y, z]``) stands on a single central
    column (a pedestal, a swivel chair, a round table on one foot), else ``"legs"``: horizontal slices
    between 15% and 35% of the shape's height hold one connected piece (in the median) whose
    footprint spans under 40% of the shape's own in both directions."""
    from scipy import ndimage

    occ = np.asarray(occupancy, bool)
    ys = np.flatnonzero(occ.any(axis=(0, 2)))
    xs, zs = np.flatnonzero(occ.any(axis=(1, 2))), np.flatnonzero(occ.any(axis=(0, 1)))
    lo, hi = ys[0], ys[-1]
    counts, narrow = [], []
    for y in range(int(lo + 0.15 * (hi - lo)), int(lo + 0.35 * (hi - lo)) + 1):
        labels, n = ndimage.label(occ[:, y, :], structure=np.ones((3, 3)))
        counts.append(n)
        if n == 1:
            ii, kk = np.nonzero(labels)
            narrow.append(np.ptp(ii) + 1 < 0.4 * (np.ptp(xs) + 1) and np.ptp(kk) + 1 < 0.4 * (np.ptp(zs) + 1))
    if counts and np.median(counts) == 1 and narrow and np.mean(narrow) > 0.5:
        return "column"
    return "legs"


def _partnet_test_names() -> set:
    sys.path.insert(0, str(ROOT / "scripts"))
    import partnet_chairs

    _, test, _ = partnet_chairs.split()
    return {data.shape_name(p) for p in test}


def _partnet_stools() -> list[str]:
    out = []
    for p in sorted((SHARED / "partnet_chair_boxes").glob("*.json")):
        d = json.loads(p.read_text())
        if "back" not in {b.get("label") for b in d["boxes"]}:
            out.append(d["shapenet_id"])
    return out


def _halves(items: list) -> list:
    for i, it in enumerate(items):
        it.part = "choose" if i % 2 == 0 else "report"
    return items


def shapenet_items(models: dict, per_synset: int, columns_max: int) -> list[Item]:
    test = _partnet_test_names()
    out = []
    for cat, synset in SYNSETS.items():
        files = data.find_shape_files(SHARED / "shapenetvox32" / synset)
        _, held = data.split_files(files, models[cat].hold_out_every or 10)
        held = [p for p in held if data.shape_name(p) not in test]
        pick = np.unique(np.linspace(0, len(held) - 1, per_synset).round().astype(int))
        out += _halves([Item(data.shape_name(held[i]), cat, f"shapenet {cat}", "", "+y", "+x", held[i]) for i in pick])
        if cat in ("chair", "table"):
            taken = {held[i] for i in pick}
            columns = [p for p in held if p not in taken and base_kind(io.read_voxels(p).occupancy) == "column"]
            columns = columns[:: max(1, len(columns) // columns_max)][:columns_max]
            out += _halves([Item(data.shape_name(p), cat, f"shapenet {cat} on a column", "", "+y", "+x", p) for p in columns])
    stools = [n for n in _partnet_stools() if n not in test]
    chairs = SHARED / "shapenetvox32" / SYNSETS["chair"]
    out += _halves([Item(n, "chair", "shapenet stool (PartNet, no back)", "", "+y", "+x", chairs / n / "model.binvox")
                    for n in stools])
    for it in out:
        if it.model == "table":
            it.front = None
    return out


def coseg_items() -> list[Item]:
    out = []
    for sub in ("large_chairs", "chairs_101-120"):
        for p in sorted((SHARED / "coseg_chairs" / sub / "shapes").glob("*.off"), key=lambda p: int(p.stem)):
            out.append(Item(f"coseg-{p.stem}", "chair", "coseg chair", "report", "+y", "+z", p))
    return out


def psb_items() -> list[Item]:
    out = []
    for folder, cat in PSB_CATEGORIES.items():
        files = sorted((SHARED / "psb_seg_benchmark" / folder / "off").glob("*.off"), key=lambda p: int(p.stem))
        items = []
        for p in files:
            frame = PSB_FRAMES.get(folder, {}).get(p.stem)
            if frame is None:
                continue
            items.append(Item(f"psb-{p.stem}", cat, f"princeton {cat}", "", frame[0], frame[1], p))
        out += _halves(items)
    return out


def procedural_items(count: int) -> list[Item]:
    kinds = [
        ("chair", "procedural chair", synthetic.chair, {"swivel": False}),
        ("chair", "procedural swivel chair", synthetic.chair, {"swivel": True}),
        ("chair", "procedural stool, four legs", synthetic.stool, {"base": "legs4"}),
        ("chair", "procedural stool, three legs", synthetic.stool, {"base": "legs3"}),
        ("chair", "procedural stool, column", synthetic.stool, {"base": "column"}),
        ("table", "procedural table, legs", synthetic.table, {"pedestal": False}),
        ("table", "procedural table, pedestal", synthetic.table, {"pedestal": True}),
        ("airplane", "procedural airplane", synthetic.airplane, {}),
    ]
    out = []
    for cat, group, make, kw in kinds:
        items = []
        for seed in range(count):
            s = make(1000 + seed, **kw)
            front = None if cat == "table" or "stool" in group else "+x"
            items.append(Item(f"{group.split()[-1]}-{seed}", cat, group, "", "+y", front,
                              mesh=io.Mesh(s.vertices, s.faces)))
        out += _halves(items)
    return out


def prepare(items: list[Item], settings) -> None:
    files = [it.path for it in items if it.path is not None]
    if files:
        coll = data.prepare_collection(files, settings, workers=1, progress=False)
        if coll.errors:
            raise SystemExit("\n".join(coll.errors))
        by_path = {}
        for i in range(len(coll)):
            by_path[Path(coll[i].source).resolve()] = coll[i]
        for it in items:
            if it.path is not None:
                it.shape = by_path[Path(it.path).resolve()]
    for it in items:
        if it.mesh is not None:
            it.shape = data.prepare(it.mesh, settings, name=it.name)


def upright(item: Item, composite: np.ndarray) -> tuple[bool, bool]:
    """(up right, front right) of a composite map from the shape's input to the chosen canonical frame."""
    axes = orientation.describe_rotation(composite)
    return axes.up == item.up, item.front is None or axes.front == item.front


def judge(items: list[Item], losses: np.ndarray, symmetry: np.ndarray, choose) -> dict:
    """Every shape in every turn, alone and as a collection of its group; ``choose`` maps (s, 24)
    losses and (s, 3) mirror symmetries to (s,) choices (:func:`primkit.model.orientation.choose_auto`)."""
    rot = orientation.AXIS_ROTATIONS
    frames = [np.asarray(it.shape.frame.rotation, float) for it in items]
    out = {"alone": np.zeros((len(items), 24, 2), bool), "collection": np.zeros((len(items), 24, 2), bool),
           "choice_alone": np.zeros((len(items), 24), int)}
    groups: dict = {}
    for i, it in enumerate(items):
        groups.setdefault(it.group, []).append(i)
    for t in range(len(rot)):
        turned = losses[:, orientation.compose_index(np.arange(len(rot)), t)]  # (s, 24): candidate c of the turned shape
        sym = orientation.turn_symmetry(symmetry, rot[t])
        for i in range(len(items)):
            c = int(choose(turned[i : i + 1], sym[i : i + 1])[0])
            out["choice_alone"][i, t] = c
            out["alone"][i, t] = upright(items[i], rot[c] @ rot[t] @ frames[i])
        for idx in groups.values():
            choice = choose(turned[idx], sym[idx])
            for i, c in zip(idx, choice):
                out["collection"][i, t] = upright(items[i], rot[c] @ rot[t] @ frames[i])
    return out


def summarise(items: list[Item], judged: dict, seconds: dict) -> dict:
    rows = {}
    models = sorted({it.model for it in items})
    keys = sorted({(it.model, it.group) for it in items}) + [(m, g) for g in ("shared", "all") for m in models] \
        + [("every model", "shared")]

    def member(it, model, group):  # "shared": the meshes and grids of ../shared, no procedural shape
        shared = not it.group.startswith("procedural")
        return model in (it.model, "every model") and (group == it.group or group == "all" or (group == "shared" and shared))

    for model, group in keys:
        for part in ("choose", "report", "all"):
            idx = [i for i, it in enumerate(items) if member(it, model, group) and (part == "all" or it.part == part)]
            if not idx:
                continue
            row = {"shapes": len(idx)}
            for how in ("alone", "collection"):
                up = judged[how][idx, :, 0]
                both = judged[how][idx, :, 0] & judged[how][idx, :, 1]
                given = [judged[how][i, 0, 0] for i in idx if items[i].up == "+y"]
                row[how] = {
                    "upright_kept": [int(np.sum(given)), len(given)],  # shapes given upright, +Y up
                    "up_found_mean": float(up.mean()),  # over shapes and the 24 turns
                    "up_found_worst_turn": float(up.mean(axis=0).min()),
                    "up_and_front_found_mean": float(both.mean()),
                    "shapes_found_in_every_turn": int(up.all(axis=1).sum()),
                }
            rows[f"{model} | {group} | {part}"] = row
    return {"rows": rows, "seconds_a_shape": seconds}


def verify(models: dict, items: list[Item], count: int) -> dict:
    """The search itself (:meth:`Abstractor.search_orientations`, default rule) on ``count`` shapes
    spread over the list, each turned into the 24 turns and searched alone, against the judgement
    derived from the shape's one scoring: how often the up axis found differs."""
    rot = orientation.AXIS_ROTATIONS
    picked = items[:: max(1, len(items) // count)][:count]
    differ = total = 0
    for it in picked:
        model = models[it.model]
        losses = model._candidate_losses([it.shape], np.arange(24), 0.5, 16)
        sym = orientation.mirror_symmetry(it.shape.occupancy)[None]
        frame = np.asarray(it.shape.frame.rotation, float)
        for t in range(len(rot)):
            found = int(model.search_orientations([orientation.rotate_prepared(it.shape, rot[t])], "auto").choice[0])
            derived = int(orientation.choose_auto(losses[:, orientation.compose_index(np.arange(24), t)],
                                                  symmetry=orientation.turn_symmetry(sym, rot[t])).choice[0])
            differ += int(upright(it, rot[found] @ rot[t] @ frame)[0] != upright(it, rot[derived] @ rot[t] @ frame)[0])
            total += 1
    return {"shapes": [f"{it.group}/{it.name}" for it in picked], "turns": total, "up_judged_differently": differ}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-synset", type=int, default=40)
    ap.add_argument("--columns", type=int, default=12, help="held-out chairs and tables on a column, at most")
    ap.add_argument("--procedural", type=int, default=6, help="shapes of each procedural kind")
    ap.add_argument("--part", choices=["choose", "report", "all"], default="all")
    ap.add_argument("--verify", type=int, default=0, metavar="N", help="search N shapes in every turn for real")
    ap.add_argument("--losses", type=Path, default=None, help="keep the scored losses in this .npz (and reuse them)")
    ap.add_argument("--json", type=Path, default=Path(__file__).with_suffix(".json"))
    args = ap.parse_args(argv)

    models = {k: Abstractor.load(k) for k in SYNSETS}
    items = shapenet_items(models, args.per_synset, args.columns) + coseg_items() + psb_items() \
        + procedural_items(args.procedural)
    if args.part != "all":
        items = [it for it in items if it.part == args.part]
    t0 = time.perf_counter()
    prepare(items, models["chair"].settings)
    print(f"{len(items)} shapes prepared in {time.perf_counter() - t0:.0f} s", file=sys.stderr)

    rot = orientation.AXIS_ROTATIONS
    losses = np.full((len(items), 24), np.nan)  # shape, candidate
    seconds = {}
    keys = [f"{it.model}/{it.group}/{it.name}" for it in items]
    if args.losses is not None and args.losses.exists():
        with np.load(args.losses) as kept:
            known = dict(zip(kept["keys"], kept["losses"]))
        for i, k in enumerate(keys):
            if k in known and known[k].shape == (24,):
                losses[i] = known[k]
    for cat, model in models.items():
        idx = [i for i, it in enumerate(items) if it.model == cat and np.isnan(losses[i]).any()]
        if not idx:
            continue
        t0 = time.perf_counter()
        losses[idx] = model._candidate_losses([items[i].shape for i in idx], np.arange(24), 0.5, 16)
        seconds[cat] = round((time.perf_counter() - t0) / len(idx), 4)
    if args.losses is not None:
        np.savez(args.losses, keys=np.array(keys), losses=losses)

    symmetry = np.array([orientation.mirror_symmetry(it.shape.occupancy) for it in items])

    def choose(rows, sym):
        return orientation.choose_auto(rows, symmetry=sym).choice

    def choose_before(rows, sym):  # the rule before mirror symmetry was read
        return orientation.choose_auto(rows, 0.7).choice

    report = {}
    for key, rule in (("before", choose_before), ("default", choose)):
        judged = judge(items, losses, symmetry, rule)
        report[key] = summarise(items, judged, seconds)
        report[key]["shapes"] = [
            {"name": it.name, "group": it.group, "model": it.model, "part": it.part, "up": it.up, "front": it.front,
             "kept_upright": bool(judged["alone"][i, 0, 0]) if it.up == "+y" else None,
             "turns_found_alone": int(judged["alone"][i, :, 0].sum())} for i, it in enumerate(items)]
    if args.verify:
        report["verify"] = verify(models, items, args.verify)
    report["sample"] = {"per_synset": args.per_synset, "columns": args.columns, "procedural": args.procedural,
                        "part": args.part, "shapes": len(items)}
    args.json.write_text(json.dumps(report, indent=1))
    for key in ("before", "default"):
        print(f"== {key}: kept = shapes given upright kept upright; found = share of the 24 turns in which the up "
              "axis is found, mean over shapes / worst turn")
        print(f"{'category | group | part':62s} shapes  kept alone  found alone  | kept coll.  found coll.")
        for name, row in report[key]["rows"].items():
            a, c = row["alone"], row["collection"]
            print(f"{name:62s} {row['shapes']:5d}  {a['upright_kept'][0]:4d}/{a['upright_kept'][1]:<4d} "
                  f"{a['up_found_mean']:.3f}/{a['up_found_worst_turn']:.3f}  | {c['upright_kept'][0]:4d}/"
                  f"{c['upright_kept'][1]:<4d} {c['up_found_mean']:.3f}/{c['up_found_worst_turn']:.3f}")
    print("seconds a shape to score its 24 candidates (the default's cost):", seconds)
    if "verify" in report:
        print("verify:", report["verify"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

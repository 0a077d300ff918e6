"""Put a part labeller into the bundled table and airplane models, learned from procedural shapes.

No real table or airplane in ``../shared/data`` carries part *names*: the Princeton benchmark's
tables and airplanes (``psb_seg_benchmark``) have human segmentations whose segment ids are
arbitrary per file (its README: "not semantic and not consistent across models"), and the
ShapeNetVox32 grids have no labels at all. So the labellers are learned from the part-labelled
shapes primkit makes itself (:mod:`primkit.synthetic`): ``synthetic.generate(CATEGORY, TRAIN,
seed=7)`` (the seed ``scripts/name_bundled_models.sh`` named the indices with; never used in
training or tests), each face labelled with its part's group (``PART_GROUPS``: table ``top`` /
``legs`` / ``base``, airplane ``fuselage`` / ``wings`` / ``tail`` / ``engines``). Every shape is
abstracted and segmented as ``primkit segment --semantic`` does with default flags (no axes given,
no refinement), exactly as ``primkit name-parts SHAPES --model CATEGORY`` learns one.

Figures (written into the card): the share of the surface named right (area-weighted, mean over
shapes) and each label's IoU, on held-out procedural shapes (``seed=9``, never learned from; the
classifier's size was chosen on ``seed=8``), for the labeller and for today's one-name-per-index
naming, measured the same way. Only the labeller and the card change: the network's tensors and
every other metadata key are copied unchanged (checked here; ``tests/segmentation/
test_bundled_labellers.py`` checks the tensors' hash).

Usage (from the repository root; 10-15 minutes on two loaded cores)::

    python -m scripts.build_labellers --install           # rebuild both bundled labellers in place
    python -m scripts.build_labellers -o DIR [--categories table] [--pictures docs/images]
    python -m scripts.build_labellers --install --refigure  # the same trees, the card's figures measured again
    python -m scripts.build_labellers --upgrade            # the bundled labellers (chair too) in today's format

``--upgrade`` rewrites the labeller description of each bundled model that carries one (chair,
table, airplane) in this primkit's labeller format, without learning anything again: the trees,
the prior and every other tensor are copied bit for bit, the settings a file written before a key
existed read as it read them then, and the chair's arms rule and seat cut (stored as ``presence``
and ``layer_cut`` before post-steps existed) become its ``post`` list, in the order they ran.

``--pictures`` also draws 12 held-out ShapeNetVox32 shapes (real, unlabelled) named by the new
labeller, to look at (``labeller-real-CATEGORY.png``; red, blue, green, orange: the labels in order).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

import primkit
from primkit import data, geometry, io, synthetic
from primkit.model.bundled import bundled_models
from primkit.model.modelfile import load_model_file, read_metadata
from primkit.segmentation import Segmenter
from primkit.segmentation.evaluation import label_iou, read_ground_truth
from primkit.segmentation.labeller import (LABELLER_FORMAT_VERSION, LABELLER_KEY, LABELLER_PREFIX, read_labeller,
                                           write_labeller)
from primkit.labelling.layers import LayerCut
from primkit.labelling.post import step_to_dict
from primkit.labelling.presence import PresenceRule
from primkit.segmentation.segmenter import apply_labeller, fit_labeller

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
CATEGORIES = ("table", "airplane")
SYNSETS = {"table": "04379243", "airplane": "02691156"}

#: seeds of ``synthetic.generate``: learned from, settings chosen on, figures reported on
SEEDS = {"train": 7, "validation": 8, "test": 9}
#: shapes per part (train 100, as the chair's labeller; test 60)
COUNTS = {"train": 100, "validation": 40, "test": 60}

#: The classifier's size, chosen on the validation seed (scripts/build_labellers.py's docstring):
#: procedural shapes are told apart with far fewer and smaller trees than the chair's labeller
#: (100 rounds of 31 leaves), and the bundled models must stay small enough for the wheel
#: (tests/model/test_models.py: all bundled models under 4 MiB).
CLASSIFIER = {"max_iter": 40, "max_leaf_nodes": 7}

TERMS = ("the labeller was learned from procedural shapes that primkit generates itself (primkit.synthetic): no "
         "third-party data and no terms of their own; the model it sits in keeps its own terms (above)")

WHY_PROCEDURAL = ("no real table or airplane with part names exists in ../shared/data: the Princeton "
                  "benchmark's tables and airplanes (psb_seg_benchmark) carry human segmentations whose segment ids "
                  "are arbitrary per file, without names; the ShapeNetVox32 grids carry no labels")

#: What the labeller does on real shapes: looked at, not measured (nothing real here has part names), on
#: held-out ShapeNetVox32 shapes (``--pictures``: docs/images/labeller-real-CATEGORY.png, and 16 more
#: of each drawn in a scratch run).
REAL_SHAPES = {
    "table": ("looked at, not measured (no real table here has part names). Of the 12 held-out ShapeNetVox32 "
              "tables in docs/images/labeller-real-table.png, 9 come out about right (top, legs; crossed and trestle "
              "legs and a stretcher included); the others misname what the generator never makes: the body of an "
              "L-shaped desk `top`, the legs of a C-shaped side table and half of one four-legged table's legs "
              "`base`. Trust it for the top / legs / base of simple four-legged and pedestal tables only."),
    "airplane": ("looked at, not measured (no real airplane here has part names). Of the 12 held-out ShapeNetVox32 "
                 "airplanes in docs/images/labeller-real-airplane.png, the 8 airliners and the light plane come out "
                 "mostly right (fuselage, wings, tail; engines under the wings in 5 of them, others missed); the 2 "
                 "fighters and 1 odd shape are named badly (parts of the fuselage called wings, tail pieces at the "
                 "nose). Over the 28 distinct real airplanes looked at the same holds. Trust it for a rough "
                 "fuselage / wings / tail split of airliners only."),
}

#: where the card's text about the labeller starts (cut off when the labeller is built again)
LABELLER_SECTION = "\n\nPart labeller "


def label_names(category: str) -> list:
    """The part groups of ``category`` in :data:`primkit.synthetic.PART_GROUPS` order (table: top,
    legs, base; airplane: fuselage, wings, tail, engines)."""
    out = []
    for group in synthetic.PART_GROUPS[category].values():
        if group not in out:
            out.append(group)
    return out


def prepare(category: str, part: str, work: Path, count: int | None = None):
    """The procedural shapes of one part (``train``, ``validation``, ``test``), written to ``work``,
    abstracted and segmented with the bundled model as ``segment`` does with default flags.

    Returns a list of ``(segmentation, abstraction result, truth (f,) int)``, the truth indexing
    :func:`label_names`."""
    count = COUNTS[part] if count is None else count
    folder = work / f"{category}-{part}-{count}"
    files = sorted(folder.glob("*.ply")) if folder.is_dir() else []
    if len(files) != count:
        files = synthetic.write_collection(folder, category, count, seed=SEEDS[part], overwrite=True)
    segmenter = Segmenter(bundled_models()[category], labeller=None)
    results, errors = segmenter.abstract_files(files, cache_dir=work / "cache", workers=1)
    segs, errors = segmenter.segment_results(results, errors=errors, workers=1)
    if errors or len(segs) != count:
        raise SystemExit(f"{category} {part}: {len(errors)} shapes failed: {errors[:3]}")
    names = label_names(category)
    by_name = {r.name: r for r in results}
    out = []
    for s in segs:
        truth = read_ground_truth(Path(s.source).with_suffix(".seg"), len(s.faces), names=list(names))
        assert truth.names == names, truth.names  # no label beyond the groups
        out.append((s, by_name[s.name], truth.labels))
    return out


def index_codes(seg, names) -> np.ndarray:
    """Each face's label under one name per index (the model's ``part_names``; -1: an unnamed index)."""
    lookup = np.array([names.index(n) if n in names else -1 for n in seg.part_names] + [-1])
    return lookup[seg.face_labels]


def labeller_codes(seg, labeller, result, names) -> np.ndarray:
    """Each face's label as ``segment --semantic`` names it with ``labeller``, indexing ``names``."""
    named = apply_labeller(seg, labeller, result).named
    lookup = np.array([names.index(n) for n in labeller.names] + [-1])
    return lookup[named]


def measure(prepared, names, codes_of) -> dict:
    """Area-weighted share of the surface named right (mean over shapes, and its minimum) and each
    label's IoU over the collection, for the codes ``codes_of(seg, result)`` gives."""
    right, predicted, truths, areas = [], [], [], []
    for s, r, truth in prepared:
        codes = codes_of(s, r)
        w = s.face_areas
        ok = truth >= 0
        right.append(float(w[ok & (codes == truth)].sum() / w[ok].sum()))
        predicted.append(codes), truths.append(truth), areas.append(w)
    iou = label_iou(predicted, truths, areas, len(names))
    return {"shapes": len(prepared), "area_right": round(float(np.mean(right)), 4),
            "area_right_min": round(float(np.min(right)), 4),
            "iou": {n: (None if np.isnan(v) else round(float(v), 4)) for n, v in zip(names, iou)},
            "mean_iou": round(float(np.nanmean(iou)), 4)}


def learn(category: str, train, **options):
    names = label_names(category)
    return fit_labeller(train, names, 20, seed=0, **{**CLASSIFIER, **options},
                        info={"learned_from": f"primkit.synthetic.generate({category!r}, {len(train)}, "
                                              f"seed={SEEDS['train']})",
                              "shape_seeds": [int(json.loads(Path(s.source).with_suffix('.json').read_text())["seed"])
                                              for s, _, _ in train]})


def build(category: str, output: Path, work: Path, *, overwrite: bool = False) -> tuple[Path, dict]:
    """Learn ``category``'s labeller again, measure it on the held-out seed and write the model
    file with it and its card to ``output``."""
    train = prepare(category, "train", work)
    labeller = learn(category, train)
    return write_card(category, labeller, len(train), held_out_figures(category, labeller, work), output,
                      overwrite=overwrite)


def refigure(category: str, output: Path, work: Path, *, overwrite: bool = False) -> tuple[Path, dict]:
    """The bundled labeller as it is (its trees untouched), measured again on the held-out seed
    with today's code, and its card's figures replaced: for when the way its names are decided
    changes but not what it learned (e.g. a mesh's faces labelled over the surface, meshlabels.py)."""
    labeller = read_labeller(bundled_models()[category])
    out = write_card(category, labeller, labeller.info["shapes"], held_out_figures(category, labeller, work), output,
                     overwrite=overwrite)
    same = read_labeller(out[0])
    assert same.to_tensors()[0].keys() == labeller.to_tensors()[0].keys() and all(
        np.array_equal(a, same.to_tensors()[0][k]) for k, a in labeller.to_tensors()[0].items())
    return out


def held_out_figures(category: str, labeller, work: Path) -> dict:
    """The card's ``held_out_procedural``: :func:`measure` of ``labeller`` and of one name per index
    on the test seed's shapes."""
    names = label_names(category)
    test = prepare(category, "test", work)
    return {"labeller": measure(test, names, lambda s, r: labeller_codes(s, labeller, r, names)),
            "index_names": measure(test, names, lambda s, r: index_codes(s, names)),
            "seed": SEEDS["test"]}


def write_card(category: str, labeller, shapes: int, figures: dict, output: Path, *,
               overwrite: bool = False) -> tuple[Path, dict]:
    """Copy the bundled model of ``category`` to ``output`` with ``labeller`` (learned from ``shapes``
    procedural shapes) and a card that says so, with the held-out ``figures``."""
    source = bundled_models()[category]
    meta = read_metadata(source)
    meta.pop(LABELLER_KEY, None)  # built again: write_labeller replaces the labeller, the card's part is redone
    meta["card"] = {k: v for k, v in meta["card"].items() if k != "labeller"}
    meta["card"]["text"] = meta["card"]["text"].split(LABELLER_SECTION)[0]
    names = label_names(category)
    generator = (f"primkit.synthetic.generate({category!r}, {COUNTS['train']}, seed={SEEDS['train']}) "
                 f"(primkit {primkit.__version__}'s generator; each face labelled with its part's group)")
    card = dict(meta["card"])
    card["labeller"] = {
        "shapes": shapes, "labels": names, "data": "procedural shapes: " + generator,
        "procedural": True, "generator": "primkit.synthetic.generate", "seeds": dict(SEEDS), "counts": dict(COUNTS),
        "terms": TERMS, "command": "python -m scripts.build_labellers --install", "classifier": dict(CLASSIFIER),
        "settings": {**labeller.settings.to_dict(), "prior_weight": labeller.settings.prior_weight},
        "held_out_procedural": figures,
        "why_procedural": WHY_PROCEDURAL,
        "real_shapes": REAL_SHAPES[category],
    }
    lab, idx = figures["labeller"], figures["index_names"]
    card["text"] = card["text"].rstrip("\n") + (
        f"{LABELLER_SECTION}(`segment --semantic` names each voxel, face or point with it: "
        f"{', '.join(names)}): learned from **procedural shapes only**, {generator}, with "
        f"`python -m scripts.build_labellers --install`; no real {category} with part names exists here. "
        f"On {lab['shapes']} held-out procedural {category}s (seed {SEEDS['test']}): {lab['area_right']:.1%} of the "
        f"surface named right (one name per index: {idx['area_right']:.1%}), mean IoU {lab['mean_iou']:.3f} "
        f"(index names {idx['mean_iou']:.3f}). **Real shapes**: {REAL_SHAPES[category]} Terms: {TERMS}.\n")
    out = write_labeller(source, output, labeller, {"card": card}, overwrite=overwrite)
    check_unchanged(source, out, meta)
    print(f"{category}: wrote {out}: {out.stat().st_size} bytes (from {source.stat().st_size}), "
          f"{len(labeller.ensemble.feature)} tree nodes; held out: labeller {lab['area_right']:.4f} "
          f"(min {lab['area_right_min']:.4f}, mIoU {lab['mean_iou']:.4f}), index names {idx['area_right']:.4f} "
          f"(mIoU {idx['mean_iou']:.4f})")
    return out, figures


def network_tensors(path) -> dict:
    return {k: v for k, v in load_model_file(path)[0].items() if not k.startswith(LABELLER_PREFIX)}


def check_unchanged(source, out, meta) -> None:
    """The network's tensors and every metadata key but the card, the labeller and ``created`` as
    in ``source`` (``meta``: its metadata without its labeller)."""
    before, after = network_tensors(source), network_tensors(out)
    assert before.keys() == after.keys() and all(np.array_equal(before[k].numpy(), after[k].numpy()) for k in before)
    new = read_metadata(out)
    assert {k: v for k, v in new.items() if k not in ("card", LABELLER_KEY, "created")} == \
        {k: v for k, v in meta.items() if k not in ("card", "created")}
    assert {k: v for k, v in new["card"].items() if k not in ("labeller", "text")} == \
        {k: v for k, v in meta["card"].items() if k != "text"}
    assert read_labeller(out) is not None


#: What a settings key absent from an older labeller description read (the format it was added in:
#: grid_sample and prior_weight 2-3, profile 3, sides 4).
OLD_SETTINGS = {"grid_sample": 1, "prior_weight": 0.0, "profile": False, "sides": False}


def upgraded_description(d: dict) -> dict:
    """An older labeller description (format 2-10) as this primkit's format writes it, meaning
    what it meant: the settings it lacked as they were read then; the arms rule (``presence``)
    and the seat cut (``layer_cut``) as the post-steps ``chair.arms_from_side_region`` and
    ``chair.seat_layer_cut``, in that order (the order they ran), with the values older files
    read for the parameters they lacked (no fill before format 5, ``grid_add`` = ``add`` before 9,
    no hint before 10; the cut's floor 0 before 7, no restore before 8)."""
    version = d["format_version"]
    if version == LABELLER_FORMAT_VERSION:
        return d
    if not 2 <= version < LABELLER_FORMAT_VERSION:
        raise ValueError(f"labeller format version {version}: nothing to upgrade from it")
    post = []
    if d.get("presence") is not None:
        rule = dict(d["presence"])
        if version < 5:
            rule["fill"] = 2.0
        if version < 9:
            rule["grid_add"] = rule["add"]
        if version < 10:
            rule.update(hint=2.0, hint_add=2.0, grid_hint_add=2.0)
        post.append(step_to_dict(PresenceRule.from_dict(rule)))
    if version >= 6 and d.get("layer_cut") is not None:
        cut = dict(d["layer_cut"])
        if version < 7:
            cut["floor"] = 0.0
        if version < 8:
            cut["restore"] = False
        post.append(step_to_dict(LayerCut.from_dict(cut)))
    out = {k: v for k, v in d.items() if k not in ("presence", "layer_cut")}
    out.update(format_version=LABELLER_FORMAT_VERSION, settings={**OLD_SETTINGS, **d["settings"]},
               info=d.get("info", {}), post=post)
    return out


def upgrade(path: Path, output: Path) -> Path:
    """Write the model file ``path`` to ``output`` with its labeller description upgraded
    (:func:`upgraded_description`); every tensor and every other metadata key copied unchanged."""
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    with safe_open(str(path), framework="pt") as f:
        meta = json.loads(f.metadata()["primkit"])
    tensors = load_file(str(path))
    meta[LABELLER_KEY] = upgraded_description(meta[LABELLER_KEY])
    with io.atomic_output(output, overwrite=True) as tmp:
        save_file(tensors, str(tmp), metadata={"primkit": json.dumps(meta, allow_nan=False, sort_keys=True)})
    after = load_file(str(output))
    assert after.keys() == tensors.keys() and all(after[k].dtype == v.dtype and after[k].equal(v)
                                                  for k, v in tensors.items())
    assert read_labeller(output) is not None
    return output


#: label colours of the pictures (uint8 RGB): red, blue, green, orange
COLOURS = np.array([[215, 50, 50], [50, 100, 215], [60, 165, 60], [235, 160, 30]], np.uint8)
COLOUR_NAMES = ["red", "blue", "green", "orange"]


def real_picture(category: str, model: Path, path: Path, work: Path, count: int = 12) -> Path:
    """``count`` held-out ShapeNetVox32 shapes (never trained on: the model's own split, drawn with
    seed 0) named by ``model``'s labeller as ``segment --semantic`` does (default flags), each
    label's voxels coloured (:data:`COLOURS`)."""
    from primkit.viz.render import Tile, mesh_layer, write_png

    _, held = data.split_files(data.find_shape_files(SHARED / "shapenetvox32" / SYNSETS[category]), 10)
    rng = np.random.default_rng(0)
    files = [held[i] for i in sorted(rng.choice(len(held), count, replace=False))]
    segmenter = Segmenter(model)
    segs, errors = segmenter.segment_files(files, cache_dir=work / "cache", workers=1)
    if errors:
        print("\n".join(errors))
    names = segmenter.labeller.names
    tiles = []
    for s in segs:  # each label's voxels as a closed block
        size = s.grid.scale / s.grid.resolution
        layers = [mesh_layer(v, f, np.repeat(COLOURS[k][None], len(f), axis=0))
                  for k in range(len(names)) if np.any(s.named == k)
                  for v, f in [geometry.voxel_boundary_mesh(s.named == k, voxel_size=size, origin=s.grid.translate)]]
        tiles.append(Tile(s.name[:10], layers))
    write_png(path, tiles, columns=4, tile=300, overwrite=True)
    legend = ", ".join(f"{c} {n}" for c, n in zip(COLOUR_NAMES, names))
    print(f"  picture: {path} ({legend})")
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    where = ap.add_mutually_exclusive_group(required=True)
    where.add_argument("-o", "--output", type=Path, help="a folder for CATEGORY.safetensors")
    where.add_argument("--install", action="store_true", help="replace primkit/model/bundled/CATEGORY.safetensors")
    where.add_argument("--upgrade", action="store_true",
                       help="rewrite the bundled chair, table and airplane labellers in this primkit's labeller "
                            "format, in place, learning nothing again (the module notes)")
    ap.add_argument("--categories", nargs="+", default=list(CATEGORIES), choices=CATEGORIES)
    ap.add_argument("--work", type=Path, default=None, help="a folder for the procedural shapes and the cache")
    ap.add_argument("--pictures", type=Path, default=None, help="draw held-out ShapeNetVox32 shapes named here")
    ap.add_argument("--refigure", action="store_true",
                    help="keep the bundled labellers' trees; measure them again and write only their cards' figures")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    if args.upgrade:
        for category in ("chair", *CATEGORIES):
            target = bundled_models()[category]
            upgrade(target, target)
            print(f"upgraded {target}: {read_labeller(target).post}")
        return 0
    make = refigure if args.refigure else build
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        for category in args.categories:
            if args.install:
                target = bundled_models()[category]
                out, _ = make(category, work / f"{category}.safetensors", work, overwrite=True)
                with io.atomic_output(target, overwrite=True) as tmp_target:  # work may be another file system
                    shutil.copyfile(out, tmp_target)
                print(f"installed {target}")
                model = target
            else:
                args.output.mkdir(parents=True, exist_ok=True)
                model, _ = make(category, args.output / f"{category}.safetensors", work, overwrite=args.force)
            if args.pictures:
                args.pictures.mkdir(parents=True, exist_ok=True)
                real_picture(category, model, args.pictures / f"labeller-real-{category}.png", work)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

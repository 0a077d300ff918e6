"""Put a part labeller into the bundled chair model (``primkit/model/bundled/chair.safetensors``).

The labeller (:mod:`primkit.segmentation.labeller`) is learned from the PartNet **validation**
chairs of ``scripts/partnet_chairs.py``'s split (all 219 by default, ``--chairs N``: the first N;
never the test part), abstracted and segmented as ``primkit segment`` does with default flags,
exactly as ``primkit name-parts CHAIRS --model chair --labels ../shared/data/partnet_chair_boxes
--mirror --post chair`` learns one (the chair's arms rule and seat cut, :mod:`primkit.labelling.post`) (each chair's left-right mirror learned from too: better arms on the
validation chairs, docs/labeller.md; ``--no-mirror`` leaves them out). Only the labeller and the card change: the
network's weights, the part names and every other metadata key are copied unchanged (checked). Run again on a
bundled file that has a labeller, it replaces it (and the card's part about it).

Usage (from the repository root)::

    python -m scripts.build_chair_labeller -o chair-labelled.safetensors [--chairs N] [--cache DIR] [--no-mirror]
    python -m scripts.labeller_curve model --model chair-labelled.safetensors --part test   # its figures
    cp chair-labelled.safetensors primkit/model/bundled/chair.safetensors
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from primkit.model.bundled import bundled_models
from primkit.model.modelfile import read_metadata
from primkit.segmentation import Segmenter
from primkit.segmentation.labeller import LABELLER_KEY, read_labeller, write_labeller
from primkit.segmentation.segmenter import fit_labeller
from primkit.segmentation.selftrain import learn_labeller

from scripts.build_labellers import check_unchanged
from scripts.partnet_chairs import split

NAMES = ["back", "seat", "legs", "arms"]  # PartNet's values 0-3 (partnet_chair_boxes README)
#: the chair's post-steps (primkit.labelling.post), as ``name-parts --post chair`` asks for them
POST = "chair"

TERMS = ("the labeller was learned from PartNet's part annotations (Mo et al., CVPR 2019) of ShapeNet chairs, "
         "as voxel labels in ../shared/data/partnet_chair_boxes: non-commercial research and educational use "
         "only, as ShapeNet's; cite PartNet, ShapeNet and 3D-R2N2")


#: where the card's text about the labeller starts (cut off when the labeller is built again)
LABELLER_SECTION = "\n\nPart labeller "


def build(output: Path, chairs: int | None = None, cache=None, *, mirror: bool = True, overwrite: bool = False) -> Path:
    source = bundled_models()["chair"]
    meta = read_metadata(source)
    meta.pop(LABELLER_KEY, None)  # built again: write_labeller replaces the labeller, the card's part is redone
    meta["card"] = {k: v for k, v in meta["card"].items() if k != "labeller"}
    meta["card"]["text"] = meta["card"]["text"].split(LABELLER_SECTION)[0]
    validation, _, archive = split()
    chairs = len(validation) if chairs is None else chairs
    files = validation[:chairs]
    segmenter = Segmenter(source, labeller=None)
    results, errors = segmenter.abstract_files(files, cache_dir=cache, progress=False)
    segs, errors = segmenter.segment_results(results, errors=errors, progress=False)
    if errors or len(segs) != chairs:
        raise SystemExit(f"{len(errors)} chairs failed: {errors[:3]}")
    by_name = {r.name: r for r in results}
    learned = []
    for s in segs:
        occupied = np.argwhere(s.grid.occupancy)  # np.argwhere order, as the labeller reads a grid
        truth = archive.get(s.name, s.grid.occupancy.shape).labels[tuple(occupied.T)]
        learned.append((s, by_name[s.name], truth))
    info = {"learned_from": f"the first {chairs} PartNet validation chairs of scripts/partnet_chairs.py's split",
            "shape_ids": [s.name for s in segs]}
    if mirror:  # each chair's left-right mirror too, abstracted again (docs/labeller.md)
        labeller = learn_labeller(learned, NAMES, segmenter.abstractor.parts, mirror=True, segmenter=segmenter,
                                  info=info, post=POST)
    else:
        labeller = fit_labeller(learned, NAMES, segmenter.abstractor.parts, info=info, post=POST)
    card = dict(meta["card"])
    card["labeller"] = {"shapes": chairs, "labels": NAMES, "data": "partnet_chair_boxes voxel labels, validation part",
                        "terms": TERMS, "mirrored": int(labeller.info.get("mirrored", 0)),
                        "command": "python -m scripts.build_chair_labeller" + (" --mirror" if mirror else " --no-mirror"),
                        "settings": labeller.settings.to_dict()}
    card["text"] = card["text"].rstrip("\n") + (
        f"{LABELLER_SECTION}(`segment --semantic` names each voxel, face or point with it): learned from the first "
        f"{chairs} PartNet validation chairs (scripts/partnet_chairs.py's split; never the test part)"
        f"{' and their left-right mirrors' if mirror else ''} with "
        f"`python -m scripts.build_chair_labeller`; docs/labeller.md gives its figures. Terms: {TERMS}.\n")
    out = write_labeller(source, output, labeller, {"card": card}, overwrite=overwrite)
    check_unchanged(source, out, meta)  # the network and every other key unchanged
    back = read_labeller(out)
    print(f"wrote {out}: {out.stat().st_size} bytes (the file it started from: {source.stat().st_size}), "
          f"{len(back.ensemble.feature)} tree nodes, prior weight {back.settings.prior_weight}; post-steps "
          f"{back.post} (checks: {back.info.get('post_check')})")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--chairs", type=int, default=None, help="the first N validation chairs (default: all 219)")
    ap.add_argument("--cache", type=Path, default=None, help="the abstractions' cache folder")
    ap.add_argument("--mirror", action=argparse.BooleanOptionalAction, default=True,
                    help="learn from each chair's left-right mirror too (name-parts --mirror; better arms on the "
                         "validation chairs: docs/labeller.md)")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    build(args.output, args.chairs, args.cache, mirror=args.mirror, overwrite=args.force)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

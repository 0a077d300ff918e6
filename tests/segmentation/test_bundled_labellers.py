"""The bundled table and airplane models' labellers (``scripts/build_labellers.py``): learned from
procedural shapes and said so in their cards, the networks untouched, and held-out procedural
shapes named by ``segment --semantic`` about as well as the cards claim."""

import hashlib
import json

import numpy as np
import pytest

from primkit import io, synthetic
from primkit.cli import main
from primkit.model.bundled import resolve_model
from primkit.model.modelfile import read_metadata
from primkit.segmentation import labeller as lab
from primkit.segmentation.evaluation import read_ground_truth

#: what the labeller may not change: digests of each file's network tensors and of its metadata
#: without the labeller, the card's labeller entry, the card text after "Part labeller" and the fit
#: reference (:func:`primkit.model.abstraction.fit_reference`), taken
#: from the files before they had a labeller (the airplane at commit 455eeb7; the table model retrained
#: at parsimony 1e-5, before scripts/build_labellers.py --install --categories table)
FROZEN = {
    "table": "b48ab06d34f596f1143d08dca4c6a6acdeaab3e2e16ca1ba8e88a48b316b869b",
    "airplane": "80a4dad2a8d2ca686ed18ca8fba4a390fe024c1d5b773ffd178b05846447206c",
}
LABELS = {"table": ["top", "legs", "base"], "airplane": ["fuselage", "wings", "tail", "engines"]}


def frozen_digest(path) -> str:
    """SHA-256 over the tensors that are not the labeller's (name, dtype, shape, bytes; sorted by
    name) and the metadata a labeller leaves alone (JSON, sorted keys)."""
    from safetensors import safe_open

    h = hashlib.sha256()
    with safe_open(str(path), framework="numpy") as f:
        for name in sorted(k for k in f.keys() if not k.startswith(lab.LABELLER_PREFIX)):
            a = np.ascontiguousarray(f.get_tensor(name))
            h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
            h.update(a.tobytes())
    meta = read_metadata(path)
    card = {k: v for k, v in meta["card"].items() if k not in ("labeller", "text")}
    card["text"] = meta["card"]["text"].split("\n\nPart labeller ")[0].rstrip("\n")  # the section follows a blank line
    # the fit reference came later, from scripts/fit_reference.py (which checks that it changes nothing else)
    rest = {k: v for k, v in meta.items() if k not in ("card", lab.LABELLER_KEY, "created", "fit_reference")}
    h.update(json.dumps({"card": card, **rest}, sort_keys=True).encode())
    return h.hexdigest()


@pytest.mark.parametrize("category", ["table", "airplane"])
def test_the_labeller_changed_nothing_else_in_the_model_file(category):
    assert frozen_digest(resolve_model(category)) == FROZEN[category]


@pytest.mark.parametrize("category", ["table", "airplane"])
def test_the_card_says_the_labeller_was_learned_from_procedural_shapes(category):
    path = resolve_model(category)
    got = lab.read_labeller(path)  # safetensors and JSON: no code runs (tests/segmentation/test_labeller.py)
    assert got is not None and got.names == LABELS[category] and got.parts == 20
    card = read_metadata(path)["card"]
    entry = card["labeller"]
    assert entry["procedural"] is True and entry["generator"] == "primkit.synthetic.generate"
    assert entry["shapes"] == got.info["shapes"] == entry["counts"]["train"]
    assert len(set(entry["seeds"].values())) == 3  # learned from, chosen on, reported on: three seeds
    assert "procedural shapes only" in card["text"] and "Terms:" in card["text"]
    assert entry["held_out_procedural"]["labeller"]["shapes"] == entry["counts"]["test"]
    from primkit.model.modelfile import read_header

    _, tensors = read_header(path)
    stored = sum(np.prod(shape, dtype=np.int64) * {"F64": 8, "I64": 8, "I16": 2, "U8": 1}[kind]
                 for name, (shape, kind) in tensors.items() if name.startswith(lab.LABELLER_PREFIX))
    assert 0 < stored < 100_000  # the labeller's arrays small beside the 450 kB network (bundled models: < 4 MiB)


@pytest.mark.integration  # six shapes generated, abstracted and named through the CLI
@pytest.mark.parametrize("category", ["table", "airplane"])
def test_segment_semantic_names_held_out_procedural_shapes_as_the_card_claims(category, tmp_path):
    """The first six held-out procedural shapes (the card's test seed) named by ``primkit segment
    --semantic`` with default flags: the share of their surface named right, area-weighted, at
    least the card's figure (over all its 60 held-out shapes) less 0.02. These six score 1.000 (table)
    and 0.999 (airplane) against claims of 1.000 and 0.996; naming by index alone (the card's
    ``index_names``: 0.959 and 0.770) falls below the bound."""
    entry = read_metadata(resolve_model(category))["card"]["labeller"]
    claim = entry["held_out_procedural"]["labeller"]["area_right"]
    files = synthetic.write_collection(tmp_path / "in", category, 6, seed=entry["seeds"]["test"])
    out = tmp_path / "seg"
    assert main(["segment", str(tmp_path / "in"), "--model", category, "-o", str(out), "--semantic",
                 "--workers", "1"]) == 0
    codes = [line.split(",") for line in (out / "labels.csv").read_text().splitlines()[1:]]
    names = {int(c): n for c, n in codes}
    right = []
    for f in files:
        mesh = io.read_mesh(f)
        truth = read_ground_truth(f.with_suffix(".seg"), len(mesh.faces), names=list(LABELS[category]))
        got = io.read_labels(out / f"{f.stem}.seg", len(mesh.faces))
        got = np.array([LABELS[category].index(names[c]) if c > 0 else -1 for c in got])
        v = mesh.vertices[mesh.faces]
        area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)  # by hand, not trimesh
        ok = truth.labels >= 0
        right.append(area[ok & (got == truth.labels)].sum() / area[ok].sum())
    assert np.mean(right) >= claim - 0.02, (np.round(right, 3), claim)

"""Labeller post-steps: chosen by name when fitting, never by how a label is spelled; their labels
are parameters; stored with every parameter and read back."""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import pytest

from primkit import primitives
from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.segmentation.labeller import Labeller, LabellerSettings, decide, frame_features
from primkit.labelling.layers import LayerCut
from primkit.labelling.post import parse_post, resolve_post, step_from_dict, step_to_dict
from primkit.labelling.presence import PresenceRule

from test_presence import _chair

CHAIR = ["back", "seat", "legs", "arms"]
KINDS = ("rests", "sofa", "none", "rests")


def _grid_chair(kind):
    """``(points, grid index, labels)`` of test_presence's 24-cell chair ``kind`` as a voxel grid:
    0 the back (x <= 1), 2 the legs (below the seat plate), 3 the arms, 1 the rest (the seat)."""
    points, arm = _chair(kind)
    index = np.rint((points + 0.5) * 24 - 0.5).astype(np.int64)
    y = np.ones(len(points), np.int64)
    y[index[:, 0] <= 1] = 0
    y[index[:, 1] < 10] = 2
    y[arm] = 3
    return points, index, y


@functools.lru_cache(maxsize=None)
def _set():
    """The labelled set: each chair's features (one set of random cuboids) and labels."""
    rng = np.random.default_rng(5)
    settings = LabellerSettings(neighbours=8, smooth=0)
    c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), rng.normal(size=(5, 4)), rng.uniform(-0.4, 0.4, (5, 3)),
                           np.ones(5, bool))
    shapes = []
    for kind in KINDS:
        points, _, y = _grid_chair(kind)
        shapes.append((frame_features(points, c, None, settings), y))
    return shapes, settings, c


def _fit(names, **post):
    shapes, settings, c = _set()
    return Labeller.fit(shapes, list(names), 5, settings=settings, max_iter=10, **post), c


def _labels(labeller, c):
    out = []
    for kind in KINDS:
        points, index, _ = _grid_chair(kind)
        out.append(labeller.predict(points, c, grid_index=index))
    return out


def test_renamed_labels_get_the_same_labels_when_the_steps_are_told_the_names():
    """"arms" renamed "armrest" and "seat" renamed "Seat": the chair steps given those names keep
    the same rules (the same checks) and give every shape the same labels, element for element."""
    plain, c = _fit(CHAIR, post="chair")
    renamed_names = ["back", "Seat", "legs", "armrest"]
    renamed, _ = _fit(renamed_names, post=["chair.arms_from_side_region:label=armrest",
                                           {"step": "chair.seat_layer_cut", "upper": "Seat"}])
    assert plain.post == (PresenceRule(), LayerCut())
    assert renamed.post == (PresenceRule(label="armrest"), LayerCut(upper="Seat"))
    assert renamed.info["post_check"] == plain.info["post_check"]
    assert renamed.names == renamed_names
    for a, b in zip(_labels(plain, c), _labels(renamed, c)):
        np.testing.assert_array_equal(a, b)
    # the steps do act on this set: without them some shape is labelled otherwise
    bare = replace(plain, post=())
    assert any(np.any(a != b) for a, b in zip(_labels(plain, c), _labels(bare, c)))


def test_no_step_is_chosen_by_a_labels_spelling():
    """Without ``post`` no rule runs, whatever the labels are called: a chair's own "arms" and
    "seat", or a lamp's "arms"; the chair steps asked for by their default names do not switch on
    for labels spelled otherwise."""
    chair, c = _fit(CHAIR)
    assert chair.post == () and "post_check" not in chair.info
    lamp, _ = _fit(["base", "shade", "cord", "arms"])  # a lamp-like set with an "arms" label
    assert lamp.post == ()
    shapes, settings, _ = _set()
    for kind in KINDS:
        points, index, _ = _grid_chair(kind)
        proba = lamp.predict_proba(points, c, grid_index=index)
        np.testing.assert_array_equal(lamp.predict(points, c, grid_index=index),
                                      decide(proba, lamp.settings.min_share))
    renamed, _ = _fit(["back", "Seat", "legs", "armrest"], post="chair")  # told no names: labels not learned
    assert renamed.post == ()


def test_the_steps_are_stored_by_name_with_every_parameter(tmp_path):
    labeller, c = _fit(["back", "Seat", "legs", "armrest"],
                       post=[PresenceRule(label="armrest", veto=0.02), LayerCut(upper="Seat", window=3)], post_check=False)
    path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller)
    _, description = labeller.to_tensors()
    assert description["post"] == [
        {"step": "chair.arms_from_side_region", "label": "armrest", "veto": 0.02, "add": 0.1, "fill": 0.1,
         "grid_add": 0.05, "hint": 0.1, "hint_add": 2.0, "grid_hint_add": 0.025},
        {"step": "chair.seat_layer_cut", "upper": "Seat", "lower": "legs", "share": 0.6, "window": 3, "floor": 0.2,
         "restore": True}]
    got = lab.read_labeller(path)
    assert got.post == labeller.post
    for a, b in zip(_labels(got, c), _labels(labeller, c)):
        np.testing.assert_array_equal(a, b)
    for step in labeller.post:
        assert step_from_dict(step_to_dict(step)) == step


def test_post_specs():
    assert resolve_post(None) == [] and resolve_post(()) == []
    assert resolve_post("chair") == [PresenceRule(), LayerCut()]
    assert resolve_post(["chair.seat_layer_cut:upper=Seat,window=3,restore=false"]) == \
        [LayerCut(upper="Seat", window=3, restore=False)]
    assert parse_post("chair.arms_from_side_region: label = armrest , veto=0.02") == \
        [PresenceRule(label="armrest", veto=0.02)]
    assert resolve_post(PresenceRule(label="x")) == [PresenceRule(label="x")]
    for bad, needle in (("lamp", "unknown post-step"), ("chair:label=x", "takes no parameters"),
                        ("chair.seat_layer_cut:colour=red", "no parameter colour"),
                        ("chair.seat_layer_cut:window", "KEY=VALUE"), ("chair.seat_layer_cut:window=-1", "window"),
                        ({"step": "lamp.x"}, "unknown post-step"), (3, "not int")):
        with pytest.raises(ValueError, match=needle) as err:
            resolve_post(bad)
        assert len(str(err.value).splitlines()) == 1


def test_name_parts_refuses_an_unknown_step_in_one_line_before_any_work(tmp_path, capsys):
    from primkit.cli import main

    out = tmp_path / "named.safetensors"
    code = main(["name-parts", str(tmp_path / "none"), "--model", "chair", "-o", str(out),
                 "--post", "chair.seat_layer_cut:colour=red"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists()
    assert len(err.splitlines()) == 1 and "--post" in err and "no parameter colour" in err

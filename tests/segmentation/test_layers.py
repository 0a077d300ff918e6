"""The seat/legs layer cut: against a plain per-element loop, on a hand-built chair grid, off
layers, in Labeller.fit and Labeller.predict, and in storage (round trip, hostile values, files
from before it)."""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import numpy as np
import pytest

from primkit import primitives
from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.segmentation.labeller import Labeller, LabellerSettings, decide, frame_features
from primkit.labelling.layers import LayerCut, apply_layer_cut, layer_levels

from small_labellers import rewrite_description

BACK, SEAT, LEGS = 0, 1, 2


def _loop(labels, proba, heights, upper, lower, cut):
    """The cut element by element: layers by sorting the distinct heights, every cut in the window
    costed by summing over the elements."""
    labels = [int(v) for v in labels]
    if upper not in labels or (lower not in labels and not cut.restore):
        return labels
    values = sorted(set(float(h) for h in heights))
    layer = [values.index(float(h)) for h in heights]
    count = [layer.count(k) for k in range(len(values))]
    low = math.ceil(round(cut.floor * len(values), 9))
    if low >= len(values):
        return labels
    densest = low + count[low:].index(max(count[low:]))
    bottom = densest
    while bottom > 0 and count[bottom - 1] >= cut.share * count[densest]:
        bottom -= 1
    if lower not in labels:  # restored: cut at the bottom itself, whatever the probabilities
        return [(lower if k < bottom else upper) if v == upper else v for v, k in zip(labels, layer)]
    best = None
    for h in range(max(bottom - cut.window, 0), min(bottom + cut.window, len(values)) + 1):
        cost = 0.0
        for v, p, k in zip(labels, proba, layer):
            if v in (upper, lower):
                s = p[upper] / (p[upper] + p[lower]) if p[upper] + p[lower] > 0 else 0.5
                cost += s if k < h else 1.0 - s
        if best is None or cost < best[0]:
            best = (cost, h)
    return [(lower if k < best[1] else upper) if v in (upper, lower) else v for v, k in zip(labels, layer)]


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("cut", [LayerCut(), LayerCut(share=0.3, window=0), LayerCut(share=1.0, window=3, floor=0.0),
                                 LayerCut(floor=0.5), LayerCut(restore=False)])
def test_the_cut_is_a_per_element_loop(seed, cut):
    rng = np.random.default_rng(seed)
    n = 300
    heights = (rng.integers(0, 12, n) + 0.5) / 24.0 - 0.5  # 12 layers of a 24-cell grid, canonical units
    labels = rng.integers(0, 4, n)
    if seed % 2:  # no legs: restored (or left alone)
        labels[labels == LEGS] = BACK
    proba = rng.random((n, 4))
    # dyadic probabilities (multiples of 1/8 over a total of 1/2): every cost sums exactly, no near-ties
    proba[:, SEAT] = rng.integers(0, 5, n) / 8.0
    proba[:, LEGS] = 0.5 - proba[:, SEAT]
    proba[rng.random(n) < 0.05, SEAT: LEGS + 1] = 0.0  # both 0: weighs a half either way
    got = apply_layer_cut(labels, proba, heights, SEAT, LEGS, cut)
    np.testing.assert_array_equal(got, _loop(labels, proba, heights, SEAT, LEGS, cut))
    others = ~np.isin(labels, [SEAT, LEGS])
    np.testing.assert_array_equal(got[others], labels[others])  # only seat and legs move


def _chair(sled=False):
    """A 24-cell chair grid (x front, y up, z across): a seat slab two layers thick (y 9-10) over
    x 2-21, z 4-19, a back at x 0-1 from y 11 to 23, four 2 x 2 legs under the seat corners
    (``sled``: standing on a plate on the floor, y 0, larger than the seat, labelled legs).
    Returns the voxel indices, canonical centres and labels."""
    g = np.mgrid[0:24, 0:24, 0:24].reshape(3, -1).T
    x, y, z = g.T
    seat = (y >= 9) & (y <= 10) & (x >= 2) & (x <= 21) & (z >= 4) & (z <= 19)
    back = (x <= 1) & (y >= 11) & (z >= 4) & (z <= 19)
    legs = (y < 9) & (np.isin(x, [2, 3, 20, 21])) & np.isin(z, [4, 5, 18, 19])
    if sled:
        legs |= (y == 0) & (z >= 2) & (z <= 21)
    keep = seat | back | legs
    truth = np.where(seat, SEAT, np.where(legs, LEGS, BACK))[keep]
    return g[keep], (g[keep] + 0.5) / 24.0 - 0.5, truth


@pytest.mark.parametrize("sled", [False, True])
def test_the_cut_puts_the_seat_bottom_back(sled):
    """A decision that called the seat's lower layer legs in places and the legs' top seat: the
    probabilities favour the true boundary on the whole, and the cut restores it everywhere (on a
    sled too: its plate on the floor is the densest layer, which the cut does not take for a seat)."""
    index, points, truth = _chair(sled)
    rng = np.random.default_rng(0)
    proba = np.zeros((len(truth), 3))
    proba[np.arange(len(truth)), truth] = 1.0
    seat_bottom = (truth == SEAT) & (index[:, 1] == 9)
    legs_top = (truth == LEGS) & (index[:, 1] == 8)
    for rows, s in ((seat_bottom, 0.65), (legs_top, 0.35)):
        proba[rows, SEAT], proba[rows, LEGS] = s, 1 - s
        flip = rows & (rng.random(len(truth)) < 0.4)  # these went the wrong way
        proba[flip, SEAT], proba[flip, LEGS] = 1 - s, s
    labels = decide(proba)
    assert np.count_nonzero(labels != truth) > 20
    np.testing.assert_array_equal(apply_layer_cut(labels, proba, points[:, 1], SEAT, LEGS, LayerCut()), truth)
    if sled:  # sought from the floor up, the seat's bottom would be the plate, the cut off the boundary
        assert np.bincount(index[:, 1]).argmax() == 0
        assert np.any(apply_layer_cut(labels, proba, points[:, 1], SEAT, LEGS, LayerCut(floor=0.0)) != truth)
    # on its own truth the cut moves nothing: this chair does not contradict it
    np.testing.assert_array_equal(apply_layer_cut(truth, np.eye(3)[truth], points[:, 1], SEAT, LEGS, LayerCut()),
                                  truth)


def test_elements_off_layers_or_without_both_labels_are_left_alone():
    _, points, truth = _chair()
    proba = np.full((len(truth), 3), 1 / 3)
    rng = np.random.default_rng(1)
    off = points[:, 1] + rng.uniform(-0.01, 0.01, len(points))  # a surface's heights: no layers
    assert layer_levels(off) is None and layer_levels(points[:, 1]) is not None
    np.testing.assert_array_equal(apply_layer_cut(truth, proba, off, SEAT, LEGS, LayerCut()), truth)
    no_seat = np.where(truth == SEAT, BACK, truth)
    np.testing.assert_array_equal(apply_layer_cut(no_seat, proba, points[:, 1], SEAT, LEGS, LayerCut()), no_seat)
    no_legs = np.where(truth == LEGS, SEAT, truth)  # restored only when the cut says so
    np.testing.assert_array_equal(apply_layer_cut(no_legs, proba, points[:, 1], SEAT, LEGS, LayerCut(restore=False)),
                                  no_legs)
    # more layers than the grid has sides: not a grid's layers
    assert layer_levels(points[:, 1], most=10) is None


@pytest.mark.parametrize("called", [SEAT, BACK])
def test_feet_called_seat_are_restored(called):
    """A chair whose legs the decision called seat (or, dropped as a rare label, back): with no
    legs left, everything labelled seat below the seat's bottom becomes legs, whatever the
    probabilities there say; a shape standing on its seat's block has nothing below it."""
    index, points, truth = _chair()
    proba = np.zeros((len(truth), 3))
    proba[:, SEAT] = 1.0  # the probabilities agree with the mistake
    labels = np.where(truth == LEGS, called, truth)
    got = apply_layer_cut(labels, proba, points[:, 1], SEAT, LEGS, LayerCut())
    want = np.where(labels == SEAT, np.where(index[:, 1] < 9, LEGS, SEAT), labels)  # the seat's bottom: y 9
    np.testing.assert_array_equal(got, want)
    if called == SEAT:
        np.testing.assert_array_equal(got, truth)
    # a sofa on its seat's block: each layer under the seat as full as the seat, no bottom above the floor
    grid = np.mgrid[0:24, 0:24, 0:24].reshape(3, -1).T
    x, y, z = grid.T
    block = (y < 9) & (x >= 2) & (x <= 21) & (z >= 4) & (z <= 19)
    upper = index[:, 1] >= 9
    heights = np.concatenate([points[upper, 1], (y[block] + 0.5) / 24.0 - 0.5])
    sofa = np.concatenate([labels[upper], np.full(np.count_nonzero(block), SEAT)])
    np.testing.assert_array_equal(apply_layer_cut(sofa, np.eye(3)[sofa], heights, SEAT, LEGS, LayerCut()), sofa)


def test_layers_take_heights_a_rounding_apart_as_one():
    heights = np.repeat((np.arange(5) + 0.5) / 24.0 - 0.5, 4)
    heights[::4] += 1e-15
    np.testing.assert_array_equal(layer_levels(heights), np.repeat(np.arange(5), 4))


@functools.lru_cache(maxsize=None)
def _learned(names, layer_cut, raise_legs=0):
    """A labeller learned from three copies of the chair grid (``raise_legs`` of them labelling
    the seat's lower layer legs too, which the cut contradicts) and cuboids to read."""
    rng = np.random.default_rng(0)
    settings = LabellerSettings(neighbours=8, smooth=0)
    index, points, truth = _chair()
    c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), rng.normal(size=(5, 4)),
                           rng.uniform(-0.4, 0.4, (5, 3)), np.ones(5, bool))
    shapes = []
    for k in range(3):
        y = truth.copy()
        if k < raise_legs:
            y[(truth == SEAT) & (index[:, 1] <= 10)] = LEGS  # all of the seat's layers called legs but the top...
            y[(truth == SEAT) & (index[:, 1] == 10) & (index[:, 0] < 12)] = SEAT  # ...but half the top layer
        shapes.append((frame_features(points, c, None, settings), y))
    # "auto": the cut step with its defaults, checked on the labelled grids; a cut: kept unchecked
    post = {"post": LayerCut.STEP} if layer_cut == "auto" else {} if layer_cut is None \
        else {"post": layer_cut, "post_check": False}
    return Labeller.fit(shapes, list(names), 5, settings=settings, max_iter=10, **post), c


def _check(shapes, contradicted):
    return [{"step": LayerCut.STEP, "shapes": shapes, "contradicted": contradicted}]


def test_fit_keeps_the_cut_when_it_learns_seat_and_legs():
    got = _learned(("back", "seat", "legs"), "auto")[0]
    assert got.post == (LayerCut(),) and got.info["post_check"] == _check(3, 0)
    assert _learned(("back", "seat", "arms"), "auto")[0].post == ()  # no legs
    assert _learned(("back", "seat", "legs"), None)[0].post == ()


def test_fit_keeps_no_cut_without_a_labelled_grid():
    """Surface points (heights on no layers) cannot be checked against the cut: none is kept."""
    rng = np.random.default_rng(2)
    settings = LabellerSettings(neighbours=8, smooth=0)
    _, points, truth = _chair()
    c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), rng.normal(size=(5, 4)),
                           rng.uniform(-0.4, 0.4, (5, 3)), np.ones(5, bool))
    shapes = [(frame_features(points + rng.uniform(-0.01, 0.01, points.shape), c, None, settings), truth)
              for _ in range(3)]
    got = Labeller.fit(shapes, ["back", "seat", "legs"], 5, settings=settings, max_iter=10, post="chair.seat_layer_cut")
    assert got.post == () and got.info["post_check"] == _check(0, 0)


def test_fit_leaves_the_cut_out_when_the_labelled_grids_contradict_it():
    got = _learned(("back", "seat", "legs"), "auto", raise_legs=1)[0]  # one in three: over 20%
    assert got.post == () and got.info["post_check"] == _check(3, 1)


def test_predict_applies_the_cut_on_grids_only():
    labeller, c = _learned(("back", "seat", "legs"), LayerCut(window=3))
    index, points, _ = _chair()
    proba = labeller.predict_proba(points, c)
    plain = decide(proba, labeller.settings.min_share)
    want = apply_layer_cut(plain, proba, points[:, 1], SEAT, LEGS, LayerCut(window=3), 24)
    np.testing.assert_array_equal(labeller.predict(points, c, grid_index=index), want)
    np.testing.assert_array_equal(labeller.predict(points, c), plain)  # points: no grid, no cut
    np.testing.assert_array_equal(replace(labeller, post=()).predict(points, c, grid_index=index), plain)


def test_the_cut_is_stored_and_read_back(tmp_path):
    labeller, c = _learned(("back", "seat", "legs"), LayerCut("seat", "legs", 0.4, 3, 0.1))
    path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller)
    got = lab.read_labeller(path)
    assert got.post == (LayerCut("seat", "legs", 0.4, 3, 0.1),)
    index, points, _ = _chair()
    np.testing.assert_array_equal(got.predict(points, c, grid_index=index),
                                  labeller.predict(points, c, grid_index=index))


#: a valid stored cut, spoilt one key at a time below
_CUT = {"upper": "seat", "lower": "legs", "share": 0.6, "window": 2, "floor": 0.2, "restore": True}


@pytest.mark.parametrize("cut", [{**_CUT, "share": 0}, {**_CUT, "window": -1}, {**_CUT, "window": 2.5},
                                 {**_CUT, "share": "x"}, {**_CUT, "window": 10**9}, {**_CUT, "floor": 1.0},
                                 {**_CUT, "floor": -0.1}, {**_CUT, "floor": None}, {**_CUT, "lower": "seat"},
                                 {**_CUT, "lower": "wheels"}, {**_CUT, "restore": 1}, {**_CUT, "restore": "yes"},
                                 {k: v for k, v in _CUT.items() if k != "restore"},
                                 {k: v for k, v in _CUT.items() if k not in ("floor", "restore")}, [1, 2], None])
def test_a_hostile_cut_is_refused_in_one_line(tmp_path, cut):
    labeller, _ = _learned(("back", "seat", "legs"), "auto")
    path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller)
    step = {"step": LayerCut.STEP, **cut} if isinstance(cut, dict) else cut
    bad = rewrite_description(path, tmp_path / "bad.safetensors", lambda d: d.update(post=[step]))
    with pytest.raises(lab.ModelFileError) as err:
        lab.read_labeller(bad)
    assert "layer cut" in str(err.value).replace("_", " ") and len(str(err.value).splitlines()) == 1

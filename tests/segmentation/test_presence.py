"""The arms presence rule: the side region on hand-built chairs, the rule against a plain
per-element loop, its place in Labeller.predict, and its storage (round trip, hostile values,
files from before it)."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from primkit import primitives
from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.segmentation.labeller import Labeller, LabellerSettings, decide, frame_features
from primkit.labelling.presence import PresenceRule, apply_presence, side_region

from small_labellers import rewrite_description


def _chair(arms: str):
    """A 24-cell chair (x front, y up, z across): a seat plate at y = 10 over z 4-19 (x 2-23), a
    back at x = 0-1 up to y = 23, four legs, and ``arms``: "none", "rests" (bars at y = 16 over x
    12-21 beside the seat, on posts at x = 21) or "sofa" (solid side blocks z 0-3 and 20-23 up to
    y = 16)."""
    g = np.mgrid[0:24, 0:24, 0:24].reshape(3, -1).T
    x, y, z = g.T
    inside = (z >= 4) & (z <= 19)
    seat = (y == 10) & inside & (x >= 2)
    back = (x <= 1) & (y >= 10) & inside
    legs = (y < 10) & np.isin(x, [2, 23]) & np.isin(z, [4, 19])
    side = (z == 2) | (z == 21)
    if arms == "rests":
        arm = side & (((y == 16) & (x >= 12) & (x <= 21)) | ((x == 21) & (y >= 10) & (y < 16)))
    elif arms == "sofa":
        arm = ((z <= 3) | (z >= 20)) & (y <= 16) & (x >= 2)
    else:
        arm = np.zeros(len(g), bool)
    keep = seat | back | legs | arm
    return (g[keep] + 0.5) / 24.0 - 0.5, arm[keep]


@pytest.mark.parametrize("arms", ["rests", "sofa"])
def test_the_side_region_lies_on_the_arms(arms):
    points, arm = _chair(arms)
    region = side_region(points)
    assert region.any() and np.all(arm[region])  # only arm elements, and some
    assert np.mean(region) >= PresenceRule().veto


def test_a_chair_without_arms_has_no_side_region():
    points, _ = _chair("none")
    assert not side_region(points).any()


def _loop(labels, proba, region, label, rule, weights=None, grid=False):
    """The rule one element at a time."""
    add = rule.grid_add if grid else rule.add
    weights = [1.0] * len(region) if weights is None else weights
    inside = sum(w for r, w in zip(region, weights) if r)
    share = inside / sum(weights)
    leaning = inside > 0 and sum(w * p for r, w, p in zip(region, weights, proba[:, label]) if r) / inside >= rule.hint
    adds = share >= add or (share > 0 and share >= (rule.grid_hint_add if grid else rule.hint_add) and rule.hint <= 1
                            and leaning)
    has = any(v == label for v in labels)
    out = []
    for i, v in enumerate(labels):
        if has and share < rule.veto and v == label:
            out.append(max((c for c in range(proba.shape[1]) if c != label), key=lambda c: proba[i, c]))
        elif not has and adds and region[i]:
            out.append(label)
        elif has and share >= rule.veto and region[i] and proba[i, label] >= rule.fill:
            out.append(label)
        else:
            out.append(v)
    return np.array(out)


@pytest.mark.parametrize("hint", [0.1, 0.3, 2.0])
@pytest.mark.parametrize("fill", [0.1, 0.0, 2.0])
@pytest.mark.parametrize("seed", range(8))
def test_the_rule_is_a_per_element_loop(seed, fill, hint):
    rng = np.random.default_rng(seed)
    n = 200
    proba = rng.dirichlet(np.ones(4), n)
    labels = np.argmax(proba, axis=1)
    if seed % 2:
        labels[labels == 3] = 0  # no arms decided
    region = rng.random(n) < [0.0, 0.02, 0.05, 0.2, 0.5, 0.008, 0.1, 0.05][seed]  # seeds 1, 7: hint bands
    rule = PresenceRule("arms", 0.01, 0.1, fill, grid_add=0.03, hint=hint, hint_add=0.05, grid_hint_add=0.015)
    got = apply_presence(labels, proba, region, 3, rule)
    np.testing.assert_array_equal(got, _loop(labels, proba, region, 3, rule))
    on_grid = apply_presence(labels, proba, region, 3, rule, grid=True)  # a grid's voxels: grid_add
    np.testing.assert_array_equal(on_grid, _loop(labels, proba, region, 3, rule, grid=True))
    if not np.any(labels == 3) and 0.03 <= region.mean() < 0.05:  # added on a grid only (under the hint band too)
        assert np.array_equal(on_grid == 3, region) and not np.any(got == 3)
    weights = rng.uniform(0.0, 3.0, n) ** 3  # a mesh's face areas: the region's share by weight
    np.testing.assert_array_equal(apply_presence(labels, proba, region, 3, rule, weights),
                                  _loop(labels, proba, region, 3, rule, weights))
    share = region.mean()
    if share < 0.01:
        assert not np.any(got == 3)
    if not np.any(labels == 3) and share >= 0.1:
        np.testing.assert_array_equal(got == 3, region)
    leaning = region.any() and proba[region, 3].mean() >= hint
    if not np.any(labels == 3) and 0.05 <= share < 0.1:  # the hint's share: added when the labeller leans to arms
        assert np.array_equal(got == 3, region) if leaning else not np.any(got == 3)
    if not np.any(labels == 3) and 0.015 <= share < 0.03:  # the same on a grid, by grid_hint_add
        assert np.array_equal(on_grid == 3, region) if leaning else not np.any(on_grid == 3)
    if np.any(labels == 3) and share >= 0.01:  # the fill only adds, and only inside the region
        assert np.all(got[labels == 3] == 3) and np.all((got == labels) | region)
        if fill == 0.0:
            assert np.all(got[region] == 3)
        if fill > 1:
            np.testing.assert_array_equal(got, labels)


def _fit(names, presence="auto", kinds=("rests", "sofa", "none"), third="arms"):
    """A labeller learned from the hand-built chairs ``kinds`` (``presence``: "auto" asks for the
    arms step with its defaults, checked on the labelled shapes; None no step; a rule: that rule,
    kept unchecked): label 0 above the seat's middle
    height, 1 below, 2 on the ``third`` elements ("arms": the chair's arms; "legs": what lies
    under the seat plate; one for all or one per chair); the last chair's cuboids and points.
    The same arguments give the same (shared, not to be changed) objects."""
    thirds = (third,) * len(kinds) if isinstance(third, str) else tuple(third)
    return _learned(tuple(names), presence, tuple(kinds), thirds)


@functools.lru_cache(maxsize=None)
def _learned(names, presence, kinds, thirds):
    rng = np.random.default_rng(0)
    settings = LabellerSettings(neighbours=8, smooth=0)
    shapes = []
    for kind, third in zip(kinds, thirds):
        c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), rng.normal(size=(5, 4)),
                               rng.uniform(-0.4, 0.4, (5, 3)), np.ones(5, bool))
        points, arm = _chair(kind)
        y = (points[:, 1] > 0).astype(int)
        y[arm if third == "arms" else points[:, 1] < 10.5 / 24 - 0.5] = 2
        shapes.append((frame_features(points, c, None, settings), y))
    post = {"post": PresenceRule.STEP} if presence == "auto" else {} if presence is None \
        else {"post": presence, "post_check": False}
    return Labeller.fit(shapes, list(names), 5, settings=settings, max_iter=10, **post), c, points


def _check(shapes, contradicted):
    return [{"step": PresenceRule.STEP, "shapes": shapes, "contradicted": contradicted}]


def test_fit_keeps_the_rule_when_it_learns_arms():
    got = _fit(["back", "seat", "arms"])[0]
    assert got.post == (PresenceRule(),) and got.info["post_check"] == _check(3, 0)
    assert _fit(["back", "seat", "legs"])[0].post == ()  # the step's label "arms" is not learned
    assert _fit(["back", "seat", "arms"], presence=None)[0].post == ()


def test_fit_leaves_the_rule_out_when_the_labelled_shapes_contradict_it():
    """"arms" that do not rise beside a seat (here: what lies under it, on chairs without side
    arms): the rule would take them from every labelled shape, so the fit keeps none."""
    got = _fit(["back", "seat", "arms"], kinds=("none", "none", "none"), third="legs")[0]
    assert got.post == () and got.info["post_check"] == _check(3, 3)
    # one contradicting shape in five is within lab.POST_TOLERANCE (0.2): kept; two in five are not
    kinds = ("rests", "sofa", "rests", "none", "none")
    one = _fit(["back", "seat", "arms"], kinds=kinds, third=["arms"] * 4 + ["legs"])[0]
    assert one.post == (PresenceRule(),) and one.info["post_check"] == _check(5, 1)
    two = _fit(["back", "seat", "arms"], kinds=kinds, third=["arms"] * 3 + ["legs"] * 2)[0]
    assert two.post == () and two.info["post_check"] == _check(5, 2)


def test_predict_applies_the_rule_after_the_decision():
    labeller, c, _ = _fit(["back", "seat", "arms"], presence=PresenceRule("arms", 0.01, 0.0))  # add: always
    points, _ = _chair("rests")
    proba = labeller.predict_proba(points, c)
    plain = decide(proba, labeller.settings.min_share)
    want = apply_presence(plain, proba, side_region(points), 2, labeller.post[0])
    np.testing.assert_array_equal(labeller.predict(points, c), want)
    from dataclasses import replace

    np.testing.assert_array_equal(replace(labeller, post=()).predict(points, c), plain)


def test_predict_adds_by_grid_add_on_a_grid_only():
    """A rule that never adds on a surface (add above 1) and always on a grid (grid_add 0): the
    voxels of a grid, passed with their indices, get the region; the same points as a cloud do not."""
    rule = PresenceRule("arms", 0.0, 2.0, 2.0, grid_add=0.0)
    labeller, c, _ = _fit(["back", "seat", "arms"], presence=rule)
    points, _ = _chair("rests")
    index = np.rint((points + 0.5) * 24 - 0.5).astype(np.int64)
    proba = labeller.predict_proba(points, c, grid_index=index)
    proba[:, 2] = 0.0  # as if the labeller had found no arms
    plain = decide(proba, labeller.settings.min_share)
    region = side_region(points)
    assert region.any() and not np.any(plain == 2)
    np.testing.assert_array_equal(labeller.labels_from(proba, points, grid_index=index), np.where(region, 2, plain))
    np.testing.assert_array_equal(labeller.labels_from(proba, points), plain)


def test_the_hint_adds_a_small_region_only_when_the_labeller_leans_to_the_label():
    """The default rule on a voxel grid without arms decided and a side region of 3% of it (under
    grid_add, 5%, over grid_hint_add, 2.5%): arms when the region's mean arm probability reaches
    the hint (0.1), not below it; never from a region under 2.5%, nor on a surface (no hint_add)."""
    n = 1000
    labels = np.zeros(n, np.int64)
    region = np.zeros(n, bool)
    region[:30] = True
    rule = PresenceRule()
    for arm, want in ((0.12, True), (0.3, True), (0.08, False)):
        proba = np.tile([0.5, 0.5 - arm, 0.0, arm], (n, 1))
        got = apply_presence(labels, proba, region, 3, rule, grid=True)
        assert np.array_equal(got == 3, region) if want else not np.any(got == 3)
        # the same elements as a surface: the default rule has no hint there
        assert not np.any(apply_presence(labels, proba, region, 3, rule) == 3)
        surface = PresenceRule(hint_add=0.025)
        assert np.array_equal(apply_presence(labels, proba, region, 3, surface) == 3, region) if want \
            else not np.any(apply_presence(labels, proba, region, 3, surface) == 3)
    proba = np.tile([0.05, 0.05, 0.0, 0.9], (n, 1))
    small = np.zeros(n, bool)
    small[:24] = True  # 2.4%: under grid_hint_add
    assert not np.any(apply_presence(labels, proba, small, 3, rule, grid=True) == 3)
    # a mesh's faces (a rule with a hint there): the region's mean probability weighs each face by
    # its area. 70 faces (7%), 10 of them sure of arms: by count the mean is 1/7, by area (those
    # 10 tiny) about 0.002
    rule = PresenceRule(hint_add=0.05)
    proba = np.tile([0.5, 0.5, 0.0, 0.0], (n, 1))
    region = np.zeros(n, bool)
    region[60:130] = True
    proba[60:70] = [0.0, 0.0, 0.0, 1.0]
    weights = np.ones(n)
    weights[60:70] = 0.01
    assert 0.05 <= weights[region].sum() / weights.sum() < 0.1
    np.testing.assert_array_equal(apply_presence(labels, proba, region, 3, rule) == 3, region)
    assert not np.any(apply_presence(labels, proba, region, 3, rule, weights) == 3)


def test_the_rule_is_stored_and_read_back(tmp_path):
    labeller, c, points = _fit(["back", "seat", "arms"], presence=PresenceRule("arms", 0.02, 0.3, 0.25))
    path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller)
    got = lab.read_labeller(path)
    assert got.post == (PresenceRule("arms", 0.02, 0.3, 0.25),)
    np.testing.assert_array_equal(got.predict(points, c), labeller.predict(points, c))


#: a valid stored rule, spoilt one key at a time below
_RULE = {"label": "arms", "veto": 0.01, "add": 0.1, "fill": 0.1, "grid_add": 0.05, "hint": 0.1, "hint_add": 2.0,
         "grid_hint_add": 0.025}


@pytest.mark.parametrize("presence", [{**_RULE, "veto": -1}, {**_RULE, "veto": "x"}, {**_RULE, "label": "wings"},
                                      {**_RULE, "label": ""}, {**_RULE, "add": 1e300}, {**_RULE, "fill": -0.5},
                                      {**_RULE, "fill": None}, {**_RULE, "grid_add": -0.1}, {**_RULE, "grid_add": True},
                                      {**_RULE, "grid_add": "0.05"}, {**_RULE, "hint": -0.1}, {**_RULE, "hint": False},
                                      {**_RULE, "hint_add": 3.0}, {**_RULE, "grid_hint_add": [0.5]},
                                      {k: v for k, v in _RULE.items() if k != "add"},
                                      {k: v for k, v in _RULE.items() if k != "hint"},
                                      {**_RULE, "extra": 1}, [1, 2]])
def test_a_hostile_rule_is_refused_in_one_line(tmp_path, presence):
    labeller, _, _ = _fit(["back", "seat", "arms"])
    path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller)
    step = {"step": PresenceRule.STEP, **presence} if isinstance(presence, dict) else presence
    bad = rewrite_description(path, tmp_path / "bad.safetensors", lambda d: d.update(post=[step]))
    with pytest.raises(lab.ModelFileError) as err:
        lab.read_labeller(bad)
    assert PresenceRule.STEP in str(err.value) and len(str(err.value).splitlines()) == 1

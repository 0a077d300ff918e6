"""The labeller's side features against a per-element brute force, on a hand-built armchair and
sofa, their place in the feature vector, and labeller files from before them (format version 3)
still loading."""

from __future__ import annotations

import numpy as np
import pytest

from primkit import primitives
from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.segmentation.labeller import LabellerSettings, frame_features
from primkit.labelling.profile import profile_features
from primkit.labelling.sides import SIDE_FEATURES, side_features

from small_labellers import small_labeller, without_setting


def _brute(points, context, bins):
    """Each column of the module's table for one element at a time, by scanning the context
    points' cells (no histogram, no reductions over a grid)."""
    lo, hi = context.min(axis=0), context.max(axis=0)
    ext = np.maximum(hi - lo, 1e-9)
    cell = lambda p: np.clip(np.floor((p - lo) / ext * bins), 0, bins - 1).astype(int)  # noqa: E731
    cc = cell(context)
    slabs = [np.sum(cc[:, 1] == j) for j in range(bins)]
    seat = int(np.argmax(slabs))
    in_seat = cc[cc[:, 1] == seat]
    z_lo, z_hi = in_seat[:, 2].min(), in_seat[:, 2].max()
    x_lo, x_hi = in_seat[:, 0].min(), in_seat[:, 0].max()
    out = []
    for p in points:
        i, j, k = cell(p)
        r = (p - lo) / ext * bins
        column = cc[(cc[:, 0] == i) & (cc[:, 2] == k), 1]
        top, bottom = (column.max(), column.min()) if len(column) else (seat, seat)
        slab = cc[cc[:, 1] == j, 2]
        width = slab.max() - slab.min() + 1 if len(slab) else 0
        out.append([(top - seat) / bins, (bottom - seat) / bins,
                    abs(r[2] - (z_lo + z_hi + 1) / 2) / ((z_hi - z_lo + 1) / 2),
                    width / (z_hi - z_lo + 1), (r[0] - x_lo) / (x_hi - x_lo + 1)])
    return np.array(out)


@pytest.mark.parametrize("bins", [5, 24])
def test_side_features_read_as_a_brute_force_does(bins):
    rng = np.random.default_rng(bins)
    context = rng.normal(size=(700, 3)) * [0.3, 0.5, 0.2]
    points = np.vstack([context[:50], rng.normal(size=(40, 3)) * 0.4])  # some outside the context's box
    got = side_features(points, context, bins=bins)
    assert got.shape == (90, SIDE_FEATURES)
    np.testing.assert_allclose(got, _brute(points, context, bins), atol=1e-12)
    np.testing.assert_allclose(side_features(context[:60], None, bins), _brute(context[:60], context[:60], bins),
                               atol=1e-12)


def _chair(sofa: bool):
    """A 12 x 12 x 12 cell chair (x front, y up, z across): a seat plate at y = 5 over z 2-9, a back
    at x = 0 up to y = 11, and either thin arms on posts (x 6-10 at y 8, posts at x = 10) or a
    sofa's solid side blocks (z 0-1 and 10-11, y 0-8, x 1-11)."""
    g = np.mgrid[0:12, 0:12, 0:12].reshape(3, -1).T
    x, y, z = g.T
    seat = (y == 5) & (z >= 2) & (z <= 9) & (x >= 1)
    back = (x == 0) & (y >= 5) & (z >= 2) & (z <= 9)
    legs = (y < 5) & np.isin(x, [1, 11]) & np.isin(z, [2, 9])
    if sofa:
        arms = ((z <= 1) | (z >= 10)) & (y <= 8) & (x >= 1)
    else:
        arms = ((z == 1) | (z == 10)) & (((y == 8) & (x >= 6) & (x <= 10)) | ((x == 10) & (y >= 5) & (y < 8)))
    keep = seat | back | legs | arms
    return (g[keep] + 0.5) / 12.0, arms[keep], seat[keep], back[keep]


@pytest.mark.parametrize("sofa", [False, True])
def test_arms_rise_beside_the_seat_where_its_middle_does_not(sofa):
    points, arms, seat, back = _chair(sofa)
    f = side_features(points, bins=12)
    assert np.all(f[arms, 0] > 0)  # every arm column rises above the seat
    middle = seat & (np.abs(points[:, 2] - 0.5) < 0.1)
    np.testing.assert_array_equal(f[middle, 0], 0.0)  # the seat's middle: nothing above it
    assert f[arms, 2].min() > f[middle, 2].max()
    assert np.all(f[back, 4] < f[seat, 4].min())  # the back behind the seat's span


def test_the_side_features_end_the_frame_features():
    rng = np.random.default_rng(3)
    c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), rng.normal(size=(5, 4)), rng.uniform(-0.4, 0.4, (5, 3)),
                           np.array([True, True, False, True, True]))
    points, context = rng.uniform(-0.5, 0.5, (60, 3)), rng.uniform(-0.5, 0.5, (300, 3))
    on, off = LabellerSettings(neighbours=8, sides=True), LabellerSettings(neighbours=8, sides=False)
    a, b = frame_features(points, c, None, on, context), frame_features(points, c, None, off, context)
    assert a.shape == (60, lab.feature_count(5, on)) and lab.feature_count(5, on) == lab.feature_count(5, off) + 5
    np.testing.assert_array_equal(a[:, : b.shape[1]], b)
    np.testing.assert_array_equal(a[:, -15:-5], profile_features(points, context))
    np.testing.assert_array_equal(a[:, b.shape[1]:], side_features(points, context))


def test_the_sides_setting_is_stored_and_read_back(tmp_path):
    for settings in (LabellerSettings(neighbours=8, smooth=0, sides=False), LabellerSettings(neighbours=8, smooth=0, sides=True)):
        labeller, c, points = small_labeller(settings)
        path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller, overwrite=True)
        got = lab.read_labeller(path)
        assert got.settings == labeller.settings
        np.testing.assert_array_equal(got.predict(points, c), labeller.predict(points, c))


def test_a_labeller_without_the_sides_setting_is_refused(tmp_path):
    """Every setting is written: a description without ``sides`` is refused in one line."""
    labeller, _, _ = small_labeller(LabellerSettings(neighbours=8, smooth=0, sides=True))
    path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller)
    with pytest.raises(lab.ModelFileError) as err:
        lab.read_labeller(without_setting(path, tmp_path / "bad.safetensors", "sides"))
    assert "settings" in str(err.value) and len(str(err.value).splitlines()) == 1


def test_bad_inputs_are_refused_in_one_line():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        side_features(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="empty"):
        side_features(np.zeros((4, 3)), np.zeros((0, 3)))
    assert side_features(np.zeros((0, 3))).shape == (0, SIDE_FEATURES)
    with pytest.raises(ValueError, match="finite"):
        side_features(np.array([[0.0, np.nan, 0.0], [1.0, 1.0, 1.0]]))


def test_the_last_side_column_is_the_profiles_height():
    rng = np.random.default_rng(5)
    context = rng.normal(size=(500, 3)) * [0.3, 0.5, 0.2]
    points = np.vstack([context[:40], rng.normal(size=(30, 3)) * 0.4])
    from primkit.labelling.sides import side_columns

    got = side_columns(points, context)
    np.testing.assert_array_equal(got[:, :SIDE_FEATURES], side_features(points, context))
    np.testing.assert_allclose(got[:, 5], profile_features(points, context)[:, 5], atol=1e-12)

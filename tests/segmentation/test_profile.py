"""The labeller's shape-profile features against a per-element brute force, their place in the
feature vector, and labeller files from before them (format version 2) still loading."""

from __future__ import annotations

import numpy as np
import pytest

from primkit import primitives
from primkit.model.bundled import resolve_model
from primkit.segmentation import labeller as lab
from primkit.segmentation.labeller import LabellerSettings, frame_features
from primkit.labelling.profile import PROFILE_BINS, PROFILE_FEATURES, box_cells, profile_features

from small_labellers import small_labeller, without_setting


def _brute(points, context, bins):
    """Each column of the module's table computed for one element at a time by counting the
    context points that share its slab, column or row (no cumulative sums, no bincount)."""
    lo, hi = context.min(axis=0), context.max(axis=0)
    ext = np.maximum(hi - lo, 1e-9)
    cell = lambda p: np.clip(np.floor((p - lo) / ext * bins), 0, bins - 1).astype(int)  # noqa: E731
    cc = cell(context)
    slabs = [np.sum(cc[:, 1] == j) for j in range(bins)]
    densest = (int(np.argmax(slabs)) + 0.5) / bins
    out = []
    for p in points:
        i, j, k = cell(p)
        rel = (p - lo) / ext
        column = (cc[:, 0] == i) & (cc[:, 2] == k)
        row = (cc[:, 1] == j) & (cc[:, 2] == k)
        ncol, nrow = max(column.sum(), 1), max(row.sum(), 1)
        out.append([*rel, abs(2 * rel[2] - 1), slabs[j] / max(slabs), rel[1] - densest,
                    np.sum(column & (cc[:, 1] > j)) / ncol, np.sum(column & (cc[:, 1] < j)) / ncol,
                    np.sum(row & (cc[:, 0] > i)) / nrow, np.sum(row & (cc[:, 0] < i)) / nrow])
    return np.array(out)


@pytest.mark.parametrize("bins", [5, 24])
def test_profile_features_count_as_a_brute_force_does(bins):
    rng = np.random.default_rng(bins)
    context = rng.normal(size=(700, 3)) * [0.3, 0.5, 0.2]
    points = np.vstack([context[:50], rng.normal(size=(40, 3)) * 0.4])  # some outside the context's box
    got = profile_features(points, context, bins=bins)
    assert got.shape == (90, PROFILE_FEATURES)
    np.testing.assert_allclose(got, _brute(points, context, bins), atol=1e-12)
    np.testing.assert_allclose(profile_features(context[:60], None, bins), _brute(context[:60], context[:60], bins),
                               atol=1e-12)


def test_profile_features_read_a_chair_like_block_as_expected():
    """A seat plate on four legs: the seat's slab is the densest, the legs have nothing above."""
    g = np.mgrid[0:10, 0:10, 0:10].reshape(3, -1).T.astype(float)  # x, y, z cells
    seat = g[g[:, 1] == 5]
    legs = np.array([p for p in g if p[1] < 5 and p[0] in (0, 9) and p[2] in (0, 9)])
    shape = np.vstack([seat, legs]) / 10.0
    f = profile_features(shape, bins=10)
    s, leg = f[: len(seat)], f[len(seat):]
    assert np.all(s[:, 4] == 1.0) and np.all(leg[:, 4] < 1.0)
    np.testing.assert_allclose(s[:, 5], 0.0, atol=0.06)  # the seat sits in the densest slab
    assert np.all(leg[:, 5] < 0) and np.all(s[:, 7] >= 0)
    np.testing.assert_allclose(leg[:, 6] + leg[:, 7] + 1 / 6, 1.0)  # a leg column: 5 leg cells + the seat
    assert np.all(leg[:, 6] > 0)  # the seat above each leg


def test_the_profile_ends_the_frame_features():
    rng = np.random.default_rng(3)
    c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), rng.normal(size=(5, 4)), rng.uniform(-0.4, 0.4, (5, 3)),
                           np.array([True, True, False, True, True]))
    points, context = rng.uniform(-0.5, 0.5, (60, 3)), rng.uniform(-0.5, 0.5, (300, 3))
    on = LabellerSettings(neighbours=8, profile=True, sides=False)
    off = LabellerSettings(neighbours=8, profile=False, sides=False)
    a, b = frame_features(points, c, None, on, context), frame_features(points, c, None, off, context)
    assert a.shape == (60, lab.feature_count(5, on)) and lab.feature_count(5, on) == lab.feature_count(5, off) + 10
    np.testing.assert_array_equal(a[:, : b.shape[1]], b)
    np.testing.assert_array_equal(a[:, b.shape[1]:], profile_features(points, context))


def test_the_profile_setting_is_stored_and_read_back(tmp_path):
    for settings in (LabellerSettings(neighbours=8, smooth=0, profile=False, sides=False), LabellerSettings(neighbours=8, smooth=0, profile=True, sides=False)):
        labeller, c, points = small_labeller(settings)
        path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller, overwrite=True)
        got = lab.read_labeller(path)
        assert got.settings == labeller.settings
        np.testing.assert_array_equal(got.predict(points, c), labeller.predict(points, c))


def test_a_labeller_without_the_profile_setting_is_refused(tmp_path):
    """Every setting is written: a description without ``profile`` is refused in one line."""
    labeller, _, _ = small_labeller(LabellerSettings(neighbours=8, smooth=0, profile=True, sides=False))
    path = lab.write_labeller(resolve_model("chair"), tmp_path / "l.safetensors", labeller)
    with pytest.raises(lab.ModelFileError) as err:
        lab.read_labeller(without_setting(path, tmp_path / "bad.safetensors", "profile"))
    assert "settings" in str(err.value) and len(str(err.value).splitlines()) == 1


@pytest.mark.parametrize("seed", range(4))
def test_box_cells_are_numpys_box_and_clipped_cells(seed):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(300, 3)) * [1.0, 2.0, 0.5]
    points[:5] = points[5]  # repeated points, and with seed 3 a flat box
    if seed == 3:
        points[:, 2] = 0.25
    lo, extent, cells = box_cells(points)
    want_lo = points.min(axis=0)
    want_extent = np.maximum(points.max(axis=0) - want_lo, 1e-9)
    np.testing.assert_array_equal(lo, want_lo)
    np.testing.assert_array_equal(extent, want_extent)
    np.testing.assert_array_equal(cells, np.clip(((points - want_lo) / want_extent * PROFILE_BINS).astype(np.int64),
                                                 0, PROFILE_BINS - 1))
    assert cells.max() == PROFILE_BINS - 1 or seed == 3

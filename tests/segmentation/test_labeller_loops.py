"""The labeller's Numba loops on a voxel grid against the plain NumPy, scipy and Python computations
they replace: the same numbers, bit for bit (``docs/labeller.md``, "Cost")."""

from __future__ import annotations

import numpy as np
import pytest

from primkit import primitives
from primkit.labelling import smoothing
from primkit.segmentation import labeller as lab
from primkit.segmentation.labeller import Labeller, LabellerSettings, TreeEnsemble, frame_features


def _cuboids(rng, m=6, absent=(3,)):
    q = rng.normal(size=(m, 4))
    return primitives.Cuboids(rng.uniform(0.05, 0.3, (m, 3)), q, rng.uniform(-0.4, 0.4, (m, 3)),
                              np.array([k not in absent for k in range(m)]))


def _random_grid(rng, shape=(12, 11, 10), fill=0.5):
    occupancy = rng.random(shape) < fill
    index = np.argwhere(occupancy)
    return occupancy, index, (index + 0.5) / 10 - 0.5


def _stumps(rng, X, classes=4, rounds=6) -> TreeEnsemble:
    """A hand-built ensemble (no scikit-learn): ``rounds`` rounds of one split per class, each on a
    random column of ``X`` at its median (so both sides are taken), random leaf values."""
    k = 1 if classes == 2 else classes
    trees = rounds * k
    f = rng.integers(0, X.shape[1], trees)
    t = np.median(X[:, f], axis=0)
    zero = np.zeros(trees)
    return TreeEnsemble(np.stack([f, zero, zero], 1).reshape(-1).astype(np.int64),
                        np.stack([t, zero, zero], 1).reshape(-1),
                        np.tile([1, 0, 0], trees).astype(np.uint8), np.tile([1, 0, 0], trees).astype(np.int64),
                        np.tile([2, 0, 0], trees).astype(np.int64), np.tile([0, 1, 1], trees).astype(np.uint8),
                        np.stack([zero, rng.normal(size=trees), rng.normal(size=trees)], 1).reshape(-1),
                        np.arange(0, 3 * trees + 1, 3, dtype=np.int64), np.arange(trees, dtype=np.int64) % k,
                        rng.normal(size=k), X.shape[1])


@pytest.mark.parametrize("shape,fill", [((5, 5, 5), 0.5), ((6, 9, 7), 0.3), ((32, 32, 32), 0.1), ((8, 6, 5), 1.0)])
def test_the_grid_gaussian_is_scipys_bit_for_bit(shape, fill):
    from scipy import ndimage

    occupancy = np.random.default_rng(1).random(shape) < fill
    got = smoothing._grid_gaussian(occupancy)
    np.testing.assert_array_equal(got, ndimage.gaussian_filter(occupancy.astype(float), 1.0))
    assert got.any()


def test_grid_normals_are_numpys_gradient_of_scipys_gaussian():
    from scipy import ndimage

    occupancy = np.random.default_rng(2).random((14, 9, 11)) < 0.35
    occupancy[:, 0, :] = True  # voxels on a face of the grid: the one-sided ends
    index = np.argwhere(occupancy)
    grad = -np.stack(np.gradient(ndimage.gaussian_filter(occupancy.astype(float), 1.0)), axis=-1)[tuple(index.T)]
    norm = np.linalg.norm(grad, axis=1, keepdims=True)
    want = np.divide(grad, norm, out=np.zeros_like(grad), where=norm > 1e-6)
    np.testing.assert_array_equal(lab.grid_normals(occupancy, index), want)
    small = np.zeros((4, 6, 6), bool)  # a side under 5 voxels: scipy's filter itself
    small[1:3, 2:5, 1:4] = True
    np.testing.assert_array_equal(lab.grid_normals(small, np.argwhere(small)),
                                  lab.grid_normals(small)[tuple(np.argwhere(small).T)])


def test_the_nearest_cuboid_is_assign_points_even_on_ties():
    rng = np.random.default_rng(3)
    c = _cuboids(rng, m=7, absent=(4,))
    sizes, quats, centres, present = (np.array(c.half_extents), np.array(c.quaternions), np.array(c.translations),
                                      np.array(c.existence))
    sizes[1], quats[1], centres[1] = sizes[0], quats[0], centres[0]  # a twin: every distance ties, index decides
    sizes[2], quats[2], centres[2] = 2 * sizes[5], quats[5], centres[5]  # around 5: inside both, volume decides
    c = primitives.Cuboids(sizes, quats, centres, present)
    points = np.vstack([rng.uniform(-0.6, 0.6, (1500, 3)), centres[0] + rng.uniform(-1, 1, (300, 3)) * sizes[0],
                        centres[5] + rng.uniform(-1, 1, (300, 3)) * sizes[5]])
    F = frame_features(points, c, None, LabellerSettings(neighbours=0, normals=False, profile=False))
    onehot = F[:, 3 : 3 + c.count]
    assert np.all(onehot.sum(axis=1) == 1)
    want = primitives.assign_points(points, c)
    np.testing.assert_array_equal(np.argmax(onehot, axis=1), want)
    assert {0, 2}.issubset(set(want.tolist())) and not {1, 4, 5} & set(want.tolist())


@pytest.mark.parametrize("classes", [2, 3, 4, 5, 8])
def test_the_smoothing_sums_each_class_over_the_neighbours_in_order(classes):
    rng = np.random.default_rng(4)
    proba = rng.random((300, classes))
    idx = rng.integers(0, 300, (300, 27))
    X = rng.normal(size=(50, lab.feature_count(6, LabellerSettings())))
    labeller = Labeller(["a", "b"] if classes == 2 else [str(k) for k in range(classes)], 6,
                        _stumps(rng, X, classes), LabellerSettings(smooth=2, smooth_neighbours=5))
    want = proba
    for _ in range(2):
        total = np.zeros_like(want)
        for j in range(5):
            total = total + want[idx[:, j]]
        want = total / 5
    got = labeller.smooth(proba, None, idx)
    assert got.shape == proba.shape
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("step", [1, 2, 4, 8])
def test_the_sampled_and_classified_voxels_are_the_lattice_and_the_unreached(step):
    rng = np.random.default_rng(5)
    occupancy, index, _ = _random_grid(rng, (9, 8, 7), 0.25)
    near = lab.grid_neighbours(index, occupancy.shape)
    classify, sampled = lab.sample_grid(index, near, step)
    odd = index % 2
    want = {1: np.ones(len(index), bool), 2: odd.sum(1) % 2 == 0, 4: (odd == odd[:, :1]).all(1),
            8: (odd == 0).all(1)}[step]
    np.testing.assert_array_equal(sampled, want)
    for i, v in enumerate(index):  # by coordinates: a sampled voxel in the 26 around
        reached = any(want[j] for j, w in enumerate(index) if 0 < np.abs(w - v).max() <= 1)
        assert classify[i] == (want[i] or not reached)
    assert (classify & ~sampled).any() or step in (1, 2)  # the sparser lattices leave some unreached


def test_the_fill_is_grid_samplings_mean_of_the_sampled_neighbours():
    rng = np.random.default_rng(6)
    occupancy, index, points = _random_grid(rng)
    c = _cuboids(rng, absent=())
    settings = LabellerSettings(neighbours=8, smooth=0, grid_sample=4, prior_weight=0.0)
    labeller = Labeller(["a", "b", "c"], c.count, _stumps(rng, frame_features(points, c, None, settings), 3),
                        settings, early_stop=None)
    near = lab.grid_neighbours(index, occupancy.shape)
    got = labeller.predict_proba(points, c, neighbours=near, grid_index=index)
    classify, around, use = lab.grid_sampling(index, near, 4)  # the arrays the fill used to be read from
    shape = lab.grid_local_shape(points, index, np.flatnonzero(classify), 8, occupancy.shape)
    want = np.zeros((len(points), 3))
    want[classify] = labeller.classify(frame_features(points[classify], c, None, settings, points, local_shape=shape))
    for row, (a, u) in zip(np.flatnonzero(~classify), zip(around, use)):
        total = np.zeros(3)
        for j in a[u]:  # in order
            total = total + want[j]
        want[row] = total / u.sum()
    np.testing.assert_array_equal(got, want)
    assert (~classify).sum() > len(points) / 2


def test_the_probabilities_are_scipys_softmax():
    from scipy.special import softmax

    rng = np.random.default_rng(7)
    X = rng.normal(size=(500, 9))
    ensemble = _stumps(rng, X, 4, rounds=10)
    np.testing.assert_array_equal(ensemble.predict_proba(X), softmax(ensemble.raw_predict(X), axis=1))


def test_the_column_range_is_numpys_min_and_max():
    from primkit.labelling.profile import column_range

    rng = np.random.default_rng(8)
    for a in (rng.integers(-50, 50, (1, 3)), rng.integers(-5, 900, (4000, 27)), rng.integers(0, 32, (300, 3)),
              rng.normal(size=(500, 3)), rng.normal(size=(1, 3)), rng.integers(0, 9, (50, 3)).astype(np.int32)):
        low, high = column_range(a)
        np.testing.assert_array_equal(low, a.min(axis=0))
        np.testing.assert_array_equal(high, a.max(axis=0))
        assert low.dtype == (np.float64 if a.dtype.kind == "f" else np.int64)


def test_the_profile_refuses_points_that_are_not_finite():
    from primkit.labelling.profile import profile_features

    points = np.random.default_rng(9).normal(size=(50, 3))
    context = points.copy()
    context[7, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        profile_features(points, context)

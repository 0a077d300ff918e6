"""The grid labellings tried in ``scripts/voxel_crf_check.py`` (issue 33, not adopted): its Numba
loops against plain Python on tiny grids."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from primkit.segmentation.labeller import grid_neighbours
from scripts import voxel_crf_check as vc


def _grid(seed, shape=(3, 3, 2), fill=0.7):
    rng = np.random.default_rng(seed)
    occupancy = rng.random(shape) < fill
    occupancy[0, 0, 0] = True
    index = np.argwhere(occupancy)
    return index, grid_neighbours(index, shape)


def _pairs(index):
    """Face-adjacent occupied voxels, each pair once, by comparing every two indices."""
    return [(a, b) for a, b in itertools.combinations(range(len(index)), 2)
            if np.abs(index[a] - index[b]).sum() == 1]


def _energy(labels, unary, pairs, lam):
    return sum(unary[v, l] for v, l in enumerate(labels)) + lam * sum(labels[a] != labels[b] for a, b in pairs)


@pytest.mark.parametrize("seed", range(3))
def test_the_neighbour_table_holds_each_face_pair_from_both_ends(seed):
    index, near = _grid(seed)
    table, weight = vc.neighbour_weights(near, 6)
    got = {(v, int(table[v, j])) for v in range(len(index)) for j in range(7) if weight[v, j] > 0}
    pairs = _pairs(index)
    assert got == {p for a, b in pairs for p in ((a, b), (b, a))}
    assert np.all(weight[weight > 0] == 1.0)


@pytest.mark.parametrize("seed", range(3))
def test_the_grid_energy_is_the_pairs_written_out(seed):
    index, near = _grid(seed)
    table, weight = vc.neighbour_weights(near, 6)
    rng = np.random.default_rng(seed)
    unary = rng.random((len(index), 3))
    labels = rng.integers(0, 3, len(index))
    assert np.isclose(vc.grid_energy(labels, unary, table, weight, 0.7), _energy(labels, unary, _pairs(index), 0.7))


@pytest.mark.parametrize("seed", range(4))
def test_icm_ends_in_a_local_minimum_no_dearer_than_its_start(seed):
    index, near = _grid(seed, (3, 3, 3))
    table, weight = vc.neighbour_weights(near, 6)
    rng = np.random.default_rng(seed)
    unary = rng.random((len(index), 3)) * 2
    start = np.argmin(unary, axis=1)
    got = vc.icm(unary, table, weight, 0.6, sweeps=50)
    energy = vc.grid_energy(got, unary, table, weight, 0.6)
    assert energy <= vc.grid_energy(start, unary, table, weight, 0.6) + 1e-12
    for v in range(len(index)):  # no single voxel's change lowers it
        for c in range(3):
            moved = got.copy()
            moved[v] = c
            assert vc.grid_energy(moved, unary, table, weight, 0.6) >= energy - 1e-12
    assert np.array_equal(vc.icm(unary, table, weight, 0.0), start)  # no pairs: the most probable


def test_icm_on_a_tiny_grid_with_a_strong_pull_finds_the_brute_force_minimum():
    index, near = _grid(1, (2, 2, 2), fill=1.0)
    table, weight = vc.neighbour_weights(near, 6)
    unary = np.zeros((8, 2))
    unary[0] = [0.0, 0.2]  # one voxel leans to 0, the rest to 1
    unary[1:, 0] = 0.3
    best = min(itertools.product(range(2), repeat=8), key=lambda ls: _energy(ls, unary, _pairs(index), 0.5))
    assert np.array_equal(vc.icm(unary, table, weight, 0.5), best)
    assert set(best) == {1}


def _field_reference(logp, index, near, weight, direction, mu, lam, rounds):
    """Mean field written out voxel by voxel, neighbour by neighbour."""
    n, k = logp.shape
    q = np.exp(logp - logp.max(axis=1, keepdims=True))
    q /= q.sum(axis=1, keepdims=True)
    for _ in range(rounds):
        new = np.zeros_like(q)
        for v in range(n):
            msg = logp[v].copy()
            for j in range(1, near.shape[1]):
                w = near[v, j]
                if w == v or weight[v, j] == 0:
                    continue
                for c in range(k):
                    msg[c] -= lam * weight[v, j] * sum(mu[direction[j], c, b] * q[w, b] for b in range(k))
            e = np.exp(msg - msg.max())
            new[v] = e / e.sum()
        q = new
    return q


@pytest.mark.parametrize("seed,conn", [(0, 6), (1, 6), (2, 26)])
def test_mean_field_is_the_updates_written_out(seed, conn):
    index, near = _grid(seed)
    table, weight = vc.neighbour_weights(near, conn)
    rng = np.random.default_rng(seed)
    logp = np.log(rng.dirichlet(np.ones(4), len(index)))
    mu = rng.random((6, 4, 4))
    direction = rng.integers(0, 6, table.shape[1])
    got = vc.mean_field(logp, table, weight, 0.8, 3, mu, direction)
    assert np.allclose(got, _field_reference(logp, index, table, weight, direction, mu, 0.8, 3), atol=1e-12)
    assert np.allclose(got.sum(axis=1), 1.0)
    # Potts and no pull: the probabilities themselves
    assert np.allclose(vc.mean_field(logp, table, weight, 0.0, 3), np.exp(logp))
    assert np.allclose(vc.mean_field(logp, table, weight, 0.8, 3),
                       _field_reference(logp, index, table, weight, np.zeros(table.shape[1], int), vc.potts(4), 0.8, 3))


def test_directions_follow_the_canonical_axes():
    index, near = _grid(0, (3, 3, 3), fill=1.0)
    points = index * 0.1  # canonical = grid axes
    got = vc.directions(points, near)
    steps = vc.neighbour_weights(near, 6)[0]
    for j in range(1, 7):
        v = index[steps[13, j]] - index[13]  # the centre voxel's neighbours
        axis = int(np.argmax(np.abs(v)))
        assert got[j] == 2 * axis + int(v[axis] > 0)
    swapped = vc.directions(points[:, [1, 0, 2]], near)  # x and y swapped: axes 0 and 1 trade places
    assert np.array_equal(swapped[1:7] // 2, np.array([1, 0, 2])[got[1:7] // 2])
    assert np.array_equal(swapped[1:7] % 2, got[1:7] % 2)


def test_the_directional_cost_is_free_inside_a_label_and_mirrors_across_a_direction():
    class Chairs:  # the shape of labeller_curve.Chairs that learn_directional reads
        arrays = {}

    rng = np.random.default_rng(0)
    for c in range(3):
        index = np.argwhere(np.ones((4, 4, 4), bool))
        truth = np.where(index[:, 1] >= 2, 0, 1) if c else rng.integers(0, 2, len(index))  # 0 above 1
        Chairs.arrays[f"c{c}"] = {"index": index, "truth": truth, "points": index * 0.1}
    mu = vc.learn_directional(Chairs, ["c0", "c1", "c2"], 2)
    assert np.allclose(np.einsum("dii->di", mu), 0.0)
    for axis in range(3):  # label b in direction +axis of a is label a in direction -axis of b
        assert np.allclose(mu[2 * axis + 1], mu[2 * axis].T)
    # label 0 sits above label 1 (+y is direction 3): a 1 above a 0 is dearer than a 0 above a 1
    assert mu[3, 0, 1] > mu[3, 1, 0] + 1.0

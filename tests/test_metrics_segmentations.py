"""Tests for the segmentation measures of primkit.metrics (1 - Rand index, Hamming distance, cut
discrepancy), against pair counting, set arithmetic and hand-worked values."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from primkit import metrics as M

# ----------------------------------------------------------------------------------------------
# independent references and meshes
# ----------------------------------------------------------------------------------------------


def brute_rand(a, b, w):
    """Pairs (i, j) drawn with replacement with probability w_i w_j, counted one by one."""
    w = np.asarray(w, float) / np.sum(w)
    total = 0.0
    for i in range(len(a)):
        for j in range(len(a)):
            if (a[i] == a[j]) != (b[i] == b[j]):
                total += w[i] * w[j]
    return total


def brute_hamming(labels, reference, w):
    """The benchmark's directional distances with Python sets: for each segment of ``one``, the
    weight outside the segment of ``other`` that overlaps it most."""
    w = np.asarray(w, float) / np.sum(w)

    def segments(x):
        return [{i for i in range(len(x)) if x[i] == v} for v in set(x.tolist())]

    def directed(one, other):
        total = 0.0
        for seg in segments(one):
            best = max(segments(other), key=lambda s: sum(w[i] for i in seg & s))
            total += sum(w[i] for i in seg - best)
        return total

    return directed(reference, labels), directed(labels, reference)  # Rm, Rf


def grid(n, offset=(0.0, 0.0)):
    """The unit square (shifted by ``offset``) as an n x n grid of cells, two triangles each."""
    xs = np.linspace(0, 1, n + 1)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([x.ravel() + offset[0], y.ravel() + offset[1], np.zeros(x.size)], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return vertices, faces


def centres(vertices, faces):
    return vertices[faces].mean(axis=1)


OCTAHEDRON_V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
OCTAHEDRON_F = np.array([[0, 2, 4], [0, 4, 3], [0, 3, 5], [0, 5, 2], [1, 4, 2], [1, 3, 4], [1, 5, 3], [1, 2, 5]])


def relabel(x, rng):
    """The same partition under other, arbitrary ids (negative ones too)."""
    values = np.unique(x)
    new = rng.permutation(len(values)) * 7 - 5
    return new[np.searchsorted(values, x)]


# ----------------------------------------------------------------------------------------------
# 1 - Rand index
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_rand_distance_matches_pair_counting(seed):
    rng = np.random.default_rng(seed)
    f = int(rng.integers(2, 14))
    a, b = rng.integers(0, 4, f), rng.integers(0, 3, f)
    w = rng.uniform(0.1, 2.0, f)
    assert M.rand_distance(a, b, w) == pytest.approx(brute_rand(a, b, w), abs=1e-12)
    assert M.rand_distance(b, a, w) == pytest.approx(M.rand_distance(a, b, w), abs=1e-15)


def test_rand_distance_over_distinct_pairs():
    """With equal weights, the share of unordered pairs of distinct faces that disagree is
    f / (f - 1) times the measure (pairs of a face with itself always agree)."""
    rng = np.random.default_rng(3)
    a, b = rng.integers(0, 3, 11), rng.integers(0, 4, 11)
    pairs = list(itertools.combinations(range(11), 2))
    disagree = sum((a[i] == a[j]) != (b[i] == b[j]) for i, j in pairs) / len(pairs)
    assert disagree == pytest.approx(11 / 10 * M.rand_distance(a, b), abs=1e-12)


def test_rand_distance_identical_partition_is_zero():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 5, 40)
    assert M.rand_distance(a, relabel(a, rng), rng.uniform(size=40)) == pytest.approx(0.0, abs=1e-15)
    assert M.rand_distance([0, 0, 1, 1], [0, 1, 0, 1]) == pytest.approx(0.5)  # 8 of the 16 pairs


# ----------------------------------------------------------------------------------------------
# Hamming distance
# ----------------------------------------------------------------------------------------------


def test_hamming_hand_worked():
    # six faces of equal weight: labels {0,1,2}{3,4,5}, reference {0,1}{2,3}{4,5}
    labels, reference = [0, 0, 0, 1, 1, 1], [0, 0, 1, 1, 2, 2]
    h = M.hamming_distance(labels, reference)
    # Rm: {2,3} is split (face 3 outside labels' segment 0) -> 1/6; Rf: {0,1,2} loses face 2
    # to {0,1}, {3,4,5} face 3 to {4,5} -> 2/6
    assert (h.missing, h.false_alarm, h.distance) == pytest.approx((1 / 6, 1 / 3, 1 / 4))
    # face 2 weighs 2 of 7: {2,3} goes with labels' 0 (2 against 1) -> Rm 1/7; {0,1,2} ties
    # between {0,1} and {2,3} (2 each) -> 2 outside, {3,4,5} -> 1 outside: Rf 3/7
    h = M.hamming_distance(labels, reference, [1, 1, 2, 1, 1, 1])
    assert (h.missing, h.false_alarm) == pytest.approx((1 / 7, 3 / 7))


@pytest.mark.parametrize("seed", range(6))
def test_hamming_matches_set_arithmetic(seed):
    rng = np.random.default_rng(10 + seed)
    f = int(rng.integers(2, 16))
    a, b = rng.integers(0, 4, f), rng.integers(0, 5, f)
    w = rng.uniform(0.1, 2.0, f)
    h = M.hamming_distance(a, b, w)
    rm, rf = brute_hamming(a, b, w)
    assert (h.missing, h.false_alarm, h.distance) == pytest.approx((rm, rf, (rm + rf) / 2), abs=1e-12)
    swapped = M.hamming_distance(b, a, w)
    assert (swapped.missing, swapped.false_alarm) == pytest.approx((h.false_alarm, h.missing), abs=1e-15)


def test_hamming_refinement_is_zero_one_way():
    rng = np.random.default_rng(4)
    coarse = rng.integers(0, 3, 30)
    fine = coarse * 10 + rng.integers(0, 3, 30)  # splits each coarse segment, merges none
    w = rng.uniform(0.5, 1.5, 30)
    h = M.hamming_distance(fine, coarse, w)
    assert h.false_alarm == 0.0 and h.missing > 0.05
    h = M.hamming_distance(coarse, fine, w)
    assert h.missing == 0.0 and h.false_alarm > 0.05
    same = M.hamming_distance(coarse, relabel(coarse, rng), w)
    assert (same.missing, same.false_alarm, same.distance) == (0.0, 0.0, 0.0)


# ----------------------------------------------------------------------------------------------
# cut discrepancy
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("metric", ["graph", "euclidean"])
def test_cut_discrepancy_octahedron_by_hand(metric):
    """Octahedron, vertices at unit distance: the faces around +x against those around -x (cut:
    the ring y, z), and around +y against -y (ring x, z). The rings share the two z vertices; the
    other two of each ring are one edge (sqrt 2) from the other ring, so each directional mean is
    sqrt(2)/2. Every face centre is 1/sqrt(3) from the centroid: CD = sqrt(3/2)."""
    right = (OCTAHEDRON_F == 0).any(axis=1).astype(int)
    front = (OCTAHEDRON_F == 2).any(axis=1).astype(int)
    cd = M.cut_discrepancy(OCTAHEDRON_V, OCTAHEDRON_F, right, front, metric=metric)
    assert cd == pytest.approx(math.sqrt(1.5), rel=1e-12)
    assert M.cut_discrepancy(OCTAHEDRON_V, OCTAHEDRON_F, right, 5 - right, metric=metric) == 0.0


@pytest.mark.parametrize("metric", ["graph", "euclidean"])
def test_cut_discrepancy_parallel_cuts_on_a_square(metric):
    """Cuts along x = 0.5 and x = 0.75 of a unit square: every cut vertex is 0.25 from the other cut,
    along the grid's edges and straight; the square's mean distance to its centre is
    (sqrt 2 + ln(1 + sqrt 2)) / 6."""
    v, f = grid(40)
    x = centres(v, f)[:, 0]
    a, b = (x > 0.5).astype(int), (x > 0.75).astype(int)
    radius = (math.sqrt(2) + math.log(1 + math.sqrt(2))) / 6
    assert M.cut_discrepancy(v, f, a, b, metric=metric) == pytest.approx(0.25 / radius, rel=2e-3)
    assert M.cut_discrepancy(v, f, a, a, metric=metric) == 0.0


def test_cut_discrepancy_graph_is_not_shorter_than_straight_lines():
    rng = np.random.default_rng(5)
    v, f = grid(12)
    c = centres(v, f)
    a = (c[:, 0] + 0.3 * c[:, 1] > 0.6).astype(int)
    b = (np.linalg.norm(c - [0.3, 0.4, 0], axis=1) < 0.25).astype(int) + 2 * (c[:, 0] > 0.85)
    graph, straight = M.cut_discrepancy(v, f, a, b), M.cut_discrepancy(v, f, a, b, metric="euclidean")
    assert graph >= straight > 0
    assert M.cut_discrepancy(v, f, relabel(a, rng), relabel(b, rng)) == pytest.approx(graph, rel=1e-12)
    assert M.cut_discrepancy(v, f, b, a) == pytest.approx(graph, rel=1e-12)


def test_cut_discrepancy_without_a_cut():
    v, f = grid(6)
    one = np.zeros(len(f), int)
    halves = (centres(v, f)[:, 0] > 0.5).astype(int)
    assert M.cut_discrepancy(v, f, one, one + 3) == 0.0
    assert math.isnan(M.cut_discrepancy(v, f, one, halves))


def test_cut_discrepancy_across_components_falls_back_to_straight_lines():
    """Two squares 2 apart, each cut on one of them only: no path joins the cuts, so the graph
    distance is the straight one."""
    v1, f1 = grid(8)
    v2, f2 = grid(8, offset=(2.0, 0.0))
    v, f = np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)])
    x = centres(v, f)[:, 0]
    a = (x > 0.5).astype(int) + 2 * (x > 1.5)  # cut at x = 0.5 only
    b = 2 * (x > 1.5) + (x > 2.5)  # cut at x = 2.5 only
    graph = M.cut_discrepancy(v, f, a, b)
    assert np.isfinite(graph)
    assert graph == pytest.approx(M.cut_discrepancy(v, f, a, b, metric="euclidean"), rel=1e-12)


# ----------------------------------------------------------------------------------------------
# against several references
# ----------------------------------------------------------------------------------------------


def test_reference_segmentations_average_the_single_measures():
    rng = np.random.default_rng(6)
    v, f = grid(10)
    c = centres(v, f)
    refs = [(c[:, 0] > t).astype(int) + 2 * (c[:, 1] > s) for t, s in [(0.3, 0.5), (0.5, 0.5), (0.6, 0.2)]]
    refs.append(np.zeros(len(f), int))  # a reference with a single segment: no cut
    labels = (c[:, 0] > 0.4).astype(int)
    area = M._MeshCuts(v, f, "graph").areas
    r = M.ReferenceSegmentations(v, f, refs)
    s = r.score(relabel(labels, rng))
    assert s.comparisons == 4 and s.cut_undefined == 1
    assert s.rand == pytest.approx(np.mean([M.rand_distance(labels, x, area) for x in refs]), abs=1e-12)
    hs = [M.hamming_distance(labels, x, area) for x in refs]
    assert s.missing == pytest.approx(np.mean([h.missing for h in hs]), abs=1e-12)
    assert s.false_alarm == pytest.approx(np.mean([h.false_alarm for h in hs]), abs=1e-12)
    assert s.hamming == pytest.approx(np.mean([h.distance for h in hs]), abs=1e-12)
    assert s.cut == pytest.approx(np.mean([M.cut_discrepancy(v, f, labels, x) for x in refs[:3]]), rel=1e-12)
    assert (s.segments, s.reference_segments) == (2, pytest.approx((4 + 4 + 4 + 1) / 4))

    among = r.among_references()
    pairs = [(i, j) for i in range(4) for j in range(4) if i != j]
    assert among.comparisons == 12 and among.cut_undefined == 6
    assert among.rand == pytest.approx(np.mean([M.rand_distance(refs[i], refs[j], area) for i, j in pairs]), abs=1e-12)
    assert among.missing == pytest.approx(among.false_alarm, abs=1e-12)
    assert among.segments == pytest.approx(among.reference_segments)


def test_reference_segmentations_checks_inputs():
    v, f = grid(3)
    with pytest.raises(ValueError, match="one label per face"):
        M.ReferenceSegmentations(v, f, [np.zeros(len(f) - 1, int)])
    with pytest.raises(ValueError, match="empty"):
        M.ReferenceSegmentations(v, f, [])
    with pytest.raises(ValueError, match="at least two"):
        M.ReferenceSegmentations(v, f, [np.zeros(len(f), int)]).among_references()
    with pytest.raises(ValueError, match=r"\(f,\) int"):
        M.rand_distance([0.5, 1.0], [0, 1])
    with pytest.raises(ValueError, match="metric"):
        M.cut_discrepancy(v, f, np.zeros(len(f), int), np.zeros(len(f), int), metric="geodesic")

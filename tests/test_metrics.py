"""Tests for primkit.metrics: closed forms and independent (brute-force) references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from primkit import metrics as M
from primkit.geometry import lookup_distance_sq
from primkit.primitives import union_surface_samples
from primkit.geometry import grid_centres
from primkit.primitives import Cuboids

# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------


def axis_aligned(z, t, present=None):
    z = np.atleast_2d(np.asarray(z, float))
    m = len(z)
    e = np.ones(m, bool) if present is None else np.asarray(present, bool)
    return Cuboids(z, np.tile([1.0, 0, 0, 0], (m, 1)), np.atleast_2d(np.asarray(t, float)), e)


def random_cuboids(rng, m, present=None):
    z = rng.uniform(0.05, 0.3, size=(m, 3))
    q = rng.normal(size=(m, 4))
    t = rng.uniform(-0.3, 0.3, size=(m, 3))
    e = np.ones(m, bool) if present is None else np.asarray(present, bool)
    return Cuboids(z, q, t, e)


def brute_chamfer(a, b, power, reduction):
    d = np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1))  # (n, k)
    total = np.mean(d.min(axis=1) ** power) + np.mean(d.min(axis=0) ** power)
    return total / 2 if reduction == "mean_of_means" else total


def scipy_local(points, cuboids, k):
    """Points in cuboid k's frame, via scipy's (x, y, z, w) quaternions: independent of primkit."""
    w, x, y, z = cuboids.quaternions[k]
    rot = Rotation.from_quat([x, y, z, w])
    return rot.inv().apply(points - cuboids.translations[k])


def box_closest_grid(extents, resolution, rotation=None):
    """Closest-point grid of an axis-aligned (or rotated) box mesh, through primkit.geometry."""
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("open3d")
    from primkit.geometry import distance_grid

    mesh = trimesh.creation.box(extents=extents)
    v = np.asarray(mesh.vertices)
    if rotation is not None:
        v = v @ rotation.T
    return distance_grid(v, np.asarray(mesh.faces), resolution).closest


# ----------------------------------------------------------------------------------------------
# ChamferConvention and chamfer_distance
# ----------------------------------------------------------------------------------------------


def test_describe_mentions_power_and_samples():
    d1 = M.ChamferConvention().describe()
    assert "Chamfer-L1" in d1 and "unsquared" in d1 and "10000+10000 samples" in d1
    assert "/ 2" in d1 and "longest side 1" in d1
    d2 = M.ChamferConvention(power=2, reduction="sum_of_means", samples=2048).describe()
    assert "Chamfer-L2" in d2 and "squared" in d2 and "|a-b|^2" in d2 and "2048+2048 samples" in d2
    assert "/ 2" not in d2


@pytest.mark.parametrize("kwargs", [{"power": 3}, {"reduction": "mean"}, {"samples": 0}])
def test_convention_rejects_unknown_settings(kwargs):
    with pytest.raises(ValueError):
        M.ChamferConvention(**kwargs)


@pytest.mark.parametrize("power", [1, 2])
@pytest.mark.parametrize("reduction", ["mean_of_means", "sum_of_means"])
def test_chamfer_matches_brute_force(power, reduction):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(300, 3))
    b = rng.normal(size=(170, 3)) * 0.7 + 0.2
    conv = M.ChamferConvention(power=power, reduction=reduction)
    got = M.chamfer_distance(a, b, conv)
    assert got == pytest.approx(brute_chamfer(a, b, power, reduction), rel=1e-12)
    assert M.chamfer_distance(b, a, conv) == pytest.approx(got, rel=1e-12)  # symmetric


def test_chamfer_zero_for_identical_sets_and_sum_is_twice_mean():
    rng = np.random.default_rng(1)
    a = rng.uniform(size=(500, 3))
    assert M.chamfer_distance(a, a[::-1].copy()) == 0.0
    b = a + rng.normal(scale=0.01, size=a.shape)
    mean = M.chamfer_distance(a, b, M.ChamferConvention(reduction="mean_of_means"))
    total = M.chamfer_distance(a, b, M.ChamferConvention(reduction="sum_of_means"))
    assert total == pytest.approx(2 * mean, rel=1e-12)


def test_chamfer_parallel_planes_closed_form():
    h = 0.05
    rng = np.random.default_rng(2)
    # the same (x, y) on both planes: every nearest neighbour is straight across, exactly h
    xy = rng.uniform(size=(2000, 2))
    a = np.column_stack([xy, np.zeros(len(xy))])
    b = a + [0.0, 0.0, h]
    l1 = M.chamfer_distance(a, b, M.ChamferConvention(power=1))
    l2 = M.chamfer_distance(a, b, M.ChamferConvention(power=2))
    assert l1 == pytest.approx(h, rel=1e-9)
    assert l2 == pytest.approx(h * h, rel=1e-9)
    # independent dense samples on each plane: approximately h and h^2
    xy2 = rng.uniform(size=(20000, 2))
    c = np.column_stack([xy2, np.full(len(xy2), h)])
    assert M.chamfer_distance(a, c, M.ChamferConvention(power=1)) == pytest.approx(h, rel=0.05)
    assert M.chamfer_distance(a, c, M.ChamferConvention(power=2)) == pytest.approx(h * h, rel=0.1)


def test_chamfer_rejects_bad_points():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        M.chamfer_distance(np.zeros((4, 2)), np.zeros((4, 3)))
    with pytest.raises(ValueError):
        M.chamfer_distance(np.zeros((0, 3)), np.zeros((4, 3)))


# ----------------------------------------------------------------------------------------------
# union surface samples and cuboid_chamfer
# ----------------------------------------------------------------------------------------------


def test_union_samples_not_inside_other_present_cuboids():
    rng = np.random.default_rng(3)
    c = random_cuboids(rng, 6, present=[1, 1, 0, 1, 1, 1])
    pts = union_surface_samples(c, 4000, seed=0)
    assert pts.shape == (4000, 3)
    present = c.present
    # every sample is on the surface of some present cuboid ...
    on_surface = np.zeros(len(pts), bool)
    for k in present:
        local = np.abs(scipy_local(pts, c, k))
        z = c.half_extents[k]
        inside = np.all(local <= z + 1e-9, axis=1)
        on_surface |= inside & np.any(np.abs(local - z) < 1e-9, axis=1)
        # ... and strictly inside none
        assert not np.any(np.all(local < z - 1e-7, axis=1))
    assert on_surface.all()


def test_union_samples_of_touching_boxes_skip_the_shared_face():
    # two unit cubes side by side: the union is a 2 x 1 x 1 box of area 10, the face x = 0 is inside
    c = axis_aligned([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]], [[-0.5, 0, 0], [0.5, 0, 0]])
    pts = union_surface_samples(c, 20000, seed=1)
    interior = (np.abs(pts[:, 0]) < 1e-9) & np.all(np.abs(pts[:, 1:]) < 0.5 - 1e-9, axis=1)
    assert not interior.any()
    ends = np.isclose(np.abs(pts[:, 0]), 1.0)
    assert ends.mean() == pytest.approx(2 / 10, abs=0.015)  # area-uniform over the union


def test_union_samples_of_duplicated_cuboid_are_area_uniform():
    # the same box twice: every face coincides, and each must be sampled once (not twice, not never)
    c = axis_aligned([[0.4, 0.1, 0.2]] * 2, [[0.0, 0.0, 0.0]] * 2)
    pts = union_surface_samples(c, 20000, seed=2)
    z = np.array([0.4, 0.1, 0.2])
    areas = np.array([z[1] * z[2], z[0] * z[2], z[0] * z[1]])
    on_axis = np.isclose(np.abs(pts), z).argmax(axis=1)
    frac = np.bincount(on_axis, minlength=3) / len(pts)
    assert np.allclose(frac, areas / areas.sum(), atol=0.015)


def test_union_samples_absent_parts_ignored_and_seeded():
    rng = np.random.default_rng(4)
    c = random_cuboids(rng, 4, present=[1, 0, 1, 0])
    a = union_surface_samples(c, 1000, seed=7)
    b = union_surface_samples(c.subset(c.present), 1000, seed=7)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError):
        union_surface_samples(c.with_existence(np.zeros(4, bool)), 10)


def test_cuboid_chamfer_same_cuboid_near_zero_and_grows_with_shift():
    trimesh = pytest.importorskip("trimesh")
    rot = Rotation.from_euler("xyz", [20, -35, 50], degrees=True)
    z = np.array([0.3, 0.15, 0.2])
    t = np.array([0.02, -0.05, 0.03])
    w = rot.as_quat()  # (x, y, z, w)
    c = Cuboids([z], [[w[3], w[0], w[1], w[2]]], [t], [True])
    # shape surface: an independent area-uniform sample of the same box through trimesh
    mesh = trimesh.creation.box(extents=2 * z)
    pts, _ = trimesh.sample.sample_surface(mesh, 10000, seed=0)
    pts = rot.apply(pts) + t
    conv = M.ChamferConvention(samples=10000)
    near = M.cuboid_chamfer(c, pts, conv, seed=0)
    assert near < 0.01  # about half the spacing of 10^4 samples on an area of 0.86
    shifted = Cuboids([z], c.quaternions, [t + [0.05, 0, 0]], [True])
    assert M.cuboid_chamfer(shifted, pts, conv, seed=0) > near + 0.01
    l2 = M.cuboid_chamfer(c, pts, M.ChamferConvention(power=2), seed=0)
    assert l2 < near**2 * 3  # squared distances of a few 1e-3
    assert M.cuboid_chamfer(c.with_existence([False]), pts, conv) == float("inf")


def test_cuboid_chamfer_subsamples_and_checks_counts():
    rng = np.random.default_rng(5)
    c = random_cuboids(rng, 3)
    pts = rng.uniform(-0.5, 0.5, size=(3000, 3))
    a = M.cuboid_chamfer(c, pts, M.ChamferConvention(samples=1000), seed=3)
    assert a == M.cuboid_chamfer(c, pts, M.ChamferConvention(samples=1000), seed=3)
    with pytest.raises(ValueError, match="samples=3000"):
        M.cuboid_chamfer(c, pts, M.ChamferConvention(samples=5000))


# ----------------------------------------------------------------------------------------------
# volumetric IoU
# ----------------------------------------------------------------------------------------------


def box_solid(res, lo, hi):
    """Solid grid of the cells [lo, hi) (cell indices per axis)."""
    g = np.zeros((res,) * 3, bool)
    g[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = True
    return g


def cell_box(res, lo, hi):
    """Half extents and centre of the box covering cells [lo, hi) exactly."""
    lo_x = -0.5 + np.asarray(lo) / res
    hi_x = -0.5 + np.asarray(hi) / res
    return (hi_x - lo_x) / 2, (hi_x + lo_x) / 2


@pytest.mark.parametrize("supersample", [1, 2, 3])
def test_iou_cuboid_equal_to_box_is_one(supersample):
    res, lo, hi = 16, (3, 5, 2), (11, 9, 14)
    z, t = cell_box(res, lo, hi)
    c = axis_aligned(z, t)
    assert M.volumetric_iou(c, box_solid(res, lo, hi), supersample=supersample) == 1.0


def test_iou_half_volume_inside_is_half_and_absent_parts_ignored():
    res, lo, hi = 16, (4, 4, 4), (12, 10, 14)
    z, t = cell_box(res, lo, hi)
    half = axis_aligned([z * [0.5, 1, 1]], [t - [z[0] / 2, 0, 0]])
    solid = box_solid(res, lo, hi)
    assert M.volumetric_iou(half, solid) == pytest.approx(0.5, abs=1e-12)
    # an absent part covering everything changes nothing
    big = Cuboids(
        np.vstack([half.half_extents, [0.6, 0.6, 0.6]]),
        np.tile([1.0, 0, 0, 0], (2, 1)),
        np.vstack([half.translations, [0, 0, 0]]),
        [True, False],
    )
    assert M.volumetric_iou(big, solid) == pytest.approx(0.5, abs=1e-12)
    assert M.volumetric_iou(big.with_existence([False, False]), solid) == 0.0
    assert M.volumetric_iou(big.with_existence([False, False]), np.zeros_like(solid)) == 1.0


def test_iou_matches_per_point_loop():
    rng = np.random.default_rng(6)
    res, ss = 8, 2
    solid = rng.uniform(size=(res,) * 3) < 0.4
    c = random_cuboids(rng, 3, present=[1, 0, 1])
    pts = grid_centres(res * ss).reshape(-1, 3)
    inter = union = 0
    for x in pts:
        ours = any(
            np.all(np.abs(scipy_local(x[None], c, k)[0]) <= c.half_extents[k]) for k in c.present
        )
        cell = np.minimum(((x + 0.5) * res).astype(int), res - 1)
        theirs = solid[tuple(cell)]
        inter += ours and theirs
        union += ours or theirs
    assert M.volumetric_iou(c, solid, supersample=ss) == pytest.approx(inter / union, abs=1e-12)


def test_iou_rejects_non_cubic_grid():
    c = axis_aligned([0.1, 0.1, 0.1], [0, 0, 0])
    with pytest.raises(ValueError, match="R, R, R"):
        M.volumetric_iou(c, np.zeros((4, 4, 5), bool))


# ----------------------------------------------------------------------------------------------
# coverage and consistency
# ----------------------------------------------------------------------------------------------


def test_coverage_matches_brute_force():
    rng = np.random.default_rng(7)
    c = random_cuboids(rng, 5, present=[1, 1, 0, 1, 0])
    pts = rng.uniform(-0.6, 0.6, size=(800, 3))
    best = np.full(len(pts), np.inf)
    for k in c.present:
        excess = np.maximum(np.abs(scipy_local(pts, c, k)) - c.half_extents[k], 0.0)
        best = np.minimum(best, (excess**2).sum(axis=1))
    assert M.coverage_error(c, pts) == pytest.approx(best.mean(), rel=1e-10)
    assert M.coverage_error(c.with_existence(np.zeros(5, bool)), pts) == float("inf")


def test_lookup_matches_the_torch_distance_field():
    torch = pytest.importorskip("torch")
    from primkit.model.distance_field import lookup_distance_sq_torch as torch_lookup_distance_sq

    rng = np.random.default_rng(8)
    closest = rng.uniform(-0.5, 0.5, size=(6, 6, 6, 3)).astype(np.float32)
    pts = rng.uniform(-0.7, 0.7, size=(500, 3))  # some outside the grid
    ours = lookup_distance_sq(closest, pts)
    ref = torch_lookup_distance_sq(torch.from_numpy(closest[None]).double(), torch.from_numpy(pts[None]))[0].numpy()
    np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-15)


def test_lookup_brute_force_eight_cells():
    rng = np.random.default_rng(9)
    res = 5
    closest = rng.uniform(-0.5, 0.5, size=(res, res, res, 3))
    pts = rng.uniform(-0.4, 0.4, size=(50, 3))  # between the outermost cell centres (+-0.4)
    centres = grid_centres(res)
    for x, got in zip(pts, lookup_distance_sq(closest, pts)):
        # the 8 cell centres around x: those within one cell spacing along every axis
        near = np.all(np.abs(centres - x) <= 1.0 / res, axis=-1)
        # exactly 8 such cells (almost surely: x is on no centre plane)
        assert near.sum() == 8
        assert got == pytest.approx(((closest[near] - x) ** 2).sum(-1).min(), rel=1e-12)


def test_consistency_zero_on_the_surface_and_grows_with_shift():
    res = 32
    extents = np.array([0.6, 0.4, 0.5])
    closest = box_closest_grid(extents, res)
    c = axis_aligned(extents / 2, [0, 0, 0])
    on = M.consistency_error(c, closest)
    # zero up to the grid: away from the edges, the stored closest points around a sample on a
    # face are the cell centres projected onto the face, so the sample reads as the offset to the
    # nearest projected centre, uniform in [-h/2, h/2]^2 (h = 1/R): mean square 2 h^2 / 12
    assert on == pytest.approx((1.0 / res) ** 2 / 6, rel=0.2)
    errors = [on]
    for delta in (0.03, 0.06, 0.12):
        shifted = axis_aligned(extents / 2, [delta, 0, 0])
        errors.append(M.consistency_error(shifted, closest))
    assert np.all(np.diff(errors) > 0)
    # the shifted +-x faces are delta off and so is part of the others: of the order of delta^2
    assert errors[-1] > 0.1 * 0.12**2
    assert np.isnan(M.consistency_error(c.with_existence([False]), closest))


def test_consistency_is_area_weighted_mean():
    rng = np.random.default_rng(10)
    res = 8
    closest = rng.uniform(-0.5, 0.5, size=(res, res, res, 3))
    c = random_cuboids(rng, 3, present=[1, 1, 0])
    from primkit.primitives import sample_cuboid_surfaces

    s = sample_cuboid_surfaces(c.subset(c.present), 60, seed=4)
    d2 = lookup_distance_sq(closest, s.points.reshape(-1, 3)).reshape(s.weights.shape)
    expected = (s.weights * d2).sum() / s.weights.sum()
    assert M.consistency_error(c, closest, samples_per_cuboid=60, seed=4) == pytest.approx(expected, rel=1e-12)


# ----------------------------------------------------------------------------------------------
# score and summarize
# ----------------------------------------------------------------------------------------------


class FakeShape:
    """The PreparedShape fields that score reads."""

    def __init__(self, solid, closest, points):
        self.solid, self.closest, self.points = solid, closest, points


def test_score_and_summarize_box():
    trimesh = pytest.importorskip("trimesh")
    res = 16
    extents = np.array([0.5, 0.25, 0.75])  # faces on cell boundaries of the 16^3 grid
    closest = box_closest_grid(extents, res)
    lo = np.round((0.5 - extents / 2) * res).astype(int)
    hi = np.round((0.5 + extents / 2) * res).astype(int)
    solid = box_solid(res, lo, hi)
    pts, _ = trimesh.sample.sample_surface(trimesh.creation.box(extents=extents), 4000, seed=0)
    shape = FakeShape(solid, closest, pts.astype(np.float32))
    conv = M.ChamferConvention(samples=2000)
    good = axis_aligned(extents / 2, [0, 0, 0])
    s = M.score(good, shape, conv)
    assert s.iou == 1.0 and s.parts == 1 and s.convention == conv.describe()
    assert s.coverage < 1e-12 and s.chamfer < 0.02 and s.consistency < (0.5 / res) ** 2
    bad = axis_aligned([extents / 2, [0.1, 0.1, 0.1]], [[0.1, 0, 0], [0, 0, 0]], present=[True, False])
    t = M.score(bad, shape, conv)
    assert t.iou < s.iou and t.coverage > s.coverage and t.chamfer > s.chamfer
    assert t.consistency > s.consistency and t.parts == 1
    d = s.to_dict()
    assert set(d) == {"chamfer", "iou", "coverage", "consistency", "parts", "convention"}

    summary = M.summarize([s, t])
    assert summary.count == 2 and summary.empty == 0 and summary.convention == conv.describe()
    assert summary.iou.mean == pytest.approx((s.iou + t.iou) / 2)
    assert summary.chamfer.median == pytest.approx((s.chamfer + t.chamfer) / 2)
    assert summary.coverage.std == pytest.approx(abs(s.coverage - t.coverage) / 2)
    assert summary.parts == M.Statistics(mean=1.0, median=1.0, std=0.0)
    assert summary.to_dict()["parts"] == {"mean": 1.0, "median": 1.0, "std": 0.0}  # the JSON layout


def test_summarize_rejects_mixed_conventions_and_empty():
    a = M.AbstractionScores(0.1, 0.5, 0.01, 0.02, 3, "x")
    b = M.AbstractionScores(0.2, 0.6, 0.01, 0.02, 4, "y")
    with pytest.raises(ValueError, match="conventions"):
        M.summarize([a, b])
    with pytest.raises(ValueError):
        M.summarize([])
    empty = M.AbstractionScores(float("inf"), 0.0, float("inf"), float("nan"), 0, "x")
    out = M.summarize([a, empty, a])
    assert out.empty == 1 and out.chamfer.mean == float("inf")
    assert out.chamfer.median == pytest.approx(0.1)


@pytest.mark.parametrize("power", [1, 2])
def test_diagonal_unit_divides_by_the_bounding_box_diagonal(power):
    rng = np.random.default_rng(8)
    c = random_cuboids(rng, 3)
    pts = rng.uniform([-0.5, -0.2, -0.1], [0.5, 0.2, 0.1], size=(2000, 3))
    diag = np.linalg.norm(pts.max(0) - pts.min(0))
    plain = M.cuboid_chamfer(c, pts, M.ChamferConvention(power=power, samples=1000), seed=1)
    scaled = M.cuboid_chamfer(c, pts, M.ChamferConvention(power=power, samples=1000, unit="diagonal"), seed=1)
    assert scaled == pytest.approx(plain / diag**power, rel=1e-12)
    assert "diagonal" in M.ChamferConvention(unit="diagonal").describe()
    with pytest.raises(ValueError):
        M.ChamferConvention(unit="metres")

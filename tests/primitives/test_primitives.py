"""Tests for primkit.primitives: invariants, closed forms and naive references."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from primkit import primitives as P
from primkit.primitives.differentiable import surface_samples_from_coefficients_torch
from primkit.primitives.sampling import _surface_from_uv
from primkit.primitives import Cuboids

# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------


def random_cuboids(rng, m, present=None, probabilities=False):
    z = rng.uniform(0.05, 0.4, size=(m, 3))
    q = rng.normal(size=(m, 4))
    t = rng.uniform(-0.5, 0.5, size=(m, 3))
    e = np.ones(m, bool) if present is None else np.asarray(present, bool)
    p = rng.uniform(0, 1, size=m) if probabilities else None
    return Cuboids(z, q, t, e, p)


def axis_aligned(z, t, present=None):
    z = np.atleast_2d(np.asarray(z, float))
    m = len(z)
    q = np.tile([1.0, 0, 0, 0], (m, 1))
    e = np.ones(m, bool) if present is None else np.asarray(present, bool)
    return Cuboids(z, q, np.atleast_2d(np.asarray(t, float)), e)


def random_similarity(rng, reflect=False):
    A = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    if reflect:
        A = A @ np.diag([1.0, -1.0, 1.0])
    s = rng.uniform(0.3, 3.0)
    M = np.eye(4)
    M[:3, :3] = s * A
    M[:3, 3] = rng.normal(size=3)
    return M, s


def apply(M, x):
    return x @ M[:3, :3].T + M[:3, 3]


def dense_surface_grid(z, res):
    """Naive reference: a regular grid of (res x res) points on every face of the box [-z, z]."""
    u = np.linspace(-1.0, 1.0, res)
    pts = []
    for axis in range(3):
        b, c = (axis + 1) % 3, (axis + 2) % 3
        for sign in (-1.0, 1.0):
            for ub in u:
                for uc in u:
                    p = np.zeros(3)
                    p[axis] = sign * z[axis]
                    p[b] = ub * z[b]
                    p[c] = uc * z[c]
                    pts.append(p)
    return np.array(pts)


# ----------------------------------------------------------------------------------------------
# rotations
# ----------------------------------------------------------------------------------------------


def test_quaternion_to_matrix_matches_scipy():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4)) * rng.uniform(0.1, 5, size=(200, 1))  # unnormalised on purpose
    R = P.quaternion_to_matrix(q)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is (x, y, z, w)
    np.testing.assert_allclose(R, ref, atol=1e-12)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # batch shapes are kept
    assert P.quaternion_to_matrix(q.reshape(10, 20, 4)).shape == (10, 20, 3, 3)
    # a rotation of 90 degrees about z maps x to y (column vectors)
    qz = [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]
    np.testing.assert_allclose(P.quaternion_to_matrix(qz) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_matrix_to_quaternion_round_trip():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(300, 4))
    # hard cases: identity and half turns (w = 0) about axes and about diagonals
    special = np.array(
        [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 1, 1, 0], [0, 1, -1, 1], [1e-9, 0, 1, 0]],
        float,
    )
    q = np.concatenate([q, special])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q_pos = np.where(q[:, :1] < 0, -q, q)
    back = P.matrix_to_quaternion(P.quaternion_to_matrix(q))
    assert np.all(back[:, 0] >= 0)
    # q and -q are the same rotation; compare up to sign where w == 0
    err = np.minimum(np.abs(back - q_pos).max(axis=1), np.abs(back + q_pos).max(axis=1))
    assert err.max() < 1e-9
    np.testing.assert_allclose(P.quaternion_to_matrix(back), P.quaternion_to_matrix(q), atol=1e-12)
    # scipy agrees
    R = Rotation.random(50, random_state=2).as_matrix()
    ref = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    ref = np.where(ref[:, :1] < 0, -ref, ref)
    np.testing.assert_allclose(P.matrix_to_quaternion(R), ref, atol=1e-12)


def test_torch_quaternion_matches_numpy():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(4, 5, 4))
    np.testing.assert_allclose(
        P.quaternion_to_matrix_torch(torch.from_numpy(q)).numpy(), P.quaternion_to_matrix(q), atol=1e-12
    )


# ----------------------------------------------------------------------------------------------
# value type
# ----------------------------------------------------------------------------------------------


def test_construction_validates_and_normalises():
    c = Cuboids([[1, 2, 3]], [[2, 0, 0, 0]], [[0, 0, 0]], [True])
    np.testing.assert_allclose(c.quaternions, [[1, 0, 0, 0]])
    assert c.count == 1 and c.present.tolist() == [0]
    with pytest.raises(ValueError, match=r"`half_extents` must be \(m, 3\) float"):
        Cuboids([[1, 2]], [[1, 0, 0, 0]], [[0, 0, 0]], [True])
    with pytest.raises(ValueError, match=r"`quaternions` must be \(m, 4\) float"):
        Cuboids([[1, 2, 3]], [[1, 0, 0]], [[0, 0, 0]], [True])
    with pytest.raises(ValueError, match=r"`translations` must be \(m, 3\) float"):
        Cuboids([[1, 2, 3]], [[1, 0, 0, 0]], [[0, 0, 0], [1, 1, 1]], [True])
    with pytest.raises(ValueError, match=r"`existence` must be \(m,\) bool"):
        Cuboids([[1, 2, 3]], [[1, 0, 0, 0]], [[0, 0, 0]], [True, False])
    with pytest.raises(ValueError, match="> 0"):
        Cuboids([[1, 0, 3]], [[1, 0, 0, 0]], [[0, 0, 0]], [True])
    with pytest.raises(ValueError, match="finite"):
        Cuboids([[1, 2, 3]], [[1, 0, 0, 0]], [[np.nan, 0, 0]], [True])
    with pytest.raises(ValueError, match="nonzero"):
        Cuboids([[1, 2, 3]], [[0, 0, 0, 0]], [[0, 0, 0]], [True])
    with pytest.raises(ValueError, match="probabilities"):
        Cuboids([[1, 2, 3]], [[1, 0, 0, 0]], [[0, 0, 0]], [True], [1.5])
    # frozen and read-only
    with pytest.raises(ValueError):
        c.half_extents[0, 0] = 5.0
    with pytest.raises(AttributeError):
        c.half_extents = np.ones((1, 3))


def test_properties_subset_and_existence():
    rng = np.random.default_rng(4)
    c = random_cuboids(rng, 5, present=[1, 0, 1, 1, 0], probabilities=True)
    np.testing.assert_allclose(c.volumes, 8 * c.half_extents[:, 0] * c.half_extents[:, 1] * c.half_extents[:, 2])
    assert c.rotations.shape == (5, 3, 3)
    assert c.present.tolist() == [0, 2, 3]
    d = c.with_existence([0, 1, 1, 1, 1])
    assert d.count == 5 and d.present.tolist() == [1, 2, 3, 4]
    np.testing.assert_array_equal(d.half_extents, c.half_extents)
    s = c.subset(c.present)
    assert s.count == 3 and s.existence.all()
    np.testing.assert_array_equal(s.probabilities, c.probabilities[[0, 2, 3]])


# ----------------------------------------------------------------------------------------------
# frames and distances
# ----------------------------------------------------------------------------------------------


def test_world_local_round_trip():
    rng = np.random.default_rng(5)
    c = random_cuboids(rng, 4)
    x = rng.normal(size=(30, 3))
    local = P.world_to_local(x, c)
    assert local.shape == (4, 30, 3)
    np.testing.assert_allclose(P.local_to_world(local, c), np.broadcast_to(x, (4, 30, 3)), atol=1e-12)
    # naive reference: loop over cuboids and points
    for k in range(c.count):
        R = c.rotations[k]
        for i in range(0, 30, 7):
            np.testing.assert_allclose(local[k, i], R.T @ (x[i] - c.translations[k]), atol=1e-12)


def test_distance_axis_aligned_closed_form():
    rng = np.random.default_rng(6)
    z = rng.uniform(0.1, 0.5, size=(3, 3))
    t = rng.uniform(-0.3, 0.3, size=(3, 3))
    c = axis_aligned(z, t)
    x = rng.uniform(-1.5, 1.5, size=(400, 3))
    d = P.point_cuboid_distance(x, c)
    lo, hi = t - z, t + z
    ref = np.linalg.norm(
        np.maximum(np.maximum(lo[None] - x[:, None], 0), x[:, None] - hi[None]), axis=-1
    )
    np.testing.assert_allclose(d, ref, atol=1e-12)
    np.testing.assert_allclose(P.point_cuboid_distance(x, c, squared=True), ref**2, atol=1e-12)


def test_distance_matches_brute_force_rotated():
    rng = np.random.default_rng(7)
    c = random_cuboids(rng, 3)
    x = rng.uniform(-1.2, 1.2, size=(60, 3))
    d = P.point_cuboid_distance(x, c)
    res = 61
    for k in range(c.count):
        grid = dense_surface_grid(c.half_extents[k], res)
        world = grid @ c.rotations[k].T + c.translations[k]
        spacing = 2 * c.half_extents[k].max() / (res - 1)
        bound = spacing * np.sqrt(2) / 2  # farthest a surface point is from the grid
        outside = ~P.contains(x, c)[:, k]
        assert outside.sum() > 20
        for i in np.flatnonzero(outside):
            brute = np.linalg.norm(world - x[i], axis=1).min()
            # the grid lies on the cuboid, so brute force never undercuts the exact distance
            assert -1e-12 <= brute - d[i, k] <= bound + 1e-12


def test_distance_zero_inside_and_contains():
    rng = np.random.default_rng(8)
    c = random_cuboids(rng, 4)
    inside = P.sample_volume(c, 200, seed=1)  # (m, k, 3)
    for k in range(c.count):
        assert np.all(P.point_cuboid_distance(inside[k], c)[:, k] == 0)
        assert np.all(P.contains(inside[k], c)[:, k])
    x = rng.uniform(-1, 1, size=(500, 3))
    np.testing.assert_array_equal(P.contains(x, c), P.point_cuboid_distance(x, c) == 0)


def test_union_distance():
    rng = np.random.default_rng(9)
    c = random_cuboids(rng, 4, present=[1, 0, 1, 0])
    x = rng.normal(size=(50, 3))
    d = P.point_cuboid_distance(x, c)
    np.testing.assert_allclose(P.union_distance(x, c), d[:, [0, 2]].min(axis=1))
    np.testing.assert_allclose(P.union_distance(x, c, squared=True), d[:, [0, 2]].min(axis=1) ** 2)
    assert np.all(np.isinf(P.union_distance(x, c.with_existence(np.zeros(4, bool)))))


def test_points_validation():
    c = axis_aligned([1, 1, 1], [0, 0, 0])
    with pytest.raises(ValueError, match=r"`points` must be \(n, 3\) float"):
        P.point_cuboid_distance(np.zeros((4, 2)), c)


# ----------------------------------------------------------------------------------------------
# torch versions
# ----------------------------------------------------------------------------------------------


def batch_of_cuboids(rng, B, m):
    cs = [random_cuboids(rng, m) for _ in range(B)]
    z = torch.tensor(np.stack([c.half_extents for c in cs]))
    q = torch.tensor(np.stack([c.quaternions for c in cs]) * rng.uniform(0.5, 2, size=(B, m, 1)))
    t = torch.tensor(np.stack([c.translations for c in cs]))
    return cs, z, q, t


def test_torch_matches_numpy_distance_and_frames():
    rng = np.random.default_rng(10)
    B, m, n = 3, 4, 50
    cs, z, q, t = batch_of_cuboids(rng, B, m)
    x = rng.uniform(-1, 1, size=(B, n, 3))
    xt = torch.tensor(x)
    local = P.world_to_local_torch(xt, q, t)
    d2 = P.cuboid_distance_sq_torch(xt, z, q, t)
    assert local.shape == (B, m, n, 3) and d2.shape == (B, n, m)
    for b in range(B):
        np.testing.assert_allclose(local[b].numpy(), P.world_to_local(x[b], cs[b]), atol=1e-12)
        np.testing.assert_allclose(d2[b].numpy(), P.point_cuboid_distance(x[b], cs[b], squared=True), atol=1e-12)
    # float32 in, float32 out
    assert P.cuboid_distance_sq_torch(xt.float(), z.float(), q.float(), t.float()).dtype == torch.float32


def generic_points(rng, cuboid, n, margin=0.03):
    """Points away from the distance's kinks: every |local_i| at least `margin` from 0 and z_i."""
    x = rng.uniform(-1, 1, size=(20 * n, 3))
    local = P.world_to_local(x, cuboid)[0]
    z = cuboid.half_extents[0]
    ok = (np.abs(local).min(axis=1) > margin) & (np.abs(np.abs(local) - z).min(axis=1) > margin)
    x = x[ok][:n]
    assert len(x) == n
    return x


def test_distance_gradcheck():
    rng = np.random.default_rng(11)
    c = random_cuboids(rng, 1)
    x = generic_points(rng, c, 12)
    assert (P.point_cuboid_distance(x, c)[:, 0] > 0).sum() >= 6  # mostly outside: gradients non-zero
    args = (
        torch.tensor(x[None], requires_grad=True),
        torch.tensor(c.half_extents[None], requires_grad=True),
        torch.tensor(c.quaternions[None] * 1.3, requires_grad=True),
        torch.tensor(c.translations[None], requires_grad=True),
    )
    assert torch.autograd.gradcheck(P.cuboid_distance_sq_torch, args)


def test_distance_gradient_finite_everywhere():
    # points on faces, edges, corners, the centre: the gradient exists and is finite
    z = torch.tensor([[[0.2, 0.3, 0.4]]], dtype=torch.float64, requires_grad=True)
    q = torch.tensor([[[1.0, 0, 0, 0]]], dtype=torch.float64, requires_grad=True)
    t = torch.zeros(1, 1, 3, dtype=torch.float64, requires_grad=True)
    x = torch.tensor([[[0, 0, 0], [0.2, 0, 0], [0.2, 0.3, 0.4], [0.5, 0.3, 0], [0.0, 0.0, 0.4]]],
                     dtype=torch.float64, requires_grad=True)
    d2 = P.cuboid_distance_sq_torch(x, z, q, t)
    d2.sum().backward()
    for g in (x.grad, z.grad, q.grad, t.grad):
        assert torch.isfinite(g).all()
    # d(d^2)/dx = 2 (x - closest point) for the outside point
    np.testing.assert_allclose(x.grad[0, 3].numpy(), [0.6, 0, 0], atol=1e-12)


def test_torch_surface_sampling_matches_numpy():
    rng = np.random.default_rng(12)
    B, m, k = 2, 3, 24
    cs, z, q, t = batch_of_cuboids(rng, B, m)
    uv = rng.uniform(-1, 1, size=(B, m, k, 2))
    pts, w = surface_samples_from_coefficients_torch(z, q, t, torch.tensor(uv))
    for b in range(B):
        ref = _surface_from_uv(cs[b], uv[b])
        np.testing.assert_allclose(pts[b].numpy(), ref.points, atol=1e-12)
        np.testing.assert_allclose(w[b].numpy(), ref.weights, atol=1e-12)
    # the public sampler: shapes, points on the surface, weights sum to the area, reproducible
    g = torch.Generator().manual_seed(0)
    pts, w = P.sample_cuboid_surfaces_torch(z, q, t, samples_per_cuboid=k, generator=g)
    assert pts.shape == (B, m, k, 3) and w.shape == (B, m, k)
    pts2, _ = P.sample_cuboid_surfaces_torch(z, q, t, samples_per_cuboid=k, generator=torch.Generator().manual_seed(0))
    assert torch.equal(pts, pts2)
    for b in range(B):
        d = P.point_cuboid_distance(pts[b].reshape(-1, 3).numpy(), cs[b]).reshape(m, k, m)
        assert np.abs(d[np.arange(m), :, np.arange(m)]).max() < 1e-9
        zz = cs[b].half_extents
        area = 8 * (zz[:, 0] * zz[:, 1] + zz[:, 1] * zz[:, 2] + zz[:, 0] * zz[:, 2])
        np.testing.assert_allclose(w[b].sum(-1).numpy(), area, rtol=1e-12)
    with pytest.raises(ValueError, match="multiple of 6"):
        P.sample_cuboid_surfaces_torch(z, q, t, samples_per_cuboid=10)


def test_surface_sampling_gradcheck():
    rng = np.random.default_rng(13)
    _, z, q, t = batch_of_cuboids(rng, 1, 2)
    z, q, t = (a.clone().requires_grad_(True) for a in (z, q, t))

    def f(z, q, t):
        return P.sample_cuboid_surfaces_torch(z, q, t, samples_per_cuboid=12, generator=torch.Generator().manual_seed(5))

    assert torch.autograd.gradcheck(f, (z, q, t))


# ----------------------------------------------------------------------------------------------
# numpy sampling
# ----------------------------------------------------------------------------------------------


def test_sample_surface_invariants():
    rng = np.random.default_rng(14)
    c = random_cuboids(rng, 5, present=[1, 1, 0, 1, 1])
    k = 60
    s = P.sample_cuboid_surfaces(c, k, seed=3)
    assert s.points.shape == (5, k, 3) and s.weights.shape == (5, k) and s.face.shape == (5, k)
    z = c.half_extents
    for i in range(c.count):
        # on the surface of cuboid i
        assert P.point_cuboid_distance(s.points[i], c)[:, i].max() < 1e-9
        local = P.world_to_local(s.points[i], c)[i]
        at_bound = np.abs(np.abs(local) - z[i]) < 1e-9
        assert np.all(at_bound.sum(axis=1) == 1)  # exactly one axis reaches z
        axis = np.argmax(at_bound, axis=1)
        np.testing.assert_array_equal(axis, s.face[i] // 2)
        np.testing.assert_array_equal(np.sign(local[np.arange(k), axis]), np.where(s.face[i] % 2 == 0, 1, -1))
        assert np.all(np.abs(local) <= z[i] + 1e-12)
        # equal count per face
        np.testing.assert_array_equal(np.bincount(s.face[i], minlength=6), np.full(6, k // 6))
    area = 8 * (z[:, 0] * z[:, 1] + z[:, 1] * z[:, 2] + z[:, 0] * z[:, 2])
    np.testing.assert_allclose(s.weights.sum(axis=1), area, rtol=1e-12)
    # reproducible with a seed
    np.testing.assert_array_equal(P.sample_cuboid_surfaces(c, k, seed=3).points, s.points)
    with pytest.raises(ValueError, match="multiple of 6"):
        P.sample_cuboid_surfaces(c, 100)


def test_weighted_surface_samples_are_area_uniform():
    # with importance weights, the weighted mean of x^2 over a box surface matches the exact value
    z = np.array([0.1, 0.3, 0.6])
    c = axis_aligned(z, [0, 0, 0])
    s = P.sample_cuboid_surfaces(c, 6 * 20000, seed=0)
    x2 = s.points[0, :, 0] ** 2
    est = np.sum(s.weights[0] * x2) / s.weights[0].sum()
    # exact: faces +-x contribute z0^2 * area; the other four faces x^2 averages z0^2 / 3
    a = 4 * np.array([z[1] * z[2], z[2] * z[0], z[0] * z[1]])
    exact = (2 * a[0] * z[0] ** 2 + 2 * (a[1] + a[2]) * z[0] ** 2 / 3) / (2 * a.sum())
    assert abs(est - exact) < 0.02 * exact


def test_sample_volume_inside():
    rng = np.random.default_rng(15)
    c = random_cuboids(rng, 3)
    v = P.sample_volume(c, 500, seed=0)
    assert v.shape == (3, 500, 3)
    for i in range(3):
        assert P.contains(v[i], c)[:, i].all()
    # centroid of uniform samples is the translation
    np.testing.assert_allclose(v.mean(axis=1), c.translations, atol=0.05)


# ----------------------------------------------------------------------------------------------
# overlap, pruning, assignment
# ----------------------------------------------------------------------------------------------


def test_fraction_inside_others():
    inner_outer = axis_aligned([[0.1, 0.1, 0.1], [0.5, 0.5, 0.5]], [[0.05, 0, 0], [0, 0, 0]])
    f = P.fraction_inside_others(inner_outer, 2000, seed=0)
    assert f[0] == 1.0
    assert abs(f[1] - 0.008) < 0.01  # (0.2 / 1.0)^3 of the big cube lies in the small one

    disjoint = axis_aligned([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2]], [[0, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(P.fraction_inside_others(disjoint, 1000, seed=0), [0, 0])

    half = axis_aligned([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]], [[0, 0, 0], [0.5, 0, 0]])
    f = P.fraction_inside_others(half, 4000, seed=0)
    np.testing.assert_allclose(f, [0.5, 0.5], atol=0.04)

    # absent parts are nan and do not cover others
    f = P.fraction_inside_others(inner_outer.with_existence([True, False]), 1000, seed=0)
    assert f[0] == 0 and np.isnan(f[1])


def test_prune_covered():
    z = [[0.5, 0.5, 0.5], [0.3, 0.3, 0.3], [0.1, 0.1, 0.1], [0.2, 0.2, 0.2], [0.2, 0.2, 0.2]]
    t = [[0, 0, 0], [5, 0, 0], [0.1, 0, 0], [0, 3, 0], [0, 3.05, 0]]
    c = axis_aligned(z, t, present=[True, False, True, True, True])
    pruned = P.prune_covered(c, threshold=0.6, samples_per_cuboid=1000, seed=0)
    assert pruned.count == 5
    np.testing.assert_array_equal(pruned.half_extents, c.half_extents)
    # the inner cube (2) goes; of the two nearly identical cubes (3, 4) exactly one goes, since the
    # fractions are recomputed after each removal
    assert pruned.existence[0] and not pruned.existence[1] and not pruned.existence[2]
    assert pruned.existence[3] + pruned.existence[4] == 1
    # half overlapping parts stay
    half = axis_aligned([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]], [[0, 0, 0], [0.5, 0, 0]])
    assert P.prune_covered(half).existence.all()


def test_assign_points_ties_go_to_larger():
    # small cube (index 0) inside a big one (index 1), an absent cube (2) right at the probe points
    c = axis_aligned(
        [[0.1, 0.1, 0.1], [0.5, 0.5, 0.5], [0.3, 0.3, 0.3]],
        [[0, 0, 0], [0, 0, 0], [2, 0, 0]],
        present=[True, True, False],
    )
    x = np.array([[0, 0, 0], [0.05, 0.05, 0], [0.3, 0, 0], [2, 0, 0], [-3, 0, 0]])
    np.testing.assert_array_equal(P.assign_points(x, c), [1, 1, 1, 1, 1])
    # outside both: the nearest wins
    c2 = axis_aligned([[0.1, 0.1, 0.1], [0.5, 0.5, 0.5]], [[2, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(P.assign_points([[1.95, 0, 0], [0.6, 0, 0]], c2), [0, 1])
    # naive reference on random sets
    rng = np.random.default_rng(16)
    c3 = random_cuboids(rng, 6, present=[1, 1, 0, 1, 1, 1])
    x = rng.uniform(-0.6, 0.6, size=(300, 3))
    got = P.assign_points(x, c3)
    d = P.point_cuboid_distance(x, c3)
    for i in range(len(x)):
        best = min(c3.present, key=lambda k: (d[i, k], -c3.volumes[k], k))
        assert got[i] == best
    with pytest.raises(ValueError, match="no present"):
        P.assign_points(x, c3.with_existence(np.zeros(6, bool)))


# ----------------------------------------------------------------------------------------------
# serialisation and mesh
# ----------------------------------------------------------------------------------------------


def test_json_round_trip(tmp_path):
    rng = np.random.default_rng(17)
    for probs in (False, True):
        c = random_cuboids(rng, 4, present=[1, 0, 1, 1], probabilities=probs)
        d = c.to_dict()
        assert d["schema_version"] == P.SCHEMA_VERSION
        assert d["parts"][1] == {**d["parts"][1], "index": 1, "present": False}
        keys = {"index", "present", "half_extents", "quaternion_wxyz", "translation", "probability"}
        assert set(d["parts"][0]) == keys
        path = c.save_json(tmp_path / f"c{probs}.json")
        back = Cuboids.load_json(path)
        for name in ("half_extents", "quaternions", "translations", "existence"):
            np.testing.assert_array_equal(getattr(back, name), getattr(c, name))
        if probs:
            np.testing.assert_array_equal(back.probabilities, c.probabilities)
        else:
            assert back.probabilities is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cFalse.json", "cTrue.json"]  # no temp files left


def test_json_refusals(tmp_path):
    c = axis_aligned([0.1, 0.2, 0.3], [0, 0, 0])
    path = c.save_json(tmp_path / "c.json")
    with pytest.raises(FileExistsError):
        c.save_json(path)
    c2 = axis_aligned([0.4, 0.2, 0.3], [0, 0, 0])
    c2.save_json(path, overwrite=True)
    np.testing.assert_array_equal(Cuboids.load_json(path).half_extents, c2.half_extents)
    d = c.to_dict()
    with pytest.raises(ValueError, match="newer"):
        Cuboids.from_dict({**d, "schema_version": 3})  # 2 is a <name>.cuboids.json (primkit.model.cuboids_file)
    with pytest.raises(ValueError, match="schema_version"):
        Cuboids.from_dict({k: v for k, v in d.items() if k != "schema_version"})
    with pytest.raises(ValueError, match="malformed"):
        Cuboids.from_dict({**d, "parts": [{"index": 0}]})
    path.write_text(json.dumps({**d, "schema_version": 0}))
    with pytest.raises(ValueError, match="unknown"):
        Cuboids.load_json(path)


def signed_volume(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


def test_to_mesh_watertight_outward():
    rng = np.random.default_rng(18)
    c = random_cuboids(rng, 4, present=[1, 0, 1, 1])
    v, f, part = c.to_mesh()
    assert v.shape == (24, 3) and f.shape == (36, 3) and part.shape == (36,)
    assert sorted(set(part.tolist())) == [0, 2, 3]
    for k in c.present:
        fk = f[part == k]
        # watertight and consistently wound: every directed edge once, its reverse once
        edges = np.concatenate([fk[:, [0, 1]], fk[:, [1, 2]], fk[:, [2, 0]]])
        directed = {tuple(e) for e in edges.tolist()}
        assert len(directed) == len(edges) == 36
        assert all((b, a) in directed for a, b in directed)
        # outward: positive signed volume equal to 8 z0 z1 z2 (about any origin), normals point away
        np.testing.assert_allclose(signed_volume(v, fk), c.volumes[k], rtol=1e-10)
        tri = v[fk]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert np.all(np.einsum("ij,ij->i", normal, tri.mean(axis=1) - c.translations[k]) > 0)
        # vertices are the corners: on the surface, at |local| = z on all axes
        corners = np.unique(fk)
        local = P.world_to_local(v[corners], c)[k]
        np.testing.assert_allclose(np.abs(local), np.broadcast_to(c.half_extents[k], (8, 3)), atol=1e-12)
    # triangles 2f, 2f+1 lie on face f: their local normal is the face's axis with its sign
    one = axis_aligned([0.1, 0.2, 0.3], [0, 0, 0])
    v1, f1, _ = one.to_mesh()
    n1 = np.cross(v1[f1[:, 1]] - v1[f1[:, 0]], v1[f1[:, 2]] - v1[f1[:, 0]])
    axes = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
    expected = np.repeat(np.array(axes, float), 2, axis=0)
    np.testing.assert_allclose(n1 / np.linalg.norm(n1, axis=1, keepdims=True), expected, atol=1e-12)
    assert c.to_mesh(include_absent=True)[1].shape == (48, 3)


def test_to_mesh_trimesh():
    trimesh = pytest.importorskip("trimesh")
    c = random_cuboids(np.random.default_rng(19), 1)
    v, f, _ = c.to_mesh()
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    np.testing.assert_allclose(mesh.volume, c.volumes[0], rtol=1e-10)


# ----------------------------------------------------------------------------------------------
# similarity transforms
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("reflect", [False, True])
def test_transformed_scales_distances(reflect):
    rng = np.random.default_rng(20 + reflect)
    c = random_cuboids(rng, 4, present=[1, 1, 0, 1], probabilities=True)
    M, s = random_similarity(rng, reflect)
    ct = c.transformed(M)
    x = rng.uniform(-1, 1, size=(200, 3))
    np.testing.assert_allclose(
        P.point_cuboid_distance(apply(M, x), ct), s * P.point_cuboid_distance(x, c), atol=1e-10
    )
    np.testing.assert_array_equal(P.contains(apply(M, x), ct), P.contains(x, c))
    np.testing.assert_allclose(ct.volumes, s**3 * c.volumes, rtol=1e-12)
    np.testing.assert_array_equal(ct.existence, c.existence)
    np.testing.assert_array_equal(ct.probabilities, c.probabilities)
    assert np.all(ct.quaternions[:, 0] >= 0)
    # the mesh transforms with the points (as a set of corners per part)
    v, f, part = c.to_mesh()
    vt, ft, part_t = ct.to_mesh()
    np.testing.assert_array_equal(part, part_t)
    for k in c.present:
        a = np.sort(np.round(apply(M, v[np.unique(f[part == k])]), 9), axis=0)
        b = np.sort(np.round(vt[np.unique(ft[part_t == k])], 9), axis=0)
        np.testing.assert_allclose(a, b, atol=1e-8)
    # (3, 3) linear part alone
    ct3 = c.transformed(M[:3, :3])
    np.testing.assert_allclose(ct3.translations, c.translations @ M[:3, :3].T, atol=1e-12)


def test_transformed_rejects_non_similarity():
    c = axis_aligned([0.1, 0.2, 0.3], [0, 0, 0])
    with pytest.raises(ValueError, match="similarity"):
        c.transformed(np.diag([1.0, 2.0, 1.0]))
    bad = np.eye(4)
    bad[3, 0] = 1
    with pytest.raises(ValueError, match="bottom row"):
        c.transformed(bad)
    with pytest.raises(ValueError, match="similarity"):
        c.transformed(np.zeros((3, 3)))


def test_quaternion_conversions_keep_primkit_conventions():
    """scipy's Rotation does the NumPy conversions: checked against the formula primkit used before
    (the one the torch twin still uses), real part first, matrices acting on column vectors."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(7, 5, 4))
    R = P.quaternion_to_matrix(q)
    assert R.shape == (7, 5, 3, 3)
    ref = P.quaternion_to_matrix_torch(torch.from_numpy(q)).numpy()
    np.testing.assert_allclose(R, ref, atol=1e-14)
    quarter = P.quaternion_to_matrix([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # 90 degrees about +z
    np.testing.assert_allclose(quarter @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    back = P.matrix_to_quaternion(R)
    unit = q / np.linalg.norm(q, axis=-1, keepdims=True)
    assert back.shape == q.shape and np.all(back[..., 0] >= 0)
    np.testing.assert_allclose(np.abs(np.sum(back * unit, axis=-1)), 1.0, atol=1e-12)  # the same rotation
    np.testing.assert_allclose(P.matrix_to_quaternion(np.diag([1.0, -1.0, -1.0])), [0.0, 1.0, 0.0, 0.0], atol=1e-15)
    assert P.quaternion_to_matrix(np.zeros((0, 4))).shape == (0, 3, 3)
    with pytest.raises(ValueError, match="nonzero"):
        P.quaternion_to_matrix([0.0, 0.0, 0.0, 0.0])


def _prune_by_fractions(c, threshold, k, seed):
    """The published loop, literally: recompute every fraction (dense containment of all samples
    in all present parts) after each removal; returns the existence mask."""
    existence = c.existence.copy()
    while existence.sum() > 1:
        frac = P.fraction_inside_others(c.with_existence(existence), samples_per_cuboid=k, seed=seed)
        worst = int(np.nanargmax(frac))
        if not frac[worst] > threshold:
            break
        existence[worst] = False
    return existence


def test_prune_covered_many_is_prune_covered_on_each():
    rng = np.random.default_rng(11)
    sets = []
    for i in range(40):
        m = 8 if i % 3 else 5
        z = rng.uniform(0.03, 0.25, (m, 3))
        q = rng.normal(size=(m, 4))
        t = rng.uniform(-0.2, 0.2, (m, 3))  # crowded: many parts inside others
        e = rng.random(m) < 0.8
        sets.append(P.Cuboids(z, q, t, e))
    sets.append(P.Cuboids(np.full((3, 3), 0.1), np.tile([1.0, 0, 0, 0], (3, 1)), np.zeros((3, 3)),
                                   np.array([True, False, False])))  # one present part: nothing to prune
    many = P.prune_covered_many(sets, 0.6, samples_per_cuboid=300, seed=2)
    pruned = 0
    for c, got in zip(sets, many):
        want = _prune_by_fractions(c, 0.6, 300, 2)
        assert np.array_equal(got.existence, want)
        assert np.array_equal(P.prune_covered(c, 0.6, samples_per_cuboid=300, seed=2).existence, want)
        np.testing.assert_array_equal(got.half_extents, c.half_extents)
        pruned += int(c.existence.sum() - got.existence.sum())
    assert pruned > 20  # the case is not trivial


def test_part_colors_are_matplotlib_tab20():
    from matplotlib import colormaps

    from primkit.primitives.palette import part_colors

    tab20 = colormaps["tab20"]
    want = (np.array([tab20(i % 20)[:3] for i in range(45)]) * 255).astype(np.uint8)
    got = part_colors(45)
    assert got.dtype == np.uint8 and got.shape == (45, 3)
    assert np.array_equal(got, want)

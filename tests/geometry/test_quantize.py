"""The cache's compact codes (geometry.quantize) against the float arrays they stand for."""

import numpy as np
import pytest

from primkit import geometry, synthetic

R = 32


def _near_mask(near):
    return np.unpackbits(near)[: R**3].reshape(R, R, R).astype(bool)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_closest_points_within_the_declared_error(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((R, R, R)) < 0.02  # scattered voxels: offsets of every size and direction
    occ[8:20, 4:28, 10:14] = True
    closest = geometry.voxel_closest_points(occ)
    codes, near = geometry.encode_closest(closest)
    assert codes.shape == (3, R**3) and codes.dtype == np.uint8 and near.shape == (R**3 // 8,)
    decoded = geometry.decode_closest(codes, near, R)
    err = np.abs(decoded - closest).max(-1)
    near_err, far_err = geometry.closest_error(R)
    mask = _near_mask(near)
    offset = np.abs(closest - geometry.grid_centres(R)).max(-1) * R
    assert np.array_equal(mask, offset <= 1.0)  # near: within one cell of the centre on every axis
    assert err[mask].max() <= near_err + 1e-6 and err[~mask].max() <= far_err + 1e-6
    assert 0 < mask.sum() < R**3


def test_every_surface_cell_of_a_mesh_is_near():
    chair = synthetic.chair(4)
    frame = geometry.canonical_frame(chair.vertices, "+y", "+x")
    v = frame.to_canonical(chair.vertices)
    closest = geometry.distance_grid(v, chair.faces, R).closest
    codes, near = geometry.encode_closest(closest)
    surface = geometry.surface_voxels(v, chair.faces, R)
    assert _near_mask(near)[surface].all()
    err = np.abs(geometry.decode_closest(codes, near, R) - closest).max(-1)
    assert err[surface].max() <= geometry.closest_error(R)[0] + 1e-6


def test_batch_and_planar_decoding_agree_with_one_shape():
    rng = np.random.default_rng(5)
    grids = [geometry.voxel_closest_points(rng.random((R, R, R)) < p) for p in (0.01, 0.05, 0.2)]
    enc = [geometry.encode_closest(g) for g in grids]
    codes = np.stack([c for c, _ in enc])
    near = np.stack([n for _, n in enc])
    batch = geometry.decode_closest(codes, near, R)
    planar = geometry.decode_closest(codes, near, R, planar=True)
    for i, (c, n) in enumerate(enc):
        one = geometry.decode_closest(c, n, R)
        assert np.array_equal(batch[i], one)
        assert np.array_equal(planar[i].reshape(3, R, R, R), np.moveaxis(one, -1, 0))


def test_points_round_trip_within_the_declared_error():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.5, 0.5, (20000, 3))
    pts[:3] = [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5], [0.0, 0.0, 0.0]]
    codes = geometry.encode_points(pts)
    assert codes.dtype == np.uint32 and codes.shape == (20000,)
    back = geometry.decode_points(codes)
    assert (np.abs(back - pts).max(0) <= np.array(geometry.POINT_ERROR) + 1e-7).all()
    assert np.array_equal(back[:2], pts[:2])  # the cube's corners are exact
    assert np.array_equal(geometry.decode_points(codes.reshape(100, 200)), back.reshape(100, 200, 3))

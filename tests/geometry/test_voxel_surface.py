"""The voxel surface without a mesh (primkit.geometry.voxels) against the voxel boundary mesh:
exact closest points against libigl's point-to-mesh distances, samples on the squares and uniform by
area, on random grids and on ShapeNetVox32 chairs."""

import igl
import numpy as np
import pytest

from primkit import data, geometry, io


def _grids():
    rng = np.random.default_rng(3)
    out = []
    for res, fill in ((8, 0.3), (12, 0.15), (16, 0.05)):
        occ = rng.random((res, res, res)) < fill  # scattered voxels: many corners, edges, one-voxel parts
        occ[0, :, 0] = True  # touching the grid's border
        out.append(occ)
    slab = np.zeros((10, 10, 10), bool)
    slab[2:8, 4:6, 1:9] = True
    out.append(slab)
    return out


@pytest.mark.parametrize("occ", _grids(), ids=["random8", "random12", "random16", "slab"])
def test_closest_points_are_exact_and_on_the_surface(occ):
    res = occ.shape[0]
    v, f = geometry.voxel_boundary_mesh(occ)
    centres = geometry.grid_centres(res).reshape(-1, 3)
    exact, _, _ = igl.point_mesh_squared_distance(centres, v, f)
    closest = geometry.voxel_closest_points(occ).reshape(-1, 3).astype(np.float64)
    np.testing.assert_allclose(((closest - centres) ** 2).sum(1), exact, rtol=2e-6, atol=1e-12)  # float32 storage
    on, _, _ = igl.point_mesh_squared_distance(closest, v, f)
    assert on.max() < 1e-12  # every closest point is a point of the surface (up to float32)


def test_surface_nodes_are_the_squares_corners_edges_and_centres():
    occ = np.zeros((3, 3, 3), bool)
    occ[1, 1, 1] = True  # one voxel: its cube's surface holds 6 face centres, 12 edge midpoints, 8 corners
    nodes = geometry.voxel_surface_nodes(occ)
    assert nodes.sum() == 26 and not nodes[3, 3, 3]
    assert nodes[2:5, 2:5, 2:5].sum() == 26


def test_samples_lie_on_the_squares_uniformly_by_area():
    occ = np.zeros((16, 16, 16), bool)
    occ[2:14, 6:8, 3:5] = True  # a bar 12 x 2 x 2: side squares 96 + 96 along x, 48 + 48 ... ends 4 + 4
    v, f = geometry.voxel_boundary_mesh(occ)
    pts = geometry.sample_voxel_surface(occ, 20000, seed=1)
    d2, face, _ = igl.point_mesh_squared_distance(pts, v, f)
    assert d2.max() < 1e-20
    normal = np.abs(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])).argmax(1)[face]
    share = np.bincount(normal, minlength=3) / len(pts)
    area = np.array([2 * 2 * 2, 2 * 12 * 2, 2 * 12 * 2], float)  # squares facing x, y, z
    np.testing.assert_allclose(share, area / area.sum(), atol=0.01)
    again = geometry.sample_voxel_surface(occ, 20000, seed=1)
    assert np.array_equal(pts, again)


def test_prepared_voxels_match_the_mesh_path(shared_data):
    """ShapeNetVox32 chairs: the distances of the grid-only preparation equal the BVH's on the boundary
    mesh (the path used before), its samples lie on that mesh."""
    folders = sorted((shared_data / "shapenetvox32" / "03001627").iterdir())[:4]
    for folder in folders:
        prep = data.prepare_file(folder / "model.binvox")
        v, f = geometry.voxel_boundary_mesh(prep.solid)
        reference = geometry.distance_grid(v, f, prep.resolution, exact_within=None)
        np.testing.assert_allclose(prep.distance, reference.distance, atol=1e-6)
        d2, _, _ = igl.point_mesh_squared_distance(prep.points.astype(np.float64), v, f)
        assert np.sqrt(d2).max() < 1e-6
        assert prep.occupancy.sum() == prep.solid.sum() == geometry.fill_voxels(io.read_voxels(folder / "model.binvox").occupancy).sum()


def _more_grids():
    rng = np.random.default_rng(8)
    full = np.ones((6, 6, 6), bool)  # the surface is the grid's outer boundary alone
    one = np.zeros((5, 5, 5), bool)
    one[4, 0, 2] = True  # one voxel in a corner: far centres, many ties
    return _grids() + [rng.random((32, 32, 32)) < p for p in (0.002, 0.1, 0.6, 0.97)] + [full, one]


def test_compiled_transform_gives_scipys_points():
    """The transform at the voxel centres (Numba) against SciPy's transform of the whole lattice:
    the same nearest node everywhere, ties included, on grids with far centres and many ties."""
    for occ in _more_grids():
        fast = geometry.voxel_closest_points(occ)
        reference = geometry.voxel_closest_points(occ, engine="scipy")
        assert np.array_equal(fast, reference)
    with pytest.raises(ValueError, match="engine"):
        geometry.voxel_closest_points(np.ones((4, 4, 4), bool), engine="edt")

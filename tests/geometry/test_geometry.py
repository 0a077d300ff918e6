"""Shape preparation checked against brute force, closed forms and an independent library (libigl)."""

import igl
import numpy as np
import pytest
import torch
import trimesh

from primkit import geometry
from primkit.model.distance_field import lookup_distance_sq_torch


def brute_force_distance(points, vertices, faces):
    """Exact point-to-triangle distances by a method independent of the library code: minimise
    over the triangle's interior (projection when inside) and its three edges (clamped segments)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    best = np.full(len(points), np.inf)
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    for p_chunk_start in range(0, len(points), 512):
        p = points[p_chunk_start : p_chunk_start + 512, None, :]  # (P, 1, 3)
        # interior: projection onto the plane, inside if all barycentric coordinates >= 0
        t = np.einsum("pfk,fk->pf", a[None] - p, n) / nn
        proj = p + t[..., None] * n[None]
        def edge_sign(u, v):
            return np.einsum("pfk,fk->pf", np.cross(v[None] - u[None], proj - u[None]), n)
        inside = (edge_sign(a, b) >= 0) & (edge_sign(b, c) >= 0) & (edge_sign(c, a) >= 0)
        d = np.where(inside, np.abs(t) * np.sqrt(nn), np.inf)
        for u, v in ((a, b), (b, c), (c, a)):
            e = v - u
            s = np.clip(np.einsum("pfk,fk->pf", p - u[None], e) / np.einsum("fk,fk->f", e, e), 0, 1)
            q = u[None] + s[..., None] * e[None]
            d = np.minimum(d, np.linalg.norm(p - q, axis=-1))
        best[p_chunk_start : p_chunk_start + 512] = d.min(axis=1)
    return best


def canonical(mesh):
    v = np.asarray(mesh.vertices, float)
    return geometry.canonical_frame(v).to_canonical(v), np.asarray(mesh.faces)


@pytest.fixture(scope="module")
def meshes():
    torus = trimesh.creation.torus(0.3, 0.1, major_sections=24, minor_sections=12)
    box = trimesh.creation.box((0.7, 0.3, 0.5))
    box.apply_transform(trimesh.transformations.rotation_matrix(0.4, (1, 2, 3)))
    sphere = trimesh.creation.icosphere(2)
    return {"torus": canonical(torus), "box": canonical(box), "sphere": canonical(sphere)}


def test_canonical_frame_round_trip_and_axes():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3)) * (1, 3, 2) + 5
    frame = geometry.canonical_frame(pts, up="+z", front="-y")
    c = frame.to_canonical(pts)
    lo, hi = c.min(0), c.max(0)
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-12)
    assert np.isclose((hi - lo).max(), 1.0)
    np.testing.assert_allclose(frame.from_canonical(c), pts, atol=1e-12)
    # +z of the input is +y of the canonical frame, -y of the input is +x
    d = frame.to_canonical(np.array([[0, 0, 1.0], [0, -1.0, 0]])) - frame.to_canonical(np.zeros((1, 3)))
    np.testing.assert_allclose(d / np.linalg.norm(d, axis=1, keepdims=True), [[0, 1, 0], [1, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(frame.matrix[:3, :3] @ pts[0] + frame.matrix[:3, 3], c[0])
    assert np.isclose(np.linalg.det(geometry.axis_rotation("-x", "+z")), 1.0)
    with pytest.raises(ValueError):
        geometry.axis_rotation("+y", "-y")


@pytest.mark.parametrize("name", ["torus", "box", "sphere"])
def test_distance_grid_matches_brute_force(meshes, name):
    v, f = meshes[name]
    res = 16
    grid = geometry.distance_grid(v, f, res, exact_within=None)
    centres = geometry.grid_centres(res).reshape(-1, 3)
    exact = brute_force_distance(centres, v, f)
    assert np.abs(grid.distance.ravel() - exact).max() < 1e-5
    # the closest points lie on the surface and realise the distance
    cp = grid.closest.reshape(-1, 3).astype(float)
    np.testing.assert_allclose(np.linalg.norm(cp - centres, axis=1), exact, atol=1e-5)
    assert brute_force_distance(cp[::37], v, f).max() < 1e-5


@pytest.mark.parametrize("name", ["torus",  # the fast loop keeps the hardest shape; each is seconds of brute force
                                  pytest.param("box", marks=pytest.mark.integration),
                                  pytest.param("sphere", marks=pytest.mark.integration)])
@pytest.mark.integration  # a brute-force distance grid: several seconds, left to the default suite
def test_distance_grid_far_cells_within_the_declared_error(meshes, name):
    """The default: exact within 2 cells of a surface cell, beyond within 3e-3, never too small;
    every closest point on the surface, at the distance given."""
    v, f = meshes[name]
    for res in (16, 32):
        grid = geometry.distance_grid(v, f, res)
        centres = geometry.grid_centres(res).reshape(-1, 3)
        exact = brute_force_distance(centres, v, f)
        error = grid.distance.ravel().astype(float) - exact
        assert error.min() > -1e-6 and error.max() < 3e-3, (res, error.min(), error.max())
        cp = grid.closest.reshape(-1, 3).astype(float)
        np.testing.assert_allclose(np.linalg.norm(cp - centres, axis=1), grid.distance.ravel(), atol=1e-6)
        assert brute_force_distance(cp[::11], v, f).max() < 1e-6
        from scipy import ndimage

        near = ndimage.distance_transform_edt(~geometry.surface_voxels(v, f, res)).ravel() <= 2.0
        assert np.abs(error[near]).max() < 1e-6 and near.mean() < 0.9
        exact_grid = geometry.distance_grid(v, f, res, exact_within=None)
        assert np.array_equal(grid.closest.reshape(-1, 3)[near], exact_grid.closest.reshape(-1, 3)[near])


def test_closest_points_on_triangles_against_libigl():
    rng = np.random.default_rng(1)
    n = 500
    a, b, c = rng.normal(size=(3, n, 3))
    p = rng.normal(size=(n, 3)) * 2
    got = geometry.closest_points_on_triangles(p, a, b, c)
    for i in range(n):
        _, _, ref = igl.point_mesh_squared_distance(p[i : i + 1], np.stack([a[i], b[i], c[i]]), np.array([[0, 1, 2]]))
        np.testing.assert_allclose(got[i], ref[0], atol=1e-10)
    # degenerate (zero-area) triangles fall back to the nearest vertex
    deg = geometry.closest_points_on_triangles(p[:5], a[:5], a[:5], a[:5])
    np.testing.assert_allclose(deg, a[:5])


@pytest.mark.parametrize("name", ["torus", "box", "sphere"])
def test_occupancy_agrees_with_winding_number_reference(meshes, name):
    v, f = meshes[name]
    res = 32
    occ = geometry.occupancy_grid(v, f, res)
    ref = igl.winding_number(v, f, geometry.grid_centres(res).reshape(-1, 3)) > 0.5
    assert (occ.ravel() == ref).mean() >= 0.99
    assert occ.sum() > 0
    assert np.array_equal(occ, geometry.occupancy_grid(v, f, res, engine="igl"))


def test_occupancy_of_a_sphere_matches_closed_form():
    sphere = trimesh.creation.icosphere(5)  # radius 1 -> 0.5 after normalisation
    v, f = canonical(sphere)
    occ = geometry.occupancy_grid(v, f, 32)
    r = np.linalg.norm(geometry.grid_centres(32), axis=-1)
    # away from the (faceted) boundary the answer is unambiguous
    clear = np.abs(r - 0.5) > 0.01
    assert (occ[clear] == (r[clear] < 0.5)).all()


def test_open_mesh_is_still_solid():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    # remove the two triangles of the +x face: a chair seat with a hole still encloses its inside
    keep = box.face_normals[:, 0] < 0.5
    v, f = np.asarray(box.vertices) * 0.9, np.asarray(box.faces)[keep]
    occ = geometry.occupancy_grid(v, f, 16)
    c = geometry.grid_centres(16)
    interior = (np.abs(c) < 0.4).all(-1)
    assert occ[interior].mean() > 0.95
    assert not occ[(np.abs(c) > 0.46).any(-1)].any()


def test_surface_voxels_hold_the_surface(meshes):
    v, f = meshes["torus"]
    res = 32
    surf = geometry.surface_voxels(v, f, res)
    samples = geometry.sample_surface(v, f, 20000, seed=0).points
    cells = np.clip(np.floor((samples + 0.5) * res).astype(int), 0, res - 1)
    assert surf[cells[:, 0], cells[:, 1], cells[:, 2]].all()
    # a cell whose centre is farther than half its diagonal from the surface is not touched
    dist = geometry.distance_grid(v, f, res).distance
    assert not surf[dist > np.sqrt(3) / 2 / res + 1e-6].any()


def test_sample_surface_is_on_surface_and_area_uniform():
    # two triangles, one three times the area of the other
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [3, 0, 1], [0, 1, 1]], float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    s = geometry.sample_surface(v, f, 40000, seed=3)
    assert s.points.shape == (40000, 3) and s.face_index.shape == (40000,)
    frac = (s.face_index == 1).mean()
    assert abs(frac - 0.75) < 0.01
    np.testing.assert_allclose(s.points[s.face_index == 0, 2], 0)
    np.testing.assert_allclose(s.points[s.face_index == 1, 2], 1)
    assert np.array_equal(geometry.sample_surface(v, f, 100, seed=3).points, geometry.sample_surface(v, f, 100, seed=3).points)


def test_voxel_boundary_mesh_is_closed_and_has_the_voxel_volume():
    rng = np.random.default_rng(2)
    occ = np.zeros((12, 12, 12), bool)
    occ[2:9, 3:7, 4:10] = True
    occ[rng.integers(0, 12, size=(30, 3)).T.tolist()] = True
    v, f = geometry.voxel_boundary_mesh(occ)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight
    assert np.isclose(mesh.volume, occ.sum() / 12**3)
    # the winding number at cell centres recovers the voxels exactly
    w = igl.winding_number(v, f, geometry.grid_centres(12).reshape(-1, 3)) > 0.5
    assert np.array_equal(w.reshape(occ.shape), occ)


def _lookup(closest, points):
    return lookup_distance_sq_torch(torch.as_tensor(closest, dtype=torch.float64)[None], torch.as_tensor(points)[None])[0]


def test_lookup_at_cell_centres_and_upper_bound(meshes):
    v, f = meshes["torus"]
    grid = geometry.distance_grid(v, f, 16)
    centres = geometry.grid_centres(16).reshape(-1, 3)
    d = _lookup(grid.closest, centres).sqrt().numpy()
    np.testing.assert_allclose(d, grid.distance.ravel(), atol=1e-6)
    rng = np.random.default_rng(4)
    pts = rng.uniform(-0.6, 0.6, size=(500, 3))
    looked = _lookup(grid.closest, pts).sqrt().numpy()
    exact = brute_force_distance(pts, v, f)
    assert (looked >= exact - 1e-6).all()
    assert (looked - exact).max() < 1.0 / 16


def test_lookup_is_the_minimum_over_the_eight_surrounding_cells(meshes):
    """Against the definition, in NumPy: min over the 8 cells around x (indices clamped) of |x - closest|^2."""
    v, f = meshes["torus"]
    res = 16
    grid = geometry.distance_grid(v, f, res)
    pts = np.random.default_rng(6).uniform(-0.7, 0.7, size=(400, 3))
    base = np.floor((pts + 0.5) * res - 0.5).astype(int)
    ref = np.full(len(pts), np.inf)
    for corner in np.ndindex(2, 2, 2):
        idx = np.clip(base + corner, 0, res - 1)
        cp = grid.closest[idx[:, 0], idx[:, 1], idx[:, 2]].astype(float)
        ref = np.minimum(ref, ((pts - cp) ** 2).sum(1))
    closest = torch.as_tensor(grid.closest, dtype=torch.float64)[None]
    got = lookup_distance_sq_torch(closest, torch.as_tensor(pts)[None])[0].numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15)


def test_lookup_batched_planar_and_nan(meshes):
    """A batch of grids, float32, stored planar (as training hands them out) or not: the same values,
    each shape against its own grid; a NaN point gives NaN, not an index error."""
    grids = [geometry.distance_grid(*meshes[k], 16).closest for k in ("torus", "sphere")]
    stacked = torch.as_tensor(np.stack(grids))  # (2, R, R, R, 3) float32
    planar = stacked.permute(0, 4, 1, 2, 3).contiguous().permute(0, 2, 3, 4, 1)
    assert not planar.is_contiguous()
    pts = torch.as_tensor(np.random.default_rng(7).uniform(-0.8, 0.8, size=(2, 300, 3)), dtype=torch.float32)
    got = lookup_distance_sq_torch(stacked, pts)
    assert torch.equal(got, lookup_distance_sq_torch(planar, pts))
    for b in range(2):
        np.testing.assert_allclose(got[b].double().numpy(), _lookup(grids[b], pts[b].double()).numpy(), rtol=1e-5, atol=1e-7)
    pts[1, 5] = float("nan")
    out = lookup_distance_sq_torch(stacked, pts)
    assert torch.isnan(out[1, 5]) and torch.isfinite(out).sum() == out.numel() - 1


def test_lookup_gradient_matches_finite_differences(meshes):
    v, f = meshes["sphere"]
    grid = geometry.distance_grid(v, f, 16)
    closest = torch.as_tensor(grid.closest, dtype=torch.float64)[None]
    rng = np.random.default_rng(5)
    pts = torch.tensor(rng.uniform(-0.7, 0.7, size=(1, 200, 3)), requires_grad=True)
    lookup_distance_sq_torch(closest, pts).sum().backward()
    eps = 1e-6
    fd = torch.zeros_like(pts)
    with torch.no_grad():
        for k in range(3):
            step = torch.zeros_like(pts)
            step[..., k] = eps
            fd[..., k] = (lookup_distance_sq_torch(closest, pts + step) - lookup_distance_sq_torch(closest, pts - step)) / (2 * eps)
    err = (fd - pts.grad).abs().amax(-1)[0]
    # a difference across a switch of the winning cell is not a derivative: allow a few
    assert (err < 1e-6).float().mean() > 0.97


def test_lookup_outside_the_grid_keeps_growing(meshes):
    v, f = meshes["sphere"]
    grid = geometry.distance_grid(v, f, 16)
    pts = np.array([[2.0, 0, 0], [0, -3.0, 0], [1.5, 1.5, 1.5]])
    d = _lookup(grid.closest, pts).sqrt().numpy()
    exact = np.linalg.norm(pts, axis=1) - 0.5  # sphere of radius 0.5 (faceted: slightly inside)
    np.testing.assert_allclose(d, exact, atol=0.02)
    pts_t = torch.tensor(pts[None], requires_grad=True)
    lookup_distance_sq_torch(torch.as_tensor(grid.closest, dtype=torch.float64)[None], pts_t).sum().backward()
    assert (pts_t.grad.norm(dim=-1) > 1).all()


def test_fill_voxels_is_binary_fill_holes():
    """Cavities filled by one labelling of the empty cells, against SciPy's flood by dilations:
    a hollow box (its inside filled), a box open on one face (nothing filled), random grids."""
    from scipy import ndimage

    hollow = np.zeros((12, 12, 12), bool)
    hollow[2:10, 2:10, 2:10] = True
    hollow[4:8, 4:8, 4:8] = False
    opened = hollow.copy()
    opened[5:7, 5:7, 2:4] = False  # a tunnel from the cavity to the outside
    rng = np.random.default_rng(4)
    grids = [hollow, opened, np.zeros((5, 5, 5), bool), np.ones((5, 5, 5), bool)]
    grids += [rng.random((20, 20, 20)) < p for p in (0.2, 0.5, 0.8)]
    for occ in grids:
        assert np.array_equal(geometry.fill_voxels(occ), ndimage.binary_fill_holes(occ))
    assert geometry.fill_voxels(hollow).sum() == 8**3 and geometry.fill_voxels(opened).sum() == opened.sum()

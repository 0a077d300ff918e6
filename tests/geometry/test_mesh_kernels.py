"""The compiled closest-point search of distance grids against libigl, brute force and Open3D."""

from pathlib import Path

import igl
import numpy as np
import pytest

from primkit import geometry, io, synthetic

from primkit.geometry import _mesh_kernels as kernels  # noqa: E402 - Numba is a dependency: no skip

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


def segment_distance(p, u, v):
    e = v - u
    ee = np.einsum("...k,...k->...", e, e)
    s = np.where(ee > 0, np.einsum("...k,...k->...", p - u, e) / np.where(ee > 0, ee, 1), 0)
    q = u + np.clip(s, 0, 1)[..., None] * e
    return np.linalg.norm(p - q, axis=-1)


def triangle_distance(p, a, b, c):
    """Point-to-triangle distance by projection (inside test with barycentric signs) and the three
    clamped edges, independent of the kernel's Voronoi regions."""
    n = np.cross(b - a, c - a)
    nn = np.einsum("...k,...k->...", n, n)
    d = np.minimum(np.minimum(segment_distance(p, a, b), segment_distance(p, b, c)), segment_distance(p, c, a))
    ok = nn > 1e-20
    t = np.einsum("...k,...k->...", a - p, n) / np.where(ok, nn, 1)
    proj = p + t[..., None] * n
    inside = np.broadcast_to(ok, t.shape).copy()
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("...k,...k->...", np.cross(v - u, proj - u), n) >= 0
    return np.where(inside, np.minimum(d, np.abs(t) * np.sqrt(np.where(ok, nn, 0))), d)


def test_closest_point_on_a_triangle_against_brute_force():
    rng = np.random.default_rng(0)
    n = 4000
    a, b, c = rng.normal(size=(3, n, 3))
    # degenerate ones: a repeated corner, collinear corners, a point triangle
    b[:200] = a[:200]
    c[200:400] = a[200:400] + 0.3 * (b[200:400] - a[200:400])
    b[400:500] = c[400:500] = a[400:500]
    p = rng.normal(size=(n, 3)) * 1.5
    got = np.array([kernels._triangle(*p[i], *a[i], *b[i], *c[i]) for i in range(n)])
    q, d2 = got[:, :3], got[:, 3]
    ref = triangle_distance(p, a, b, c)
    np.testing.assert_allclose(np.sqrt(d2), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(p - q, axis=1), ref, rtol=0, atol=1e-12)
    # the point found is on the triangle: its own distance to it is zero
    assert triangle_distance(q, a, b, c).max() < 1e-12


@pytest.fixture(scope="module")
def chair():
    s = synthetic.generate("chair", 1, seed=3)[0]
    v = geometry.canonical_frame(s.vertices).to_canonical(s.vertices)
    return v, np.asarray(s.faces)


def test_grid_equals_libigl_and_every_point_lies_on_its_face(chair):
    v, f = chair
    closest, face = kernels.grid_closest_points(v, f, 24)
    centres = geometry.grid_centres(24).reshape(-1, 3)
    d2, _, _ = igl.point_mesh_squared_distance(centres, v, f)
    got = np.linalg.norm(closest.reshape(-1, 3) - centres, axis=1)
    np.testing.assert_allclose(got, np.sqrt(d2), rtol=0, atol=1e-12)
    t = f[face.reshape(-1)]
    on_face = triangle_distance(closest.reshape(-1, 3), v[t[:, 0]], v[t[:, 1]], v[t[:, 2]])
    assert on_face.max() < 1e-12


def test_threads_do_not_change_the_result(chair):
    """Threads change where each search starts (the bound from the cell before); ties between
    equally near triangles, everywhere on a box's medial planes, still go to the same triangle."""
    import trimesh

    box = trimesh.creation.box((0.8, 0.4, 0.6))
    for v, f in (chair, (np.asarray(box.vertices), np.asarray(box.faces))):
        one = kernels.grid_closest_points(v, f, 20, threads=1)
        for threads in (2, 3):
            other = kernels.grid_closest_points(v, f, 20, threads=threads)
            assert np.array_equal(one[0], other[0]) and np.array_equal(one[1], other[1])


def test_a_soup_with_degenerate_and_repeated_faces():
    """Random intersecting triangles with zero-area faces and duplicated faces: equal to brute force
    over every triangle and to libigl. (Open3D's point query, the other engine, was 0.12 off on this
    soup: it is not the reference.)"""
    rng = np.random.default_rng(2)
    v = rng.uniform(-0.45, 0.45, size=(60, 3))
    f = rng.integers(0, 60, size=(80, 3))
    f[:10, 1] = f[:10, 0]  # repeated corner
    f = np.concatenate([f, f[10:20]])  # duplicated faces
    res = 12
    grid = geometry.distance_grid(v, f, res, exact_within=None)
    centres = geometry.grid_centres(res).reshape(-1, 3)
    a, b, c = (v[f[:, i]] for i in range(3))
    ref = triangle_distance(centres[:, None], a[None], b[None], c[None]).min(axis=1)
    np.testing.assert_allclose(grid.distance.ravel(), ref, rtol=0, atol=1e-6)
    d2, _, _ = igl.point_mesh_squared_distance(centres, v, f)
    closest, _ = kernels.grid_closest_points(v, f, res)
    np.testing.assert_allclose(np.linalg.norm(closest.reshape(-1, 3) - centres, axis=1), np.sqrt(d2), rtol=0, atol=1e-12)


def test_both_engines_agree_on_a_chair(chair):
    v, f = chair
    auto = geometry.distance_grid(v, f, 32, exact_within=None)
    o3d = geometry.distance_grid(v, f, 32, engine="open3d")
    np.testing.assert_allclose(auto.distance, o3d.distance, rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="engine"):
        geometry.distance_grid(v, f, 8, engine="embree")
    with pytest.raises(ValueError, match="faces"):
        geometry.distance_grid(v, np.zeros((0, 3), int), 8)


def _real_meshes():
    paths = sorted((DATA / "psb_seg_benchmark").glob("*/off/*.off"))[::20] + sorted((DATA / "coseg_chairs").rglob("*.off"))[:2]
    return paths


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data (PSB and COSEG meshes) is not here")
def test_real_meshes_equal_libigl_at_32():
    paths = _real_meshes()
    assert paths
    centres = geometry.grid_centres(32).reshape(-1, 3)
    for path in paths:
        m = io.read_mesh(path)
        v = geometry.canonical_frame(m.vertices).to_canonical(m.vertices)
        closest, _ = kernels.grid_closest_points(v, m.faces, 32, threads=2)
        d2, _, _ = igl.point_mesh_squared_distance(centres, v, m.faces)
        err = np.abs(np.linalg.norm(closest.reshape(-1, 3) - centres, axis=1) - np.sqrt(d2)).max()
        assert err < 1e-12, f"{path.name}: {err:.1e}"


def test_far_cells_do_not_depend_on_threads(chair):
    """The far cells come after the exact ones, on one thread in one order."""
    import trimesh

    box = trimesh.creation.box((0.8, 0.4, 0.6))
    for v, f in (chair, (np.asarray(box.vertices), np.asarray(box.faces))):
        surface = geometry.surface_voxels(v, f, 20)
        one = kernels.grid_closest_points(v, f, 20, threads=1, surface=surface, exact_within=2.0)
        other = kernels.grid_closest_points(v, f, 20, threads=2, surface=surface, exact_within=2.0)
        assert np.array_equal(one[0], other[0]) and np.array_equal(one[1], other[1])
        exact = kernels.grid_closest_points(v, f, 20)
        assert not np.array_equal(one[1], exact[1]) or len(f) == 12  # the chair's far cells took other faces


def test_winding_numbers_against_libigls_exact_sum():
    """With every node opened (beta huge) the sum of solid angles is exact: libigl's
    ``winding_number`` (no approximation) to 1e-10. With the default beta = 2, within 0.05 of it off
    the surface of a closed mesh, where it is 0 or 1."""
    import trimesh

    rng = np.random.default_rng(4)
    v = rng.uniform(-0.45, 0.45, size=(50, 3))
    f = rng.integers(0, 50, size=(70, 3))
    pts = rng.uniform(-0.6, 0.6, size=(500, 3))
    ref = igl.winding_number(v, f, pts)
    np.testing.assert_allclose(kernels.winding_numbers(v, f, pts, beta=1e9), ref, rtol=0, atol=1e-10)
    sphere = trimesh.creation.icosphere(4)
    v, f = np.asarray(sphere.vertices) * 0.4, np.asarray(sphere.faces)
    r = np.linalg.norm(pts, axis=1)
    away = np.abs(r - 0.4) > 0.02
    for threads in (1, 2):
        w = kernels.winding_numbers(v, f, pts[away], threads=threads)
        np.testing.assert_allclose(w, (r[away] < 0.4).astype(float), rtol=0, atol=0.05)
    np.testing.assert_allclose(kernels.winding_numbers(v, f, pts), igl.winding_number(v, f, pts), rtol=0, atol=0.1)


def _open_and_messy():
    """An open box (a face missing), an inside-out box inside a box, and a random soup: meshes whose
    winding number is not 0 or 1 everywhere off the surface."""
    import trimesh

    box = trimesh.creation.box((0.8, 0.8, 0.8))
    keep = box.face_normals[:, 0] < 0.5
    shapes = [(np.asarray(box.vertices), np.asarray(box.faces)[keep])]
    inner = np.asarray(box.vertices) * 0.5
    shapes.append((np.concatenate([box.vertices, inner]), np.concatenate([box.faces, box.faces[:, ::-1] + 8])))
    rng = np.random.default_rng(5)
    shapes.append((rng.uniform(-0.45, 0.45, size=(40, 3)), rng.integers(0, 40, size=(30, 3))))
    return shapes


def test_region_sampled_occupancy_equals_every_cell():
    """primkit's occupancy (winding numbers at the surface cells and a few cells per free region)
    against the exact winding number at every cell, on meshes that are not closed."""
    for v, f in _open_and_messy():
        for res in (16, 24):
            got = geometry.occupancy_grid(v, f, res)
            exact = np.abs(igl.winding_number(v, f, geometry.grid_centres(res).reshape(-1, 3))) > 0.5
            assert (got.ravel() != exact).sum() <= 2, (len(f), res, (got.ravel() != exact).sum())
            assert np.array_equal(got, geometry.occupancy_grid(v, f, res, engine="igl")) or len(f) == 30


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data (PSB and COSEG meshes) is not here")
def test_real_meshes_occupancy_and_far_cells():
    """On real meshes: the occupancy equals libigl's at every cell, and the far cells are within the
    declared 3e-3 of libigl's exact distances (never nearer)."""
    centres = geometry.grid_centres(32).reshape(-1, 3)
    for path in _real_meshes():
        m = io.read_mesh(path)
        v = geometry.canonical_frame(m.vertices).to_canonical(m.vertices)
        surface = geometry.surface_voxels(v, m.faces, 32)
        assert np.array_equal(geometry.occupancy_grid(v, m.faces, 32, surface=surface),
                              geometry.occupancy_grid(v, m.faces, 32, engine="igl")), path.name
        grid = geometry.distance_grid(v, m.faces, 32, surface=surface)
        d2, _, _ = igl.point_mesh_squared_distance(centres, v, m.faces)
        err = grid.distance.ravel().astype(float) - np.sqrt(d2)
        assert -1e-6 < err.min() and err.max() < 3e-3, f"{path.name}: {err.min():.1e} {err.max():.1e}"


def test_the_kept_tree_follows_the_mesh_not_the_array():
    """The tree kept between the occupancy and the distances is recognised by the mesh's values: a
    vertex array changed in place gets a new one."""
    import trimesh

    sphere = trimesh.creation.icosphere(3)
    v, f = np.asarray(sphere.vertices) * 0.4, np.asarray(sphere.faces)
    first = kernels.grid_closest_points(v, f, 12)[0]
    assert kernels.tree_of(v, f) is kernels.tree_of(v.copy(), f.copy())
    v *= 0.5
    np.testing.assert_allclose(np.linalg.norm(kernels.grid_closest_points(v, f, 12)[0], axis=-1), 0.2, atol=2e-3)
    assert not np.allclose(first, kernels.grid_closest_points(v, f, 12)[0])


def test_edge_neighbours_of_a_closed_mesh():
    """Each triangle of a closed manifold mesh has three, across its own edges, and is theirs."""
    import trimesh

    f = np.asarray(trimesh.creation.icosphere(2).faces)
    adjacent = kernels._edge_neighbours(f)
    assert (adjacent >= 0).all()
    for t in range(len(f)):
        for e in range(3):
            u = adjacent[t, e]
            assert {f[t, e], f[t, (e + 1) % 3]} <= set(f[u]) and t in adjacent[u]


# ------------------------------------------------------------------ surface cells


def _clip_meets(tri, lo, hi):
    """Whether a triangle meets the box [lo, hi]: Sutherland-Hodgman clipping of the triangle by
    the box's six half-spaces leaves something (an algorithm independent of the kernel's axes)."""
    poly = [np.asarray(p, float) for p in tri]
    for axis in range(3):
        for sign, bound in ((1.0, hi[axis]), (-1.0, lo[axis])):
            out = []
            for i, p in enumerate(poly):
                q = poly[(i + 1) % len(poly)]
                dp, dq = sign * (p[axis] - bound), sign * (q[axis] - bound)
                if dp <= 0:
                    out.append(p)
                if (dp < 0 < dq) or (dq < 0 < dp):
                    out.append(p + (q - p) * (dp / (dp - dq)))
            poly = out
            if not poly:
                return False
    return True


def test_surface_cells_against_clipping_every_cell():
    rng = np.random.default_rng(5)
    res = 6
    for _ in range(25):
        corners = rng.uniform(-0.5, 0.5, (3, 3))
        if rng.random() < 0.4:  # small ones, within a cell or two
            corners = corners[0] + 0.15 * (corners - corners[0])
        got = kernels.surface_cells(corners, np.array([[0, 1, 2]]), res)
        for idx in np.ndindex(res, res, res):
            lo = -0.5 + np.array(idx) / res
            assert got[idx] == _clip_meets(corners, lo, lo + 1.0 / res), (corners, idx)


def _lattice_soups():
    """Random soups, some snapped onto the lattice of half cells so that triangles lie on cell
    faces and touch cells at edges and corners, and the boundary meshes of voxelised chairs."""
    rng = np.random.default_rng(0)
    for trial in range(60):
        v = rng.uniform(-0.5, 0.5, (30, 3))
        if trial % 2:
            v = np.round(v * 16) / 16
        yield v, rng.integers(0, 30, (40, 3)), 32
    for s in synthetic.generate("chair", 3, seed=11):
        v = geometry.canonical_frame(s.vertices).to_canonical(s.vertices)
        occupancy = geometry.occupancy_grid(v, s.faces, 32, include_surface=True)
        bv, bf = geometry.voxel_boundary_mesh(occupancy)
        for res in (32, 24, 16):
            yield bv, bf, res
        yield v, s.faces, 32


def test_surface_cells_equal_open3d_touching_cases_included():
    for v, f, res in _lattice_soups():
        ours = geometry.surface_voxels(v, f, res)
        theirs = geometry.surface_voxels(v, f, res, engine="open3d")
        assert np.array_equal(ours, theirs), f"{(ours != theirs).sum()} cells differ at {res}"


def test_surface_cells_edge_cases():
    assert not geometry.surface_voxels(np.zeros((0, 3)), np.zeros((0, 3), int), 8).any()
    # a triangle wholly outside the grid marks nothing; one on the grid's upper face marks the last cells
    outside = np.array([[0.7, 0.7, 0.7], [0.9, 0.7, 0.7], [0.7, 0.9, 0.7]])
    assert not kernels.surface_cells(outside, np.array([[0, 1, 2]]), 8).any()
    top = np.array([[-0.5, 0.5, -0.5], [0.5, 0.5, -0.5], [-0.5, 0.5, 0.5]])
    got = kernels.surface_cells(top, np.array([[0, 1, 2]]), 8)
    assert got[:, 7].any() and not got[:, :7].any()
    with pytest.raises(ValueError, match="engine"):
        geometry.surface_voxels(top, np.array([[0, 1, 2]]), 8, engine="embree")


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data (PSB and COSEG meshes) is not here")
def test_real_meshes_surface_cells_equal_open3d():
    paths = sorted((DATA / "psb_seg_benchmark").glob("*/off/*.off"))[::4] + sorted((DATA / "coseg_chairs").rglob("*.off"))
    for path in paths:
        m = io.read_mesh(path)
        v = geometry.canonical_frame(m.vertices).to_canonical(m.vertices)
        assert np.array_equal(geometry.surface_voxels(v, m.faces, 32), geometry.surface_voxels(v, m.faces, 32, engine="open3d")), path.name

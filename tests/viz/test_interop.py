"""Open3D and pyvista conversions: round trips, edge counts and lengths, colours by part."""

import numpy as np
import pytest

from primkit.viz import interop
from primkit.viz.palette import part_colors
from primkit.primitives import Cuboids, matrix_to_quaternion


def _cuboids():
    rng = np.random.default_rng(3)
    m = 5
    rot = np.linalg.qr(rng.normal(size=(m, 3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))[:, None, None]
    return Cuboids(rng.uniform(0.05, 0.3, (m, 3)), matrix_to_quaternion(rot), rng.normal(size=(m, 3)),
                   np.array([1, 0, 1, 1, 0], bool))


def test_edges_are_the_twelve_cuboid_edges():
    c = _cuboids()
    points, lines, part = interop.cuboid_edges(c)
    assert lines.shape == (12 * 3, 2) and points.shape == (8 * 3, 3)
    assert part.tolist() == np.repeat(c.present, 12).tolist()
    length = np.linalg.norm(points[lines[:, 0]] - points[lines[:, 1]], axis=1)
    for k, idx in enumerate(c.present):
        # each cuboid: 4 edges of each full extent 2 z_i (independent of how the corners are numbered)
        expected = np.sort(np.repeat(2 * c.half_extents[idx], 4))
        assert np.allclose(np.sort(length[12 * k:12 * (k + 1)]), expected)


def test_lineset_and_mesh_colours_follow_part_index():
    c = _cuboids()
    ls = interop.cuboids_to_lineset(c)
    colors = interop.colors_to_uint8(np.asarray(ls.colors))
    assert np.array_equal(colors, part_colors(c.count)[np.repeat(c.present, 12)])
    mesh = interop.cuboids_to_o3d(c)
    back = interop.mesh_from_o3d(mesh)
    v, f, part = c.to_mesh()
    assert np.allclose(back.vertices, v) and np.array_equal(back.faces, f)
    assert np.array_equal(back.face_colors, part_colors(c.count)[part])


def test_mesh_round_trip_with_face_colours_keeps_geometry_and_colours(chairs):
    s = chairs[0]
    fc = part_colors(10)[s.face_labels % 10]
    m = interop.mesh_to_o3d(s.vertices, s.faces, face_colors=fc)
    back = interop.mesh_from_o3d(m)
    # unshared: every face owns its corners, at the original positions
    assert len(back.vertices) == 3 * len(s.faces)
    assert np.allclose(back.vertices[back.faces], s.vertices[s.faces])
    assert np.array_equal(back.face_colors, fc)
    plain = interop.mesh_from_o3d(interop.mesh_to_o3d(s.vertices, s.faces))
    assert np.allclose(plain.vertices, s.vertices) and np.array_equal(plain.faces, s.faces)
    assert plain.vertex_colors is None


def test_points_round_trip():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(100, 3))
    c = rng.integers(0, 256, (100, 3)).astype(np.uint8)
    back, back_c = interop.points_from_o3d(interop.points_to_o3d(p, c))
    assert np.allclose(back, p) and np.array_equal(back_c, c)
    assert interop.points_from_o3d(interop.points_to_o3d(p))[1] is None


def test_bad_input_is_refused_with_the_expected_shape():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        interop.points_to_o3d(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="uint8"):
        interop.mesh_to_o3d(np.zeros((3, 3)), [[0, 1, 2]], face_colors=np.zeros((1, 3)))
    with pytest.raises(ValueError, match="index vertices"):
        interop.mesh_to_o3d(np.zeros((3, 3)), [[0, 1, 3]])


def test_to_pyvista_carries_part_index_and_areas():
    import pyvista as pv

    c = _cuboids()
    poly = interop.to_pyvista(c)
    assert pv.wrap(poly) is poly
    assert poly.n_cells == 12 * len(c.present)
    assert np.array_equal(poly.cell_data["part"], np.repeat(c.present, 12))
    # surface area of each cuboid against the closed form 8 (xy + yz + zx)
    z = c.half_extents[c.present]
    area = 8 * (z[:, 0] * z[:, 1] + z[:, 1] * z[:, 2] + z[:, 2] * z[:, 0])
    assert np.isclose(poly.compute_cell_sizes().cell_data["Area"].sum(), area.sum())
    edges = interop.to_pyvista(c, edges=True)
    assert edges.n_cells == 12 * len(c.present) and np.array_equal(edges.cell_data["part"], np.repeat(c.present, 12))


def test_pyvista_and_open3d_meshes_agree(chairs):
    s = chairs[1]
    v, f = interop.from_pyvista(interop.to_pyvista((s.vertices, s.faces)))
    assert np.allclose(v, s.vertices) and np.array_equal(f, s.faces)
    poly = interop.to_pyvista(interop.mesh_to_o3d(s.vertices, s.faces))
    assert np.allclose(poly.points, s.vertices)
    pc = interop.to_pyvista(interop.points_to_o3d(s.vertices[:50], np.full((50, 3), 7, np.uint8)))
    assert pc.n_points == 50 and np.all(pc.point_data["rgb"] == 7)
    ls = interop.to_pyvista(interop.cuboids_to_lineset(_cuboids()))
    assert ls.n_lines == 36


def test_draw_writes_a_picture_off_screen(tmp_path):
    from PIL import Image

    png = tmp_path / "o3d.png"
    try:
        interop.draw(_cuboids(), png=png, window_size=(160, 120))
    except RuntimeError as exc:  # no EGL/GL at all on this machine
        pytest.skip(str(exc))
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape == (120, 160, 3)
    # some pixels carry part colours (not all background)
    assert (np.abs(img.astype(int) - img[0, 0].astype(int)).sum(-1) > 30).mean() > 0.01


def test_tensor_geometry_carries_part_through_open3d_operations(chairs):
    """Open3D's tensor API keeps named per-face and per-point attributes through its own selections:
    the part of each kept face is the part it had."""
    import open3d as o3d

    s = chairs[0]
    labels = s.face_labels.astype(np.int64)
    mesh = interop.mesh_to_o3d_tensor(s.vertices, s.faces, triangle_attributes={"part": labels})
    assert mesh.triangle["part"].numpy().dtype == np.int32
    keep = labels == labels[0]
    kept = mesh.select_faces_by_mask(o3d.core.Tensor(keep))
    assert np.array_equal(kept.triangle["part"].numpy(), labels[keep])
    # the kept faces are the same triangles (select_faces_by_mask drops unused vertices and renumbers)
    corners = kept.vertex.positions.numpy()[kept.triangle.indices.numpy()]
    assert np.allclose(corners, s.vertices[s.faces[keep]], atol=1e-6)
    back = interop.mesh_from_o3d(mesh)
    assert np.allclose(back.vertices, s.vertices, atol=1e-6) and np.array_equal(back.faces, s.faces)

    rng = np.random.default_rng(1)
    points, part = rng.normal(size=(50, 3)), rng.integers(0, 5, 50)
    pcd = interop.points_to_o3d_tensor(points, attributes={"part": part})
    mask = part % 2 == 0
    assert np.array_equal(pcd.select_by_mask(o3d.core.Tensor(mask)).point["part"].numpy(), part[mask])
    assert np.allclose(interop.points_from_o3d(pcd)[0], points, atol=1e-6)
    with pytest.raises(ValueError, match="one row per triangle"):
        interop.mesh_to_o3d_tensor(s.vertices, s.faces, triangle_attributes={"part": labels[:-1]})


def test_tensor_cuboids_have_parts_colours_and_twelve_edges():
    c = _cuboids()
    mesh = interop.cuboids_to_o3d_tensor(c)
    v, f, part = c.to_mesh()
    assert np.array_equal(mesh.triangle["part"].numpy(), part)
    assert np.allclose(mesh.vertex.positions.numpy(), v, atol=1e-6)
    colours = interop.colors_to_uint8(mesh.vertex["colors"].numpy())
    assert np.array_equal(colours, part_colors(c.count)[np.repeat(c.present, 8)])
    lines = interop.cuboids_to_o3d_tensor_lineset(c)
    assert lines.line.indices.numpy().shape == (12 * len(c.present), 2)
    assert np.array_equal(lines.line["part"].numpy(), np.repeat(c.present, 12))
    poly = interop.to_pyvista(lines)  # and on to pyvista, part and colour kept
    assert poly.n_cells == 12 * len(c.present) and np.array_equal(poly.cell_data["part"], np.repeat(c.present, 12))


def test_pyvista_blocks_one_per_part_with_index_and_name():
    c = _cuboids()
    names = [f"name{k}" for k in range(c.count)]
    blocks = interop.to_pyvista_blocks(c, names)
    assert blocks.keys() == [f"{k} name{k}" for k in c.present]
    for k, block in zip(c.present, blocks):
        assert block.field_data["part"].tolist() == [k] and block.field_data["part_name"].tolist() == [f"name{k}"]
        assert block.n_cells == 12 and set(block.cell_data["part"]) == {k}
        assert np.allclose(block.volume, c.volumes[k])
    edges = interop.to_pyvista_blocks(c, names, edges=True)
    assert all(b.n_cells == 12 and b.n_lines == 12 for b in edges)

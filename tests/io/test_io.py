"""Tests for primkit.io: round trips, rejections, binvox decoding, atomic writes, shared data."""

import pickle
from pathlib import Path

import numpy as np
import pytest
import trimesh

from primkit.io import LABEL_SUFFIXES, MESH_SUFFIXES, POINT_SUFFIXES, VOXEL_SUFFIXES, Mesh, PointCloud, ShapeFileError, VoxelGrid, atomic_output, is_shape_file, read_labels, read_mesh, read_points, read_shape, read_voxels, refuse_existing, write_labels, write_mesh, write_points
from primkit import io

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"


def tetrahedron():
    """A tetrahedron with float64 coordinates that need all 17 digits, faces in no tidy order."""
    rng = np.random.default_rng(0)
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    vertices = vertices + rng.uniform(-0.1, 0.1, size=(4, 3))
    faces = np.array([[1, 2, 3], [0, 2, 1], [0, 3, 2], [0, 1, 3]], np.int64)
    return vertices, faces


COLORS = np.array(
    [[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 128], [255, 0, 0, 255]], np.uint8
)


def triangles(vertices, faces):
    """(f, 9) corner coordinates, rows sorted, for comparing meshes whose numbering differs."""
    corners = np.asarray(vertices)[np.asarray(faces)].reshape(-1, 9)
    return corners[np.lexsort(corners.T[::-1])]


# ------------------------------------------------------------------------------ value types


def test_mesh_helpers_against_heron():
    vertices, faces = tetrahedron()
    mesh = Mesh(vertices, faces)
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64
    expected = []
    for face in faces:
        corners = vertices[face]
        a, b, c = (np.linalg.norm(corners[i] - corners[(i + 1) % 3]) for i in range(3))
        s = (a + b + c) / 2
        expected.append(np.sqrt(s * (s - a) * (s - b) * (s - c)))
    assert np.allclose(mesh.face_areas(), expected)
    assert np.isclose(mesh.area(), sum(expected))
    bounds = mesh.bounds()
    assert bounds.shape == (2, 3)
    assert np.array_equal(bounds[0], [min(v[i] for v in vertices) for i in range(3)])
    assert np.array_equal(bounds[1], [max(v[i] for v in vertices) for i in range(3)])


def test_value_types_check_shapes():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        Mesh(np.zeros((4, 2)), np.zeros((1, 3), int))
    with pytest.raises(ValueError, match=r"\(f, 3\)"):
        Mesh(np.zeros((4, 3)), np.zeros((1, 4), int))
    with pytest.raises(ValueError, match="int"):
        Mesh(np.zeros((4, 3)), np.zeros((1, 3), float))
    with pytest.raises(ValueError, match="normals"):
        PointCloud(np.zeros((4, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"\(R, R, R\)"):
        VoxelGrid(np.zeros((2, 3, 2), bool), np.zeros(3), 1.0)


def test_voxel_centres_formula():
    grid = VoxelGrid(np.ones((4, 4, 4), bool), [-1.0, 2.0, 0.5], 2.0)
    centres = grid.voxel_centres()
    assert centres.shape == (4, 4, 4, 3)
    # voxel (1, 2, 3): translate + (idx + 0.5) / 4 * 2
    assert np.allclose(centres[1, 2, 3], [-1 + 0.75, 2 + 1.25, 0.5 + 1.75])
    assert np.allclose(centres[0, 0, 0], [-0.75, 2.25, 0.75])


def test_shape_file_error_is_one_line_and_pickles():
    err = ShapeFileError("a/b.off", "cannot parse\nas OFF")
    assert str(err) == "a/b.off: cannot parse as OFF"
    assert err.path == "a/b.off" and err.reason == "cannot parse as OFF"
    assert isinstance(err, ValueError)
    again = pickle.loads(pickle.dumps(err))
    assert str(again) == str(err) and again.reason == err.reason


def test_is_shape_file():
    assert is_shape_file("x/chair.OFF") and is_shape_file("a.glb") and is_shape_file("m.binvox")
    assert is_shape_file("p.npy") and is_shape_file(Path("p.xyz"))
    for name in ("labels.seg", "notes.txt", "off", "a.mtl"):
        assert not is_shape_file(name)
    assert ".ply" in MESH_SUFFIXES and ".ply" in POINT_SUFFIXES
    assert VOXEL_SUFFIXES == (".binvox",) and LABEL_SUFFIXES == (".seg",)


# ------------------------------------------------------------------------------ mesh round trips


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".off", ".glb", ".stl"])
def test_mesh_round_trip(tmp_path, suffix):
    vertices, faces = tetrahedron()
    path = write_mesh(tmp_path / f"t{suffix}", vertices, faces)
    assert path == tmp_path / f"t{suffix}"
    mesh = read_mesh(path)
    if suffix in (".obj", ".off"):  # text with 17 significant digits: exact
        assert np.array_equal(mesh.vertices, vertices)
        assert np.array_equal(mesh.faces, faces)
    elif suffix in (".ply", ".glb"):  # float32 on disk
        assert np.allclose(mesh.vertices, vertices, rtol=1e-6, atol=1e-7)
        assert np.array_equal(mesh.faces, faces)
    else:  # STL: corners merged again, numbering by first use, face order kept
        assert len(mesh.vertices) == 4
        assert np.allclose(mesh.vertices[mesh.faces], vertices[faces], atol=1e-7)
    assert np.isclose(mesh.area(), Mesh(vertices, faces).area(), rtol=1e-6)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb"])
def test_mesh_round_trip_with_colours_keeps_faces(tmp_path, suffix):
    vertices, faces = tetrahedron()
    mesh = read_mesh(write_mesh(tmp_path / f"c{suffix}", vertices, faces, COLORS))
    assert np.allclose(mesh.vertices[mesh.faces], vertices[faces], atol=1e-7)
    if suffix != ".glb":
        assert np.array_equal(mesh.faces, faces)


def test_off_faces_come_back_in_file_order(tmp_path):
    order = [[3, 1, 0], [0, 1, 2], [2, 3, 0], [1, 3, 2], [0, 2, 1]]
    lines = ["OFF", "# a comment", "4 5 0", "0 0 0", "1 0 0", "0 1 0", "0 0 1"]
    lines += [f"3 {a} {b} {c}" for a, b, c in order]
    path = tmp_path / "order.off"
    path.write_text("\n".join(lines) + "\n")
    mesh = read_mesh(path)
    assert mesh.faces.tolist() == order
    assert np.array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])


def test_off_file_is_plain_text_we_can_parse(tmp_path):
    vertices, faces = tetrahedron()
    text = write_mesh(tmp_path / "t.off", vertices, faces).read_text().split("\n")
    assert text[0] == "OFF" and text[1].split()[:2] == ["4", "4"]
    assert np.array_equal([[float(x) for x in line.split()] for line in text[2:6]], vertices)
    face_rows = [[int(x) for x in line.split()] for line in text[6:10]]
    assert face_rows == [[3, *f] for f in faces.tolist()]


def test_ply_face_colours_read_back_by_trimesh(tmp_path):
    vertices, faces = tetrahedron()
    floats = COLORS[:, :3] / 255.0
    path = write_mesh(tmp_path / "c.ply", vertices, faces, floats)
    loaded = trimesh.load(path, process=False)
    assert np.array_equal(loaded.faces, faces)
    expected = np.column_stack([COLORS[:, :3], np.full(4, 255)])
    assert np.array_equal(loaded.visual.face_colors, expected)


@pytest.mark.parametrize("coloured", [False, True])
def test_ply_bytes_equal_trimesh_exporter(tmp_path, coloured):
    # primkit writes PLY with NumPy; trimesh's exporter is the reference layout, byte for byte
    rng = np.random.default_rng(3)
    vertices, faces = rng.normal(size=(40, 3)), rng.integers(0, 40, (70, 3))
    colors = rng.integers(0, 256, (70, 4)).astype(np.uint8) if coloured else None
    ours = write_mesh(tmp_path / "r.ply", vertices, faces, colors).read_bytes()
    theirs = trimesh.Trimesh(vertices, faces, face_colors=colors, process=False).export(file_type="ply")
    assert ours.split(b"\n", 3)[3] == theirs.split(b"\n", 3)[3]  # after the comment line


def test_glb_face_colours_read_back_by_trimesh(tmp_path):
    vertices, faces = tetrahedron()
    path = write_mesh(tmp_path / "c.glb", vertices, faces, COLORS)
    scene = trimesh.load(path, process=False)
    (geometry,) = scene.geometry.values()
    corner_colors = geometry.visual.vertex_colors[geometry.faces]  # (f, 3, 4)
    for face, want in zip(range(len(faces)), COLORS):
        assert (corner_colors[face] == want).all()
    assert np.allclose(geometry.vertices[geometry.faces], vertices[faces], atol=1e-7)


def test_obj_face_colours_through_materials(tmp_path):
    vertices, faces = tetrahedron()
    path = write_mesh(tmp_path / "c.obj", vertices, faces, COLORS)
    mtl = tmp_path / "c.mtl"
    assert mtl.exists()
    # independent reading: material -> Kd/d from the .mtl, then usemtl state per face line
    palette, name = {}, None
    for line in mtl.read_text().splitlines():
        words = line.split()
        if words and words[0] == "newmtl":
            name = words[1]
            palette[name] = [0, 0, 0, 255]
        elif words and words[0] == "Kd":
            palette[name][:3] = [round(float(x) * 255) for x in words[1:4]]
        elif words and words[0] == "d":
            palette[name][3] = round(float(words[1]) * 255)
    got, current = [], None
    for line in path.read_text().splitlines():
        words = line.split()
        if words and words[0] == "mtllib":
            assert words[1] == "c.mtl"
        elif words and words[0] == "usemtl":
            current = words[1]
        elif words and words[0] == "f":
            got.append(palette[current])
    assert np.array_equal(got, COLORS)
    # and trimesh sees the same set of colours (it ignores the `d` opacity)
    scene = trimesh.load(path)
    seen = {tuple(g.visual.material.main_color[:3].tolist()) for g in scene.geometry.values()}
    assert seen == {tuple(c[:3]) for c in COLORS.tolist()}


def test_write_mesh_rejects_bad_input(tmp_path):
    vertices, faces = tetrahedron()
    with pytest.raises(ValueError, match="cannot write a mesh"):
        write_mesh(tmp_path / "t.vtk", vertices, faces)
    with pytest.raises(ValueError, match="face colours"):
        write_mesh(tmp_path / "t.off", vertices, faces, COLORS)
    with pytest.raises(ValueError, match="face_colors"):
        write_mesh(tmp_path / "t.ply", vertices, faces, COLORS[:3])
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        write_mesh(tmp_path / "t.ply", vertices, faces, COLORS / 100.0)
    with pytest.raises(ValueError, match="index"):
        write_mesh(tmp_path / "t.ply", vertices, faces + 1)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ scenes, polygons


def scene_with_two_nodes():
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    move = trimesh.transformations.translation_matrix([3.0, 0.0, -1.0])
    turn = trimesh.transformations.rotation_matrix(0.7, [0, 0, 1], point=[0, 1, 0])
    turn[:3, 3] += [0.0, 0.0, 2.0]
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="box", transform=move)
    scene.add_geometry(ball, node_name="ball", transform=turn)
    expected = []
    for mesh, matrix in ((box, move), (ball, turn)):
        moved = np.c_[mesh.vertices, np.ones(len(mesh.vertices))] @ matrix.T
        expected.append(moved[:, :3][mesh.faces].reshape(-1, 9))
    return scene, np.concatenate(expected)


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_scene_nodes_concatenated_with_transforms(tmp_path, suffix):
    scene, expected = scene_with_two_nodes()
    path = tmp_path / f"scene{suffix}"
    scene.export(path)
    mesh = read_mesh(path)
    assert len(mesh.faces) == len(expected) == 12 + 80
    got = triangles(mesh.vertices, mesh.faces)
    want = expected[np.lexsort(expected.T[::-1])]
    assert np.allclose(got, want, atol=1e-6)


def test_quad_obj_is_triangulated(tmp_path):
    path = tmp_path / "quads.obj"
    path.write_text(
        "o two_squares\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "v 0 0 2\nv 2 0 2\nv 2 2 2\nv 0 2 2\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3 4/4\n"
        "f 5 6 7 8\n"
    )
    mesh = read_mesh(path)
    assert mesh.faces.shape == (4, 3)
    assert len(mesh.vertices) == 8
    assert np.isclose(mesh.area(), 1.0 + 4.0)
    first, second = set(range(4)), set(range(4, 8))
    owners = [
        first if set(f) <= first else second if set(f) <= second else None
        for f in mesh.faces.tolist()
    ]
    assert owners.count(first) == 2 and owners.count(second) == 2
    assert np.all(mesh.face_areas() > 0)


def test_polygon_mesh_labels_are_rejected_by_count(tmp_path):
    # one quad and one triangle in the file: two labels, three triangles after reading
    off = tmp_path / "poly.off"
    off.write_text("OFF\n5 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n4 0 1 2 3\n3 0 1 4\n")
    seg = write_labels(tmp_path / "poly.seg", [1, 2])
    mesh = read_mesh(off)
    assert len(mesh.faces) == 3
    with pytest.raises(ShapeFileError, match="2 labels but the mesh has 3 faces"):
        read_labels(seg, face_count=len(mesh.faces))


def test_obj_with_materials_keeps_file_order(tmp_path):
    path = tmp_path / "m.obj"
    path.write_text(
        "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
        "usemtl a\nf 1 2 3\nusemtl b\nf 1 2 4\nusemtl a\nf 1 4 3\ng other\nf -3 -2 -1\n"
    )
    mesh = read_mesh(path)
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


def test_degenerate_faces_are_kept(tmp_path):
    path = tmp_path / "d.off"
    path.write_text("OFF\n4 3 0\n0 0 0\n1 0 0\n0 1 0\n2 0 0\n3 0 1 2\n3 0 1 3\n3 1 1 2\n")
    mesh = read_mesh(path)
    assert len(mesh.faces) == 3
    assert np.allclose(mesh.face_areas(), [0.5, 0.0, 0.0])


# ------------------------------------------------------------------------------ rejections


def _write(path, content):
    if isinstance(content, str):
        path.write_text(content)
    else:
        path.write_bytes(content)
    return path


GARBAGE = bytes(range(256)) * 3

ASCII_PLY = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 0 0\n0 1 0\n3 0 1 {last}\n"
)

REJECTED_MESHES = {
    "missing": ("gone.off", None, "no such file"),
    "empty": ("empty.off", "", "empty file"),
    "blank": ("blank.obj", "\n  \n", "empty file"),
    "garbage off": ("g.off", GARBAGE, "cannot parse as OFF"),
    "garbage ply": ("g.ply", GARBAGE, "cannot parse as PLY"),
    "garbage stl": ("g.stl", GARBAGE, "cannot parse as STL"),
    "garbage glb": ("g.glb", GARBAGE, "cannot parse as GLB"),
    "garbage obj": ("g.obj", GARBAGE, "cannot parse as OBJ"),
    "nan vertex": ("nan.off", "OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n", "NaN or inf"),
    "inf vertex": ("inf.obj", "v 0 0 0\nv 1 inf 0\nv 0 1 0\nf 1 2 3\n", "NaN or inf"),
    "index off": ("oor.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n", "range"),
    "index obj": ("oor.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "out of range"),
    "index ply": ("oor.ply", ASCII_PLY.format(last=9), "out of range"),
    "zero area": ("flat.off", "OFF\n3 2 0\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n3 2 1 0\n", "zero total area"),
    "points only": ("p.ply", ASCII_PLY.replace("element face 1", "element face 0").format(last=2)
                    .replace("3 0 1 2\n", ""), "no faces"),
    "points obj": ("p.obj", "v 0 0 0\nv 1 0 0\n", "no faces"),
    "suffix": ("shape.vtk", "anything", "unsupported suffix '.vtk'"),
    "directory": ("folder.off", "DIR", "is a directory"),
}


@pytest.mark.parametrize("case", list(REJECTED_MESHES))
def test_read_mesh_rejections(tmp_path, case):
    name, content, reason = REJECTED_MESHES[case]
    path = tmp_path / name
    if content == "DIR":
        path.mkdir()
    elif content is not None:
        _write(path, content)
    before = path.read_bytes() if path.is_file() else None
    with pytest.raises(ShapeFileError) as info:
        read_mesh(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ") and "\n" not in text
    assert reason in info.value.reason, text
    assert info.value.path == path
    if before is not None:
        assert path.read_bytes() == before  # inputs are never modified


def test_read_points_and_shape_rejections(tmp_path):
    cases = [
        (read_points, "bad.npy", b"not numpy", "cannot parse as NPY"),
        (read_points, "bad.xyz", "1 2 3\n4 5\n", "cannot parse as XYZ"),
        (read_points, "four.xyz", "1 2 3 4\n", "(n, 3) or (n, 6)"),
        (read_points, "nan.xyz", "1 2 3\nnan 0 0\n", "NaN or inf"),
        (read_points, "mesh.ply", ASCII_PLY.format(last=2), "read_mesh"),
        (read_points, "cloud.obj", "v 0 0 0\n", "unsupported suffix"),
        (read_shape, "x.txt", "1 2 3\n", "unsupported suffix"),
        (read_voxels, "bad.binvox", b"#binvox 1\ndim 2 2 2\ndata\n\x01\x07", "sum to 7"),
        (read_voxels, "empty.binvox", b"#binvox 1\ndim 2 2 2\ndata\n\x00\x08", "no occupied voxels"),
        (read_voxels, "full.binvox", b"#binvox 1\ndim 2 2 2\ndata\n\x01\x08", "every voxel is occupied"),
        (read_voxels, "nohead.binvox", b"dim 2 2 2\n\x00\x08", "cannot parse as BINVOX"),
        (read_labels, "float.seg", "1\n2.5\n", "cannot parse as SEG"),
        (read_labels, "two.seg", "1 2\n3 4\n", "one integer per line"),
    ]
    np.save(tmp_path / "wide.npy", np.zeros((4, 5)))
    cases.append((read_points, "wide.npy", None, "(n, 3) or (n, 6)"))
    for reader, name, content, reason in cases:
        path = tmp_path / name
        if content is not None:
            _write(path, content)
        with pytest.raises(ShapeFileError) as info:
            reader(path)
        assert str(info.value).startswith(f"{path}: "), str(info.value)
        assert reason in info.value.reason and "\n" not in str(info.value), str(info.value)


def test_label_count_mismatch(tmp_path):
    path = write_labels(tmp_path / "l.seg", [1, 1, 2])
    assert read_labels(path, face_count=3).tolist() == [1, 1, 2]
    with pytest.raises(ShapeFileError) as info:
        read_labels(path, face_count=4)
    assert str(info.value) == f"{path}: 3 labels but the mesh has 4 faces"


# ------------------------------------------------------------------------------ points, labels


@pytest.mark.parametrize("suffix", [".ply", ".xyz", ".npy"])
@pytest.mark.parametrize("with_normals", [False, True])
def test_points_round_trip(tmp_path, suffix, with_normals):
    rng = np.random.default_rng(1)
    points = rng.normal(size=(50, 3))
    normals = rng.normal(size=(50, 3)) if with_normals else None
    path = write_points(tmp_path / f"p{suffix}", points, normals=normals)
    cloud = read_points(path)
    assert np.array_equal(cloud.points, points)
    if with_normals:
        assert np.array_equal(cloud.normals, normals)
    else:
        assert cloud.normals is None
    if suffix == ".ply":
        assert isinstance(read_shape(path), PointCloud)
        assert np.allclose(trimesh.load(path).vertices, points)  # readable by others too


def test_read_shape_dispatch(tmp_path):
    vertices, faces = tetrahedron()
    assert isinstance(read_shape(write_mesh(tmp_path / "m.ply", vertices, faces)), Mesh)
    assert isinstance(read_shape(write_mesh(tmp_path / "m.off", vertices, faces)), Mesh)
    assert isinstance(read_shape(write_points(tmp_path / "p.npy", vertices)), PointCloud)
    binvox = _write(tmp_path / "v.binvox", encode_binvox(np.eye(2, dtype=bool)[:, :, None].repeat(2, axis=2), (0, 0, 0), 1.0))
    assert isinstance(read_shape(binvox), VoxelGrid)


def test_xyz_text_with_comments_and_six_columns(tmp_path):
    path = _write(tmp_path / "n.xyz", "# x y z nx ny nz\n0 0 0 0 0 1\n1 2 3 1 0 0\n")
    cloud = read_points(path)
    assert cloud.points.tolist() == [[0, 0, 0], [1, 2, 3]]
    assert cloud.normals.tolist() == [[0, 0, 1], [1, 0, 0]]


def test_labels_round_trip(tmp_path):
    labels = np.array([3, 0, -1, 12, 3], np.int64)
    path = write_labels(tmp_path / "l.seg", labels)
    assert path.read_text() == "3\n0\n-1\n12\n3\n"
    got = read_labels(path)
    assert got.dtype == np.int64 and np.array_equal(got, labels)
    with pytest.raises(ValueError, match=r"\(f,\) int"):
        write_labels(tmp_path / "x.seg", [0.5, 1.0])
    with pytest.raises(ValueError, match=".seg"):
        write_labels(tmp_path / "x.txt", [1])


# ------------------------------------------------------------------------------ binvox


def encode_binvox(occupancy, translate, scale):
    """binvox bytes written by hand: visit x, then z, then y (fastest); runs of at most 255."""
    r = occupancy.shape[0]
    flat = []
    for x in range(r):
        for z in range(r):
            for y in range(r):
                flat.append(1 if occupancy[x, y, z] else 0)
    runs = bytearray()
    value, count = flat[0], 0
    for v in flat:
        if v == value and count < 255:
            count += 1
        else:
            runs += bytes([value, count])
            value, count = v, 1
    runs += bytes([value, count])
    tx, ty, tz = translate
    header = f"#binvox 1\ndim {r} {r} {r}\ntranslate {tx} {ty} {tz}\nscale {scale}\ndata\n"
    return header.encode("ascii") + bytes(runs)


def test_binvox_decodes_to_xyz(tmp_path):
    r = 8  # 512 voxels, so the empty stretches need runs split at 255
    occupancy = np.zeros((r, r, r), bool)
    occupancy[1, 0:6, 2] = True  # a column along +y
    occupancy[1:7, 0, 5] = True  # a bar along x
    occupancy[6, 3, 7] = True  # one voxel, all coordinates different
    path = _write(tmp_path / "v.binvox", encode_binvox(occupancy, (-0.5, 0.25, 1.0), 2.0))
    grid = read_voxels(path)
    assert grid.occupancy.shape == (r, r, r) and grid.occupancy.dtype == bool
    assert np.array_equal(grid.occupancy, occupancy)
    assert grid.occupancy[6, 3, 7] and not grid.occupancy[6, 7, 3]
    assert np.array_equal(grid.translate, [-0.5, 0.25, 1.0]) and grid.scale == 2.0
    centre = grid.voxel_centres()[6, 3, 7]
    assert np.allclose(centre, [-0.5 + 6.5 / 8 * 2, 0.25 + 3.5 / 8 * 2, 1.0 + 7.5 / 8 * 2])


# ------------------------------------------------------------------------------ atomic writes


def test_atomic_output_refuses_existing_file(tmp_path):
    target = _write(tmp_path / "keep.txt", "original")
    with pytest.raises(FileExistsError) as info:
        with atomic_output(target) as temporary:
            temporary.write_text("new")
    assert str(info.value) == f"{target}: exists (use --force to overwrite)"
    assert target.read_text() == "original"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]
    with atomic_output(target, overwrite=True) as temporary:
        assert temporary.parent == tmp_path and temporary.suffix == ".txt"
        temporary.write_text("new")
    assert target.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


def test_atomic_output_removes_temporary_on_error(tmp_path):
    target = _write(tmp_path / "keep.txt", "original")
    with pytest.raises(RuntimeError):
        with atomic_output(target, overwrite=True) as temporary:
            temporary.write_text("half")
            raise RuntimeError("boom")
    assert target.read_text() == "original"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]
    fresh = tmp_path / "fresh.txt"
    with pytest.raises(RuntimeError):
        with atomic_output(fresh):
            raise RuntimeError("boom")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


def test_writers_do_not_overwrite(tmp_path):
    vertices, faces = tetrahedron()
    for suffix in (".ply", ".off", ".glb", ".stl", ".obj"):
        path = write_mesh(tmp_path / f"m{suffix}", vertices, faces)
        before = path.read_bytes()
        with pytest.raises(FileExistsError):
            write_mesh(path, vertices + 1, faces)
        assert path.read_bytes() == before
        write_mesh(path, vertices + 1, faces, overwrite=True)
        assert path.read_bytes() != before
    points = write_points(tmp_path / "p.xyz", vertices)
    with pytest.raises(FileExistsError):
        write_points(points, vertices)
    labels = write_labels(tmp_path / "l.seg", [1])
    with pytest.raises(FileExistsError):
        write_labels(labels, [2])
    assert labels.read_text() == "1\n"


def test_obj_with_existing_mtl_writes_nothing(tmp_path):
    vertices, faces = tetrahedron()
    mtl = _write(tmp_path / "c.mtl", "mine")
    with pytest.raises(FileExistsError, match="c.mtl"):
        write_mesh(tmp_path / "c.obj", vertices, faces, COLORS)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.mtl"] and mtl.read_text() == "mine"
    write_mesh(tmp_path / "c.obj", vertices, faces, COLORS, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.mtl", "c.obj"]


# ------------------------------------------------------------------------------ shared data


def shared(*parts):
    path = SHARED.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared data not found at {path} (needs ../shared/data beside the checkout)")
    return path


def _load_or_reject(path, cache):
    if path not in cache:
        try:
            cache[path] = read_mesh(path)
        except ShapeFileError as err:
            assert str(err).startswith(f"{path}: ")
            cache[path] = err
    return cache[path]


@pytest.mark.shared
def test_shared_off_meshes_and_seg_counts():
    root = shared()
    meshes = {}
    off_files = [
        p
        for folder in ("coseg_chairs", "coseg_tele_aliens", "psb_seg_benchmark", "standalone_meshes")
        for p in sorted((root / folder).rglob("*.off"))
    ]
    assert len(off_files) >= 50
    for path in off_files:
        _load_or_reject(path, meshes)
    loaded = [m for m in meshes.values() if isinstance(m, Mesh)]
    assert len(loaded) == len(off_files), [str(e) for e in meshes.values() if not isinstance(e, Mesh)]

    pairs = []
    for folder in ("coseg_chairs", "coseg_tele_aliens"):
        for seg in sorted((root / folder).rglob("gt/*.seg")):
            pairs.append((seg, seg.parent.parent / "shapes" / f"{seg.stem}.off"))
    for seg in sorted((root / "psb_seg_benchmark").glob("*/seg/*/*.seg")):
        category, shape_id = seg.parents[2], seg.parent.name
        pairs.append((seg, category / "off" / f"{shape_id}.off"))
    assert len(pairs) >= 500
    for seg, off in pairs:
        mesh = _load_or_reject(off, meshes)
        assert isinstance(mesh, Mesh), f"{seg}: mesh {off} was rejected"
        labels = read_labels(seg, face_count=len(mesh.faces))
        assert labels.shape == (len(mesh.faces),)


@pytest.mark.shared
def test_shared_standalone_meshes_match_their_readme():
    folder = shared("standalone_meshes")
    expected = {  # vertex and face counts stated in the folder's README
        "spot.obj": (2930, 5856),
        "stanford-bunny.obj": (35947, 69451),
        "stanford_armadillo_libigl.obj": (43243, 86482),
        "stanford_bunny_libigl.off": (3485, 6966),
    }
    for name, (n, f) in expected.items():
        mesh = read_mesh(folder / name)
        assert mesh.vertices.shape == (n, 3) and mesh.faces.shape == (f, 3), name
        assert mesh.area() > 0
    grid = read_voxels(folder / "chair.binvox")
    assert grid.occupancy.shape == (32, 32, 32) and grid.occupancy.any()
    assert isinstance(read_shape(folder / "chair.binvox"), VoxelGrid)


@pytest.mark.shared
@pytest.mark.parametrize("synset", ["02691156", "03001627", "04379243"])
def test_shared_shapenetvox32_sample(synset):
    folder = shared("shapenetvox32", synset)
    files = sorted(folder.glob("*/model.binvox"))
    assert len(files) > 50
    sample = [files[i] for i in np.linspace(0, len(files) - 1, 50).round().astype(int)]
    extents, back_low_x = [], []
    for path in sample:
        grid = read_voxels(path)
        assert grid.occupancy.shape == (32, 32, 32)
        assert 0.5 < grid.scale < 1.0 and np.all(np.abs(grid.translate) < 0.6)
        index = np.argwhere(grid.occupancy)
        low, high = index.min(axis=0), index.max(axis=0)
        extents.append(high - low + 1)
        top = index[index[:, 1] > low[1] + 0.6 * (high[1] - low[1])]
        back_low_x.append(top[:, 0].mean() < (low[0] + high[0]) / 2)
        # voxel centres sit inside the unit-ish model box
        centres = grid.voxel_centres()[grid.occupancy]
        assert np.all(np.abs(centres) < 0.6)
    if synset == "03001627":  # chairs: +y up (tallest axis), backs toward low x
        mean = np.mean(extents, axis=0)
        assert mean[1] > mean[0] and mean[1] > mean[2]
        assert np.mean(back_low_x) > 0.8


def test_refuse_existing_names_the_first_existing_path(tmp_path):
    made = tmp_path / "made.txt"
    made.write_text("mine")
    refuse_existing([None, tmp_path / "new.txt"])
    refuse_existing(made, overwrite=True)
    for paths in (made, str(made), [tmp_path / "new.txt", None, made]):
        with pytest.raises(FileExistsError, match=r"made\.txt: exists \(use --force to overwrite\)"):
            refuse_existing(paths)
    assert made.read_text() == "mine"


def test_points_with_labels_and_colours_read_back_by_another_ply_reader(tmp_path):
    import trimesh

    rng = np.random.default_rng(4)
    points, labels = rng.normal(size=(40, 3)), rng.integers(-1, 20, 40)
    colors = rng.integers(0, 256, (40, 3)).astype(np.uint8)
    path = write_points(tmp_path / "parts.ply", points, labels=labels, colors=colors)
    raw = trimesh.load(path).metadata["_ply_raw"]["vertex"]["data"]  # trimesh's own PLY parser
    assert np.array_equal(np.stack([raw["x"], raw["y"], raw["z"]], 1), points)
    assert np.array_equal(raw["part"], labels) and np.array_equal(np.stack([raw["red"], raw["green"], raw["blue"]], 1), colors)
    np.testing.assert_array_equal(read_points(path).points, points)  # still a point cloud primkit reads
    with pytest.raises(ValueError, match=r"written to \.ply"):
        write_points(tmp_path / "parts.xyz", points, labels=labels)
    with pytest.raises(ValueError, match=r"\(40,\) int"):
        write_points(tmp_path / "other.ply", points, labels=labels[:-1])


def test_binvox_writer_round_trips_and_splits_long_runs(tmp_path):
    rng = np.random.default_rng(4)
    occ = rng.random((24, 24, 24)) < 0.3
    occ[:, :12] = True                      # runs far longer than 255
    occ[0, 0, 0] = False
    grid = io.VoxelGrid(occ, translate=np.array([-0.3, 0.25, 1.5]), scale=0.75)
    path = io.write_voxels(tmp_path / "g.binvox", grid)
    back = io.read_voxels(path)
    assert np.array_equal(back.occupancy, occ)
    assert np.allclose(back.translate, grid.translate) and back.scale == grid.scale
    counts = np.frombuffer(path.read_bytes().split(b"data\n", 1)[1], np.uint8).reshape(-1, 2)[:, 1]
    assert counts.min() >= 1 and counts.sum() == 24**3
    with pytest.raises(FileExistsError):
        io.write_voxels(path, grid)
    with pytest.raises(ValueError):
        io.write_voxels(tmp_path / "g.ply", grid)


@pytest.mark.shared
def test_binvox_writer_reproduces_a_shapenet_file_byte_for_byte(shared_data, tmp_path):
    src = sorted((shared_data / "shapenetvox32" / "03001627").iterdir())[5] / "model.binvox"
    out = io.write_voxels(tmp_path / "copy.binvox", io.read_voxels(src))
    assert out.read_bytes() == src.read_bytes()


def test_write_array_round_trips_and_refuses_to_overwrite(tmp_path):
    a = np.arange(24, dtype=np.int16).reshape(2, 3, 4) - 5
    path = io.write_array(tmp_path / "a.npy", a)
    assert np.array_equal(np.load(path), a) and np.load(path).dtype == np.int16
    with pytest.raises(FileExistsError):
        io.write_array(path, a + 1)
    io.write_array(path, a + 1, overwrite=True)
    assert np.array_equal(np.load(path), a + 1)
    assert not [p for p in tmp_path.iterdir() if io.is_temporary(p)]


def test_named_labels_keep_unassigned_and_code_names_from_one():
    from primkit.model.parts import label_codes, named_labels

    names = ["seat", "legs", "legs", "back"]
    labels = np.array([[0, 1, -1], [2, 3, -1]])
    expected = np.array([[label_codes(names)[1][k] if k >= 0 else -1 for k in row] for row in labels])
    assert np.array_equal(named_labels(labels, names), expected)
    assert np.array_equal(named_labels(labels, names), [[1, 2, -1], [2, 3, -1]])

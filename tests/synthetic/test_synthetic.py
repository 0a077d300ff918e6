"""Tests for primkit.synthetic: every check is an invariant computed independently here."""

import json

import numpy as np
import pytest
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from primkit import synthetic
from primkit.synthetic import CATEGORIES, PART_GROUPS, PART_NAMES, LabelledShape

GENERATORS = {
    "chair": synthetic.chair,
    "table": synthetic.table,
    "airplane": synthetic.airplane,
    "animal": synthetic.animal,
}
LEGS = ("leg_front_left", "leg_front_right", "leg_back_left", "leg_back_right")


# --- independent helpers ----------------------------------------------------------------------


def edge_use(faces):
    """How often each directed and each undirected edge is used."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, directed_counts = np.unique(directed, axis=0, return_counts=True)
    _, undirected_counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    return directed_counts, undirected_counts


def face_components(faces):
    """Number of components of the graph joining faces that share an edge."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    face_of = np.tile(np.arange(len(faces)), 3)
    _, edge_id = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True)
    edge_id = edge_id.ravel()
    # bipartite graph faces <-> edges; faces are connected through their shared edges
    n = len(faces) + edge_id.max() + 1
    graph = coo_matrix((np.ones(len(face_of)), (face_of, len(faces) + edge_id)), shape=(n, n))
    return connected_components(graph, directed=False)[0]


def face_normals_and_areas(vertices, faces):
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    return cross / double_area[:, None], double_area / 2.0


def signed_volume(vertices, faces):
    tri = vertices[faces]
    return np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0


def centroid(shape: LabelledShape, part: str):
    """Area-weighted centroid of the faces labelled ``part``."""
    mask = shape.face_labels == shape.part_names.index(part)
    assert mask.any(), f"{shape.category} has no faces for {part}"
    _, areas = face_normals_and_areas(shape.vertices, shape.faces[mask])
    centres = shape.vertices[shape.faces[mask]].mean(axis=1)
    return (centres * areas[:, None]).sum(axis=0) / areas.sum()


def present(shape: LabelledShape):
    return {shape.part_names[i] for i in np.unique(shape.face_labels)}


# --- fixtures ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def collections():
    """A few random shapes per category plus variants that force every optional part."""
    shapes = {category: synthetic.generate(category, 6, seed=11) for category in CATEGORIES}
    shapes["chair"] += [
        synthetic.chair(1, swivel=False, has_arms=False),
        synthetic.chair(2, swivel=False, has_arms=True, back_tilt_deg=25.0),
        synthetic.chair(3, swivel=True, has_arms=False),
        synthetic.chair(4, swivel=True, has_arms=True),
        synthetic.chair(5, swivel=False, leg_style="square", leg_splay_deg=0.0, back_tilt_deg=0.0),
    ]
    shapes["table"] += [
        synthetic.table(1, top_shape="rect", pedestal=False),
        synthetic.table(2, top_shape="round", pedestal=False),
        synthetic.table(3, top_shape="round", pedestal=True),
        synthetic.table(4, top_shape="rect", pedestal=True, leg_style="square"),
    ]
    shapes["airplane"] += [synthetic.airplane(i, engine_count=n) for i, n in enumerate((0, 2, 4))]
    shapes["animal"] += [synthetic.animal(1, snout_length=0.0, tail_angle_deg=-60.0)]
    return shapes


def all_shapes(collections):
    return [shape for category in CATEGORIES for shape in collections[category]]


# --- determinism ------------------------------------------------------------------------------


@pytest.mark.parametrize("category", CATEGORIES)
def test_same_seed_same_shape_and_different_seeds_differ(category):
    make = GENERATORS[category]
    a, b, c = make(5), make(5), make(6)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.face_labels, b.face_labels)
    assert a.attributes == b.attributes and a.seed == b.seed == 5
    assert a.attributes != c.attributes
    assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)


@pytest.mark.parametrize("category", CATEGORIES)
def test_generate_derives_one_seed_per_shape(category):
    first = synthetic.generate(category, 3, seed=2)
    again = synthetic.generate(category, 3, seed=2)
    other = synthetic.generate(category, 3, seed=3)
    seeds = [shape.seed for shape in first]
    assert len(set(seeds)) == 3
    assert seeds == [shape.seed for shape in again]
    assert not set(seeds) & {shape.seed for shape in other}
    alone = GENERATORS[category](seeds[1])  # a shape regenerates from its own seed
    np.testing.assert_array_equal(alone.vertices, first[1].vertices)
    np.testing.assert_array_equal(alone.face_labels, first[1].face_labels)


def test_overrides_fix_one_attribute_and_keep_the_others():
    base = synthetic.chair(3)
    armed = synthetic.chair(3, has_arms=True, swivel=False)
    assert armed.attributes["has_arms"] is True and armed.attributes["swivel"] is False
    for key in ("seat_width", "seat_depth", "back_tilt_deg", "leg_length", "back_height"):
        assert armed.attributes[key] == base.attributes[key]
    assert synthetic.chair(3, back_tilt_deg=12.5).attributes["back_tilt_deg"] == 12.5


def test_rates_set_the_share_of_a_yes_no_attribute_and_keep_the_others():
    plain = synthetic.generate("chair", 24, seed=6)
    every = synthetic.generate("chair", 24, seed=6, rates={"has_arms": 1.0})
    none = synthetic.generate("chair", 24, seed=6, rates={"has_arms": 0.0, "swivel": 0.0})
    half = synthetic.generate("chair", 24, seed=6, rates={"has_arms": 0.5})
    assert all(s.attributes["has_arms"] for s in every)
    assert not any(s.attributes["has_arms"] or s.attributes["swivel"] for s in none)
    assert 4 <= sum(s.attributes["has_arms"] for s in half) <= 20  # binomial(24, 0.5): outside only ~1e-3
    for a, b in zip(plain, half):
        assert a.seed == b.seed
        assert {k: v for k, v in a.attributes.items() if k != "has_arms"} == \
               {k: v for k, v in b.attributes.items() if k != "has_arms"}
    again = synthetic.chair(half[3].seed, has_arms=half[3].attributes["has_arms"])
    np.testing.assert_array_equal(again.vertices, half[3].vertices)
    assert [s.attributes for s in synthetic.generate("chair", 24, seed=6, rates={"has_arms": 0.5})] == \
           [s.attributes for s in half]
    with pytest.raises(ValueError, match="yes/no"):
        synthetic.generate("chair", 2, rates={"seat_width": 0.5})
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        synthetic.generate("chair", 2, rates={"has_arms": 1.5})


def test_bad_arguments_are_refused():
    with pytest.raises(TypeError, match="wheels"):
        synthetic.chair(0, wheels=5)
    with pytest.raises(ValueError, match="leg_style"):
        synthetic.table(0, leg_style="curly")
    with pytest.raises(ValueError, match="engine_count"):
        synthetic.airplane(0, engine_count=3)
    with pytest.raises(TypeError, match="swivel"):
        synthetic.chair(0, swivel="yes")
    with pytest.raises(ValueError, match="category"):
        synthetic.generate("sofa", 2)


# --- mesh validity ----------------------------------------------------------------------------


def test_meshes_are_watertight_oriented_single_components(collections):
    for shape in all_shapes(collections):
        assert shape.vertices.dtype == np.float64 and shape.vertices.shape[1] == 3
        assert shape.faces.dtype == np.int64 and shape.faces.shape[1] == 3
        assert 1_000 <= len(shape.faces) <= 30_000
        directed, undirected = edge_use(shape.faces)
        assert (undirected == 2).all(), "every edge must be shared by exactly two faces"
        assert (directed == 1).all(), "the two faces of an edge must traverse it oppositely"
        assert face_components(shape.faces) == 1
        assert signed_volume(shape.vertices, shape.faces) > 0  # outward normals
        mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        used = np.zeros(len(shape.vertices), bool)
        used[shape.faces] = True
        assert used.all(), "no unreferenced vertices"


def test_canonical_frame(collections):
    for shape in all_shapes(collections):
        lo, hi = shape.vertices.min(axis=0), shape.vertices.max(axis=0)
        np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-9)
        assert abs((hi - lo).max() - 1.0) < 1e-12
        assert (np.abs(shape.vertices) <= 0.5 + 1e-12).all()


def test_not_a_union_of_boxes(collections):
    """Rounded or slanted faces (normal more than ~8 degrees off every axis) carry real area."""
    for category in CATEGORIES:
        fractions = []
        for shape in collections[category]:
            normals, areas = face_normals_and_areas(shape.vertices, shape.faces)
            slanted = np.abs(normals).max(axis=1) < 0.99
            fractions.append(areas[slanted].sum() / areas.sum())
            assert fractions[-1] > 0.02, (category, shape.seed)
        assert np.mean(fractions) > 0.1, category


# --- labels -----------------------------------------------------------------------------------


def test_labels_index_the_fixed_part_names(collections):
    for category in CATEGORIES:
        for shape in collections[category]:
            assert shape.category == category
            assert shape.part_names == PART_NAMES[category]
            assert shape.part_groups == PART_GROUPS[category]
            assert set(shape.part_groups) == set(shape.part_names)
            assert shape.face_labels.dtype == np.int64
            assert shape.face_labels.shape == (len(shape.faces),)
            assert shape.face_labels.min() >= 0
            assert shape.face_labels.max() < len(shape.part_names)
            assert set(shape.present_parts) == present(shape)
            json.dumps(shape.attributes)  # plain, serialisable values


def test_expected_parts_are_present(collections):
    for shape in collections["chair"]:
        parts, a = present(shape), shape.attributes
        assert {"seat", "back"} <= parts
        assert ({"arm_left", "arm_right"} <= parts) == a["has_arms"]
        assert not ({"arm_left", "arm_right"} & parts) or a["has_arms"]
        if a["swivel"]:
            assert {"column", "star_base"} <= parts and not set(LEGS) & parts
        else:
            assert set(LEGS) <= parts and not {"column", "star_base"} & parts
    for shape in collections["table"]:
        parts = present(shape)
        assert "top" in parts
        if shape.attributes["pedestal"]:
            assert {"pedestal", "foot"} <= parts and not set(LEGS) & parts
        else:
            assert set(LEGS) <= parts and not {"pedestal", "foot"} & parts
    for shape in collections["airplane"]:
        parts = present(shape)
        assert {"fuselage", "wing_left", "wing_right", "tail_left", "tail_right", "fin"} <= parts
        engines = {p for p in parts if p.startswith("engine_")}
        assert len(engines) == shape.attributes["engine_count"]
    for shape in collections["animal"]:
        assert present(shape) == set(PART_NAMES["animal"])
    # the forced variants cover every optional part at least once
    for category in CATEGORIES:
        seen = set().union(*(present(shape) for shape in collections[category]))
        assert seen == set(PART_NAMES[category]), category


def test_labels_agree_with_geometry(collections):
    for shape in collections["chair"]:
        seat, back = centroid(shape, "seat"), centroid(shape, "back")
        assert back[0] < seat[0], "the back is behind the seat (-X)"
        assert back[1] > seat[1]
        below = ("column", "star_base") if shape.attributes["swivel"] else LEGS
        for part in below:
            assert centroid(shape, part)[1] < seat[1]
        if shape.attributes["has_arms"]:
            assert centroid(shape, "arm_left")[2] < 0 < centroid(shape, "arm_right")[2]
            assert centroid(shape, "arm_left")[1] > seat[1]
    for shape in collections["chair"] + collections["table"] + collections["animal"]:
        if set(LEGS) <= present(shape):
            fl, fr, bl, br = (centroid(shape, leg) for leg in LEGS)
            assert fl[0] > 0 and fr[0] > 0 and bl[0] < 0 and br[0] < 0
            assert fl[2] < 0 and bl[2] < 0 and fr[2] > 0 and br[2] > 0
    for shape in collections["table"]:
        top = centroid(shape, "top")
        for part in sorted(present(shape) - {"top"}):
            assert centroid(shape, part)[1] < top[1]
        top_vertices = shape.vertices[shape.faces[shape.part_faces("top")]].reshape(-1, 3)
        assert top_vertices[:, 1].max() == shape.vertices[:, 1].max()
    for shape in collections["airplane"]:
        fuselage = shape.vertices[shape.faces[shape.part_faces("fuselage")]].reshape(-1, 3)
        others = shape.vertices[shape.faces[shape.face_labels != 0]].reshape(-1, 3)
        assert fuselage[:, 0].max() > 0 and fuselage[:, 0].max() >= others[:, 0].max()
        wings = (centroid(shape, "wing_left") + centroid(shape, "wing_right")) / 2
        assert centroid(shape, "fin")[0] < wings[0] and centroid(shape, "tail_left")[0] < wings[0]
        assert centroid(shape, "fin")[1] > centroid(shape, "fuselage")[1]
        assert centroid(shape, "wing_left")[2] < 0 < centroid(shape, "wing_right")[2]
        for part in present(shape):
            if part.startswith("engine_"):
                wing = "wing_left" if "_left_" in part else "wing_right"
                assert centroid(shape, part)[1] < centroid(shape, wing)[1]
                assert np.sign(centroid(shape, part)[2]) == np.sign(centroid(shape, wing)[2])
    for shape in collections["animal"]:
        torso, head = centroid(shape, "torso"), centroid(shape, "head")
        assert head[0] > torso[0] and head[1] > torso[1]
        assert centroid(shape, "tail")[0] < torso[0]
        assert all(centroid(shape, leg)[1] < torso[1] for leg in LEGS)


# --- files ------------------------------------------------------------------------------------


def test_write_collection_round_trip(tmp_path):
    paths = synthetic.write_collection(tmp_path / "chairs", "chair", 3, seed=4)
    expected = synthetic.generate("chair", 3, seed=4)
    assert [p.name for p in paths] == [f"chair_{i:04d}.ply" for i in range(3)]
    names = sorted(p.name for p in (tmp_path / "chairs").iterdir())
    suffixes = (".ply", ".seg", ".json")
    assert names == sorted(f"chair_{i:04d}{ext}" for i in range(3) for ext in suffixes)
    for path, shape in zip(paths, expected):
        mesh = trimesh.load(path, process=False)
        assert len(mesh.vertices) == len(shape.vertices)
        np.testing.assert_array_equal(mesh.faces, shape.faces)
        np.testing.assert_allclose(mesh.vertices, shape.vertices, atol=1e-6)  # PLY stores float32
        labels, meta = synthetic.read_collection_labels(path)
        np.testing.assert_array_equal(labels, shape.face_labels)
        assert labels.dtype == np.int64
        assert meta["category"] == "chair"
        assert meta["part_names"] == shape.part_names
        assert meta["part_groups"] == shape.part_groups
        assert meta["attributes"] == shape.attributes
        assert meta["seed"] == shape.seed
        seg_lines = path.with_suffix(".seg").read_text().splitlines()
        assert len(seg_lines) == len(shape.faces)


def test_write_collection_refuses_to_overwrite(tmp_path):
    synthetic.write_collection(tmp_path, "table", 2, seed=1)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(FileExistsError, match="table_0000"):
        synthetic.write_collection(tmp_path, "table", 2, seed=9)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    (tmp_path / "table_0000.json").unlink()  # one existing file of a shape is enough to refuse
    with pytest.raises(FileExistsError, match="table_0000.ply"):
        synthetic.write_collection(tmp_path, "table", 1, seed=9)
    synthetic.write_collection(tmp_path, "table", 2, seed=9, overwrite=True)
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert set(after) == set(before)  # no temporary files left behind
    assert after["table_0001.json"] != before["table_0001.json"]
    expected_seed = synthetic.generate("table", 2, seed=9)[1].seed
    assert json.loads(after["table_0001.json"])["seed"] == expected_seed

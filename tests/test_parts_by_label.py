"""Parts by label (primkit.segmentation.bylabel, primkit.embedding.label_boxes, ``embed --parts arms``):
boxes of known point sets in closed form, the spec rule, and the labelled arms of procedural chairs
against the chairs' own arm faces."""

import json

import numpy as np
import pytest

from primkit import primitives, synthetic
from primkit.cli import main
from primkit.embedding import PartDescriptor, label_boxes, region_box
from primkit.segmentation.bylabel import by_label, label_regions, labelled_voxels


def _rot_z(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])


def test_region_box_recovers_a_sampled_box():
    rng = np.random.default_rng(0)
    half = np.array([0.3, 0.1, 0.05])
    R, t = _rot_z(12.0), np.array([0.1, -0.2, 0.05])
    # a lattice filling the box: its covariance is diagonal in the box's axes, so the box is exact
    axes = [np.linspace(-h, h, n) for h, n in zip(half, (13, 7, 5))]
    local = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    z, Rb, c = region_box(local @ R.T + t)
    np.testing.assert_allclose(z, half, atol=1e-9)
    np.testing.assert_allclose(c, t, atol=1e-9)
    np.testing.assert_allclose(Rb, R, atol=1e-9)
    # points drawn at random in it: close
    z, Rb, c = region_box(rng.uniform(-half, half, (4000, 3)) @ R.T + t)
    np.testing.assert_allclose(z, half, atol=0.01)
    angle = np.degrees(np.arccos(np.clip((np.trace(Rb.T @ R) - 1) / 2, -1, 1)))
    assert angle < 3.0
    # a box standing on its side is the same box: named so that its rotation is nearest identity
    Ry = np.array([[0, 0, 1.0], [0, 1, 0], [-1, 0, 0]])
    z2, R2, _ = region_box(local @ (Ry @ R).T)
    assert np.trace(R2) > 2.9  # about 12 degrees from identity at most
    np.testing.assert_allclose(sorted(z2), sorted(half), atol=0.01)


def test_label_boxes_presence_and_descriptor():
    rng = np.random.default_rng(1)
    a = rng.uniform(-0.1, 0.1, (300, 3)) + [0.2, 0, 0]
    b = rng.uniform(-0.05, 0.05, (100, 3))
    pts = [np.vstack([a, b]), np.vstack([a, b])]
    labs = [np.repeat([0, 1], [300, 100]), np.repeat([0, -1], [300, 100])]  # shape 1: no "b"
    table = label_boxes(pts, labs, ["a", "b"], names=["s0", "s1"])
    v = table.values.reshape(2, 2, 11)
    assert v[0, :, 10].tolist() == [1.0, 1.0] and v[1, :, 10].tolist() == [1.0, 0.0]
    z, R, c = region_box(b)
    np.testing.assert_allclose(v[0, 1, :3], z)
    np.testing.assert_allclose(v[0, 1, 7:10], c)
    np.testing.assert_allclose(primitives.quaternion_to_matrix(v[0, 1, 3:7]), R, atol=1e-9)
    # a label under min_share is absent
    few = [np.vstack([a, b[:3]])]
    assert label_boxes(few, [np.repeat([0, 1], [300, 3])], ["a", "b"]).values.reshape(2, 11)[1, 10] == 0.0
    d = PartDescriptor(what="presence").fit(table)
    assert d.feature_names_ == ["a.presence", "b.presence"]
    X = d.transform(table)
    assert np.linalg.norm(X[0] - X[1]) == pytest.approx(1 / 0.5)  # one part present/absent: 1 / scale


def test_by_label_rule():
    names = ["back", "seat", "legs", "arms"]
    assert by_label("arms", names) == ["arms"]
    assert by_label(" Arms, back ", names) == ["arms", "back"]
    for spec in (None, "all", "3", "part3", "arms,3", "base"):
        assert by_label(spec, names) is None, spec
    assert by_label("arms", None) is None


@pytest.fixture(scope="module")
def armed_chairs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("armed")
    paths = synthetic.write_collection(folder, "chair", 10, seed=5, rates={"has_arms": 0.5})
    return folder, sorted(paths)


def test_labelled_arms_boxes_match_the_chairs_arm_faces(armed_chairs):
    """The bundled chair labeller's arms on each chair, as a box, against the box of that chair's
    own arm faces (the procedural labels, in the same canonical frame)."""
    from primkit import io
    from primkit.model.abstraction import abstract_shapes
    from primkit.segmentation.labeller import read_labeller
    from primkit.model.bundled import resolve_model

    folder, paths = armed_chairs
    labeller = read_labeller(resolve_model("chair"))
    out = abstract_shapes(paths, "chair")
    arm = labeller.names.index("arms")
    pts, labs, truth, has = [], [], [], []
    for a, path in zip(out, paths):
        p, lab = labelled_voxels(labeller, a.canonical_shape().occupancy, a.result.canonical)
        pts.append(p)
        labs.append(lab)
        info = json.loads(path.with_suffix(".json").read_text())
        has.append(bool(info["attributes"]["has_arms"]))
        mesh = io.read_mesh(path)
        faces = np.asarray(io.read_labels(path.with_suffix(".seg"), len(mesh.faces)))
        arms = [i for i, n in enumerate(info["part_names"]) if info["part_groups"][n] == "arms"]
        v = a.result.frame.to_canonical(mesh.vertices[mesh.faces[np.isin(faces, arms)]].reshape(-1, 3))
        truth.append(v)
    table = label_boxes(pts, labs, labeller.names).values.reshape(len(paths), len(labeller.names), 11)
    present = table[:, arm, 10] > 0.5
    assert (present == np.array(has)).mean() >= 0.8, (present, has)
    checked = 0
    for i in np.flatnonzero(present & np.array(has)):
        lo, hi = truth[i].min(0), truth[i].max(0)
        # the arms' box centre: at the height of the true arms (between their lowest and highest
        # point), and front-back and sideways within 3 voxels (of 32) of the true arms' box centre
        c = table[i, arm, 7:10]
        assert lo[1] <= c[1] <= hi[1], i
        assert np.all(np.abs(c[[0, 2]] - (lo + hi)[[0, 2]] / 2) < 3 / 32), i
        checked += 1
    assert checked >= 3


def test_label_regions_are_each_shapes_voxels_of_the_chosen_labels(armed_chairs):
    """What ``embed --parts arms,back`` and the embedding explorer box: each voxel's slot among the
    chosen labels (arms 0, back 1, any other label or none -1), against labelled_voxels."""
    from primkit.model.abstraction import abstract_shapes
    from primkit.model.bundled import resolve_model
    from primkit.segmentation.labeller import read_labeller

    _, paths = armed_chairs
    labeller = read_labeller(resolve_model("chair"))
    assert labeller.names == ["back", "seat", "legs", "arms"]
    out = list(abstract_shapes(paths[:3], "chair"))
    grids = [a.canonical_shape().occupancy for a in out]
    points, slots = label_regions(labeller, ["arms", "back"], grids, [a.result.canonical for a in out])
    assert len(points) == len(slots) == 3
    for a, p, s in zip(out, points, slots):
        want_p, named = labelled_voxels(labeller, a.canonical_shape().occupancy, a.result.canonical)
        assert np.array_equal(p, want_p) and len(p) == a.canonical_shape().occupancy.sum()
        assert np.array_equal(s, np.where(named == 3, 0, np.where(named == 0, 1, -1)))
        assert (s == 1).any() and (s == -1).any()  # every chair has a back, and seat or legs


def test_embed_parts_by_label_and_by_index(armed_chairs, tmp_path):
    """By label, ``embed`` describes each chair's labelled voxels (RegionDescriptor of labelled_grid,
    the same numbers), and ``similar`` from a chair with arms finds chairs with arms."""
    from primkit.embedding import RegionDescriptor, RegionTable
    from primkit.model.abstraction import abstract_shapes
    from primkit.model.bundled import resolve_model
    from primkit.segmentation.bylabel import labelled_grid
    from primkit.segmentation.labeller import read_labeller

    folder, paths = armed_chairs
    has = np.array([json.loads(p.with_suffix(".json").read_text())["attributes"]["has_arms"] for p in paths])
    out = tmp_path / "arms"
    assert main(["embed", str(folder), "--model", "chair", "--parts", "arms", "--what", "share", "-o", str(out),
                 "-q", "--perplexity", "3"]) == 0
    X = np.load(out / "descriptors.npy")
    assert X.shape == (len(paths), 1)
    labeller = read_labeller(resolve_model("chair"))
    shapes = list(abstract_shapes(paths, "chair"))
    grids = [a.canonical_shape().occupancy for a in shapes]
    table = RegionTable.from_grids(grids, [labelled_grid(labeller, g, a.result.canonical) for g, a in zip(grids, shapes)],
                                   labeller.names)
    np.testing.assert_allclose(X, RegionDescriptor("arms", "share").fit_transform(table))
    found = table.present[:, labeller.names.index("arms")]
    assert (found == has).mean() >= 0.8
    # similar: from a chair whose arms are found, the nearest by arms are chairs with arms
    query = next(p for p, f, h in zip(paths, found, has) if f and h)
    sim = tmp_path / "sim"
    assert main(["similar", str(query), str(folder), "--model", "chair", "--parts", "arms",
                 "-k", "3", "-o", str(sim), "-q"]) == 0
    import csv

    rows = list(csv.DictReader((sim / "similar.csv").open()))
    by_name = {p.stem: h for p, h in zip(paths, has)}
    assert len(rows) == 3 and all(by_name[r["name"]] for r in rows)
    # an index keeps the index-based descriptor: the same numbers as PartDescriptor on index 12
    out2 = tmp_path / "index"
    assert main(["embed", str(folder), "--model", "chair", "--parts", "12", "--what", "presence", "-o", str(out2),
                 "-q", "--perplexity", "3"]) == 0
    results = [a.result for a in shapes]
    want = PartDescriptor("12", "presence").fit(results).transform(results)
    np.testing.assert_allclose(np.load(out2 / "descriptors.npy"), want)


def test_edit_scale_by_label_edits_the_cuboids_mostly_of_that_label(armed_chairs, tmp_path, capsys):
    """``edit --scale seat=1.2`` with the chair model's labeller: the cuboids edited are those whose
    faces (nearest cuboid) are mostly seat by the procedural chair's own labels."""
    from primkit import io
    from primkit.model.abstraction import abstract_shapes

    folder, paths = armed_chairs
    path = paths[0]
    info = json.loads(path.with_suffix(".json").read_text())
    mesh = io.read_mesh(path)
    faces = io.read_labels(path.with_suffix(".seg"), len(mesh.faces))
    groups = np.array([info["part_groups"][n] for n in info["part_names"]])[faces]
    a = abstract_shapes([path], "chair")[0]
    centroids = a.result.frame.to_canonical(mesh.vertices[mesh.faces].mean(axis=1))
    index = primitives.assign_points(centroids, a.result.canonical)
    seat = set()
    for k in np.unique(index):
        g, c = np.unique(groups[index == k], return_counts=True)
        if g[np.argmax(c)] == "seat":
            seat.add(int(k))
    assert seat
    out = tmp_path / "edited.ply"
    assert main(["edit", str(path), "--model", "chair", "--scale", "seat=1.2", "-o", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    edited = {int(key.split("[")[1].rstrip("]")) for key in report["edits"]["scale"]}
    assert edited == seat
    # an index still selects that index
    out2 = tmp_path / "edited2.ply"
    k = min(seat)
    assert main(["edit", str(path), "--model", "chair", "--scale", f"{k}=1.2", "-o", str(out2)]) == 0
    assert [int(key.split("[")[1].rstrip("]")) for key in json.loads(out2.with_suffix(".json").read_text())["edits"]["scale"]] == [k]

"""Co-segmentation: projection against brute force, tie-breaking, face votes, label files, the
label-mapping protocols on a constructed example, named parts, and the command on a batch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from primkit import io, primitives, segmentation, synthetic
from primkit.model import parts
from primkit.cli import main


def _random_cuboids(rng, m=12, present=0.8):
    return primitives.Cuboids(rng.uniform(0.05, 0.3, (m, 3)), rng.normal(size=(m, 4)),
                              rng.uniform(-0.4, 0.4, (m, 3)), rng.random(m) < present)


def _brute_force_label(p, cub):
    """One point at a time: local coordinates, clamped excess, the closest present cuboid,
    ties to the larger volume, then the lower index."""
    best, best_key = -1, None
    for k in range(cub.count):
        if not cub.existence[k]:
            continue
        R = primitives.quaternion_to_matrix(cub.quaternions[k])
        local = R.T @ (p - cub.translations[k])
        excess = np.maximum(np.abs(local) - cub.half_extents[k], 0.0)
        d2 = float(excess @ excess)
        key = (d2, -np.prod(cub.half_extents[k]), k)
        if best_key is None or key < best_key:
            best, best_key = k, key
    return best


def test_point_labels_match_brute_force():
    rng = np.random.default_rng(3)
    for trial in range(3):
        cub = _random_cuboids(rng)
        pts = rng.uniform(-0.6, 0.6, (700, 3))
        pts[:100] = cub.translations[cub.present[0]] + rng.uniform(-0.02, 0.02, (100, 3))  # inside points too
        got = segmentation.point_labels(pts, cub)
        want = np.array([_brute_force_label(p, cub) for p in pts])
        np.testing.assert_array_equal(got, want)
    both = primitives.assign_points_with_distance(pts, cub, chunk=64)  # several chunks
    np.testing.assert_array_equal(both.labels, got)
    np.testing.assert_array_equal(primitives.assign_points(pts, cub, chunk=64), got)
    d = primitives.point_cuboid_distance(pts, cub)
    np.testing.assert_allclose(both.distance, d[np.arange(len(pts)), got], atol=1e-12)


def test_ties_go_to_the_larger_cuboid_then_the_lower_index():
    q = [[1, 0, 0, 0]] * 3
    # cuboid 0 small, 1 large, both around the origin; 2 is as large as 1, elsewhere
    cub = primitives.Cuboids([[0.1] * 3, [0.3] * 3, [0.3] * 3], q, [[0, 0, 0], [0, 0, 0], [2, 0, 0]], [True] * 3)
    assert segmentation.point_labels([[0.0, 0.0, 0.0]], cub)[0] == 1
    # equal volumes, a point inside both: the lower index
    same = primitives.Cuboids([[0.2] * 3, [0.2] * 3], q[:2], [[0, 0, 0], [0.1, 0, 0]], [True, True])
    assert segmentation.point_labels([[0.05, 0.0, 0.0]], same)[0] == 0
    # the larger cuboid absent: the smaller one takes the point
    absent = primitives.Cuboids([[0.1] * 3, [0.3] * 3], q[:2], [[0, 0, 0]] * 2, [True, False])
    assert segmentation.point_labels([[0.0, 0.0, 0.0]], absent)[0] == 0


def test_face_labels_follow_the_area_majority():
    """Random triangles against two half-spaces; a face's label must be the side holding most of
    its area whenever that majority is clear (> 60%), checked by dense area sampling."""
    q = [[1, 0, 0, 0]] * 2
    cub = primitives.Cuboids([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], q, [[-1.0, 0, 0], [1.0, 0, 0]], [True, True])
    rng = np.random.default_rng(0)
    verts = rng.uniform(-0.5, 0.5, (300, 3))
    faces = np.arange(300).reshape(-1, 3)
    got = segmentation.face_labels(verts, faces, cub)
    u = rng.random((4000, 2))
    u = np.where(u.sum(1, keepdims=True) > 1, 1 - u, u)
    bary = np.column_stack([1 - u.sum(1), u])
    checked = 0
    for i, f in enumerate(faces):
        pts = bary @ verts[f]
        share_right = np.mean(pts[:, 0] > 0)
        if share_right > 0.6:
            assert got[i] == 1
            checked += 1
        elif share_right < 0.4:
            assert got[i] == 0
            checked += 1
    assert checked > 60


def test_label_file_round_trip(tmp_path):
    shape = synthetic.chair(1)
    cub = primitives.Cuboids([[0.3, 0.05, 0.3], [0.05, 0.3, 0.3], [0.3, 0.25, 0.3]], [[1, 0, 0, 0]] * 3,
                             [[0, 0.45, 0], [-0.25, 0.8, 0], [0, 0.2, 0]], [True] * 3)
    seg = segmentation.segment_mesh(shape.vertices, shape.faces, cub, name="c", part_names=["seat", "back", "legs"])
    paths = seg.save(tmp_path)
    np.testing.assert_array_equal(io.read_labels(paths.labels, len(shape.faces)), seg.face_labels)
    mesh = io.read_mesh(paths.mesh)
    assert len(mesh.faces) == len(shape.faces)
    names, codes = seg.semantic_labels()
    assert names == ["seat", "back", "legs"]
    np.testing.assert_array_equal(codes, seg.face_labels + 1)
    with pytest.raises(FileExistsError):
        seg.save(tmp_path)
    np.testing.assert_allclose(seg.part_areas().sum(), io.Mesh(shape.vertices, shape.faces).face_areas().sum())


class _Seg:
    """The parts of a Segmentation that evaluate() reads."""

    def __init__(self, name, labels, count):
        self.name = name
        self.face_labels = np.asarray(labels)
        self.face_areas = np.ones(len(labels))
        self.cuboids = primitives.Cuboids(np.ones((count, 3)), [[1, 0, 0, 0]] * count, np.zeros((count, 3)),
                                          np.ones(count, bool))


def test_mapping_protocols_on_a_constructed_example():
    # 3 shapes, 4 primitive indices, labels 0 = seat, 1 = back.
    # index 0 is mostly seat, index 1 mostly back, index 2 is back on shape a only, index 3 unused
    names = ["seat", "back"]
    segs = [_Seg("a", [0, 0, 0, 1, 1, 2, 2], 4), _Seg("b", [0, 0, 1, 1, 1, 0], 4), _Seg("c", [0, 1, 1, 0, 2], 4)]
    truth = [segmentation.GroundTruth(np.array(t), names)
             for t in ([0, 0, 0, 1, 1, 1, 1], [0, 0, 1, 1, 1, 1], [0, 1, 1, 0, 0])]
    report = segmentation.evaluate(segs, truth, part_names=["seat", "back", "arm", "part3"])
    majority = report.protocols["collection-majority"]
    # by hand: index 0 holds seat 7 times, back 1 -> seat; index 1: back 5, seat 0 -> back;
    # index 2: back 2 (shape a), seat 1 (shape c) -> back; index 3: nothing -> None
    assert majority.mapping == {"0": "seat", "1": "back", "2": "back", "3": None}
    acc = majority.shapes
    assert acc["a"].faces == pytest.approx(1.0)
    assert acc["b"].faces == pytest.approx(5 / 6)  # the last face: index 0 -> seat, truth back
    assert acc["c"].faces == pytest.approx(4 / 5)  # the last face: index 2 -> back, truth seat
    # leave-one-out for shape c: learned on a and b, index 2 -> back (a) -> the same 4/5;
    # for shape a: learned on b and c, index 2 -> seat (c) -> faces 5, 6 wrong -> 5/7
    loo = report.protocols["leave-one-out"].shapes
    assert loo["a"].faces == pytest.approx(5 / 7)
    assert loo["c"].faces == pytest.approx(4 / 5)
    # model names: "arm" is not a ground-truth label, so index 2 counts as wrong everywhere
    named = report.protocols["model-names"]
    assert named.mapping == {"0": "seat", "1": "back", "2": None, "3": None}
    assert named.shapes["a"].faces == pytest.approx(5 / 7)
    assert named.shapes["c"].faces == pytest.approx(4 / 5)
    # IoU of seat under the majority mapping (faces predicted seat / truly seat):
    # a: {0,1,2} / {0,1,2}; b: {0,1,5} / {0,1}; c: {0,3} / {0,3,4}
    inter, union = 3 + 2 + 2, 3 + 3 + 3
    assert majority.iou["seat"] == pytest.approx(inter / union)


def test_aliases_and_label_names(tmp_path):
    path = tmp_path / "x.seg"
    path.write_text("1\n2\n3\n3\n")
    names = []
    gt = segmentation.read_ground_truth(path, 4, "back,seat,legs/base", names)
    assert gt.names == ["back", "seat", "legs/base"]
    np.testing.assert_array_equal(gt.labels, [0, 1, 2, 2])
    other = segmentation.read_ground_truth(path, 4, "3=seat", names)  # same names list: codes agree
    np.testing.assert_array_equal(other.labels, [-1, -1, 1, 1])
    mapping = segmentation.name_mapping(["base", "seat", "arms"], gt.names)
    np.testing.assert_array_equal(mapping, [2, 1, -1])


def test_names_from_labels_by_area():
    assign = [np.array([0, 0, 1, 1, 2])]
    labels = [np.array([0, 1, 1, 1, 0])]
    weights = [np.array([1.0, 3.0, 1.0, 1.0, 2.0])]
    names, table = parts.names_from_labels(assign, labels, weights, ["seat", "back"], 4)
    assert names == ["back", "back", "seat", "part3"]  # index 0: back holds 3 of its 4 units of area
    np.testing.assert_allclose(table[0], [1.0, 3.0])
    np.testing.assert_array_equal(parts.resolve_parts("back", names), [0, 1])


def test_seat_and_back_agree_across_leg_counts():
    """A four-legged chair and a swivel chair (one column, five spokes): with the bundled chair
    model, the faces of the seat go to the same index on both, and so do the back's."""
    from primkit import data
    from primkit.model.abstractor import Abstractor

    abstractor = Abstractor.load("chair")
    picks = {}
    for swivel in (False, True):
        shape = synthetic.chair(11, swivel=swivel, has_arms=False)
        prepared = data.prepare(io.Mesh(shape.vertices, shape.faces), name=f"s{swivel}")
        result = abstractor.predict([prepared], refine=50)[0]
        labels = segmentation.face_labels(shape.vertices, shape.faces, result.cuboids)
        for part in ("seat", "back"):
            faces = shape.face_labels == shape.part_names.index(part)
            picks.setdefault(part, []).append(np.bincount(labels[faces]).argmax())
    assert picks["seat"][0] == picks["seat"][1]
    assert picks["back"][0] == picks["back"][1]
    assert picks["seat"][0] != picks["back"][0]


def test_segment_command_goes_past_a_bad_file(tmp_path, capsys):
    folder = tmp_path / "in"
    synthetic.write_collection(folder, "chair", 3, seed=2)
    (folder / "broken.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n")  # truncated
    out = tmp_path / "out"
    code = main(["segment", str(folder), "--model", "chair", "-o", str(out), "--refine", "0", "--workers", "1",
                 "--gt", str(folder), "--cache", str(tmp_path / "cache"), "--png", str(out / "segmentation.png")])
    captured = capsys.readouterr()
    assert code == 1
    assert "broken.off" in captured.err
    for i in range(3):
        labels = io.read_labels(out / f"chair_{i:04d}.seg")
        assert len(labels) == len(io.read_mesh(folder / f"chair_{i:04d}.ply").faces)
        assert (out / f"chair_{i:04d}.parts.ply").is_file()
    assert (out / "summary.csv").read_text().count("\n") == 4
    from pictures import read_picture

    picture = read_picture(out / "segmentation.png")  # each chair's grey mesh beside it coloured by part
    panel = picture.size[0] // 6
    assert picture.crop(0, panel).coloured_pixels < 0.05 * picture.crop(0, panel).foreground.sum()
    assert picture.crop(panel, 2 * panel).coloured_pixels > 0.5 * picture.crop(panel, 2 * panel).foreground.sum()
    shown = picture.part_colours_shown({16, 18})  # the seat's and the back's colours, on every chair
    assert min(shown.values()) > 1000, shown
    assert "collection-majority" in captured.out and "evaluation.json" in captured.out
    # the procedural .json beside the labels names the ground truth: seat, back, legs, ...
    import json

    report = json.loads((out / "evaluation.json").read_text())
    assert "seat" in report["labels"] and "back" in report["labels"]
    # outputs are not overwritten without --force
    again = main(["segment", str(folder / "chair_0000.ply"), "--model", "chair", "-o", str(out), "--refine", "0",
                  "--workers", "1", "--cache", str(tmp_path / "cache")])
    assert again == 2  # refused before any work
    assert "exists" in capsys.readouterr().err


@pytest.mark.integration  # name-parts on meshes through the CLI
def test_name_parts_writes_a_named_copy(tmp_path, capsys):
    from primkit.model.abstractor import Abstractor
    from primkit.model.bundled import resolve_model

    folder = tmp_path / "in"
    synthetic.write_collection(folder, "chair", 4, seed=5)
    out = tmp_path / "named.safetensors"
    before = resolve_model("chair").read_bytes()
    code = main(["name-parts", str(folder), "--model", "chair", "-o", str(out), "--refine", "0", "--workers", "1",
                 "--cache", str(tmp_path / "cache")])
    assert code == 0
    assert resolve_model("chair").read_bytes() == before  # the input model is untouched
    named = Abstractor.load(out)
    assert "seat" in named.part_names and "back" in named.part_names
    assert named.metadata["part_naming"]["shapes"] == 4
    seg = tmp_path / "seg"
    assert main(["segment", str(folder / "chair_0000.ply"), "--model", str(out), "-o", str(seg), "--semantic",
                 "--refine", "0", "--workers", "1", "--cache", str(tmp_path / "cache")]) == 0
    legend = (seg / "labels.csv").read_text().splitlines()
    codes = set(io.read_labels(seg / "chair_0000.seg").tolist())
    assert codes <= set(range(1, len(legend)))


@pytest.mark.shared
def test_coseg_chairs_accuracy(shared_data, tmp_path):
    """The figure of docs/results.md: with default flags (no axes declared, no refinement) the
    bundled chair labels 94.4% of the COSEG chairs' faces (98.2% of their surface) right under the
    paper's protocol and with its stored names (both label conventions: large_chairs 1 back,
    2 seat, 3 legs; chairs_101-120 1 legs, 2 seat, 3 back). The run is deterministic (measured
    again here: 0.9439 and 0.9820); the bounds allow 0.01, one chair in ten losing a tenth of its
    faces."""
    root = shared_data / "coseg_chairs"
    seg = segmentation.Segmenter("chair")
    files = sorted(root.glob("*/shapes/*.off"))
    segs, errors = seg.segment_files(files, cache_dir=tmp_path, workers=1, progress=False)
    assert not errors and len(segs) == len(files) >= 10
    names, truths = [], []
    for s in segs:
        p = Path(s.source)
        conv = "back,seat,legs/base" if p.parent.parent.name == "large_chairs" else "legs/base,seat,back"
        truths.append(segmentation.read_ground_truth(p.parent.parent / "gt" / f"{p.stem}.seg", len(s.faces), conv, names))
    report = segmentation.evaluate(segs, truths, part_names=seg.part_names)
    paper = report.protocols["collection-majority"]
    assert paper.mean_area >= 0.982 - 0.01 and paper.mean_faces >= 0.944 - 0.01
    assert report.protocols["model-names"].mean_faces >= 0.944 - 0.01

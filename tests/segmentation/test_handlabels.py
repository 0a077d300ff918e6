"""Hand labelling without a GUI (primkit.segmentation.handlabels): naming a cuboid's elements, the
brush, undo, and the files name-parts reads, checked against brute-force sets and file contents."""

import json

import numpy as np
import pytest

from primkit import io
from primkit.segmentation.evaluation import read_ground_truth, read_point_truth
from primkit.segmentation.handlabels import HandLabels, names_path, read_label_names


def _plate(n, z, offset=0):
    """An n x n grid of unit-square cells (two triangles each) at height z, spanning [0, 1]^2."""
    t = np.linspace(0, 1, n + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]) + offset
    return v, f


@pytest.fixture()
def plates():
    """Two parallel plates 0.02 apart (not connected): a brush on one must not reach the other."""
    v0, f0 = _plate(20, 0.0)
    v1, f1 = _plate(20, 0.02, offset=len(v0))
    v, f = np.vstack([v0, v1]), np.vstack([f0, f1])
    parts = np.repeat([0, 1], [len(f0), len(f1)])
    return v, f, parts


def test_assign_part_undo_and_codes(plates):
    v, f, parts = plates
    h = HandLabels.for_mesh(v, f, parts)
    assert h.assign_part(1, "top") == (parts == 1).sum()
    assert h.assign_part(0, "bottom") == (parts == 0).sum()
    assert h.assign_part(0, "bottom") == 0  # nothing changes: no step
    np.testing.assert_array_equal(h.codes, np.where(parts == 1, 1, 2))
    assert h.counts() == {"top": int((parts == 1).sum()), "bottom": int((parts == 0).sum())}
    assert h.undo() and np.all(h.codes[parts == 0] == 0) and np.all(h.codes[parts == 1] == 1)
    assert h.undo() and not h.codes.any() and not h.undo()
    h.assign_part(0, "bottom")  # "top" no longer used: saved codes renumber from 1
    codes, used = h.saved_codes()
    assert used == ["bottom"] and set(codes.tolist()) == {0, 1}
    with pytest.raises(ValueError, match="empty"):
        h.assign_part(1, "  ")


def test_brush_stays_on_its_own_surface(plates):
    v, f, parts = plates
    h = HandLabels.for_mesh(v, f, parts)
    centroids = v[f].mean(axis=1)
    centre, radius = np.array([0.5, 0.5, 0.02]), 0.2
    start = int(np.flatnonzero(parts == 1)[np.argmin(np.linalg.norm(centroids[parts == 1] - centre, axis=1))])
    got = h.brush(centre, radius, start)
    # brute force: the top plate's faces whose centroid is in the ball (the plate is convex: all reachable)
    want = np.flatnonzero((parts == 1) & (np.linalg.norm(centroids - centre, axis=1) <= radius))
    np.testing.assert_array_equal(got, want)
    ball = np.flatnonzero(np.linalg.norm(centroids - centre, axis=1) <= radius)
    assert len(ball) > len(want)  # the ball itself reaches the bottom plate too
    np.testing.assert_array_equal(h.brush(centre, radius), ball)  # no start: the whole ball
    assert h.paint(centre, radius, "top", start) == len(want)
    assert h.undo() and not h.codes.any()


def test_point_cloud_brush_is_euclidean():
    rng = np.random.default_rng(0)
    pts = rng.random((500, 3))
    h = HandLabels(pts, np.zeros(500, int))
    c = np.array([0.3, 0.4, 0.5])
    np.testing.assert_array_equal(h.brush(c, 0.25), np.flatnonzero(((pts - c) ** 2).sum(1) <= 0.25 ** 2))


def test_save_writes_seg_and_names_and_never_overwrites(tmp_path, plates):
    v, f, parts = plates
    h = HandLabels.for_mesh(v, f, parts)
    with pytest.raises(ValueError, match="nothing is labelled"):
        h.save(tmp_path / "plates.seg")
    h.assign_part(1, "top")
    seg, meta = h.save(tmp_path / "plates.seg", source="plates.ply")
    assert meta == tmp_path / "plates.names.json" == names_path(seg)
    np.testing.assert_array_equal(io.read_labels(seg, len(f)), np.where(parts == 1, 1, 0))
    doc = json.loads(meta.read_text())
    assert doc["names"] == {"1": "top"} and doc["format_version"] == 1 and doc["source"] == "plates.ply"
    h.assign_part(0, "bottom")
    h.save(seg)  # its own file: replaced
    truth = read_ground_truth(seg, len(f))  # no names given: the names file says what 1 and 2 mean
    assert truth.names == ["top", "bottom"]
    np.testing.assert_array_equal(truth.labels, np.where(parts == 1, 0, 1))
    other = HandLabels.for_mesh(v, f, parts)
    other.assign_part(0, "x")
    with pytest.raises(FileExistsError, match="plates.seg"):
        other.save(seg)
    other.save(seg, overwrite=True)
    assert read_label_names(seg) == {1: "x"}
    # an unlabelled face (0) has no name: it stays out of the learning
    assert np.all(read_ground_truth(seg, len(f)).labels[parts == 1] == -1)


def test_point_labels_and_bad_names_file(tmp_path):
    pts = np.random.default_rng(1).random((50, 3))
    h = HandLabels(pts, (pts[:, 0] > 0.5).astype(int))
    h.assign_part(1, "front")
    path, meta = h.save(tmp_path / "cloud.labels.npy")
    assert meta.name == "cloud.names.json"
    names = []
    codes = read_point_truth(path, 50, None, names)
    assert names == ["front"] and np.array_equal(codes, np.where(pts[:, 0] > 0.5, 0, -1))
    meta.write_text("{not json")
    with pytest.raises(ValueError, match="cloud.names.json"):
        read_label_names(path)
    with pytest.raises(ValueError, match="<stem>.seg"):
        h.save(tmp_path / "cloud.txt")


def test_load_goes_on_from_a_saved_file(tmp_path, plates):
    v, f, parts = plates
    h = HandLabels.for_mesh(v, f, parts)
    h.assign_part(1, "top")
    h.paint([0.5, 0.5, 0.0], 0.2, "middle", start=int(np.argmin(np.linalg.norm(h.points - [0.5, 0.5, 0], axis=1))))
    seg, _ = h.save(tmp_path / "plates.seg")
    again = HandLabels.for_mesh(v, f, parts).load(seg)
    assert again.names == h.used_names()
    np.testing.assert_array_equal(again.saved_codes()[0], h.saved_codes()[0])
    assert again.undo() and not again.codes.any()  # loading is one step
    # without a names file each value is its own name; 0 stays unlabelled
    io.write_labels(tmp_path / "raw.seg", np.where(parts == 1, 7, 0))
    raw = HandLabels.for_mesh(v, f, parts).load(tmp_path / "raw.seg")
    assert raw.names == ["7"] and raw.counts() == {"7": int((parts == 1).sum())}
    with pytest.raises(ValueError, match="faces"):
        HandLabels.for_mesh(v[:-3], f[:10], parts[:10]).load(seg)


def test_start_from_a_guess(plates):
    v, f, parts = plates
    h = HandLabels.for_mesh(v, f, parts)
    guess = np.where(parts == 1, 0, -1)
    guess[:5] = 2  # a name given as None: unlabelled
    h.start_from(guess, ["top", "unused", None])
    assert h.counts() == {"top": int((parts == 1).sum())} and h.names == ["top", "unused"]
    assert h.undo() and not h.codes.any()
    with pytest.raises(ValueError, match="one per element"):
        h.start_from(guess[:-1], ["top"])


def test_names_file_of_upper_case_and_other_files(tmp_path):
    assert names_path(tmp_path / "Chair.SEG") == tmp_path / "Chair.names.json"
    assert read_label_names(tmp_path / "chair.txt") is None

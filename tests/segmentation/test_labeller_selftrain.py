"""Self-training a labeller with unlabelled shapes (primkit.segmentation.selftrain): the
pseudo-labels against a direct computation, the refit against Labeller.fit on the labelled and
pseudo-labelled shapes, determinism, and name-parts --unlabelled end to end."""

from __future__ import annotations

import numpy as np
import pytest

from primkit import primitives
from primkit.segmentation.labeller import Labeller, LabellerSettings, frame_features
from primkit.segmentation.selftrain import SelfTraining, UnlabelledShape, fit_self_trained, pseudo_labels

pytest.importorskip("sklearn.ensemble")

SETTINGS = LabellerSettings(neighbours=0, normals=False, smooth=1, smooth_neighbours=5, profile=False, min_share=0.0)
NAMES = ["a", "b", "c"]


def _shape(rng, n):
    """Random cuboids and points; a point's label: which side of cuboid 0 it lies on, or cuboid 1's."""
    q = rng.normal(size=(5, 4))
    c = primitives.Cuboids(rng.uniform(0.05, 0.3, (5, 3)), q, rng.uniform(-0.4, 0.4, (5, 3)), np.ones(5, bool))
    points = rng.uniform(-0.5, 0.5, (n, 3))
    local = primitives.world_to_local(points, c)
    y = np.minimum(np.where(local[0, :, 0] > 0, 0, 1) + 2 * (primitives.assign_points(points, c) == 1), 2)
    return frame_features(points, c, None, SETTINGS), y, points


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(5)
    labelled = [_shape(rng, 80) for _ in range(2)]
    pool = [_shape(rng, 150) for _ in range(4)]
    return [(X, y) for X, y, _ in labelled], [UnlabelledShape(X, p) for X, _, p in pool]


def test_pseudo_labels_are_the_sure_smoothed_labels(problem):
    labelled, pool = problem
    labeller = Labeller.fit(labelled, NAMES, 5, settings=SETTINGS, max_iter=10)
    sure_counts = []
    for threshold in (0.95, 0.7):
        sure_counts.append(0)
        for shape in pool:
            got = pseudo_labels(labeller, shape, threshold, NAMES)
            # by hand: the classifier's probabilities averaged over the 5 nearest points (brute force)
            proba = labeller.classify(shape.features)
            d = np.linalg.norm(shape.points[:, None] - shape.points[None], axis=2)
            near = np.argsort(d, axis=1, kind="stable")[:, :5]
            smoothed = proba[near].mean(axis=1)
            sure = smoothed.max(axis=1) >= threshold
            want = np.where(sure, np.array([NAMES.index(k) for k in labeller.names])[smoothed.argmax(axis=1)], -1)
            assert np.array_equal(got, want)
            sure_counts[-1] += np.count_nonzero(got >= 0)
    assert sure_counts[0] < sure_counts[1] < sum(len(s.points) for s in pool)  # some sure, some not


def test_self_training_learns_again_from_the_pseudo_labels(problem):
    """One round: the labeller is Labeller.fit on the labelled shapes and the pseudo-labelled ones
    (weighing ``weight``), with the labelled shapes' prior and prior weight; zero rounds: Labeller.fit."""
    labelled, pool = problem
    how = SelfTraining(rounds=1, threshold=0.8, weight=0.5)
    got = fit_self_trained(labelled, pool, NAMES, 5, self_training=how, settings=SETTINGS, max_iter=10, seed=3)
    settings = LabellerSettings(**{**SETTINGS.to_dict(), "prior_weight": 0.4})  # min(0.4, 4 / 2 labelled shapes)
    first = Labeller.fit(labelled, NAMES, 5, settings=settings, max_iter=10, seed=3)
    pseudo = [(s.features, pseudo_labels(first, s, 0.8, NAMES), 0.5) for s in pool]
    want = Labeller.fit(labelled + pseudo, NAMES, 5, settings=settings, max_iter=10, seed=3)
    X = np.vstack([s.features for s in pool])
    np.testing.assert_array_equal(got.ensemble.predict_proba(X), want.ensemble.predict_proba(X))
    np.testing.assert_array_equal(got.prior, first.prior)
    assert got.settings.prior_weight == 0.4
    assert got.info["self_training"] == {**how.to_dict(), "unlabelled_shapes": 4,
                                         "pseudo_labelled_elements": int(sum(np.sum(y >= 0) for _, y, _ in pseudo))}
    assert got.info["labelled_shapes"] == 2 and got.info["shapes"] == 6
    # the pseudo-labelled shapes change the trees (the test can fail), and the same seed the same trees
    assert not np.array_equal(got.ensemble.predict_proba(X), first.ensemble.predict_proba(X))
    again = fit_self_trained(labelled, pool, NAMES, 5, self_training=how, settings=SETTINGS, max_iter=10, seed=3)
    for k, v in got.ensemble.arrays().items():
        np.testing.assert_array_equal(v, again.ensemble.arrays()[k])
    none = fit_self_trained(labelled, pool, NAMES, 5, self_training=SelfTraining(rounds=0), settings=SETTINGS,
                            max_iter=10, seed=3)
    np.testing.assert_array_equal(none.ensemble.predict_proba(X), first.ensemble.predict_proba(X))


def test_a_shape_weight_scales_its_share_of_the_prior():
    """Labeller.fit's optional third item: a shape weighing w counts w in the index prior."""
    rng = np.random.default_rng(2)
    a, b = _shape(rng, 60), _shape(rng, 60)
    settings = LabellerSettings(**{**SETTINGS.to_dict(), "prior_weight": 0.1})
    got = Labeller.fit([(a[0], a[1]), (b[0], b[1], 0.25)], NAMES, 5, settings=settings, max_iter=5)
    counts = np.zeros((5, 3))
    for (X, y, _), w in ((a, 1.0), (b, 0.25)):
        np.add.at(counts, (np.argmax(X[:, 3:8], axis=1), y), w / len(y))
    rows = counts.sum(axis=1, keepdims=True)
    want = np.where(rows > 0, counts / np.maximum(rows, 1e-300), counts.sum(axis=0) / counts.sum())
    np.testing.assert_allclose(got.prior, want)


@pytest.mark.parametrize("bad", [{"rounds": -1}, {"threshold": 0.0}, {"weight": 1.5}])
def test_bad_self_training_settings_are_refused(bad):
    with pytest.raises(ValueError):
        SelfTraining(**bad)


@pytest.mark.integration  # name-parts abstracts five procedural chairs and learns twice
def test_name_parts_learns_from_unlabelled_shapes(chairs, tmp_path):
    from primkit import io
    from primkit.cli import main
    from primkit.segmentation import labeller as lab

    labelled, unlabelled = tmp_path / "labelled", tmp_path / "unlabelled"
    labelled.mkdir()
    unlabelled.mkdir()
    for i, s in enumerate(chairs[:5]):
        folder = labelled if i < 2 else unlabelled
        io.write_mesh(folder / f"c{i}.ply", s.vertices, s.faces)
        if i < 2:
            (folder / f"c{i}.seg").write_text("\n".join(str(k + 1) for k in s.face_labels) + "\n")
    names = ",".join(chairs[0].part_names)
    out = tmp_path / "named.safetensors"
    assert main(["name-parts", str(labelled), "--model", "chair", "--names", names, "-o", str(out), "--workers", "1",
                 "--refine", "0", "--unlabelled", str(unlabelled)]) == 0
    labeller = lab.read_labeller(out)
    assert labeller.info["labelled_shapes"] == 2 and labeller.info["self_training"]["unlabelled_shapes"] == 3
    assert labeller.info["self_training"]["pseudo_labelled_elements"] > 0 and "mirrored" not in labeller.info
    # the mirrors: two more labelled shapes learned from, the prior weight still that of two
    assert main(["name-parts", str(labelled), "--model", "chair", "--names", names, "-o", str(out), "--workers", "1",
                 "--refine", "0", "--mirror", "--force"]) == 0
    labeller = lab.read_labeller(out)
    assert labeller.info["mirrored"] == 2 and labeller.info["shapes"] == 4 and labeller.info["labelled_shapes"] == 2
    assert labeller.settings.prior_weight == 0.4 and "self_training" not in labeller.info


def _frame(rotation, centre=(0.0, 0.0, 0.0)):
    from primkit.geometry import CanonicalFrame

    return CanonicalFrame(np.asarray(rotation, float), np.asarray(centre, float), 1.0)


def test_a_mirrored_grid_carries_each_voxels_label_to_its_mirror():
    from primkit import io
    from primkit.segmentation.mirror import mirror_shape

    rng = np.random.default_rng(4)
    occupancy = rng.random((8, 8, 8)) < 0.4
    grid = io.VoxelGrid(occupancy, np.zeros(3), 1.0)
    index = np.argwhere(occupancy)
    labels = rng.integers(0, 4, len(index))
    # canonical z is input x here (a quarter turn about y): the grid is flipped along axis 0
    turn = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]
    for rotation, axis in (([[1, 0, 0], [0, 1, 0], [0, 0, 1]], 2), (turn, 0)):
        mirrored, order = mirror_shape(grid, _frame(rotation))
        new = np.argwhere(mirrored.occupancy)
        assert len(new) == len(index)
        for v, k in zip(new, order):  # by hand: voxel v is the mirror of voxel index[k]
            w = v.copy()
            w[axis] = occupancy.shape[axis] - 1 - v[axis]
            assert np.array_equal(index[k], w)
        carried = labels[order]
        back, order2 = mirror_shape(mirrored, _frame(rotation))
        assert np.array_equal(back.occupancy, occupancy) and np.array_equal(carried[order2], labels)


def test_a_mirrored_mesh_is_reflected_across_the_canonical_middle_plane():
    from primkit import io
    from primkit.segmentation.mirror import mirror_shape

    rng = np.random.default_rng(6)
    vertices = rng.normal(size=(30, 3))
    faces = rng.integers(0, 30, (40, 3))
    angle = 0.3
    rotation = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    frame = _frame(rotation, (0.1, -0.2, 0.25))
    mirrored, order = mirror_shape(io.Mesh(vertices, faces), frame)
    assert np.array_equal(order, np.arange(40)) and np.array_equal(mirrored.faces, faces[:, ::-1])
    # in the canonical frame the mirror negates z and keeps x and y
    a, b = frame.to_canonical(vertices), frame.to_canonical(mirrored.vertices)
    np.testing.assert_allclose(b, a * [1, 1, -1], atol=1e-12)
    # face normals stay outward: the mirrored face's normal is the original's mirrored
    def normals(v, f):
        return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])

    n0 = normals(a, faces)
    n1 = normals(b, mirrored.faces)
    np.testing.assert_allclose(n1, n0 * [1, 1, -1], atol=1e-9)


def test_a_mirrored_cloud_keeps_its_points_order_and_mirrors_its_normals():
    from primkit import io
    from primkit.segmentation.mirror import mirror_shape

    rng = np.random.default_rng(8)
    points = rng.normal(size=(50, 3))
    normals = rng.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    frame = _frame([[0, 0, -1], [0, 1, 0], [1, 0, 0]], (0.0, 0.0, 0.3))  # canonical z = input x, middle at x = 0.3
    mirrored, order = mirror_shape(io.PointCloud(points, normals), frame)
    assert np.array_equal(order, np.arange(50))
    np.testing.assert_allclose(mirrored.points, np.c_[0.6 - points[:, 0], points[:, 1:]], atol=1e-12)
    np.testing.assert_allclose(mirrored.normals, normals * [-1, 1, 1], atol=1e-12)

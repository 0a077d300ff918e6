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
    assert labeller.info["self_training"]["pseudo_labelled_elements"] > 0

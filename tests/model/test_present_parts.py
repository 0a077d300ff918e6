"""Present parts have a size: :func:`primkit.model.abstractor.drop_unsized_parts` and the predictions
of the bundled chair model, checked against a plain per-part distance loop."""

import numpy as np
import pytest

from primkit import data, io, primitives, synthetic
from primkit.model.abstraction import abstract_shapes
from primkit.model.abstractor import MIN_EXTENT, Abstractor, drop_unsized_parts
from primkit.primitives.rotations import quaternion_to_matrix


def brute_distances(points, cuboids):
    """(n, m) distance from each point to each present box (inf for absent ones), one box at a time
    from its quaternion: the norm of the excess of the point's local coordinates over the half extents."""
    out = np.full((len(points), cuboids.count), np.inf)
    for k in cuboids.present:
        rot = quaternion_to_matrix(cuboids.quaternions[k])
        local = (points - cuboids.translations[k]) @ rot  # rows: rot.T @ (p - t)
        out[:, k] = np.linalg.norm(np.maximum(np.abs(local) - cuboids.half_extents[k], 0.0), axis=1)
    return out


def unsized_present(cuboids, points, min_extent=MIN_EXTENT):
    """Present parts whose longest side is under ``min_extent`` or that are strictly the nearest
    present part of no point (a part that only ties for a point counts as owning it)."""
    d = brute_distances(points, cuboids)
    best = d.min(axis=1, keepdims=True)
    owns = np.any(d <= best + 1e-12, axis=0)
    bad = []
    for k in cuboids.present:
        if 2.0 * np.max(cuboids.half_extents[k]) < min_extent or not owns[k]:
            bad.append(int(k))
    return bad


@pytest.fixture(scope="module")
def chairs():
    shapes = synthetic.generate("chair", 6, seed=321)
    return [data.prepare(io.Mesh(s.vertices, s.faces), name=f"c{i}") for i, s in enumerate(shapes)]


@pytest.fixture(scope="module")
def model():
    return Abstractor.load("chair")


@pytest.mark.integration  # the bundled models over generated collections: several seconds, left to the default suite
def test_predicted_present_parts_have_a_size(model, chairs):
    before = model.predict(chairs, align="auto", min_extent=None)
    after = model.predict(chairs, align="auto")
    found_before = 0
    for b, a, shape in zip(before, after, chairs):
        points = a.canonical_shape(shape).points[::10]  # brute force on every tenth sample
        assert unsized_present(a.canonical, points) == [], a.name
        # only existence and the grown parts' boxes change; no part appears
        assert not np.any(a.canonical.existence & ~b.canonical.existence)
        found_before += len(unsized_present(b.canonical, points))
    assert found_before > 0  # the bundled model does predict parts without a size: the rule has work


def test_the_rule_against_brute_force_on_random_boxes():
    rng = np.random.default_rng(5)
    for trial in range(20):
        m = 8
        half = rng.uniform(0.02, 0.2, (m, 3))
        half[rng.random(m) < 0.4] *= 1e-5  # degenerate parts: points
        q = rng.normal(size=(m, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        c = primitives.Cuboids(half, q, rng.uniform(-0.5, 0.5, (m, 3)), rng.random(m) < 0.8)
        points = rng.uniform(-0.6, 0.6, (150, 3))
        for grow in (False, True):
            out = drop_unsized_parts(c, points, grow=grow)
            assert not np.any(out.existence & ~c.existence)
            if not c.existence.any():
                assert not out.existence.any()
                continue
            assert out.existence.any()
            assert unsized_present(out, points) == [], (trial, grow)
            if not grow:  # without growing, every box is as given and every sized owner is kept
                assert np.allclose(out.half_extents, c.half_extents)
                sized = c.with_existence(c.existence & (2 * c.half_extents.max(1) >= MIN_EXTENT))
                if sized.existence.any():
                    d = brute_distances(points, sized)
                    owners = set(np.flatnonzero(np.any(d <= d.min(1, keepdims=True) + 1e-12, axis=0)).tolist())
                    assert set(out.present.tolist()) <= owners


def test_a_grown_part_is_the_box_of_its_points():
    # a sized seat and a point-sized part among four leg-like points below it
    half = np.array([[0.3, 0.02, 0.3], [1e-6, 1e-6, 1e-6]])
    q = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    t = np.array([[0.0, 0.5, 0.0], [0.2, -0.3, 0.1]])
    c = primitives.Cuboids(half, q, t, np.array([True, True]))
    points = np.array([[0.0, 0.52, 0.0], [0.18, -0.4, 0.1], [0.22, -0.2, 0.12], [0.2, -0.3, 0.08]])
    out = drop_unsized_parts(c, points)
    assert out.existence.tolist() == [True, True]
    assert np.allclose(out.translations[1], [0.2, -0.3, 0.1])
    assert np.allclose(out.half_extents[1], [0.02, 0.1, 0.02])
    assert np.allclose(out.half_extents[0], half[0]) and np.allclose(out.translations[0], t[0])
    # without growing it has no size and goes
    assert drop_unsized_parts(c, points, grow=False).existence.tolist() == [True, False]


def test_a_shape_keeps_its_longest_part_when_none_has_a_size():
    half = np.array([[0.001, 1e-6, 1e-6], [0.004, 1e-6, 1e-6]])
    c = primitives.Cuboids(half, np.tile([1.0, 0, 0, 0], (2, 1)), np.zeros((2, 3)), np.array([True, True]))
    out = drop_unsized_parts(c, np.zeros((0, 3)))
    assert out.existence.tolist() == [False, True]


def test_abstract_shapes_and_json_count_only_sized_parts(model, chairs):
    """Through the one way in (points given in memory, input frame), the JSON's present parts are
    the sized ones: the longest side times the frame's scale is the canonical longest side."""
    out = abstract_shapes([s.points * 3.0 + 1.0 for s in chairs[:2]], model, progress=False, workers=1)
    for a in out:
        d = a.result.to_dict()
        present = [p for p in d["parts"] if p["present"]]
        assert [p["index"] for p in present] == a.cuboids.present.tolist() == a.canonical.present.tolist()
        assert 0 < len(present) < a.cuboids.count
        scale = a.result.frame.scale
        assert all(2 * max(p["half_extents"]) * scale >= MIN_EXTENT for p in present)
        assert unsized_present(a.canonical, a.canonical_shape().points[::10]) == []

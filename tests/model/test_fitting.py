import numpy as np
import pytest
import trimesh

from primkit import data, io, primitives
from primkit.model.fitting import fit_losses, refine


@pytest.fixture(scope="module")
def box_shape():
    """A box of half-extents (0.5, 0.3, 0.2) rotated about Y, as a prepared mesh shape."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    return data.prepare(io.Mesh(np.asarray(box.vertices), np.asarray(box.faces)), name="box")


def _box(half, t=(0, 0, 0), present=True):
    return primitives.Cuboids(np.array([half]), np.array([[1.0, 0, 0, 0]]), np.array([t], float), np.array([present]))


def test_the_exact_box_has_near_zero_losses_and_worse_boxes_more(box_shape):
    exact = _box((0.5, 0.3, 0.2))
    small = _box((0.35, 0.2, 0.15))
    moved = _box((0.5, 0.3, 0.2), t=(0.1, 0.0, 0.0))
    out = fit_losses([exact, small, moved], [box_shape] * 3)
    # coverage of the exact box is zero up to float32 (every surface point is on it)
    assert out.coverage[0] < 1e-10
    # consistency goes through the closest-point grid: bounded by the grid's spacing, not zero
    assert out.consistency[0] < (1 / 32) ** 2
    assert out.total[1] > 10 * out.total[0] and out.total[2] > 10 * out.total[0]
    # coverage of the small box against brute force: squared distance of the samples to the box
    d = primitives.point_cuboid_distance(box_shape.points, small)[:, 0]
    assert abs(out.coverage[1] - np.mean(d**2)) < 0.05 * np.mean(d**2)


def test_refine_recovers_the_box_and_keeps_slots(box_shape):
    start = primitives.Cuboids(
        np.array([[0.3, 0.2, 0.3], [0.1, 0.1, 0.1]]),
        np.array([[np.cos(0.15), 0, np.sin(0.15), 0], [1.0, 0, 0, 0]]),
        np.array([[0.08, -0.05, 0.02], [0.3, 0.3, 0.3]]),
        np.array([True, False]),
    )
    refined = refine([start], [box_shape], steps=300, seed=1)
    (out,) = refined.cuboids
    assert refined.loss_after[0] < 0.1 * refined.loss_before[0]
    assert np.allclose(out.half_extents[0], [0.5, 0.3, 0.2], atol=0.03)
    assert np.allclose(out.translations[0], 0.0, atol=0.03)
    # absent slot untouched, existence unchanged
    assert np.array_equal(out.existence, start.existence)
    assert np.array_equal(out.half_extents[1], start.half_extents[1])
    assert np.array_equal(out.translations[1], start.translations[1])


def test_refine_zero_steps_returns_the_input(box_shape):
    start = _box((0.4, 0.3, 0.2))
    refined = refine([start], [box_shape], steps=0)
    (out,) = refined.cuboids
    assert out is start and refined.loss_before[0] == refined.loss_after[0]


def test_losses_of_sets_are_fit_losses_of_the_list_bit_for_bit():
    """fit_losses_of_sets (each shape's grid read once, the present parts only) against fit_losses
    on the flattened list with every shape repeated: equal, bit for bit, including a set with no
    present part (scored on all its parts) and a shape whose sets are all empty."""
    from primkit import synthetic
    from primkit.model import fitting

    made = synthetic.generate("chair", 3, seed=11)
    shapes = [data.prepare(io.Mesh(s.vertices, s.faces), name=f"c{i}") for i, s in enumerate(made)]
    rng = np.random.default_rng(1)
    s, k, m = 3, 5, 7
    z = rng.uniform(0.02, 0.3, (s, k, m, 3))
    q = rng.normal(size=(s, k, m, 4))
    t = rng.uniform(-0.4, 0.4, (s, k, m, 3))
    e = rng.uniform(size=(s, k, m)) < 0.5
    e[0, 1] = False
    e[1, 2] = True
    e[2] = False
    cubs = [primitives.Cuboids(z[i, j], q[i, j], t[i, j], e[i, j]) for i in range(s) for j in range(k)]
    unit = np.stack([c.quaternions for c in cubs]).reshape(s, k, m, 4)
    ref = fit_losses(cubs, [sh for sh in shapes for _ in range(k)], points=0, samples_per_cuboid=60, seed=3)
    for compiled in (True, False):  # the kernels on present parts, and the torch forms
        if not compiled:
            fitting.kernels, saved = (lambda *a, **kw: None), fitting.kernels
        try:
            got = fitting.fit_losses_of_sets(z, unit, t, e, shapes, samples_per_cuboid=60, seed=3)
        finally:
            if not compiled:
                fitting.kernels = saved
        for name in ("coverage", "consistency", "total"):
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name).reshape(s, k), err_msg=name)
    draws = {}  # the random coefficients kept by the caller: read back, a smaller call's as the first rows
    for _ in range(2):
        got = fitting.fit_losses_of_sets(z, unit, t, e, shapes, samples_per_cuboid=60, seed=3, draws=draws)
        np.testing.assert_array_equal(got.total, ref.total.reshape(s, k))
    small = fit_losses(cubs[:2 * k], [sh for sh in shapes[:2] for _ in range(k)], points=0, samples_per_cuboid=60,
                       seed=3)
    got = fitting.fit_losses_of_sets(z[:2], unit[:2], t[:2], e[:2], shapes[:2], samples_per_cuboid=60, seed=3,
                                     draws=draws)
    np.testing.assert_array_equal(got.total, small.total.reshape(2, k))
    assert len(draws) == 1 and len(next(iter(draws.values()))) == s * k
    assert np.all(ref.total.reshape(s, k)[2] > 50)  # no part at all: the absence term, as fit_losses has it

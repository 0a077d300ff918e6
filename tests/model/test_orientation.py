import numpy as np
import pytest

from primkit import geometry
from primkit.model import orientation


def test_the_24_rotations_are_distinct_proper_axis_rotations():
    r = orientation.AXIS_ROTATIONS
    assert r.shape == (24, 3, 3)
    assert np.allclose(r[0], np.eye(3))
    for a in r:
        assert np.allclose(a @ a.T, np.eye(3)) and np.isclose(np.linalg.det(a), 1.0)
        assert set(np.abs(a).ravel()) == {0.0, 1.0}
    assert len({tuple(a.ravel()) for a in r}) == 24
    # closed under composition: a group
    keys = {tuple(a.ravel()) for a in r}
    for a in r[::5]:
        for b in r[::7]:
            assert tuple((a @ b).ravel()) in keys


def test_describe_rotation_names_the_input_axes():
    rot = geometry.axis_rotation("+z", "-y")
    assert orientation.describe_rotation(rot) == {"up": "+z", "front": "-y"}


@pytest.mark.parametrize("which", [3, 11, 20])
def test_rotated_shape_matches_preparing_the_rotated_mesh(prepared_chairs, chairs, which):
    """Turning prepared arrays must give what a preparation of the turned mesh gives: the exact
    distances near the surface, within the far cells' declared 3e-3 of them (never nearer) beyond."""
    shape, mesh = prepared_chairs[0], chairs[0]
    a = orientation.AXIS_ROTATIONS[which]
    turned = orientation.rotate_prepared(shape, a)
    v = turned.frame.to_canonical(mesh.vertices)  # the input mesh in the turned canonical frame
    assert np.allclose(v, shape.frame.to_canonical(mesh.vertices) @ a.T)
    reference = geometry.distance_grid(v, mesh.faces, shape.resolution, exact_within=None)
    dist = np.linalg.norm(turned.closest - geometry.grid_centres(shape.resolution), axis=-1)
    error = dist - reference.distance
    assert error.min() > -1e-5 and error.max() < 3e-3
    from scipy import ndimage

    near = ndimage.distance_transform_edt(~geometry.surface_voxels(v, mesh.faces, shape.resolution)) <= 2
    assert np.abs(error[near]).max() < 1e-5
    solid = geometry.occupancy_grid(v, mesh.faces, shape.resolution)
    assert (solid == turned.solid).mean() > 0.999
    # samples stay on the surface: their distance to the exact grid's nearest cell point is tiny
    assert np.allclose(turned.points, shape.points @ a.T)


def test_identity_is_a_no_op_and_non_axis_rotations_are_refused(prepared_chairs):
    s = prepared_chairs[0]
    assert orientation.rotate_prepared(s, np.eye(3)) is s
    c, d = np.cos(0.3), np.sin(0.3)
    with pytest.raises(ValueError):
        orientation.rotate_prepared(s, [[c, -d, 0], [d, c, 0], [0, 0, 1]])
    with pytest.raises(ValueError):
        orientation.rotate_prepared(s, np.diag([1.0, 1.0, -1.0]))  # a mirror


def test_upright_turns_are_the_four_that_keep_y():
    up = orientation.AXIS_ROTATIONS[orientation.UPRIGHT]
    assert len(up) == 4 and np.allclose(up[:, 1], [0, 1, 0])
    assert orientation.UPRIGHT[0]  # the identity
    assert list(orientation.candidate_rotations("front")) == list(np.flatnonzero(orientation.UPRIGHT))
    assert len(orientation.candidate_rotations("auto")) == 24 and orientation.candidate_rotations("none").tolist() == [0]


def test_auto_keeps_the_shape_upright_unless_another_up_axis_is_clearly_better():
    cands = np.arange(24)
    losses = np.full(24, 1.0)
    up = np.flatnonzero(orientation.UPRIGHT)
    losses[up[2]] = 0.8                      # best upright turn
    other = int(np.flatnonzero(~orientation.UPRIGHT)[5])
    losses[other] = 0.7                      # better, but not by the margin (0.7 * 0.8 = 0.56)
    assert orientation.choose_orientation(losses, cands, "auto") == up[2]
    assert orientation.choose_orientation(losses, cands, "any") == other
    losses[other] = 0.5                      # clearly lying down: another up axis wins
    assert orientation.choose_orientation(losses, cands, "auto") == other
    assert orientation.choose_orientation(losses[up], up, "front") == up[2]


def test_resolve_align_follows_what_was_declared():
    assert orientation.resolve_align() == "auto"
    assert orientation.resolve_align(up="+z") == "front"
    assert orientation.resolve_align(up="+z", front="-x") == "none"
    assert orientation.resolve_align(up="auto", front="auto") == "auto"
    assert orientation.resolve_align("any", up="+z", front="+x") == "any"
    with pytest.raises(ValueError):
        orientation.resolve_align("sideways")

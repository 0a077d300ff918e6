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
    assert orientation.describe_rotation(rot) == orientation.FrameAxes(up="+z", front="-y")


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


# ---- the default frame search (issue 32) -------------------------------------------------------


@pytest.fixture(scope="module")
def chair_model_for_frames():
    from primkit.model.abstractor import Abstractor

    return Abstractor.load("chair")


@pytest.fixture(scope="module")
def procedural_prepared():
    from primkit import data, io, synthetic

    shapes = synthetic.generate("chair", 6, seed=123)
    return [data.prepare(io.Mesh(s.vertices, s.faces), name=f"c{i}") for i, s in enumerate(shapes)]


def test_auto_keeps_the_expected_up_unless_another_cuts_the_loss_by_the_margin():
    rot = orientation.AXIS_ROTATIONS
    everything = np.arange(24)
    up_z = np.flatnonzero(np.all(np.isclose(rot[:, 1], [0.0, 0.0, 1.0]), axis=1))
    losses = np.ones(24)
    losses[up_z[2]] = 0.75  # +Z up a little better than every +Y turn: kept +Y (a stool on its side)
    assert np.allclose(rot[orientation.choose_orientation(losses, everything, "auto")][1], [0, 1, 0])
    assert orientation.choose_orientation(losses, everything, "any") == up_z[2]
    losses[up_z[2]] = 0.65  # clearly lying down: turned
    assert orientation.choose_orientation(losses, everything, "auto") == up_z[2]
    # the expected up axis may be the collection's: then +Y must cut the loss by the margin
    losses = np.ones(24)
    losses[0] = 0.75  # identity (+Y up) a little better than every +Z-up turn
    assert orientation.choose_orientation(losses, everything, "auto", up=(0.0, 0.0, 1.0)) in up_z
    losses[0] = 0.65
    assert orientation.choose_orientation(losses, everything, "auto", up=(0.0, 0.0, 1.0)) == 0


@pytest.mark.integration  # 24 turns scored over a collection: several seconds, left to the default suite
def test_a_chair_lying_down_among_upright_ones_is_stood_up(chair_model_for_frames, procedural_prepared):
    """The collection's up axis is expected, not imposed: one chair of six on its side is found."""
    shapes = list(procedural_prepared)
    lying = orientation.AXIS_ROTATIONS[7]
    assert not np.allclose(lying[1], [0, 1, 0])
    shapes[2] = orientation.rotate_prepared(shapes[2], lying)
    results = chair_model_for_frames.predict(shapes, align="auto")
    ups = [r.frame.rotation[1] for r in results]
    originals = [s.frame.rotation[1] for s in procedural_prepared]
    assert np.allclose(ups[2], originals[2])  # canonical Y of the result is the original's Y
    assert sum(np.allclose(u, o) for u, o in zip(ups, originals)) >= 5
    assert results[2].alignment.up_decided_by.startswith("shape: lying down")


def test_the_vtk_filter_takes_the_command_lines_frame_on_a_coseg_chair(shared_data, tmp_path):
    """Without axes declared the filter finds the frame as ``primkit segment`` does: the same face
    labels on a COSEG chair (+Z front, so the filter's former +X front assumption fails it)."""
    pv = pytest.importorskip("pyvista")
    from primkit import io
    from primkit.cli import main
    from vtkmodules.vtkCommonExecutionModel import vtkTrivialProducer

    from primkit.plugins.vtk_filter import PrimkitSegmentation

    path = shared_data / "coseg_chairs" / "large_chairs" / "shapes" / "13.off"
    code = main(["segment", str(path), "--model", "chair", "-o", str(tmp_path / "out"), "--workers", "1"])
    assert code == 0
    expected = io.read_labels(tmp_path / "out" / "13.seg")
    mesh = io.read_mesh(path)
    surface = pv.PolyData(mesh.vertices, np.hstack([np.full((len(mesh.faces), 1), 3), mesh.faces]).ravel())
    source = vtkTrivialProducer()
    source.SetOutput(surface)
    f = PrimkitSegmentation(Model="chair")
    f.SetInputConnection(source.GetOutputPort())
    f.Update()
    labels = np.asarray(pv.wrap(f.GetOutputDataObject(0)).cell_data["part"])
    assert np.array_equal(labels, expected)
    declared = PrimkitSegmentation(Model="chair", Up="+y", Front="+x")  # the former default: another answer
    declared.SetInputConnection(source.GetOutputPort())
    declared.Update()
    assert not np.array_equal(np.asarray(pv.wrap(declared.GetOutputDataObject(0)).cell_data["part"]), expected)


def _stool(seed: int):
    """A square seat on four round legs: symmetric enough that a chair model could explain it on a side."""
    import trimesh

    from primkit import io

    rng = np.random.default_rng(seed)
    w, h, t, r = rng.uniform(0.35, 0.45), rng.uniform(0.4, 0.6), rng.uniform(0.04, 0.07), rng.uniform(0.02, 0.03)
    move = trimesh.transformations.translation_matrix
    parts = [trimesh.creation.box((w, t, w), move((0, h + t / 2, 0)))]
    stand = trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0))
    for sx in (-1, 1):
        for sz in (-1, 1):
            parts.append(trimesh.creation.cylinder(r, h, transform=move((sx * (w / 2 - r), h / 2, sz * (w / 2 - r))) @ stand))
    m = trimesh.util.concatenate(parts)
    return io.Mesh(m.vertices, m.faces)


@pytest.mark.integration  # 24 turns scored over stools: several seconds, left to the default suite
def test_stools_are_not_laid_on_their_side(chair_model_for_frames, procedural_prepared):
    from primkit import data

    stools = [data.prepare(_stool(s), name=f"stool{s}") for s in range(2)]
    for shapes in (stools[:1], stools, list(procedural_prepared[:3]) + stools):
        for r in chair_model_for_frames.predict(shapes, align="auto"):
            assert orientation.axis_name(r.frame.rotation[1]) == "+y", r.name


def test_source_index_turns_many_grids_as_rotate_grid_turns_one():
    rng = np.random.default_rng(0)
    grids = rng.uniform(size=(3, 6, 6, 6))
    for a in orientation.AXIS_ROTATIONS[::5]:
        turned = grids.reshape(3, -1)[:, orientation.source_index(6, a)].reshape(grids.shape)
        for g, t in zip(grids, turned):
            np.testing.assert_array_equal(t, orientation.rotate_grid(g, a))


def _straightforward_losses(model, shapes, candidates, chunk=16, points=4000, samples=300):
    """The frame search's losses the plain way: each turned grid through the network alone, each
    answer turned back as a Cuboids, fit_losses on the list, ``chunk`` shapes at a time (the
    search's own order of random draws)."""
    from dataclasses import replace

    from primkit.model.fitting import fit_losses

    out = np.empty((len(shapes), len(candidates)))
    rotations = orientation.AXIS_ROTATIONS[candidates]
    rng = np.random.default_rng(0)
    for start in range(0, len(shapes), chunk):
        block = shapes[start:start + chunk]
        cubs, scored = [], []
        for s in block:
            for a in rotations:
                raw = model.predict_canonical(orientation.rotate_grid(s.occupancy, a)[None])
                cubs.append(model._cuboids(raw, 0, 0.5).transformed(a.T))
            pick = rng.choice(len(s.points), min(points, len(s.points)), replace=False)
            scored.extend([replace(s, points=s.points[pick])] * len(candidates))
        out[start:start + len(block)] = fit_losses(cubs, scored, points=0, samples_per_cuboid=samples).total.reshape(
            len(block), len(candidates))
    return out


@pytest.mark.integration  # 24 turns of 6 shapes scored twice: several seconds
def test_the_search_picks_the_turns_of_the_straightforward_evaluation(chair_model_for_frames, procedural_prepared):
    """The frame search (a shape's turns through the network together, answers turned back as
    arrays, each distance grid read once, present parts only) against the per-turn evaluation on
    procedural chairs turned into other frames: the same choice in every mode, and losses equal up
    to the network's batch rounding (a batch of 24 turns rounds differently from 24 batches of one:
    measured 5e-6 relative at most on 40 ShapeNet chairs' 960 turns; 1e-4 allowed). On the CPU,
    where the search batches a shape's turns (on CUDA it batches a chunk's, and TF32 may round more)."""
    import copy

    from primkit.model.abstractor import Abstractor

    model = Abstractor(copy.deepcopy(chair_model_for_frames.network), chair_model_for_frames.metadata, device="cpu")
    turns = [0, 7, 13, 18, 3, 22]
    shapes = [orientation.rotate_prepared(s, orientation.AXIS_ROTATIONS[a]) for s, a in zip(procedural_prepared, turns)]
    everything = np.arange(24)
    plain = _straightforward_losses(model, shapes, everything, chunk=4)
    fast = model._candidate_losses(shapes, everything, 0.5, 4)
    np.testing.assert_allclose(fast, plain, rtol=1e-4, atol=0)
    for mode in ("any", "auto"):
        assert [orientation.choose_orientation(r, everything, mode) for r in fast] == \
            [orientation.choose_orientation(r, everything, mode) for r in plain]
    # the search itself: the same choices, and each chair back to its own up axis
    found = model.search_orientations(shapes, "auto", chunk=4, answers=True)
    expected = [orientation.choose_orientation(r, everything, "auto") for r in plain]
    assert found.choice.tolist() == expected
    for s, c, report in zip(shapes, found.choice, found.reports):
        np.testing.assert_array_equal(report.rotation, orientation.AXIS_ROTATIONS[c])
    ups = [(orientation.AXIS_ROTATIONS[c] @ s.frame.rotation)[1] for c, s in zip(found.choice, shapes)]
    assert all(np.allclose(u, p.frame.rotation[1]) for u, p in zip(ups, procedural_prepared))
    # the answers are the chosen turn's forward pass: predict_canonical of the turned shape
    turned = [orientation.rotate_prepared(s, orientation.AXIS_ROTATIONS[c]) for s, c in zip(shapes, found.choice)]
    again = model.predict_canonical(np.stack([s.occupancy for s in turned]))
    for key, value in again.arrays().items():
        np.testing.assert_allclose(found.answers.arrays()[key], value, rtol=0, atol=1e-5, err_msg=key)
    front = orientation.candidate_rotations("front")
    fast, plain = model._candidate_losses(shapes, front, 0.5, 4), _straightforward_losses(model, shapes, front, chunk=4)
    np.testing.assert_allclose(fast, plain, rtol=1e-4, atol=0)
    assert [orientation.choose_orientation(r, front, "front") for r in fast] == \
        [orientation.choose_orientation(r, front, "front") for r in plain]


# ---- mirror symmetry in the default frame search ------------------------------------------------


def test_compose_index_is_the_product_of_the_rotations():
    r = orientation.AXIS_ROTATIONS
    for i in range(24):
        for j in range(24):
            assert np.array_equal(r[orientation.compose_index(i, j)], r[i] @ r[j])


def _mirror_iou_by_loops(grid, axis):
    """The mirror IoU of ``grid`` across the mid-plane normal to ``axis``, cell by cell."""
    n = grid.shape[axis]
    both = either = 0
    for idx in np.ndindex(grid.shape):
        other = list(idx)
        other[axis] = n - 1 - idx[axis]
        a, b = bool(grid[idx]), bool(grid[tuple(other)])
        both += a and b
        either += a or b
    return both / either


def test_mirror_symmetry_matches_a_cell_by_cell_count_and_turns_with_the_grid():
    rng = np.random.default_rng(4)
    grid = rng.random((6, 6, 6)) < 0.3
    grid[:, :, :3] |= grid[:, :, :2:-1]  # more symmetric across z than across x and y
    sym = orientation.mirror_symmetry(grid)
    assert np.allclose(sym, [_mirror_iou_by_loops(grid, a) for a in range(3)])
    for a in orientation.AXIS_ROTATIONS:
        assert np.allclose(orientation.mirror_symmetry(orientation.rotate_grid(grid, a)),
                           orientation.turn_symmetry(sym, a))
    assert np.allclose(orientation.mirror_symmetry(np.zeros((4, 4, 4), bool)), 1.0)


def test_auto_never_takes_a_mirror_axis_as_up():
    rot = orientation.AXIS_ROTATIONS
    everything = np.arange(24)
    up_x = np.flatnonzero(np.all(np.isclose(rot[:, 1], [1.0, 0.0, 0.0]), axis=1))
    up_y = np.flatnonzero(orientation.UPRIGHT)
    losses = np.ones(24)
    losses[up_x[1]] = 0.5  # on its side, explained far better: stood on +X without symmetry ...
    assert orientation.choose_orientation(losses, everything, "auto") == up_x[1]
    stool = (0.97, 0.4, 0.96)  # ... but X is a mirror axis (a pedestal stool's column lies across it)
    assert orientation.choose_orientation(losses, everything, "auto", symmetry=stool) in up_y
    # the expected up is a mirror axis (a stool lying with its seat toward +X): the best other up wins
    lying = (0.4, 0.97, 0.96)
    losses = np.ones(24)
    losses[up_y[0]] = 0.5
    losses[up_x[2]] = 0.8
    assert orientation.choose_orientation(losses, everything, "auto", symmetry=lying) == up_x[2]
    # every axis a mirror axis (a cube): no axis is set aside
    assert orientation.choose_orientation(losses, everything, "auto", symmetry=(1, 1, 1)) == up_y[0]
    # the vote reads it too: rows alone and as a collection
    vote = orientation.choose_auto(np.tile(losses, (3, 1)), symmetry=np.tile(lying, (3, 1)))
    assert vote.voted and np.allclose(vote.expected, [1, 0, 0]) and list(vote.choice) == [up_x[2]] * 3


def test_the_default_keeps_a_pedestal_stool_upright_and_stands_a_z_up_chair_up(chair_model_for_frames):
    """A round seat on a column and foot (the pedestal stool the rule before mirror symmetry laid on
    its side), as given; and a procedural chair exported Z-up (its +Y turned onto +Z)."""
    from primkit import data, io, synthetic

    stool = synthetic.stool(1004, base="column")
    chair = synthetic.chair(7, swivel=False)
    y_to_z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # x' = x, y' = -z, z' = y
    shapes = [data.prepare(io.Mesh(stool.vertices, stool.faces), name="stool"),
              data.prepare(io.Mesh(chair.vertices @ y_to_z.T, chair.faces), name="chair-z-up")]
    for shape, up in zip(shapes, ("+y", "+z")):
        (result,) = chair_model_for_frames.predict([shape], align="auto")
        assert result.alignment.up == up, (shape.name, result.alignment)

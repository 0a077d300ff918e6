"""Adapting a model to a collection without labels: deterministic, indices kept, recorded, saved."""

from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh

from primkit import data, io, synthetic
from primkit.model.abstractor import Abstractor
from primkit.model.adaptation import (LEAVE_ONE_OUT_RECIPE, AdaptConfig, adapt, collection_digest, index_agreement,
                                     save_adapted)


@pytest.fixture(scope="module")
def parent():
    return Abstractor.load("chair")


@pytest.fixture(scope="module")
def shapes():
    made = synthetic.generate("chair", 3, seed=11)
    return [data.prepare(io.Mesh(s.vertices, s.faces), name=f"c{i}") for i, s in enumerate(made)]


@pytest.mark.integration  # two adaptation runs compared: several seconds, left to the default suite
def test_adapting_is_deterministic_keeps_the_parent_and_records_itself(parent, shapes, tmp_path):
    before = {k: v.clone() for k, v in parent.network.state_dict().items()}
    config = AdaptConfig(steps=4, batch_size=4, seed=3)
    a = adapt(parent, shapes, config)
    b = adapt(parent, shapes, config)
    for k, v in parent.network.state_dict().items():  # the parent is unchanged
        assert torch.equal(v, before[k]), k
    moved = False
    for (k, va), vb in zip(a.network.state_dict().items(), b.network.state_dict().values()):
        assert torch.equal(va, vb), k  # the same seed: the same weights
        moved |= not torch.equal(va, before[k])
    assert moved
    other = adapt(parent, shapes, AdaptConfig(steps=4, batch_size=4, seed=4))
    assert any(not torch.equal(x, y) for x, y in zip(a.network.parameters(), other.network.parameters()))
    info = a.metadata["adaptation"]
    assert info["shapes"] == 3 and info["digest"] == collection_digest(shapes) and info["labels_used"] is False
    assert info["config"]["steps"] == 4 and "adaptation" not in parent.metadata
    assert 0.9 < info["index_agreement"] <= 1 and info["agreement_shapes"] == 3
    # a few small steps keep the part indices: nearly every surface sample keeps its part
    agreement = index_agreement(parent.predict(shapes, align="auto"), a.predict(shapes, align="auto"), shapes)
    assert agreement > 0.9
    path = save_adapted(a, tmp_path / "mine.safetensors")
    loaded = Abstractor.load(path)
    assert loaded.metadata["adaptation"]["digest"] == info["digest"]
    x = np.stack([s.occupancy for s in shapes])
    np.testing.assert_allclose(loaded.predict_canonical(x).translations, a.predict_canonical(x).translations,
                               atol=1e-6)


def test_bad_settings_are_refused(parent, shapes):
    with pytest.raises(ValueError, match="weights"):
        adapt(parent, shapes, AdaptConfig(steps=1, weights="encoder"))
    with pytest.raises(ValueError, match="no shapes"):
        adapt(parent, [], AdaptConfig(steps=1))


def test_default_steps_follow_the_collection_and_the_command_line_resolves_them():
    from primkit.cli._common import _adapt_steps
    from primkit.model.adaptation import default_steps

    # 40 draws a shape in batches of 16, within [200, 600]
    assert [default_steps(n) for n in (1, 20, 80, 81, 219, 240, 1000)] == [200, 200, 200, 203, 548, 600, 600]
    assert default_steps(219, batch_size=32) == 274
    assert _adapt_steps("auto") is True and _adapt_steps("50") == 50  # --adapt alone, --adapt 50
    with pytest.raises(ValueError, match="steps"):
        adapt(Abstractor.load("chair"), [object()], AdaptConfig(steps=0))


def test_adapt_true_takes_the_default_steps_of_the_inputs(parent, tmp_path, monkeypatch):
    # abstract_shapes(..., adapt=True) (what --adapt without a number passes) resolves the steps by
    # default_steps on the run's own inputs; replaced here by a spy so that the test stays short
    from primkit.model import adaptation
    from primkit.model.abstraction import abstract_shapes

    seen = []
    monkeypatch.setattr(adaptation, "default_steps", lambda count, batch_size=16: seen.append(count) or 2)
    paths = []
    for i, s in enumerate(synthetic.generate("chair", 2, seed=13)):
        paths.append(tmp_path / f"c{i}.obj")
        trimesh.Trimesh(s.vertices, s.faces, process=False).export(paths[-1])
    out = abstract_shapes(paths, parent, adapt=True, cache=tmp_path / "cache", workers=1)
    assert seen == [2] and out.model.metadata["adaptation"]["config"]["steps"] == 2


def test_parent_answers_computed_once_equal_the_per_step_pass(parent, shapes):
    # the pull's target is the parent's answer on an input that is never augmented: computed once per
    # shape before the steps, it equals the parent's network run on each shape alone, turned as found
    from primkit.model.adaptation import _frames_and_answers

    rotations, answers, _ = _frames_and_answers(parent, shapes, "auto", chunk=2, want_answers=True)
    turned, _ = parent.orient(shapes, "auto")
    parent.network.eval()
    for i, s in enumerate(turned):
        np.testing.assert_allclose(rotations[i], s.frame.rotation @ np.linalg.inv(shapes[i].frame.rotation), atol=1e-9)
        with torch.no_grad():
            ref = parent.network(torch.from_numpy(s.occupancy[None, None].astype(np.float32)))
        torch.testing.assert_close(answers.translations[i], ref.translations[0], rtol=0, atol=1e-5)
        torch.testing.assert_close(answers.half_extents[i], ref.half_extents[0], rtol=0, atol=1e-5)
        torch.testing.assert_close(answers.existence[i], ref.existence[0], rtol=0, atol=1e-5)
    # and training with them moves the weights as the per-step pass does, up to float noise that
    # Adam's normalised steps lift to at most one step of the weight's own rate (3 steps move three):
    # learning_rate (1e-4) for the network, existence_learning_rate (5e-2) for the existence head,
    # whose sampled existence turns float noise into larger gradient differences (1.2e-3 seen on one
    # machine, 1e-5 on another)
    config = AdaptConfig(steps=3, batch_size=4, seed=5, parent_pass="once")
    once = adapt(parent, shapes, config)
    every = adapt(parent, shapes, replace(config, parent_pass="every-step"))
    for (k, a), b in zip(once.network.state_dict().items(), every.network.state_dict().values()):
        step = config.existence_learning_rate if k.startswith("existence_head.") else config.learning_rate
        torch.testing.assert_close(a, b, rtol=0, atol=step, msg=k)


def test_a_turned_batch_equals_the_turned_shapes(shapes):
    # the stream turns each shape of a batch by its frame's rotation; the arrays must be those of
    # orientation.rotate_prepared (cells moved with their centres, vectors turned), shape by shape
    from primkit.model import orientation
    from primkit.model.adaptation import _Stream

    turns = [orientation.AXIS_ROTATIONS[5], np.eye(3), orientation.AXIS_ROTATIONS[17]]
    stream = _Stream(shapes, np.stack(turns))
    occ, closest, pts = stream.batch([0, 1, 2, 0], 50, torch.Generator().manual_seed(4))
    pick = torch.randint(0, stream.samples, (4, 50), generator=torch.Generator().manual_seed(4)).numpy()
    assert occ.shape == (4, 1, 32, 32, 32) and closest.shape == (4, 32, 32, 32, 3) and pts.shape == (4, 50, 3)
    for b, i in enumerate([0, 1, 2, 0]):
        turned = orientation.rotate_prepared(shapes[i], turns[i])
        np.testing.assert_array_equal(occ[b, 0].numpy(), turned.occupancy.astype(np.float32))
        np.testing.assert_allclose(closest[b].numpy(), turned.closest, rtol=0, atol=1e-6)
        np.testing.assert_allclose(pts[b].numpy(), np.asarray(turned.points)[pick[b]], rtol=0, atol=1e-6)


def test_the_recorded_agreement_is_one_for_the_parent_itself_and_drops_when_parts_move(parent, shapes):
    import copy

    from primkit import primitives
    from primkit.model.adaptation import _Stream, _stream_agreement

    stream = _Stream(shapes, np.stack([np.eye(3)] * len(shapes)))
    net = parent.network.eval()
    assert _stream_agreement(net, net, stream) == (1.0, 3)
    moved = copy.deepcopy(net)
    with torch.no_grad():  # every part's translation shifted: the nearest parts of some samples change
        moved.translation_head.bias += 0.2
    agreement, _ = _stream_agreement(net, moved, stream)
    assert agreement < 0.99
    # the same figure by hand on one shape: nearest present part (p > 0.5) of the same samples
    occ, _, pts = stream.batch([1], 1000, torch.Generator().manual_seed(0))
    with torch.no_grad():
        a, b = net(occ), moved(occ)

    def labels(pred):
        c = primitives.Cuboids(pred.half_extents[0].double().numpy(), pred.quaternions[0].double().numpy(),
                               pred.translations[0].double().numpy(), pred.existence[0].numpy() > 0.5)
        return primitives.assign_points(pts[0].double().numpy(), c)

    one, _ = _stream_agreement(net, moved, _Stream([shapes[1]], np.eye(3)[None]))
    assert one == pytest.approx(float(np.mean(labels(a) == labels(b))))


def test_a_cached_collection_streams_the_same_batches_as_its_decoded_list(parent, tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    for i, s in enumerate(synthetic.generate("chair", 3, seed=12)):
        trimesh.Trimesh(s.vertices, s.faces, process=False).export(folder / f"c{i}.obj")
    coll = data.prepare_collection(folder, data.PrepareSettings(resolution=parent.resolution), cache_dir=tmp_path / "c",
                                   workers=1, progress=False)
    config = AdaptConfig(steps=3, batch_size=4, seed=2)
    streamed = adapt(parent, coll, config)
    listed = adapt(parent, [coll[i] for i in range(len(coll))], config)
    assert streamed.metadata["adaptation"]["digest"] == listed.metadata["adaptation"]["digest"]
    for (k, a), b in zip(streamed.network.state_dict().items(), listed.network.state_dict().values()):
        assert torch.equal(a, b), k


def test_a_removed_part_hands_its_samples_to_the_next_nearest_part_grown_to_hold_them():
    # _handed_over: without part k, each sample nearest to k goes to its next-nearest present part,
    # which grows (one-sidedly, in its own frame) to the smallest box holding its old box and them;
    # checked against the bounding boxes computed by hand in each cuboid's frame
    from scipy.spatial.transform import Rotation

    from primkit import primitives
    from primkit.model.adaptation import _handed_over

    rng = np.random.default_rng(0)
    m, n = 4, 300
    z = torch.tensor(rng.uniform(0.05, 0.2, (1, m, 3)), dtype=torch.float64)
    t = torch.tensor(rng.uniform(-0.3, 0.3, (1, m, 3)), dtype=torch.float64)
    quat = Rotation.random(m, random_state=1).as_quat()[:, [3, 0, 1, 2]]  # (w, x, y, z)
    rot = primitives.quaternion_to_matrix_torch(torch.tensor(quat[None]))
    pts = torch.tensor(rng.uniform(-0.5, 0.5, (1, n, 3)))
    present = torch.tensor([[True, True, False, True]])
    local = (pts[:, None] - t[:, :, None]) @ rot
    d2 = ((local.abs() - z[:, :, None]).clamp_min(0) ** 2).sum(-1).masked_fill(~present[:, :, None], torch.inf)
    k1 = d2.argmin(1)
    k2 = d2.scatter(1, k1[:, None], torch.inf).argmin(1)
    k = 0
    z2, t2, p2 = _handed_over(local, z, t, rot, present, k1, k2, k)
    assert p2.tolist() == [[False, True, False, True]]
    r = rot[0].numpy()
    heirs = 0
    for j in range(1, m):
        mine = (k1[0] == k).numpy() & (k2[0] == j).numpy()
        if not mine.any():  # nothing taken over: the cuboid is unchanged
            np.testing.assert_allclose(z2[0, j], z[0, j])
            np.testing.assert_allclose(t2[0, j], t[0, j])
            continue
        heirs += 1
        x = (pts[0].numpy()[mine] - t[0, j].numpy()) @ r[j]  # the taken samples in j's frame
        lo = np.minimum(x.min(0), -z[0, j].numpy())
        hi = np.maximum(x.max(0), z[0, j].numpy())
        np.testing.assert_allclose(z2[0, j].numpy(), (hi - lo) / 2, atol=1e-12)
        np.testing.assert_allclose(t2[0, j].numpy(), t[0, j].numpy() + r[j] @ ((hi + lo) / 2), atol=1e-12)
        # every sample it took is inside the grown cuboid
        assert (np.abs((pts[0].numpy()[mine] - t2[0, j].numpy()) @ r[j]) <= z2[0, j].numpy() + 1e-12).all()
    assert heirs >= 1
    with pytest.raises(ValueError, match="existence_pull_on"):
        adapt(Abstractor.load("chair"), [object()], AdaptConfig(steps=1, existence_pull_on="encoder"))


def _outliers_by_loops(boxes, present, fit, reach, support, speak=None):
    # index_outliers written out shape by shape: the weights, then for every present part the
    # weight of the other shapes (of those in `speak`: all by default) whose box k lies within
    # reach on all six coordinates
    count, m = present.shape
    speak = range(count) if speak is None else speak
    ordered = sorted(fit)
    pos = 0.25 * (count - 1)
    lo, frac = int(np.floor(pos)), pos - np.floor(pos)
    q = ordered[lo] + frac * (ordered[min(lo + 1, count - 1)] - ordered[lo])  # numpy's default quantile
    w = [min(1.0, q / f) for f in fit]
    out = np.zeros((count, m), bool)
    for s in range(count):
        others = sum(w[o] for o in speak if o != s)
        for k in range(m):
            if not present[s, k]:
                continue
            mass = 0.0
            for o in speak:
                if o != s and present[o, k] and all(abs(boxes[s, k].ravel()[c] - boxes[o, k].ravel()[c]) <= reach
                                                    for c in range(6)):
                    mass += w[o]
            out[s, k] = mass < support * others
    return out


def test_index_outliers_flags_a_part_unlike_its_index_on_the_well_explained_shapes():
    from primkit.model.adaptation import index_outliers

    # a hand-built collection: 10 shapes, 3 parts; part 1 is a tall slab on every shape (small
    # jitter), except on shape 7 where it is a flat slab lower down; part 2 is present only on the
    # two shapes the parent fits badly (9 and 7), and on shape 3, fitted well
    rng = np.random.default_rng(0)
    count, m = 10, 3
    centre = np.array([[0.0, -0.3, 0.0], [-0.2, 0.25, 0.0], [0.0, 0.4, 0.0]])
    half = np.array([[0.25, 0.05, 0.25], [0.04, 0.25, 0.25], [0.05, 0.05, 0.05]])
    c = centre[None] + rng.normal(0, 0.01, (count, m, 3))
    h = half[None] + rng.normal(0, 0.005, (count, m, 3))
    c[7, 1], h[7, 1] = [-0.2, 0.3, 0.0], [0.04, 0.06, 0.12]  # the stool's "back"
    boxes = np.stack([c - h, c + h], 2)
    present = np.ones((count, m), bool)
    present[:, 2] = False
    present[[3, 7, 9], 2] = True
    fit = np.full(count, 0.005)
    fit[[7, 9]] = [0.06, 0.1]  # the parent explains shapes 7 and 9 12 and 20 times worse
    odd = index_outliers(boxes, present, fit)
    expected = np.zeros((count, m), bool)
    expected[7, 1] = True  # unlike every other shape's part 1
    # part 2 (weights: 1 on shape 3, 1/12 and 1/20 on shapes 7 and 9, the other shapes 1 each): on
    # shapes 7 and 9 it finds shape 3's weight, (1 + 1/20) / 8.05 and (1 + 1/12) / 8.08 of the
    # others' (0.13): kept; on shape 3 only (1/12 + 1/20) / 7.13 (0.02): an outlier
    expected[3, 2] = True
    np.testing.assert_array_equal(odd, expected)
    np.testing.assert_array_equal(odd, _outliers_by_loops(boxes, present, fit, 0.15, 0.1))
    # a typical part on a badly fitted shape is not an outlier, and the same slab on half of the
    # well-fitted shapes is a mode of its own: not an outlier either
    c2 = c.copy()
    c2[:5, 1], h2 = [-0.2, 0.3, 0.0], h.copy()
    h2[:5, 1] = [0.04, 0.06, 0.12]
    boxes2 = np.stack([c2 - h2, c2 + h2], 2)
    assert not index_outliers(boxes2, present, fit)[:, 1].any()
    # and against the loops on random collections, thresholds varied
    for seed in range(5):
        r = np.random.default_rng(seed)
        n = int(r.integers(2, 30))
        lo = r.uniform(-0.5, 0.3, (n, 4, 3))
        b = np.stack([lo, lo + r.uniform(0, 0.2, (n, 4, 3))], 2)
        pres = r.random((n, 4)) < 0.7
        f = r.uniform(0.001, 0.1, n)
        reach, support = r.uniform(0.05, 0.4), r.uniform(0.02, 0.5)
        np.testing.assert_array_equal(index_outliers(b, pres, f, reach=reach, support=support),
                                      _outliers_by_loops(b, pres, f, reach, support))
    with pytest.raises(ValueError, match="boxes"):
        index_outliers(boxes[:, :2], present, fit)


def test_index_outliers_in_a_large_collection_ask_evenly_spaced_shapes(monkeypatch):
    from primkit.model import adaptation

    monkeypatch.setattr(adaptation, "REFERENCE_SHAPES", 7)
    r = np.random.default_rng(7)
    n = 25
    lo = r.uniform(-0.5, 0.3, (n, 4, 3))
    b = np.stack([lo, lo + r.uniform(0, 0.2, (n, 4, 3))], 2)
    pres = r.random((n, 4)) < 0.8
    f = r.uniform(0.001, 0.1, n)
    speak = [0, 4, 8, 12, 16, 20, 24]  # 7 shapes evenly spaced over 25
    np.testing.assert_array_equal(adaptation.index_outliers(b, pres, f, reach=0.3, support=0.2),
                                  _outliers_by_loops(b, pres, f, 0.3, 0.2, speak))


def test_part_boxes_bound_each_cuboid_s_corners():
    from scipy.spatial.transform import Rotation

    from primkit import primitives
    from primkit.model.adaptation import _part_boxes

    rng = np.random.default_rng(1)
    z = rng.uniform(0.01, 0.3, (2, 5, 3))
    t = rng.uniform(-0.3, 0.3, (2, 5, 3))
    quat = Rotation.random(10, random_state=2).as_quat()[:, [3, 0, 1, 2]].reshape(2, 5, 4)  # (w, x, y, z)
    boxes = _part_boxes(torch.tensor(z), torch.tensor(quat), torch.tensor(t)).numpy()
    for s in range(2):
        c = primitives.Cuboids(z[s], quat[s], t[s], np.ones(5, bool))
        for k in range(5):
            corners = t[s, k] + (np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T * z[s, k]) @ c.rotations[k].T
            np.testing.assert_allclose(boxes[s, k, 0], corners.min(0), atol=1e-12)
            np.testing.assert_allclose(boxes[s, k, 1], corners.max(0), atol=1e-12)


def test_outlier_targets_remove_only_cheap_outliers_and_keep_the_other_cuboids():
    # six shapes answered with three slots: a seat slab (0), a back above it (1) and a thin slab (2)
    # lying on the seat's rear. Shapes 0-4 are a seat and a back, answered with slots 0 and 1; shape
    # 5 is a seat with the thin slab and no back, answered with all three (the back covering
    # nothing, so the parent fits it badly). In shape 5's own canonical frame (its bounding box is
    # the seat's) all three of its parts are unlike their index on shapes 0-4; the slab and the
    # back cost nothing to remove and go, the seat would cost its samples and stays. Every cuboid
    # of the targets is the parent's
    from primkit import primitives
    from primkit.model.adaptation import AdaptConfig, _outlier_targets, _ParentAnswers, _Stream
    from primkit.model.losses import LossWeights

    half = np.array([[0.25, 0.04, 0.25], [0.04, 0.2, 0.25], [0.05, 0.04, 0.25]])
    centre = np.array([[0.0, -0.1, 0.0], [-0.21, 0.14, 0.0], [-0.2, -0.1, 0.0]])
    count = 6
    shapes, t, z = [], [], []
    for s in range(count):
        parts = [0, 1] if s < 5 else [0, 2]
        verts, faces, _ = primitives.Cuboids(half[parts], np.tile([1.0, 0, 0, 0], (2, 1)), centre[parts],
                                             np.ones(2, bool)).to_mesh()
        shapes.append(data.prepare(io.Mesh(verts, faces), name=f"b{s}"))
        frame = shapes[-1].frame  # the answer in the prepared shape's canonical frame
        t.append(frame.to_canonical(centre))
        z.append(half * frame.scale)
    t, z = torch.tensor(np.array(t), dtype=torch.float32), torch.tensor(np.array(z), dtype=torch.float32)
    p = torch.ones(count, 3)
    p[:5, 2] = 0.0
    q = torch.zeros(count, 3, 4)
    q[..., 0] = 1.0
    answers = _ParentAnswers(t.clone(), z.clone(), p.clone(), q.clone())
    stream = _Stream(shapes, np.stack([np.eye(3)] * count))
    new, removed = _outlier_targets(answers, stream, LossWeights(1, 1, 0), AdaptConfig(seed=0))
    torch.testing.assert_close(new.translations, t)
    torch.testing.assert_close(new.half_extents, z)
    assert removed.tolist() == [0, 0, 0, 0, 0, 2]
    expected = p.clone()
    expected[5, 1:] = 0.0
    torch.testing.assert_close(new.existence, expected)
    again, twice = _outlier_targets(answers, stream, LossWeights(1, 1, 0), AdaptConfig(seed=0))
    assert torch.equal(again.existence, new.existence) and twice.tolist() == removed.tolist()  # deterministic


@pytest.mark.slow
@pytest.mark.parametrize("recipe", [pytest.param({}, id="defaults"),
                                    pytest.param(LEAVE_ONE_OUT_RECIPE, id="leave-one-out")])
def test_adapting_to_stools_and_chairs_drops_the_back_on_stools_and_keeps_the_seat(parent, recipe):
    # the check: adapted to a few procedural stools and chairs (no labels), the chair model's
    # back index is not present on the stools, and its seat index (where the chairs' seats go) is the
    # seat on the chairs and on the stools. The parent fails both on the stools: its back is a slab
    # at every stool's rear edge (p = 1.000), and most of the stools' seat samples go to index 13, a
    # box on the seat's top that the chairs never use, not to the chairs' seat index 16. The default
    # settings drop from the pull's targets the stools' parts that are unlike their index on the
    # chairs and cost nothing to remove (removal="outliers"); the leave-one-out recipe re-fits
    stools = synthetic.generate("stool", 3, seed=3)
    chairs = synthetic.generate("chair", 3, seed=21, rates={"swivel": 0.0, "has_arms": 0.0})
    made = stools + chairs
    shapes = [data.prepare(io.Mesh(s.vertices, s.faces), face_labels=s.face_labels, name=f"s{i}")
              for i, s in enumerate(made)]
    seat, back = synthetic.PART_NAMES["chair"].index("seat"), synthetic.PART_NAMES["chair"].index("back")

    def indices(model):
        results = model.predict(shapes, align="auto")
        from primkit import primitives

        return results, [primitives.assign_points(r.canonical_shape(s).points, r.canonical)
                         for r, s in zip(results, shapes)]

    def majority(idx, label, which):
        return int(np.bincount(np.concatenate([idx[k][shapes[k].point_labels == label] for k in which])).argmax())

    before, idx0 = indices(parent)
    back_index = majority(idx0, back, range(3, 6))
    seat_index = majority(idx0, seat, range(3, 6))
    assert all(back_index in r.canonical.present for r in before[:3])  # the parent puts a back on every stool
    assert majority(idx0, seat, range(3)) != seat_index  # and the stools' seats on another index
    child = adapt(parent, shapes, AdaptConfig(steps=200, seed=0, **recipe))
    after, idx1 = indices(child)
    assert majority(idx1, seat, range(3, 6)) == seat_index  # the chairs keep their seat
    assert majority(idx1, back, range(3, 6)) == back_index  # and their back
    assert all(back_index in r.canonical.present for r in after[3:])
    assert majority(idx1, seat, range(3)) == seat_index  # the stools' seats take the chairs' seat index
    assert not any(back_index in r.canonical.present for r in after[:3])  # and have no back


def test_the_command_writes_an_adapted_model_and_never_overwrites(parent, tmp_path, capsys):
    from primkit.cli import main

    folder = tmp_path / "in"
    folder.mkdir()
    for i, s in enumerate(synthetic.generate("stool", 2, seed=5)):
        trimesh.Trimesh(s.vertices, s.faces, process=False).export(folder / f"s{i}.obj")
    out = tmp_path / "mine.safetensors"
    args = ["adapt", str(folder), "--model", "chair", "-o", str(out), "--steps", "2", "--cache", str(tmp_path / "c"),
            "--workers", "1"]
    assert main(args) == 0
    info = Abstractor.load(out).metadata["adaptation"]
    assert info["shapes"] == 2 and info["config"]["steps"] == 2 and info["parent"] == "chair"
    from primkit.segmentation import Segmenter

    assert Segmenter(out).abstractor.metadata["adaptation"]["digest"] == info["digest"]  # the file segments
    assert main(args) != 0  # the output exists: refused without --force
    assert "exists" in capsys.readouterr().err

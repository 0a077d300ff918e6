"""The part labeller: exported trees against scikit-learn, the features against brute force, and
the storage (a hostile or truncated labeller refused in one line; loading runs no code)."""

from __future__ import annotations

import builtins
import json
import pickle
import struct

import numpy as np
import pytest

from primkit import primitives
from primkit.model.bundled import resolve_model
from primkit.model.modelfile import ModelFileError
from primkit.segmentation import labeller as lab
from primkit.segmentation.labeller import Labeller, LabellerSettings, TreeEnsemble, frame_features

sklearn = pytest.importorskip("sklearn.ensemble")


def _random_problem(classes, rng, n=3000, d=8):
    X = rng.normal(size=(n, d))
    y = (X[:, 0] > 0).astype(int)
    if classes > 2:
        y += 2 * (X[:, 1] + 0.5 * X[:, 2] > 0.3)
        y = np.minimum(y, classes - 1)
    X[rng.random(X.shape) < 0.1] = np.nan  # missing values: each split's learned side
    return X, y


@pytest.mark.parametrize("classes", [2, 3, 4])
def test_exported_trees_give_sklearns_probabilities(classes):
    rng = np.random.default_rng(classes)
    X, y = _random_problem(classes, rng)
    model = sklearn.HistGradientBoostingClassifier(max_iter=40, random_state=0).fit(X, y)
    ensemble = TreeEnsemble.from_sklearn(model)
    ensemble.check()
    Z = rng.normal(size=(4000, X.shape[1])) * 2
    Z[rng.random(Z.shape) < 0.15] = np.nan
    np.testing.assert_allclose(ensemble.predict_proba(Z), model.predict_proba(Z), rtol=0, atol=1e-6)
    assert ensemble.classes == classes


def _leaf(ensemble, t, x):
    """The leaf of tree ``t`` that sample ``x`` reaches, walked in plain Python on the exported arrays."""
    base, node = ensemble.tree_start[t], ensemble.tree_start[t]
    while not ensemble.is_leaf[node]:
        v = x[ensemble.feature[node]]
        left = ensemble.missing_left[node] if np.isnan(v) else v <= ensemble.threshold[node]
        node = base + (ensemble.left[node] if left else ensemble.right[node])
    return node


def _walk_one(ensemble, x):
    """A plain Python walk of the exported arrays (the reference for the Numba kernel)."""
    raw = ensemble.baseline.copy()
    for t in range(len(ensemble.tree_class)):
        raw[ensemble.tree_class[t]] += ensemble.value[_leaf(ensemble, t, x)]
    return raw


def test_kernel_matches_a_python_walk():
    rng = np.random.default_rng(0)
    X, y = _random_problem(4, rng, n=500)
    ensemble = TreeEnsemble.from_sklearn(sklearn.HistGradientBoostingClassifier(max_iter=5, random_state=0).fit(X, y))
    Z = X[:20]
    np.testing.assert_allclose(ensemble.raw_predict(Z), [_walk_one(ensemble, z) for z in Z], atol=1e-12)


def _cuboids(rng, m=5, absent=(3,)):
    q = rng.normal(size=(m, 4))
    return primitives.Cuboids(rng.uniform(0.05, 0.3, (m, 3)), q, rng.uniform(-0.4, 0.4, (m, 3)),
                              np.array([k not in absent for k in range(m)]))


def test_features_are_the_frame_read_by_brute_force():
    rng = np.random.default_rng(1)
    c = _cuboids(rng)
    points = rng.uniform(-0.5, 0.5, (50, 3))
    normals = rng.normal(size=(50, 3))
    s = LabellerSettings(neighbours=0, normals=True)
    F = frame_features(points, c, normals, s)
    m = c.count
    assert F.shape == (50, lab.feature_count(m, s))
    R = c.rotations
    for i, p in enumerate(points[:10]):
        local = np.array([R[k].T @ (p - c.translations[k]) for k in range(m)])
        dist = np.linalg.norm(np.maximum(np.abs(local) - c.half_extents, 0), axis=1)
        scaled = local / c.half_extents
        present = np.flatnonzero(c.existence)
        nearest = present[np.argmin(dist[present])]
        np.testing.assert_allclose(F[i, :3], p)
        assert F[i, 3 + nearest] == 1 and F[i, 3 : 3 + m].sum() == 1
        np.testing.assert_allclose(F[i, 3 + m : 6 + m], scaled[nearest])
        for k in range(m):
            want = scaled[k] if c.existence[k] else [lab.ABSENT] * 3
            np.testing.assert_allclose(F[i, 6 + m + 3 * k : 9 + m + 3 * k], want)
            np.testing.assert_allclose(F[i, 6 + 4 * m + k], dist[k] if c.existence[k] else lab.ABSENT)
        np.testing.assert_allclose(F[i, 6 + 5 * m : 9 + 5 * m], normals[i])


def test_local_shape_tells_a_line_from_a_plane():
    rng = np.random.default_rng(2)
    line = np.c_[np.linspace(0, 1, 200), np.zeros(200), np.zeros(200)] + rng.normal(0, 1e-4, (200, 3))
    plane = np.c_[rng.uniform(0, 1, (400, 2)), np.zeros(400)]
    shape_line = lab._local_shape(line, 16)
    shape_plane = lab._local_shape(plane, 16)
    assert np.all(shape_line[:, 2] > 0.95)  # one eigenvalue holds the spread
    np.testing.assert_allclose(shape_line[:, 3], 1, atol=1e-2)  # along x
    assert np.all(shape_plane[:, 0] < 1e-6)  # no spread off the plane
    np.testing.assert_allclose(shape_plane[:, 8], 1, atol=1e-6)  # which faces z


_TOY = {}  # (generator state, settings) -> (labeller, shapes, generator state after): a fit is seconds


def _random_grid(rng):
    """A random 10 x 9 x 8 occupancy, its voxels' indices and centres (cells of 0.1), random cuboids."""
    occupancy = rng.random((10, 9, 8)) < 0.5
    index = np.argwhere(occupancy)
    return occupancy, index, (index + 0.5) / 10 - 0.5, _cuboids(rng, absent=())


def _toy_labeller(rng, settings=None):
    """Learned from shapes whose label is which side of cuboid 0 a point lies on, and cuboid 1.
    The same generator state and settings give the same fit, so it is made once (the generator is
    left where the fit would have left it)."""
    settings = settings or LabellerSettings(neighbours=8, smooth=1, smooth_neighbours=5)
    key = (repr(rng.bit_generator.state), settings)
    if key in _TOY:
        labeller, shapes, after = _TOY[key]
        rng.bit_generator.state = after
        return labeller, shapes
    shapes = []
    for _ in range(4):
        c = _cuboids(rng, absent=())
        points = rng.uniform(-0.5, 0.5, (400, 3))
        local = primitives.world_to_local(points, c)
        y = np.where(local[0, :, 0] > 0, 0, 1) + 2 * (primitives.assign_points(points, c) == 1)
        shapes.append((frame_features(points, c, None, settings), np.minimum(y, 2)))
    labeller = Labeller.fit(shapes, ["a", "b", "c"], 5, settings=settings, max_iter=20)
    _TOY[key] = (labeller, shapes, rng.bit_generator.state)
    return labeller, shapes


@pytest.mark.integration  # a labeller fitted and written: seconds, left to the default suite
def test_labeller_learns_the_frame_and_round_trips_through_a_model_file(tmp_path):
    rng = np.random.default_rng(3)
    labeller, shapes = _toy_labeller(rng)
    X, y = shapes[0]
    assert np.mean(np.argmax(labeller.ensemble.predict_proba(X), axis=1) == y) > 0.9
    out = lab.write_labeller(resolve_model("chair"), tmp_path / "named.safetensors", labeller, {"part_names": None})
    back = lab.read_labeller(out)
    assert back.names == labeller.names and back.settings == labeller.settings
    np.testing.assert_array_equal(back.ensemble.predict_proba(X), labeller.ensemble.predict_proba(X))
    assert lab.read_labeller(resolve_model("chair-image")) is None  # the bundled image model has none
    # the network still loads from the file that carries the labeller
    from primkit.model.abstractor import Abstractor

    assert Abstractor.load(out).parts == 20
    with pytest.raises(FileExistsError):
        lab.write_labeller(resolve_model("chair"), out, labeller)


def _rewrite(path, out, change_arrays=None, change_description=None):
    """A copy of a labelled model file with its labeller's arrays or description changed."""
    from safetensors.numpy import load_file, save_file
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as f:
        header = f.metadata()
    arrays = load_file(str(path))
    meta = json.loads(header["primkit"])
    if change_arrays:
        change_arrays(arrays)
    if change_description:
        change_description(meta["labeller"])
    save_file(arrays, str(out), metadata={"primkit": json.dumps(meta)})
    return out


@pytest.fixture(scope="module")
def labelled(tmp_path_factory):
    labeller, _ = _toy_labeller(np.random.default_rng(4))
    return lab.write_labeller(resolve_model("chair"), tmp_path_factory.mktemp("lab") / "m.safetensors", labeller)


def _back_edge(a):
    split = np.flatnonzero(a["labeller.is_leaf"] == 0)
    a["labeller.left"][split[1]] = 0  # back to the root: a cycle


def _bad_feature(a):
    a["labeller.feature"][np.flatnonzero(a["labeller.is_leaf"] == 0)[0]] = 30000


def _float_children(a):
    a["labeller.left"] = a["labeller.left"].astype(np.float64)


def _short_values(a):
    a["labeller.value"] = a["labeller.value"][:-1]


def _lost_array(a):
    del a["labeller.threshold"]


def _newer(d):
    d["format_version"] = 99


def _more_features(d):
    d["features"] += 1


def _nan_leaf(a):
    a["labeller.value"][np.flatnonzero(a["labeller.is_leaf"] == 1)[0]] = np.nan


def _class_past_end(a):
    a["labeller.tree_class"][0] = 7


def _wide_children(a):
    a["labeller.left"] = a["labeller.left"].astype(np.int64)  # version 1's type in a version 2 file


def _bad_prior(a):
    a["labeller.prior"] = a["labeller.prior"][:, :2].copy()


def _lost_prior(a):
    del a["labeller.prior"]


@pytest.mark.parametrize("arrays,description,needle", [
    (_back_edge, None, "child index"),
    (_bad_feature, None, "feature past"),
    (_float_children, None, "labeller tensor labeller.left is F64"),
    (_short_values, None, "differ in length"),
    (_lost_array, None, "lacks its tensor labeller.threshold"),
    (None, _newer, "newer"),
    (None, _more_features, "features"),
    (_nan_leaf, None, "non-finite"),
    (_class_past_end, None, "raw score"),
    (_wide_children, None, "labeller tensor labeller.left is I64"),
    (_bad_prior, None, "prior must be"),
    (_lost_prior, None, "but no prior"),
])
def test_a_hostile_labeller_is_refused_in_one_line(labelled, tmp_path, arrays, description, needle):
    bad = _rewrite(labelled, tmp_path / "bad.safetensors", arrays, description)
    with pytest.raises(ModelFileError) as info:
        lab.read_labeller(bad)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(bad)) and needle in message


def test_a_truncated_labeller_file_is_refused_in_one_line(labelled, tmp_path):
    data = labelled.read_bytes()
    (header_length,) = struct.unpack("<Q", data[:8])
    for cut in (len(data) - 100, 8 + header_length + 10, 8 + header_length // 2, 5):
        bad = tmp_path / f"cut{cut}.safetensors"
        bad.write_bytes(data[:cut])
        with pytest.raises(ModelFileError) as info:
            lab.read_labeller(bad)
        assert "\n" not in str(info.value) and str(info.value).startswith(str(bad))


def test_loading_a_labeller_runs_no_code(labelled, tmp_path, monkeypatch):
    # a pickle that would run code if anything unpickled it, and a description holding code text
    marker = tmp_path / "ran"
    evil = _rewrite(labelled, tmp_path / "evil.safetensors",
                    change_description=lambda d: d["info"].update(
                        {"payload": pickle.dumps(f"__import__('pathlib').Path({str(marker)!r}).touch()").hex(),
                         "code": f"__import__('pathlib').Path({str(marker)!r}).touch()"}))

    def refuse(*args, **kwargs):
        raise AssertionError("code ran while loading a labeller")

    for module, name in ((pickle, "loads"), (pickle, "load"), (pickle, "Unpickler"), (builtins, "eval"),
                         (builtins, "exec"), (builtins, "compile")):
        monkeypatch.setattr(module, name, refuse)
    import torch

    monkeypatch.setattr(torch, "load", refuse)
    got = lab.read_labeller(evil)
    assert got.info["code"].startswith("__import__") and not marker.exists()
    # a pickle in place of the model file: refused, not unpickled
    fake = tmp_path / "pickled.safetensors"
    fake.write_bytes(pickle.dumps({"labeller": 1}))
    with pytest.raises(ModelFileError):
        lab.read_labeller(fake)


def test_grid_neighbours_are_the_27_nearest_voxels_of_a_full_block():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    occupancy = rng.random((9, 8, 7)) < 0.6
    index = np.argwhere(occupancy)
    near = lab.grid_neighbours(index, occupancy.shape)
    for i in rng.choice(len(index), 40, replace=False):
        want = {j for j, v in enumerate(index) if np.abs(v - index[i]).max() <= 1}
        got = set(near[i].tolist())
        assert got == want  # every occupied voxel of the block, the voxel itself for the empty ones
    full = np.argwhere(np.ones((5, 5, 5), bool))
    centre = 62  # (2, 2, 2)
    _, knn = cKDTree(full).query(full[centre], k=27)
    near = lab.grid_neighbours(full, (5, 5, 5))[centre]
    assert set(near.tolist()) == set(knn.tolist())
    d = np.linalg.norm(full[near] - full[centre], axis=1)
    assert near[0] == centre and np.all(np.diff(d) >= 0)  # nearest first: the first k are k nearest
    np.testing.assert_allclose(d[[1, 6, 7, 18, 19, 26]], [1, 1, 2**0.5, 2**0.5, 3**0.5, 3**0.5])


@pytest.mark.integration  # every grid step classified in full: seconds, left to the default suite
@pytest.mark.parametrize("step", [2, 4, 8])
def test_grid_sampling_classifies_one_voxel_in_step_and_fills_the_rest(step):
    from dataclasses import replace

    rng = np.random.default_rng(6)
    labeller, _ = _toy_labeller(rng, LabellerSettings(neighbours=8, smooth=0, grid_sample=1))
    occupancy, index, points, c = _random_grid(rng)
    near = lab.grid_neighbours(index, occupancy.shape)
    every = labeller.predict_proba(points, c, neighbours=near, grid_index=index)  # grid_sample 1
    sampled = replace(labeller, settings=replace(labeller.settings, grid_sample=step))
    got = sampled.predict_proba(points, c, neighbours=near, grid_index=index)
    picked = {2: index.sum(1) % 2 == 0, 4: (index % 2 == 0).all(1) | (index % 2 == 1).all(1),
              8: np.all(index % 2 == 0, axis=1)}[step]
    classified = 0
    for i, v in enumerate(index):  # brute force: the picked voxels of the 26 around, by coordinates
        around = [j for j, w in enumerate(index) if 0 < np.abs(w - v).max() <= 1 and picked[j]]
        if picked[i] or not around:
            np.testing.assert_allclose(got[i], every[i], atol=1e-12)  # classified: the same row
            classified += 1
        else:
            np.testing.assert_allclose(got[i], every[around].mean(axis=0), atol=1e-12)
    assert classified < len(index) * {2: 0.7, 4: 0.55, 8: 0.4}[step]
    assert not np.array_equal(got, every)
    assert np.all(lab.decide(got) >= 0)


@pytest.mark.integration  # a brute-force smoothing: seconds, left to the default suite
def test_smoothing_is_the_mean_over_the_neighbours_repeated():
    rng = np.random.default_rng(7)
    labeller, _ = _toy_labeller(rng, LabellerSettings(neighbours=8, smooth=2, smooth_neighbours=4))
    proba = rng.random((300, 3))
    idx = rng.integers(0, 300, (300, 6))
    want = proba.copy()
    for _ in range(2):
        want = np.array([want[row[:4]].sum(axis=0) / 4 for row in idx])
    np.testing.assert_allclose(labeller.smooth(proba, None, idx), want, rtol=0, atol=1e-15)


def test_grid_sample_is_read_back_and_checked():
    assert LabellerSettings.from_dict({}).grid_sample == 1  # files written before it: every voxel
    assert LabellerSettings.from_dict({"grid_sample": 2}).grid_sample == 2
    assert LabellerSettings.from_dict({"grid_sample": 4}).grid_sample == 4
    with pytest.raises(ValueError, match="grid_sample"):
        LabellerSettings.from_dict({"grid_sample": 3})


def test_decide_drops_labels_below_their_share():
    proba = np.array([[0.6, 0.4, 0.0]] * 99 + [[0.1, 0.3, 0.6]])
    assert np.array_equal(lab.decide(proba), [0] * 99 + [2])
    assert np.array_equal(lab.decide(proba, 0.02), [0] * 99 + [1])  # label 2 on 1% of the elements: dropped


@pytest.mark.integration  # fits a labeller on whole chairs through name-parts
def test_a_learned_labeller_names_the_faces_the_segmenter_writes(chairs, tmp_path):
    """fit_labeller on abstracted labelled meshes; the segmenter's ``named`` is the labeller's
    labelling of the mesh's faces (:func:`primkit.segmentation.meshlabels.label_faces`), and --semantic codes are those names' 1-based codes."""
    from primkit import io
    from primkit.segmentation import Segmenter
    from primkit.segmentation.segmenter import apply_labeller, fit_labeller, shape_elements

    files = []
    for i, s in enumerate(chairs):
        files.append(tmp_path / f"c{i}.ply")
        io.write_mesh(files[-1], s.vertices, s.faces)
    seg = Segmenter("chair", labeller=None)
    results, errors = seg.abstract_files(files, workers=1, progress=False)
    segs, errors = seg.segment_results(results, workers=1, progress=False)
    assert not errors
    names = list(chairs[0].part_names)
    labeller = fit_labeller([(s, r, c.face_labels) for s, r, c in zip(segs[:3], results, chairs)], names, 20,
                            max_iter=20)
    named = apply_labeller(segs[3], labeller, results[3])
    elements, _ = shape_elements(segs[3], results[3].frame)
    from primkit.segmentation.meshlabels import label_faces

    want = label_faces(labeller, elements, results[3].canonical)  # a mesh: labelled over its surface
    assert np.array_equal(named.named, want)
    # the shapes it did not learn from: 0.64-0.97 of faces each, mean 0.83 (0.86 without growing
    # unsized parts, min_extent=None); one chair alone is too noisy a bound
    right = [np.mean(np.array(labeller.names)[apply_labeller(segs[k], labeller, results[k]).named]
                     == np.array(names)[chairs[k].face_labels]) for k in range(3, len(chairs))]
    assert np.mean(right) > 0.75, right
    codes_names, codes = named.semantic_labels()
    assert codes_names == labeller.names and np.array_equal(codes, named.named + 1)


def _chair_with_a_labeller(tmp_path, *, seed, axis, names):
    """The bundled chair model with a labeller learned from random 20-slot frames, naming points by
    the sign of one coordinate: ``(labeller, model file)``."""
    rng = np.random.default_rng(seed)
    settings = LabellerSettings(neighbours=8, smooth=1, smooth_neighbours=5)
    shapes = []
    for _ in range(3):
        c = _cuboids(rng, m=20, absent=(3, 7))
        points = rng.uniform(-0.5, 0.5, (300, 3))
        shapes.append((frame_features(points, c, rng.normal(size=(300, 3)), settings), (points[:, axis] > 0).astype(int)))
    labeller = Labeller.fit(shapes, names, 20, settings=settings, max_iter=10)
    return labeller, lab.write_labeller(resolve_model("chair"), tmp_path / "m.safetensors", labeller)


@pytest.mark.integration  # a labeller fitted, then the accessor end to end
def test_the_pyvista_accessor_carries_a_label_array(chairs, tmp_path):
    """A model file with a labeller (here learned from random 20-slot frames): the accessor's copy
    has cell_data["label"], the labeller's names of the faces (as the library computes them)."""
    pv = pytest.importorskip("pyvista")
    from primkit.model.abstraction import abstract
    from primkit.plugins import pyvista_accessor  # noqa: F401  (registers dataset.primkit)

    labeller, model = _chair_with_a_labeller(tmp_path, seed=6, axis=1, names=["low", "high"])
    s = chairs[0]
    mesh = pv.PolyData.from_regular_faces(s.vertices, s.faces)
    out = mesh.primkit.segment(model=str(model), refine=0)
    a = abstract((s.vertices, s.faces), str(model), refine=0)
    want = lab.label_elements(labeller, lab.mesh_elements(s.vertices, s.faces, a.result.frame), a.result.canonical)
    assert np.array_equal(np.asarray(out.cell_data["label"]), want)
    assert list(out.field_data["label_names"]) == ["low", "high"]
    from primkit.model.modelfile import load_model_file, save_model

    weights, meta = load_model_file(resolve_model("table"))  # the bundled table without its labeller
    none = save_model(tmp_path / "plain.safetensors", {k: v for k, v in weights.items() if not k.startswith(lab.LABELLER_PREFIX)},
                      {k: v for k, v in meta.items() if k not in (lab.LABELLER_KEY, "created")})
    plain = mesh.primkit.segment(model=str(none), refine=0)
    assert "label" not in plain.cell_data  # a model without a labeller


@pytest.mark.integration  # a labeller fitted, then the VTK filter end to end
def test_the_vtk_filter_carries_a_label_array(chairs, tmp_path):
    """The VTK filter on a model file with a labeller: port 0 has cell_data["label"] beside
    "part", the labeller's names of the faces as the library computes them; none without one."""
    pv = pytest.importorskip("pyvista")
    from primkit.model.abstraction import abstract
    from primkit.plugins.vtk_filter import PrimkitSegmentation

    labeller, model = _chair_with_a_labeller(tmp_path, seed=8, axis=0, names=["rear", "front"])
    s = chairs[1]
    mesh = pv.PolyData.from_regular_faces(s.vertices, s.faces)
    f = PrimkitSegmentation(Model=str(model), RefineSteps=0)
    f.SetInputDataObject(0, mesh)
    f.Update()
    out = pv.wrap(f.GetOutputDataObject(0))
    a = abstract((s.vertices, s.faces), str(model), refine=0)
    want = lab.label_elements(labeller, lab.mesh_elements(s.vertices, s.faces, a.result.frame), a.result.canonical)
    assert np.array_equal(np.asarray(out.cell_data["label"]), want)
    assert list(out.field_data["label_names"]) == ["rear", "front"] and "part" in out.cell_data
    f.SetModel("chair")  # the bundled chair model carries a labeller (scripts/build_chair_labeller.py)
    f.Update()
    bundled = pv.wrap(f.GetOutputDataObject(0))
    assert list(bundled.field_data["label_names"]) == ["back", "seat", "legs", "arms"]
    assert len(bundled.cell_data["label"]) == len(s.faces) and np.all(np.asarray(bundled.cell_data["label"]) >= 0)


@pytest.mark.integration  # two name-parts runs; scikit-learn bins weighted samples slowly
def test_name_parts_learns_from_labelled_point_clouds(chairs, tmp_path):
    """Point clouds with <stem>.labels.npy beside them: name-parts learns a labeller from three,
    and segment --semantic names the fourth's points with it (codes of labels.csv)."""
    import trimesh

    from primkit import io
    from primkit.cli import main

    folder = tmp_path / "clouds"
    folder.mkdir()
    for i, s in enumerate(chairs[:4]):
        points, faces = trimesh.sample.sample_surface(trimesh.Trimesh(s.vertices, s.faces, process=False), 1500, seed=i)
        np.savetxt(folder / f"c{i}.xyz", points)
        groups = ["seat" if "seat" in n else "back" if "back" in n else "other" for n in s.part_names]
        np.save(folder / f"c{i}.labels.npy", np.array([1 + ["seat", "back", "other"].index(groups[k])
                                                        for k in s.face_labels[faces]]))
    train = [str(folder / f"c{i}.xyz") for i in range(3)]
    out = tmp_path / "named.safetensors"
    assert main(["name-parts", *train, "--model", "chair", "--names", "seat,back,other", "-o", str(out),
                 "--workers", "1", "--refine", "0"]) == 0
    labeller = lab.read_labeller(out)
    assert sorted(labeller.names) == ["back", "other", "seat"] and labeller.info["shapes"] == 3
    seg = tmp_path / "seg"
    assert main(["segment", str(folder / "c3.xyz"), "--model", str(out), "--semantic", "-o", str(seg),
                 "--workers", "1", "--refine", "0"]) == 0
    legend = [line.split(",")[1] for line in (seg / "labels.csv").read_text().splitlines()[1:]]
    assert legend == labeller.names
    codes = np.load(seg / "c3.parts.npy")
    truth = np.load(folder / "c3.labels.npy")
    named = np.array(legend)[codes - 1]
    right = np.mean(named == np.array(["seat", "back", "other"])[truth - 1])
    assert right > 0.8
    # a label file of the wrong length: one line naming it, the batch goes on, exit non-zero
    np.save(folder / "c2.labels.npy", np.zeros(7, np.int64))
    assert main(["name-parts", *train, "--model", "chair", "--names", "seat,back,other", "-o", str(out), "--force",
                 "--workers", "1", "--refine", "0"]) == 1


def test_names_by_index_is_each_index_majority_label():
    rng = np.random.default_rng(9)
    named = rng.integers(-1, 3, 500)
    index = rng.integers(0, 6, 500)  # index 5 ...
    index[index == 5] = 4  # ... holds nothing: it keeps its fallback name
    got = lab.names_by_index(named, index, 6, ["a", "b", "c"], [f"p{k}" for k in range(6)])
    for k in range(6):
        mine = named[(index == k) & (named >= 0)]
        want = "abc"[int(np.argmax(np.bincount(mine, minlength=3)))] if len(mine) else f"p{k}"
        assert got[k] == want


@pytest.mark.integration  # a labeller fitted for one edit: seconds, left to the default suite
def test_edit_scales_the_cuboids_a_label_names(chairs, tmp_path, capsys):
    """edit --scale NAME=... with a labelled model: NAME is a label of the labeller (not of the
    model's index names); the cuboids edited are those whose faces mostly carry it."""
    from primkit import io
    from primkit.cli import main

    rng = np.random.default_rng(10)
    settings = LabellerSettings(neighbours=8, smooth=1, smooth_neighbours=5)
    shapes = []
    for _ in range(3):
        c = _cuboids(rng, m=20, absent=(3, 7))
        points = rng.uniform(-0.5, 0.5, (300, 3))
        shapes.append((frame_features(points, c, rng.normal(size=(300, 3)), settings), (points[:, 1] > 0).astype(int)))
    labeller = Labeller.fit(shapes, ["lower", "upper"], 20, settings=settings, max_iter=10)
    model = lab.write_labeller(resolve_model("chair"), tmp_path / "m.safetensors", labeller)
    s = chairs[2]
    path = io.write_mesh(tmp_path / "c.off", s.vertices, s.faces)
    edited = {}
    for name in ("upper", "lower"):
        rc = main(["edit", str(path), "--model", str(model), "--scale", f"{name}=1.2", "-o",
                   str(tmp_path / f"{name}.off"), "--cache", str(tmp_path / "cache"), "--workers", "1"])
        out = capsys.readouterr().out
        assert rc == 0, out
        line = next(x for x in out.splitlines() if x.startswith("edited: "))
        edited[name] = {item.split("[")[0] for item in line[len("edited: "):].split(", ")}
        assert edited[name] == {name}  # every cuboid edited carries the label asked for
    rc = main(["edit", str(path), "--model", str(model), "--scale", "seat=1.2", "-o", str(tmp_path / "x.off"),
               "--cache", str(tmp_path / "cache"), "--workers", "1"])
    assert rc != 0 and "unknown part 'seat'" in capsys.readouterr().err  # index names give way to labels


@pytest.mark.integration  # a labeller fitted against brute force: seconds, left to the default suite
def test_the_prior_is_each_index_share_of_the_labels_and_is_blended_in(tmp_path):
    rng = np.random.default_rng(8)
    labeller, shapes = _toy_labeller(rng)
    m = labeller.parts
    # brute force: per shape, each index's label shares over all its labelled elements, summed
    counts = np.zeros((m, 3))
    for X, y in shapes:
        for k, label in zip(np.argmax(X[:, 3 : 3 + m], axis=1), y):
            counts[k, label] += 1.0 / len(y)
    rows = counts.sum(axis=1, keepdims=True)
    want = np.where(rows > 0, counts / np.maximum(rows, 1e-300), counts.sum(axis=0) / counts.sum())
    np.testing.assert_allclose(labeller.prior, want, atol=1e-12)
    X = shapes[1][0]
    w = labeller.settings.prior_weight
    assert w > 0
    blend = (1 - w) * labeller.ensemble.predict_proba(X) + w * want[np.argmax(X[:, 3 : 3 + m], axis=1)]
    from dataclasses import replace

    np.testing.assert_allclose(replace(labeller, early_stop=None).classify(X), blend, atol=1e-12)  # every tree
    stopped = labeller.ensemble.predict_proba(X, lab.EARLY_STOP)  # the trees as classify walks them by default
    np.testing.assert_allclose(labeller.classify(X), (1 - w) * stopped + w * want[np.argmax(X[:, 3 : 3 + m], axis=1)],
                               atol=1e-12)
    back = lab.read_labeller(lab.write_labeller(resolve_model("chair"), tmp_path / "p.safetensors", labeller))
    np.testing.assert_array_equal(back.prior, labeller.prior)
    np.testing.assert_array_equal(back.classify(X), labeller.classify(X))


def test_a_version_1_labeller_still_loads(labelled, tmp_path):
    """Version 1 stored indices as int64 and had no prior (prior_weight reads 0)."""
    def widen(a):
        for k in ("feature", "left", "right"):
            a["labeller." + k] = a["labeller." + k].astype(np.int64)
        del a["labeller.prior"]

    def old(d):
        d["format_version"] = 1
        del d["settings"]["prior_weight"]

    got = lab.read_labeller(_rewrite(labelled, tmp_path / "v1.safetensors", widen, old))
    now = lab.read_labeller(labelled)
    assert got.settings.prior_weight == 0 and got.prior is None
    np.testing.assert_array_equal(got.ensemble.feature, now.ensemble.feature)
    assert got.ensemble.feature.dtype == np.int64


@pytest.mark.shared
def test_the_bundled_chair_labeller_learned_from_validation_chairs_only(shared_data):
    """scripts/build_chair_labeller.py: the 219 validation chairs of scripts/partnet_chairs.py's
    split (rebuilt here from primkit.data: held-out files with PartNet labels, sorted by id, even
    positions validation, odd test) and their mirrors, never a test chair; the card states the
    PartNet terms."""
    from primkit import data
    from primkit.model.modelfile import read_metadata
    from primkit.segmentation import VoxelLabelArchive

    path = resolve_model("chair")
    got = lab.read_labeller(path)
    assert got is not None and got.names == ["back", "seat", "legs", "arms"] and got.parts == 20
    _, held = data.split_files(data.find_shape_files(shared_data / "shapenetvox32" / "03001627"), 10)
    archive = VoxelLabelArchive(shared_data / "partnet_chair_boxes")
    labelled = sorted((p for p in held if data.shape_name(p) in archive), key=data.shape_name)
    validation = [data.shape_name(p) for p in labelled[0::2]]
    test = {data.shape_name(p) for p in labelled[1::2]}
    ids = got.info["shape_ids"]
    assert ids == validation and len(ids) == 219 and not set(ids) & test
    card = read_metadata(path)["card"]
    labelled = got.info.get("labelled_shapes", got.info["shapes"])  # (shapes: with the chairs' mirrors, if any)
    assert card["labeller"]["shapes"] == labelled == 219
    assert got.info["shapes"] == 219 + got.info["mirrored"] == 219 + card["labeller"]["mirrored"]
    assert got.info["mirrored"] == 219  # every chair's left-right mirror learned from too
    assert "non-commercial research" in card["labeller"]["terms"] and "PartNet" in card["text"]


# -- the faster paths against straightforward computations ------------------------------------


def test_packed_kernel_gives_the_plain_kernels_sums_exactly():
    rng = np.random.default_rng(11)
    X, y = _random_problem(4, rng, n=2000)
    ensemble = TreeEnsemble.from_sklearn(sklearn.HistGradientBoostingClassifier(max_iter=30, random_state=0).fit(X, y))
    assert ensemble.packed() is not None and np.any(ensemble.missing_left == 0) and np.any(ensemble.missing_left == 1)
    Z = rng.normal(size=(500, X.shape[1])) * 2
    Z[rng.random(Z.shape) < 0.2] = np.nan  # NaN down both stored sides
    Z[:50] = X[:50]  # values on the thresholds' own side of the bins
    split = ensemble.is_leaf == 0
    Z[50:60, ensemble.feature[split][:10]] = ensemble.threshold[split][:10]  # exactly on a threshold: left
    plain = np.empty((len(Z), len(ensemble.baseline)))
    plain[:] = ensemble.baseline
    lab._kernel()(Z, ensemble.feature, ensemble.threshold, ensemble.missing_left, ensemble.left, ensemble.right,
                  ensemble.is_leaf, ensemble.value, ensemble.tree_start, ensemble.tree_class, plain)
    np.testing.assert_array_equal(ensemble.raw_predict(Z), plain)  # the same walk, the same float64 sums
    np.testing.assert_allclose(plain[:20], [_walk_one(ensemble, z) for z in Z[:20]], atol=1e-12)


def test_packed_nodes_point_where_the_exported_arrays_do():
    rng = np.random.default_rng(12)
    X, y = _random_problem(3, rng, n=800)
    e = TreeEnsemble.from_sklearn(sklearn.HistGradientBoostingClassifier(max_iter=4, random_state=0).fit(X, y))
    meta, split_or_value, missing_left, roots = e.packed()
    base = np.repeat(e.tree_start[:-1], np.diff(e.tree_start))
    split = e.is_leaf == 0
    np.testing.assert_array_equal(roots, e.tree_start[:-1])
    np.testing.assert_array_equal(meta[split] & 0xFFFF, e.feature[split])
    assert np.all(meta[~split] & 0xFFFF == lab.PACKED_LEAF)
    np.testing.assert_array_equal((meta[split] >> 16) & 0xFFFFFF, (base + e.left)[split])
    np.testing.assert_array_equal((meta[split] >> 40) & 0xFFFFFF, (base + e.right)[split])
    np.testing.assert_array_equal(split_or_value, np.where(split, e.threshold, e.value))
    np.testing.assert_array_equal(missing_left, e.missing_left)


def _brute_knn_distances(index, i, k):
    return np.sort(np.linalg.norm(index - index[i], axis=1))[:k]


@pytest.mark.parametrize("seed", [0, 1])
def test_grid_knn_finds_the_k_nearest_voxels_by_brute_force(seed):
    rng = np.random.default_rng(seed)
    occupancy = rng.random((12, 11, 10)) < 0.3
    occupancy[2:10, 5, 4] = True  # a thin line: its neighbours lie far along it
    index = np.argwhere(occupancy)
    rows = rng.choice(len(index), 60, replace=False)
    rows[0] = int(np.flatnonzero((index == [5, 5, 4]).all(axis=1))[0])
    near, found = lab.grid_knn(index, rows, 16, occupancy.shape)
    assert found.all()
    for q, i in enumerate(rows):
        assert near[q, 0] == i and len(set(near[q].tolist())) == 16  # itself first, distinct voxels
        d = np.linalg.norm(index[near[q]] - index[i], axis=1)
        assert np.all(np.diff(d) >= 0)  # nearest first
        np.testing.assert_allclose(d, _brute_knn_distances(index, i, 16), atol=1e-12)  # the k smallest


def test_grid_knn_says_when_the_ball_holds_too_few_and_the_local_shape_asks_a_tree():
    occupancy = np.zeros((40, 4, 4), bool)
    occupancy[0:40:3, 1, 1] = True  # 14 voxels three apart: the 16 nearest lie beyond 8 voxels
    occupancy[0:3, 2, 2] = True
    index = np.argwhere(occupancy)
    near, found = lab.grid_knn(index, np.arange(len(index)), 16, occupancy.shape)
    assert not found.any() and np.all(near[:, -1] == -1)
    points = index * 0.1
    got = lab.grid_local_shape(points, index, np.arange(len(index)), 16, occupancy.shape)
    np.testing.assert_allclose(got, lab._local_shape(points, 16), atol=1e-9)  # the k-d tree's, all rows


def test_grid_local_shape_is_the_covariance_of_the_nearest_voxels_in_any_similar_frame():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    occupancy = rng.random((10, 9, 8)) < 0.35
    occupancy[1:9, 4, 2] = True
    index = np.argwhere(occupancy)
    rotation = Rotation.random(random_state=4).as_matrix()
    points = (index * 0.07 + [0.1, -0.2, 0.3]) @ rotation.T  # a similarity of the grid (canonical-like)
    rows = np.arange(0, len(index), 3)
    got = lab.grid_local_shape(points, index, rows, 16, occupancy.shape)
    near, _ = lab.grid_knn(index, rows, 16, occupancy.shape)
    d_all = np.linalg.norm(index[:, None, :] - index[None, rows, :], axis=2)  # (c, n)
    unique = 0
    for q, i in enumerate(rows):
        sel = points[near[q]] - points[near[q]].mean(axis=0)
        cov = sel.T @ sel / 16
        values, vectors = np.linalg.eigh(cov)
        np.testing.assert_allclose(got[q, :3], values / values.sum(), atol=1e-9)  # brute force on its set
        np.testing.assert_allclose(got[q, 3:6], np.abs(vectors[:, 2]), atol=1e-6)
        d = np.sort(d_all[:, q])
        if d[15] < d[16] - 1e-9 and values[2] - values[1] > 1e-6 and values[1] - values[0] > 1e-6:
            unique += 1  # no tie at the 16th: the k-d tree's set, the same columns
            np.testing.assert_allclose(got[q], lab._local_shape(points, 16)[i], atol=1e-6)
    assert unique > 5


def test_a_labeller_reads_a_grids_local_shape_on_the_grid():
    rng = np.random.default_rng(8)
    labeller, _ = _toy_labeller(rng, LabellerSettings(neighbours=8, smooth=0, grid_sample=1))
    occupancy, index, points, c = _random_grid(rng)
    near = lab.grid_neighbours(index, occupancy.shape)
    got = labeller.predict_proba(points, c, neighbours=near, grid_index=index)
    shape = lab.grid_local_shape(points, index, np.arange(len(index)), 8, occupancy.shape)
    want = labeller.classify(frame_features(points, c, None, labeller.settings, local_shape=shape))
    np.testing.assert_array_equal(got, want)


def test_grid_normals_at_some_voxels_are_the_full_grids():
    rng = np.random.default_rng(9)
    occupancy = rng.random((9, 8, 7)) < 0.4
    occupancy[:, 0, :] = occupancy[-1] = True  # voxels on the grid's faces: the one-sided ends
    index = np.argwhere(occupancy)
    np.testing.assert_array_equal(lab.grid_normals(occupancy, index), lab.grid_normals(occupancy)[tuple(index.T)])


def test_a_labeller_learns_a_grids_local_shape_as_it_reads_it():
    rng = np.random.default_rng(10)
    occupancy, index, points, c = _random_grid(rng)
    settings = LabellerSettings(neighbours=8)
    elements = lab.Elements(points, grid_index=index)
    shape = lab.grid_local_shape(points, index, np.arange(len(index)), 8, occupancy.shape)
    np.testing.assert_array_equal(lab.element_features(elements, c, settings),
                                  frame_features(points, c, None, settings, local_shape=shape))
    np.testing.assert_array_equal(lab.element_features(lab.Elements(points), c, settings),
                                  frame_features(points, c, None, settings))  # no grid: the k-d tree


def _stopped_walk(ensemble, x, rounds, margin, taper):
    """A plain Python walk with the early stop (the reference for :func:`lab._packed_kernel` with a stop): the
    trees in rounds of ``k``, the scores after each round from ``rounds`` on checked."""
    k = len(ensemble.baseline)
    total = len(ensemble.tree_class) // k
    raw = ensemble.baseline.copy()
    for t in range(len(ensemble.tree_class)):
        raw[ensemble.tree_class[t]] += ensemble.value[_leaf(ensemble, t, x)]
        if (t + 1) % k == 0 and (t + 1) // k >= rounds:
            top = np.sort(raw)[::-1]
            if (abs(raw[0]) if k == 1 else top[0] - top[1]) > margin + taper * (total - (t + 1) // k) / total:
                break
    return raw


@pytest.mark.parametrize("classes", [2, 4])
def test_the_early_stop_walks_each_sample_to_its_stopping_round(classes):
    rng = np.random.default_rng(20 + classes)
    X, y = _random_problem(classes, rng, n=1500)
    e = TreeEnsemble.from_sklearn(sklearn.HistGradientBoostingClassifier(max_iter=25, random_state=0).fit(X, y))
    assert e.in_rounds()
    Z = rng.normal(size=(300, X.shape[1])) * 2
    Z[rng.random(Z.shape) < 0.2] = np.nan
    for stop in [(3, 1.0, 0.0), (10, 2.0, 0.0), (1, 0.5, 0.0), (5, 0.5, 3.0)]:
        got = e.raw_predict(Z, stop)
        want = [_stopped_walk(e, z, *stop) for z in Z]
        np.testing.assert_array_equal(got, want)  # the same trees in the same order: the same sums
    full = e.raw_predict(Z)
    early = e.raw_predict(Z, (3, 1.0, 2.0))
    assert 0 < np.mean(np.all(early == full, axis=1)) < 1  # some samples stopped, some walked every tree
    np.testing.assert_array_equal(e.raw_predict(Z, (25, 0.0, 0.0)), full)  # the last round: nothing left to skip
    np.testing.assert_array_equal(e.raw_predict(Z, (1, np.inf, 0.0)), full)
    if classes > 2:  # trees not in round order walk in full whatever the stop
        from dataclasses import replace

        shuffled = replace(e, tree_class=e.tree_class[::-1].copy())
        assert not shuffled.in_rounds()
        np.testing.assert_array_equal(shuffled.raw_predict(Z, (1, 0.0, 0.0)), shuffled.raw_predict(Z))


def test_the_frame_columns_are_numpys_cuboid_frames():
    rng = np.random.default_rng(21)
    c = _cuboids(rng, m=20, absent=(2, 7, 19))
    points = rng.uniform(-0.6, 0.6, (700, 3))
    F = frame_features(points, c, None, LabellerSettings(neighbours=0, normals=False, profile=False, sides=False))
    local = primitives.world_to_local(points, c) / c.half_extents[:, None, :]  # (m, n, 3)
    local[~c.existence] = lab.ABSENT
    dist = primitives.point_cuboid_distance(points, c)
    dist[:, ~c.existence] = lab.ABSENT
    nearest = primitives.assign_points(points, c)
    want = np.hstack([points, np.eye(20)[nearest], local[nearest, np.arange(700)],
                      local.transpose(1, 0, 2).reshape(700, 60), dist])
    np.testing.assert_allclose(F, want, rtol=1e-13, atol=1e-13)  # the same products, summed in another order


def test_the_profile_loop_gives_numpys_sums_exactly():
    from primkit.segmentation.profile import _profile_reference, profile_features

    rng = np.random.default_rng(22)
    context = rng.normal(size=(3000, 3)) * [0.3, 0.5, 0.2]
    points = np.vstack([context[:500], rng.normal(size=(40, 3))])  # some outside the context's box
    np.testing.assert_array_equal(profile_features(points, context), _profile_reference(points, context))
    np.testing.assert_array_equal(profile_features(context, bins=7), _profile_reference(context, bins=7))


def test_the_grid_loops_refuse_indices_off_the_grid():
    occupancy = np.zeros((4, 4, 4), bool)
    occupancy[1:3, 1:3, 1:3] = True
    index = np.argwhere(occupancy)
    near = lab.grid_neighbours(index, occupancy.shape)
    with pytest.raises(ValueError, match="outside the grid"):
        lab.grid_neighbours(index + [0, 0, 2], occupancy.shape)
    with pytest.raises(ValueError, match="outside the grid"):
        lab.grid_normals(occupancy, index - 2)
    with pytest.raises(ValueError, match="neighbours"):
        lab.grid_sampling(index, near[:, :19], 4)


def test_the_closed_form_axes_are_eighs():
    rng = np.random.default_rng(23)
    A = rng.normal(size=(500, 16, 3)) * [1.0, 0.5, 0.2]
    A -= A.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", A, A) / 16
    cov[:3] = [np.diag([0.3, 0.1, 0.2]), np.diag([0.2, 0.2, 0.5]), np.zeros((3, 3))]  # diagonal, a tie, nothing
    got = np.empty((len(cov), 9))
    lab._eigen_kernel()(cov, got)
    want = lab._shape_columns(cov)
    np.testing.assert_allclose(got[:, :3], want[:, :3], atol=1e-12)  # the shares, ties included
    np.testing.assert_allclose(got[3:], want[3:], atol=1e-9)  # the axes where the eigenvalues are apart
    np.testing.assert_allclose(got[0], [1 / 6, 1 / 3, 1 / 2, 1, 0, 0, 0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(got[1, 3:6], [0, 0, 1], atol=1e-15)  # the largest apart; the tied pair's smallest:
    assert abs(np.linalg.norm(got[1, 6:]) - 1) < 1e-12 and got[1, 8] < 1e-12  # any unit axis of their plane
    np.testing.assert_allclose(np.linalg.norm(got[:, 3:6], axis=1), 1, atol=1e-12)


@pytest.mark.shared
@pytest.mark.slow  # re-measures the stated figures on 218 chairs
def test_the_shipped_chair_labeller_meets_its_stated_bars_on_the_test_chairs(shared_data):
    """The chair model as ``primkit segment --semantic`` runs it (``Segmenter``, default flags) on
    the 218 PartNet test chairs of scripts/partnet_chairs.py's split, scored as
    ``scripts/labeller_curve.py model`` scores it: the README and docs/labeller.md state mean
    back/seat/legs IoU 0.810, arm IoU 0.771, arm F1 0.906, and so issue 33's bars for the shipped
    model (0.78, 0.65, 0.9). The labeller learned from validation chairs only (the test above)."""
    from scripts.labeller_curve import model_figures

    got = model_figures("chair", "test")
    assert got["chairs"] == 218
    assert got["mean"] >= 0.78 and got["arm_iou"] >= 0.65 and got["arm_f1"] >= 0.9
    # each figure a chair or two from the stated one (an armed chair of about 90 moves F1 by 0.006)
    assert abs(got["mean"] - 0.810) < 0.005 and abs(got["arm_iou"] - 0.771) < 0.01 and abs(got["arm_f1"] - 0.906) < 0.012

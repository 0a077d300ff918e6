"""Per-part descriptors, distances, neighbours and the embed / similar commands."""

import numpy as np
import pytest

from primkit import embedding
from primkit.primitives import Cuboids, matrix_to_quaternion
from primkit.embedding import PartDescriptor


def axis_angle_quaternion(axis, degrees):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    h = np.radians(degrees) / 2
    return np.concatenate([[np.cos(h)], np.sin(h) * axis])


def make(z, q, t, e):
    return Cuboids(np.asarray(z, float), np.asarray(q, float), np.asarray(t, float), np.asarray(e, bool))


IDENTITY = [1.0, 0.0, 0.0, 0.0]


def two_part(z0=(0.1, 0.2, 0.3), t0=(0.0, 0.1, 0.0), q0=IDENTITY, present1=True, z1=(0.05, 0.05, 0.05), t1=(0.2, 0.0, 0.0)):
    return make([z0, z1], [q0, IDENTITY], [t0, t1], [True, present1])


def test_descriptor_matches_hand_computed_values():
    a = two_part()
    scales = {"size": 0.5, "position": 0.25, "orientation": 60.0, "presence": 2.0}
    desc = PartDescriptor(parts="part0", scales=scales).fit([a])
    x = desc.transform([a])[0]
    # orientation block: identity / (2 sqrt 2 sin 30 deg) = identity / sqrt 2
    expected = np.concatenate([np.array([0.1, 0.2, 0.3]) / 0.5, np.array([0.0, 0.1, 0.0]) / 0.25,
                               np.eye(3).ravel() / np.sqrt(2.0), [1.0 / 2.0]])
    assert np.allclose(x, expected)
    assert desc.feature_names_[0] == "part0.size.x" and desc.feature_names_[-1] == "part0.presence"
    assert len(desc.feature_names_) == 16


def test_rotation_distance_is_the_chord_of_the_angle():
    # a rotation of theta costs sin(theta/2) / sin(scale/2); of exactly the scale, 1
    for theta in (10.0, 15.0, 90.0, 170.0):
        a = two_part()
        b = two_part(q0=axis_angle_quaternion([0.3, 1.0, -0.2], theta))
        desc = PartDescriptor(parts=[0], what="orientation", scales={"orientation": 15.0}).fit([a, b])
        d = embedding.descriptor_distances(desc.transform([a, b]))[0, 1]
        assert d == pytest.approx(np.sin(np.radians(theta) / 2) / np.sin(np.radians(15.0) / 2), rel=1e-9)


def test_quaternion_sign_does_not_matter():
    q = axis_angle_quaternion([1.0, 2.0, 0.5], 70.0)
    a, b = two_part(q0=q), two_part(q0=-q)
    X = PartDescriptor().fit([a, b]).transform([a, b])
    assert np.allclose(X[0], X[1], atol=1e-12)
    assert embedding.descriptor_distances(X)[0, 1] == pytest.approx(0.0, abs=1e-12)
    # and the round trip through a matrix (w >= 0) gives the same descriptor
    c = two_part(q0=matrix_to_quaternion(a.rotations[0]))
    assert np.allclose(PartDescriptor().fit([a]).transform([c])[0], X[0], atol=1e-12)


def test_absent_part_costs_the_presence_penalty_plus_its_distance_from_the_average_part():
    shapes = [two_part(z1=(0.05, 0.05, 0.05), t1=(0.2, 0.0, 0.0)), two_part(z1=(0.15, 0.05, 0.05), t1=(0.4, 0.0, 0.0)),
              two_part(present1=False, z1=(9.0, 9.0, 9.0), t1=(-7.0, 3.0, 1.0))]
    scales = {"size": 0.1, "position": 0.1, "orientation": 15.0, "presence": 0.5}
    desc = PartDescriptor(parts="part1", scales=scales).fit(shapes)
    # fill values: the mean of the present instances (identity rotations average to identity)
    assert np.allclose(desc.fill_["size"][0], [0.1, 0.05, 0.05])
    assert np.allclose(desc.fill_["position"][0], [0.3, 0.0, 0.0])
    assert np.allclose(desc.fill_["orientation"][0], np.eye(3).ravel())
    D = embedding.descriptor_distances(desc.transform(shapes))
    # present (0.05, pos 0.2) against absent (filled with the mean): size 0.05/0.1, position 0.1/0.1, presence 1/0.5
    assert D[0, 2] == pytest.approx(np.sqrt(0.5 ** 2 + 1.0 ** 2 + 2.0 ** 2))
    # the absent part's own (garbage) values never enter
    other = two_part(present1=False, z1=(0.01, 0.02, 0.03), t1=(1.0, 1.0, 1.0))
    assert np.allclose(desc.transform([other]), desc.transform([shapes[2]]))
    # presence alone: exactly the fixed penalty
    only = PartDescriptor(parts="part1", what="presence", scales=scales).fit(shapes)
    Dp = embedding.descriptor_distances(only.transform(shapes))
    assert Dp[0, 2] == pytest.approx(2.0) and Dp[0, 1] == pytest.approx(0.0)


def test_parts_by_name_and_unknown_names():
    a, b = two_part(), two_part(t1=(0.5, 0.0, 0.0))
    names = ["seat", "arms"]
    by_name = PartDescriptor(parts="arms", part_names=names).fit([a, b])
    by_index = PartDescriptor(parts="1", part_names=names).fit([a, b])
    assert list(by_name.parts_) == [1]
    assert np.array_equal(by_name.transform([a, b]), by_index.transform([a, b]))
    assert by_name.feature_names_[0].startswith("arms.")
    with pytest.raises(ValueError, match="seat, arms"):
        PartDescriptor(parts="back", part_names=names).fit([a])
    with pytest.raises(ValueError, match="unknown property"):
        PartDescriptor(what="colour").fit([a])
    with pytest.raises(ValueError, match="same number of part slots"):
        PartDescriptor().fit([a, make([[0.1, 0.1, 0.1]], [IDENTITY], [[0, 0, 0]], [True])])


def random_cuboids(rng, s, m=6):
    out = []
    for _ in range(s):
        q = rng.normal(size=(m, 4))
        out.append(make(rng.uniform(0.02, 0.3, (m, 3)), q, rng.uniform(-0.4, 0.4, (m, 3)), rng.random(m) < 0.7))
    return out


@pytest.mark.parametrize("algorithm", ["auto", "ball_tree", "kd_tree", "brute"])
def test_nearest_neighbours_agree_with_brute_force(algorithm):
    rng = np.random.default_rng(1)
    cubs = random_cuboids(rng, 120)
    X = PartDescriptor().fit_transform(cubs)
    nn = embedding.nearest_neighbors(X, 3, algorithm=algorithm)
    D = embedding.descriptor_distances(X)
    np.fill_diagonal(D, np.inf)
    order = np.argsort(D, axis=1)[:, :3]
    assert np.array_equal(nn.indices, order)
    assert np.allclose(nn.distances, np.take_along_axis(D, order, axis=1))
    # queries from outside the collection
    Q = PartDescriptor().fit(cubs).transform(random_cuboids(rng, 5))
    nq = embedding.nearest_neighbors(X, 2, queries=Q, algorithm=algorithm)
    Dq = embedding.descriptor_distances(Q, X)
    assert np.array_equal(nq.indices, np.argsort(Dq, axis=1)[:, :2])


def test_voxel_iou_distances_against_sets():
    rng = np.random.default_rng(2)
    grids = rng.random((5, 6, 6, 6)) < 0.3
    grids[4] = False
    D = embedding.voxel_iou_distances(grids, chunk=2)
    for i in range(5):
        for j in range(5):
            a, b = grids[i].ravel(), grids[j].ravel()
            union = np.sum(a | b)
            expected = 0.0 if union == 0 else 1 - np.sum(a & b) / union
            assert D[i, j] == pytest.approx(expected)


@pytest.mark.integration  # a t-SNE map of forty shapes: several seconds, left to the default suite
def test_tsne_map_of_two_separated_groups():
    rng = np.random.default_rng(3)
    X = np.concatenate([rng.normal(0, 0.1, (15, 4)), rng.normal(5, 0.1, (15, 4))])
    Y = embedding.tsne_map(X, random_state=0)
    assert Y.shape == (30, 2)
    nn = embedding.nearest_neighbors(Y, 1)
    assert embedding.neighbour_agreement(nn.indices, np.repeat([0, 1], 15)) == 1.0
    # precomputed and on-descriptor paths give maps of the right shape
    assert embedding.tsne_map(X, random_state=0, precomputed_below=10).shape == (30, 2)


@pytest.mark.integration  # the embed and similar commands end to end: several seconds, left to the default suite
def test_embed_and_similar_commands(tmp_path, capsys):
    from primkit import synthetic
    from primkit.cli import main

    shapes = tmp_path / "chairs"
    synthetic.write_collection(shapes, "chair", 6, seed=5)
    cache = tmp_path / "cache"
    out = tmp_path / "embed"
    common = ["--model", "chair", "--cache", str(cache), "--workers", "1"]
    assert main(["embed", str(shapes), *common, "--parts", "16,18", "--what", "orientation,size", "-o", str(out),
                 "--png", str(out / "map.png")]) == 0
    D = np.load(out / "distances.npy")
    X = np.load(out / "descriptors.npy")
    assert D.shape == (6, 6) and np.allclose(D, D.T) and np.allclose(np.diag(D), 0)
    assert np.allclose(D, embedding.descriptor_distances(X))
    header = (out / "distances.csv").read_text().splitlines()[0].split(",")
    assert header[1:] == [f"chair_{i:04d}" for i in range(6)]
    assert len((out / "map.csv").read_text().splitlines()) == 7
    from pictures import read_picture

    assert 2 <= read_picture(out / "map.png").blobs() <= 6  # the thumbnails (close ones may touch)
    # outputs are not overwritten without --force
    assert main(["embed", str(shapes), *common, "-o", str(out)]) == 2
    # voxel IoU baseline
    out2 = tmp_path / "iou"
    assert main(["embed", str(shapes), *common, "--metric", "voxel-iou", "-o", str(out2)]) == 0
    Di = np.load(out2 / "distances.npy")
    assert np.all((Di >= 0) & (Di <= 1)) and np.allclose(np.diag(Di), 0)
    capsys.readouterr()
    # similar: the query is left out of its own ranking; the ranking follows the descriptor distances
    out3 = tmp_path / "similar"
    assert main(["similar", str(shapes / "chair_0000.ply"), str(shapes), *common, "--parts", "16,18",
                 "--what", "orientation,size", "-k", "3", "-o", str(out3), "--png", str(out3 / "similar.png")]) == 0
    rows = (out3 / "similar.csv").read_text().splitlines()[1:]
    assert len(rows) == 3 and all("chair_0000" not in r for r in rows)
    dist = [float(r.split(",")[2]) for r in rows]
    assert dist == sorted(dist)
    assert read_picture(out3 / "similar.png").blobs() >= 4  # the query and its 3 matches
    # unknown part name: one-line usage error
    assert main(["similar", str(shapes / "chair_0000.ply"), str(shapes), *common, "--parts", "wings", "-o", str(tmp_path / "x")]) == 2
    assert "unknown part 'wings'" in capsys.readouterr().err


def test_embed_refine_passes_through(tmp_path):
    """``--refine N`` gives the descriptors of the library's refined cuboids, which differ from the network's."""
    from primkit import data, synthetic
    from primkit.model.abstractor import Abstractor
    from primkit.cli import main

    shapes = tmp_path / "chairs"
    synthetic.write_collection(shapes, "chair", 4, seed=7)
    cache = tmp_path / "cache"
    common = ["--model", "chair", "--cache", str(cache), "--workers", "1", "--parts", "16,18"]
    assert main(["embed", str(shapes), *common, "--refine", "5", "-o", str(tmp_path / "r")]) == 0
    assert main(["embed", str(shapes), *common, "-o", str(tmp_path / "n")]) == 0
    model = Abstractor.load("chair")
    coll = data.prepare_collection(sorted(shapes.glob("*.ply")), model.settings, cache_dir=cache, workers=1)
    expected = PartDescriptor("16,18").fit_transform(model.predict(list(coll), refine=5))
    got = np.load(tmp_path / "r" / "descriptors.npy")
    assert np.allclose(got, expected, atol=1e-5)
    assert not np.allclose(got, np.load(tmp_path / "n" / "descriptors.npy"), atol=1e-5)


# ---- scikit-learn: PartDescriptor and AbstractionTransformer as estimators ---------------------------

from sklearn.base import clone  # noqa: E402
from sklearn.utils.estimator_checks import parametrize_with_checks  # noqa: E402

# the estimator declares a cuboid table as its input (scikit-learn's own tags), so the checks that fit
# on generic data of 1-10 columns skip themselves; tests/test_sklearn.py shows that they are exactly
# the ones that fail with the tag lifted, and repeats what they check on real tables
@parametrize_with_checks([PartDescriptor()])
def test_part_descriptor_passes_scikit_learns_checks(estimator, check):
    check(estimator)


def random_table(rng, s, m=6):
    """A cuboid table laid out as CUBOID_COLUMNS, with its Cuboids."""
    cubs = random_cuboids(rng, s, m)
    return np.stack([np.concatenate([c.half_extents, c.quaternions, c.translations, c.existence[:, None]], 1).ravel()
                     for c in cubs]), cubs


def test_part_descriptor_reads_tables_as_it_reads_cuboids():
    import pickle

    rng = np.random.default_rng(3)
    X, cubs = random_table(rng, 12)
    assert X.shape == (12, 6 * len(embedding.CUBOID_COLUMNS))
    ref = PartDescriptor(parts="1,4").fit(cubs)
    est = PartDescriptor(parts="1,4").fit(X)
    assert np.allclose(est.transform(X), ref.transform(cubs), atol=1e-12) and est.n_features_in_ == X.shape[1]
    assert np.allclose(est.fill_["orientation"], ref.fill_["orientation"], atol=1e-12)
    # a CuboidTable is the same numbers; the fit is idempotent; rows are independent of order and subset
    table = embedding.CuboidTable.from_cuboids(cubs)
    assert np.array_equal(np.asarray(table), X) and table.feature_names()[11] == "part1.size.x"
    Y = est.transform(table)
    assert np.array_equal(clone(est).fit(X).transform(X), Y)
    perm = rng.permutation(12)
    assert np.array_equal(est.transform(X[perm]), Y[perm]) and np.array_equal(est.transform(X[3:5]), Y[3:5])
    assert np.array_equal(pickle.loads(pickle.dumps(est)).transform(X), Y)
    ro = X.copy()
    ro.flags.writeable = False
    assert np.array_equal(est.transform(ro), Y)
    assert list(est.get_feature_names_out()) == est.feature_names_ and len(est.feature_names_) == Y.shape[1]
    bad = X.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        est.transform(bad)
    with pytest.raises(ValueError, match="11 columns per part slot"):
        PartDescriptor().fit(X[:, :-1])
    with pytest.raises(ValueError, match="features"):
        est.transform(X[:, :-11])


def test_part_descriptor_clone_and_params():
    est = PartDescriptor(parts="back", what="orientation", scales={"orientation": 30.0}, part_names=["back", "seat"])
    twin = clone(est)
    assert twin is not est and twin.get_params() == est.get_params()
    assert twin.set_params(parts="seat").parts == "seat" and est.parts == "back"
    a, b = two_part(), two_part(q0=axis_angle_quaternion([0, 1, 0], 30.0))
    assert PartDescriptor(parts="back", part_names=["back", "seat"]).fit([a, b]).get_feature_names_out()[0] == "back.size.x"
    # names shared by several slots get the index: no two columns share a name
    shared = PartDescriptor(part_names=["legs", "legs"]).fit([a, b]).get_feature_names_out()
    assert len(set(shared)) == len(shared) and shared[0] == "legs0.size.x"


@pytest.mark.integration  # a scikit-learn pipeline over chairs: seconds, left to the default suite
@pytest.mark.parametrize("form", ["arrays", "paths"])
def test_abstraction_pipeline_on_procedural_chairs(tmp_path, form):
    """make_pipeline(AbstractionTransformer("chair"), PartDescriptor(parts="back"), TSNE()) on a few
    procedural chairs, given as (vertices, faces) or as files; the middle step equals the library's own."""
    from sklearn.manifold import TSNE
    from sklearn.pipeline import make_pipeline

    from primkit import synthetic
    from primkit.embedding import AbstractionTransformer
    from primkit.model.abstraction import abstract_shapes

    chairs = synthetic.generate("chair", 6, seed=21)
    if form == "arrays":
        X = [(c.vertices, c.faces) for c in chairs]
    else:
        X = synthetic.write_collection(tmp_path / "in", "chair", 6, seed=21)
    step = AbstractionTransformer("chair", workers=1, cache=tmp_path / "cache")
    twin = clone(step)
    assert twin.get_params() == step.get_params() and not hasattr(twin, "model_")
    pipe = make_pipeline(step, PartDescriptor(parts="back"), TSNE(perplexity=2.0, init="random", random_state=0))
    Y = pipe.fit_transform(X)
    assert Y.shape == (6, 2) and np.all(np.isfinite(Y))
    # the descriptor in the pipeline resolved "back" through the part names the table carried
    back = pipe[1].parts_
    assert [pipe[0].part_names_[k] for k in back] == ["back"] * len(back) and len(back) >= 1
    table = pipe[0].transform(X)
    assert table.shape == (6, 11 * 20) and list(pipe[0].get_feature_names_out()) == table.feature_names()
    expected = PartDescriptor(parts="back", part_names=step.model_.part_names).fit_transform(
        abstract_shapes(X, "chair", workers=1, cache=tmp_path / "cache", progress=False).results)
    assert np.allclose(pipe[:2].transform(X), expected, atol=1e-9)
    with pytest.raises(ValueError, match="folder"):
        step.transform([tmp_path])


@pytest.mark.parametrize("check", ["check_get_params_invariance", "check_set_params", "check_estimator_cloneable",
                                   "check_estimator_repr", "check_no_attributes_set_in_init",
                                   "check_parameters_default_constructible", "check_do_not_raise_errors_in_init_or_set_params",
                                   "check_estimator_tags_renamed", "check_valid_tag_types", "check_mixin_order",
                                   "check_get_feature_names_out_error"])
def test_abstraction_transformer_passes_the_checks_that_need_no_numeric_data(check):
    """The transformer takes shapes, not numbers, so only scikit-learn's checks of parameters, tags
    and cloning apply (the pipeline test above runs it on shapes)."""
    import sklearn.utils.estimator_checks as checks

    from primkit.embedding import AbstractionTransformer

    est = AbstractionTransformer("chair")
    getattr(checks, check)("AbstractionTransformer", est)
    assert est.__sklearn_tags__().input_tags.two_d_array is False


def test_set_output_default_keeps_arrays():
    rng = np.random.default_rng(5)
    X, _ = random_table(rng, 5)
    est = PartDescriptor(parts="0,2").set_output(transform="default")
    Y = est.fit_transform(X)
    assert isinstance(Y, np.ndarray) and Y.shape == (5, 2 * 16)

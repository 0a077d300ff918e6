"""primkit's scikit-learn estimators as a scikit-learn user meets them: the README's pipeline on 12
shapes, pandas output with named columns through a pipeline, ``GridSearchCV`` over a precomputed
cuboid table with ``parts`` in the grid, and ``check_estimator`` on both estimators."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.model_selection import GridSearchCV
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import make_pipeline
from sklearn.utils.estimator_checks import check_estimator

from primkit import embedding
from primkit.embedding import AbstractionTransformer, CuboidTable, PartDescriptor

ROOT = Path(__file__).resolve().parents[1]
CHAIR_NAMES = ["legs", "seat", "back", "legs", "back"]  # a name shared by slots, as the chair model's


def _table(rng, s, names=CHAIR_NAMES) -> CuboidTable:
    m = len(names)
    q = rng.normal(size=(s, m, 4))
    rows = np.concatenate([rng.uniform(0.02, 0.3, (s, m, 3)), q / np.linalg.norm(q, axis=-1, keepdims=True),
                           rng.uniform(-0.4, 0.4, (s, m, 3)), (rng.random((s, m, 1)) < 0.7).astype(float)], axis=2)
    return CuboidTable(rows.reshape(s, -1), tuple(names), tuple(f"shape{i}" for i in range(s)))


# ---- the README's pipeline and pandas output, on shapes ------------------------------------------


@pytest.fixture(scope="module")
def twelve_chairs(tmp_path_factory):
    from primkit import synthetic

    root = tmp_path_factory.mktemp("sk")
    return sorted(synthetic.write_collection(root / "chairs", "chair", 12, seed=4)), root / "cache"


@pytest.mark.integration  # abstracts 12 procedural chairs: seconds
def test_the_readmes_pipeline_maps_twelve_shapes(twelve_chairs):
    from sklearn.manifold import TSNE  # noqa: F401 - the README's expression names it

    shapes, cache = twelve_chairs
    text = (ROOT / "README.md").read_text()
    expression = re.search(r"`(make_pipeline\(AbstractionTransformer.*?\))`", text).group(1)
    pipe = eval(expression, {"make_pipeline": make_pipeline, "AbstractionTransformer": AbstractionTransformer,
                             "PartDescriptor": PartDescriptor, "TSNE": TSNE, "shapes": shapes})
    pipe.steps[0][1].set_params(cache=cache, workers=1)
    xy = pipe.fit_transform(shapes)
    assert xy.shape == (12, 2) and np.isfinite(xy).all()


@pytest.mark.integration  # abstracts 12 procedural chairs (cached by the test above when run together)
def test_pandas_output_through_the_pipeline_has_named_columns(twelve_chairs):
    pd = pytest.importorskip("pandas")
    shapes, cache = twelve_chairs
    pipe = make_pipeline(AbstractionTransformer("chair", cache=cache, workers=1), PartDescriptor(parts="back"))
    plain = clone(pipe).fit_transform(shapes)
    frame = pipe.set_output(transform="pandas").fit_transform(shapes)
    assert isinstance(frame, pd.DataFrame) and frame.shape == plain.shape == (12, len(pipe[1].feature_names_))
    assert list(frame.columns) == list(pipe[1].get_feature_names_out()) == list(pipe.get_feature_names_out())
    assert frame.columns[0].startswith("back") and np.allclose(frame.to_numpy(), plain)
    # the transformer's own frame: its columns name the parts, which the descriptor read back
    table = pipe[0].transform(shapes)
    assert isinstance(table, pd.DataFrame) and list(table.columns) == pipe[0].get_feature_names_out().tolist()
    assert pipe[1].part_names_ == pipe[0].part_names_


def test_pandas_frames_carry_the_part_names_shared_or_not():
    pd = pytest.importorskip("pandas")
    table = _table(np.random.default_rng(0), 6)
    frame = pd.DataFrame(table, columns=table.feature_names())  # what set_output makes of a table
    assert frame.shape == table.shape and np.array_equal(frame.to_numpy(), table.values)
    assert frame.columns[0] == "legs0.size.x" and "seat.present" in frame.columns
    est = PartDescriptor(parts="back").fit(frame)
    assert est.part_names_ == CHAIR_NAMES and list(est.parts_) == [2, 4]
    assert np.array_equal(est.transform(frame), PartDescriptor(parts="back").fit(table).transform(table))
    assert embedding._names_from_columns(CuboidTable(table.values, ("part0", "b3", "c", "part3", "x")).feature_names()) \
        == ["part0", "b3", "c", "part3", "x"]
    # columns of another layout carry no names: the default ones, as for a plain array
    other = pd.DataFrame(table.values, columns=[f"c{i}" for i in range(table.shape[1])])
    assert PartDescriptor().fit(other).part_names_ == [f"part{k}" for k in range(5)]


# ---- a precomputed table through GridSearchCV ----------------------------------------------------


def test_a_table_keeps_its_names_through_indexing():
    table = _table(np.random.default_rng(1), 8)
    sub = table[np.array([5, 1, 2])]
    assert isinstance(sub, CuboidTable) and sub.part_names == table.part_names
    assert sub.names == ("shape5", "shape1", "shape2") and np.array_equal(sub.values, table.values[[5, 1, 2]])
    assert np.array_equal(table[[0, 3], ...].values, table.values[[0, 3]])  # as scikit-learn indexes
    assert table[table.values[:, 10] > 0.5].shape[0] == int((table.values[:, 10] > 0.5).sum())
    assert np.array_equal(table[2], table.values[2]) and len(table[1:4]) == 3
    with pytest.raises(IndexError):
        table[:, 3]


def test_grid_search_over_a_precomputed_table_with_parts_in_the_grid():
    rng = np.random.default_rng(2)
    table = _table(rng, 30)
    # a label that the seat's size decides: searching by parts must pick the seat
    y = (table.values[:, 11:14].sum(axis=1) > np.median(table.values[:, 11:14].sum(axis=1))).astype(int)
    search = GridSearchCV(make_pipeline(PartDescriptor(what="size"), KNeighborsClassifier(3)),
                          {"partdescriptor__parts": ["back", "seat", "legs"]}, cv=3, error_score="raise")
    search.fit(table, y)
    assert search.best_params_ == {"partdescriptor__parts": "seat"}
    assert search.cv_results_["mean_test_score"][1] > 0.8
    assert search.best_estimator_[0].part_names_ == CHAIR_NAMES


# ---- scikit-learn's estimator checks ------------------------------------------------------------


def test_check_estimator_passes_on_both_estimators():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SkipTestWarning: the generic-data checks, declared by the tags
        for est in (PartDescriptor(), PartDescriptor(parts="back", what="size"), AbstractionTransformer("chair")):
            results = check_estimator(est, on_fail=None)
            assert results and all(r["status"] != "failed" for r in results), type(est).__name__
            assert est.__sklearn_tags__().input_tags.two_d_array is False


class _AnyArray(PartDescriptor):
    """The descriptor with its tag lifted, so that every check of scikit-learn runs on it."""

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.two_d_array = True
        return tags


#: scikit-learn's checks that fit on generic data of 1-10 columns, which no cuboid table is
GENERIC_DATA = {
    "check_fit_score_takes_y", "check_estimators_overwrite_params", "check_dont_overwrite_parameters",
    "check_estimators_fit_returns_self", "check_readonly_memmap_input", "check_n_features_in_after_fitting",
    "check_positive_only_tag_during_fit", "check_estimators_dtypes", "check_dtype_object", "check_pipeline_consistency",
    "check_estimators_nan_inf", "check_estimators_pickle", "check_f_contiguous_array_estimator",
    "check_transformer_data_not_an_array", "check_transformer_general", "check_transformer_preserve_dtypes",
    "check_methods_sample_order_invariance", "check_methods_subset_invariance", "check_fit2d_1sample",
    "check_fit2d_1feature", "check_dict_unchanged", "check_fit_idempotent", "check_fit_check_is_fitted",
    "check_n_features_in", "check_fit2d_predict1d",
}


def test_with_the_tag_lifted_only_the_generic_data_checks_fail():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        results = check_estimator(_AnyArray(), on_fail=None)
    failed = {r["check_name"] for r in results if r["status"] == "failed"}
    passed = {r["check_name"] for r in results if r["status"] == "passed"}
    assert failed == GENERIC_DATA and len(failed) == 25
    assert {"check_get_params_invariance", "check_set_params", "check_estimators_unfitted",
            "check_no_attributes_set_in_init", "check_estimators_empty_data_messages"} <= passed
    for r in results:  # each failure is the table layout, not something else
        if r["status"] == "failed":
            assert "11 columns per part slot" in str(r["exception"]) or "cuboid table" in str(r["exception"]) \
                or "positive" in str(r["exception"]), (r["check_name"], r["exception"])

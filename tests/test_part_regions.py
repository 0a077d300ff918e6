"""Parts described by their labelled voxels (primkit.embedding.region_properties, RegionTable,
RegionDescriptor), the retrieval scores (retrieval_gain, distance_spearman) against brute force, and
``similar --parts back``'s picture with the parts highlighted."""

import itertools

import numpy as np
import pytest

from primkit import embedding
from primkit.embedding import REGION_WEIGHTS, RegionDescriptor, RegionTable, region_properties

BACK, SEAT, LEGS, ARMS = range(4)
NAMES = ["back", "seat", "legs", "arms"]


def chair(back_height=16, leg_inset=0, arms=False, leg_height=10, R=32):
    """A voxel chair: ``(occupancy, labels)``, labels back 0, seat 1, legs 2, arms 3 (-1 empty).
    Index axes x front, y up, z side, as the canonical grid. Seat: x 8-23, z 8-23, two cells thick
    on top of the legs; back: x 8-9 on the seat, ``back_height`` cells; legs: 2x2 posts ``leg_inset``
    cells in from the seat's corners; arms: x 10-21 at both sides, 1 cell wide, 1 thick, 6 above the seat."""
    labels = np.full((R, R, R), -1)
    top = leg_height
    lo, hi = 8 + leg_inset, 22 - leg_inset
    for x, z in itertools.product((lo, hi), (lo, hi)):
        labels[x:x + 2, 0:top, z:z + 2] = LEGS
    labels[8:24, top:top + 2, 8:24] = SEAT
    labels[8:10, top + 2:top + 2 + back_height, 8:24] = BACK
    if arms:
        labels[10:22, top + 8, 8] = ARMS
        labels[10:22, top + 8, 23] = ARMS
    return labels >= 0, labels


def test_region_properties_in_closed_form():
    occupancy, labels = chair()
    values, present = region_properties(occupancy, labels, 4)
    assert present.tolist() == [True, True, True, False]
    height = 10 + 2 + 16  # legs, seat, back
    total = 16 * 10 + 16 * 16 * 2 + 2 * 16 * 16
    # back: 16 high, 16 wide, 2 deep; a solid panel two cells thick
    np.testing.assert_allclose(values["extent"][BACK], np.array([16, 16, 2]) / height)
    np.testing.assert_allclose(values["share"][BACK], [2 * 16 * 16 / total])
    np.testing.assert_allclose(values["thickness"][BACK], [2 / height])
    np.testing.assert_allclose(values["fill"][BACK], [1.0])
    # its centroid: y 12 + 8 = 20 against the chair's centre 14; x 9 against 16 (the chair's box is x 8-24)
    np.testing.assert_allclose(values["place"][BACK], np.array([20 - 14, 16 - 16, 9 - 16]) / height)
    # legs: four 2x2 posts 10 high at the corners of a 16 x 16 square; thinnest extent the height
    np.testing.assert_allclose(values["extent"][LEGS], np.array([10, 16, 16]) / height)
    np.testing.assert_allclose(values["fill"][LEGS], [160 / (10 * 16 * 16)])
    np.testing.assert_allclose(values["thickness"][LEGS], [160 / 16 / height])
    assert np.all(values["extent"][ARMS] == 0) and np.all(values["signature"][ARMS] == 0)


def test_signature_is_the_histogram_of_all_cell_distances():
    occupancy, labels = chair(back_height=8)
    values, _ = region_properties(occupancy, labels, 4)
    cells = np.argwhere(labels == BACK)  # 256 cells: under max_elements, all of them
    height = 10 + 2 + 8
    counts = np.zeros(embedding.SIGNATURE_BINS)
    width = embedding.SIGNATURE_RANGE / embedding.SIGNATURE_BINS
    for i in range(len(cells)):
        for j in range(i + 1, len(cells)):
            d = np.sqrt(((cells[i] - cells[j]) ** 2).sum()) / height
            counts[min(int(d / width), embedding.SIGNATURE_BINS - 1)] += 1
    np.testing.assert_allclose(values["signature"][BACK], counts / counts.sum())


def _table(*chairs):
    occ, lab = zip(*chairs)
    return RegionTable.from_grids(list(occ), list(lab), NAMES)


def test_identical_backs_are_at_distance_0_by_back_and_apart_by_legs():
    # a and b differ in their legs only (inset posts: same count and height, so the back's share
    # and the chair's height are the same); c differs in both, so no property is constant
    table = _table(chair(), chair(leg_inset=3), chair(back_height=10, leg_height=12))
    for part, same in (("back", True), ("legs", False), ("seat", True)):
        X = RegionDescriptor(part).fit_transform(table)
        d = np.linalg.norm(X[0] - X[1])
        assert (d == pytest.approx(0.0, abs=1e-12)) if same else d > 0.5, (part, d)
        assert np.linalg.norm(X[0] - X[2]) > 0.5
    # the descriptor: each component standardised over the chairs, times its property's weight
    desc = RegionDescriptor("legs", what="extent,share").fit(table)
    v = np.hstack([table.values["extent"][:, LEGS], table.values["share"][:, LEGS]])
    z = (v - v.mean(0)) / np.where(v.std(0) > 0, v.std(0), 1)
    w = np.array([REGION_WEIGHTS["extent"]] * 3 + [REGION_WEIGHTS["share"]])
    np.testing.assert_allclose(desc.transform(table), z * w, atol=1e-12)


def test_absent_part_and_weights():
    table = _table(chair(arms=True), chair(), chair(back_height=12, arms=True))
    assert table.present[:, ARMS].tolist() == [True, False, True]
    desc = RegionDescriptor("arms", what="extent,signature", weights={"signature": 2.0}).fit(table)
    X = desc.transform(table)
    assert X.shape == (3, 3 + embedding.SIGNATURE_BINS)
    assert desc.feature_names_[0] == "arms.extent.height" and desc.feature_names_[-1].startswith("arms.signature.d")
    # the absent arms: extent 0 (standardised), signature the mean of the present ones' (0 after standardising)
    ext = table.values["extent"][:, ARMS]
    np.testing.assert_allclose(X[1, :3], (0 - ext.mean(0)) / np.where(ext.std(0) > 0, ext.std(0), 1))
    np.testing.assert_allclose(X[1, 3:], 0.0, atol=1e-12)
    # default properties: those weighted above 0; a 0-weight property asked for counts 1
    assert RegionDescriptor().fit(table).what_ == tuple(p for p, w in REGION_WEIGHTS.items() if w > 0)
    assert RegionDescriptor(what="fill").fit(table).weights_["fill"] == (REGION_WEIGHTS["fill"] or 1.0)
    with pytest.raises(ValueError, match="no property with a weight above 0"):
        RegionDescriptor(what="fill", weights={"fill": 0.0}).fit(table)
    with pytest.raises(ValueError, match="unknown property"):
        RegionDescriptor(what="size").fit(table)
    with pytest.raises(ValueError, match="must be >= 0"):
        RegionDescriptor(weights={"share": -1}).fit(table)
    with pytest.raises(ValueError, match="not the fitted ones"):
        desc.transform(RegionTable.from_grids([chair()[0]], [chair()[1]], ["a", "b", "c", "d"]))
    # rows of a table
    assert np.array_equal(table[1:].present, table.present[1:]) and table[[2]].names == (table.names[2],)


def test_the_cli_help_states_the_region_weights():
    from primkit.cli.embed import _WEIGHTS_HELP

    stated = dict(item.split("=") for item in _WEIGHTS_HELP.split(", "))
    assert {k: float(v) for k, v in stated.items()} == REGION_WEIGHTS


def _brute_gain(D, T, k):
    s = len(D)
    ranked, best, random = [], [], []
    for i in range(s):
        others = [j for j in range(s) if j != i]
        by_d = sorted(others, key=lambda j: (D[i, j], j))[:k]
        by_t = sorted(others, key=lambda j: (T[i, j], j))[:k]
        ranked.append(np.mean([T[i, j] for j in by_d]))
        best.append(np.mean([T[i, j] for j in by_t]))
        random.append(np.mean([T[i, j] for j in others]))
    return (np.mean(random) - np.mean(ranked)) / (np.mean(random) - np.mean(best))


def test_retrieval_gain_and_spearman_against_brute_force():
    from scipy.spatial.distance import pdist, squareform

    rng = np.random.default_rng(3)
    truth = rng.normal(size=(40, 4))
    T = squareform(pdist(truth))
    noisy = squareform(pdist(truth + rng.normal(scale=0.7, size=truth.shape)))
    unrelated = squareform(pdist(rng.normal(size=(40, 4))))
    for D in (noisy, unrelated, T):
        for k in (1, 5):
            assert embedding.retrieval_gain(D, T, k) == pytest.approx(_brute_gain(D, T, k), abs=1e-12)
    assert embedding.retrieval_gain(T, T, 5) == pytest.approx(1.0)
    assert embedding.retrieval_gain(noisy, T, 5) > 0.3 > abs(embedding.retrieval_gain(unrelated, T, 5))
    # Spearman: Pearson's correlation of the ranks of the distinct pairs (no ties here)
    upper = np.triu_indices(40, 1)
    ranks = [np.argsort(np.argsort(M[upper])) for M in (noisy, T)]
    assert embedding.distance_spearman(noisy, T) == pytest.approx(np.corrcoef(*ranks)[0, 1], abs=1e-12)
    with pytest.raises(ValueError, match="k must be"):
        embedding.retrieval_gain(T, T, 40)


@pytest.mark.integration  # abstracts and renders a few procedural chairs: several seconds
def test_similar_by_back_highlights_the_backs(tmp_path):
    from pictures import read_picture

    from primkit import synthetic
    from primkit.cli import main
    from primkit.model.abstraction import abstract_shapes
    from primkit.model.bundled import resolve_model
    from primkit.segmentation.bylabel import labelled_grid, labelled_voxels
    from primkit.segmentation.labeller import read_labeller
    from primkit.viz.palette import label_colors

    folder = tmp_path / "chairs"
    paths = sorted(synthetic.write_collection(folder, "chair", 8, seed=2))
    # labelled_grid is labelled_voxels written into the grid
    labeller = read_labeller(resolve_model("chair"))
    a = next(iter(abstract_shapes(paths[:1], "chair")))
    occupancy = a.canonical_shape().occupancy
    grid = labelled_grid(labeller, occupancy, a.result.canonical)
    points, named = labelled_voxels(labeller, occupancy, a.result.canonical)
    cells = np.rint((points + 0.5) * occupancy.shape[0] - 0.5).astype(int)
    assert np.array_equal(grid[tuple(cells.T)], named) and (grid[~occupancy] == -1).all()

    back = label_colors(len(labeller.names))[labeller.names.index("back")]
    k = 3
    for metric, highlighted in (("descriptor", True), ("voxel-iou", False)):
        png = tmp_path / f"{metric}.png"
        assert main(["similar", str(paths[0]), str(folder), "--model", "chair", "--parts", "back", "--metric", metric,
                     "-k", str(k), "-o", str(tmp_path / metric), "--png", str(png), "-q"]) == 0
        picture = read_picture(png)
        width = picture.size[0]
        panels = [picture.crop(i * width // (k + 1), (i + 1) * width // (k + 1)) for i in range(k + 1)]
        shown = [p.colour_pixels(back, tolerance=0.05) for p in panels]
        if highlighted:  # the query's back and each match's back in the back's colour
            assert min(shown) > 150, shown
        else:
            assert max(shown) < 20, shown
        assert all(p.blobs(min_pixels=300) >= 1 for p in panels)

"""The graph-cut labelling: the solver against brute force on tiny graphs, the graphs against
direct constructions, and on a procedural chair smoother labels without losing agreement."""

import itertools

import numpy as np
import pytest

from primkit import io, primitives, segmentation, synthetic
from primkit.segmentation import graphcut


def _random_problem(rng, n, k, density=0.5):
    unary = rng.random((n, k))
    edges = np.array([(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < density], np.int64)
    edges = edges.reshape(-1, 2)
    weights = rng.random(len(edges)) * rng.choice([0.1, 0.5, 2.0])
    return unary, edges, weights


def _brute_force_minimum(unary, edges, weights):
    n, k = unary.shape
    return min(graphcut.mrf_energy(np.array(c), unary, edges, weights) for c in itertools.product(range(k), repeat=n))


def test_energy_matches_a_direct_sum():
    unary = np.array([[0.0, 1.0], [2.0, 0.5], [0.3, 0.3]])
    edges = np.array([[0, 1], [1, 2]])
    weights = np.array([0.7, 0.2])
    # labels (0, 1, 1): unary 0 + 0.5 + 0.3, edge 0-1 cut (0.7), edge 1-2 not
    assert graphcut.mrf_energy([0, 1, 1], unary, edges, weights) == pytest.approx(1.5)


def test_two_labels_reach_the_brute_force_minimum():
    rng = np.random.default_rng(0)
    for _ in range(60):
        unary, edges, weights = _random_problem(rng, int(rng.integers(2, 10)), 2)
        labels = graphcut.alpha_expansion(unary, edges, weights)
        best = _brute_force_minimum(unary, edges, weights)
        assert graphcut.mrf_energy(labels, unary, edges, weights) == pytest.approx(best, rel=1e-6, abs=1e-9)


def test_many_labels_never_worse_than_nearest_or_random_and_within_the_bound():
    rng = np.random.default_rng(1)
    for _ in range(40):
        n, k = int(rng.integers(2, 8)), int(rng.integers(3, 5))
        unary, edges, weights = _random_problem(rng, n, k)
        labels = graphcut.alpha_expansion(unary, edges, weights)
        energy = graphcut.mrf_energy(labels, unary, edges, weights)
        assert energy <= graphcut.mrf_energy(unary.argmin(axis=1), unary, edges, weights) + 1e-12
        for _ in range(5):
            assert energy <= graphcut.mrf_energy(rng.integers(0, k, n), unary, edges, weights) + 1e-12
        # alpha-expansion is within 2x of the minimum for a Potts energy
        assert energy <= 2 * _brute_force_minimum(unary, edges, weights) + 1e-12


def test_no_smoothness_gives_the_unary_minimum():
    rng = np.random.default_rng(2)
    unary, edges, _ = _random_problem(rng, 30, 4)
    labels = graphcut.alpha_expansion(unary, edges, np.zeros(len(edges)))
    np.testing.assert_array_equal(labels, unary.argmin(axis=1))


def test_without_edges_each_element_takes_its_cheapest_label_from_any_start():
    rng = np.random.default_rng(6)
    unary = rng.random((20, 3))
    labels = graphcut.alpha_expansion(unary, np.zeros((0, 2), np.int64), np.zeros(0), init=rng.integers(0, 3, 20))
    np.testing.assert_array_equal(labels, unary.argmin(axis=1))


def test_voxel_graph_is_the_six_neighbourhood():
    rng = np.random.default_rng(3)
    occupied = rng.random((5, 4, 6)) < 0.5
    index = np.argwhere(occupied)
    edges, contact, mass = graphcut.voxel_graph(index)
    expected = {(i, j) for i in range(len(index)) for j in range(len(index))
                if i < j and np.abs(index[i] - index[j]).sum() == 1}
    assert {tuple(sorted(e)) for e in edges.tolist()} == expected
    assert len(edges) == len(expected)
    np.testing.assert_allclose(mass.sum(), 1.0)
    np.testing.assert_allclose(contact, len(index) ** (-2 / 3))


def test_point_graph_holds_every_nearest_neighbour():
    rng = np.random.default_rng(4)
    points = rng.random((40, 3))
    edges, _, mass = graphcut.point_graph(points, k=3)
    pairs = {tuple(e) for e in edges.tolist()}
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.fill_diagonal(d, np.inf)
    for i in range(len(points)):
        for j in np.argsort(d[i])[:3]:
            assert (min(i, j), max(i, j)) in pairs
    np.testing.assert_allclose(mass.sum(), 1.0)


def test_mesh_graph_on_a_box_weights_convex_creases_by_their_angle():
    import trimesh

    box = trimesh.creation.box([1.0, 2.0, 3.0])
    # a polygon soup: every face with its own three vertices
    vertices = box.vertices[box.faces].reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    edges, contact, mass = graphcut.mesh_graph(vertices, faces)
    assert len(edges) == 18  # 12 triangles, 3 neighbours each
    np.testing.assert_allclose(mass.sum(), 1.0)
    normals = box.face_normals
    expected = []
    for a, b in edges:
        shared = [v for v in vertices[faces[a]] if np.isclose(vertices[faces[b]], v).all(axis=1).any()]
        assert len(shared) == 2
        length = np.linalg.norm(shared[0] - shared[1])
        flat = np.isclose(normals[a] @ normals[b], 1.0)
        # every crease of a box is convex and right-angled: counted at 0.2 of its angle
        expected.append(length / np.sqrt(box.area) * (1.0 if flat else np.exp(-(0.2 * np.pi / 2) ** 2 / 0.5)))
    np.testing.assert_allclose(contact, expected, rtol=1e-9)


def _label_changes(vertices, faces, labels):
    edges, _, _ = graphcut.mesh_graph(vertices, faces)
    return int((labels[edges[:, 0]] != labels[edges[:, 1]]).sum())


def _agreement(labels, truth, weights):
    """Area share of faces whose index maps (by majority) to their generator part."""
    mapping = segmentation.majority_mapping([labels], [truth], [weights], labels.max() + 1, truth.max() + 1)
    return segmentation.accuracy(mapping[labels], truth, weights)


def test_on_a_procedural_chair_labels_are_smoother_and_agree_as_well():
    shape = synthetic.chair(7)
    vertices, faces, truth = shape.vertices, shape.faces, np.asarray(shape.face_labels)
    # one loose box per generator part: each part's bounds grown by 15% of the shape's size, so that
    # boxes overlap and the nearest rule cuts across panels where they meet
    size = np.ptp(vertices, axis=0)
    lows, highs = [], []
    for part in np.unique(truth):
        v = vertices[np.unique(faces[truth == part])]
        lows.append(v.min(axis=0) - 0.15 * size * np.array([1, 1, 1]))
        highs.append(v.max(axis=0) + 0.15 * size)
    lows, highs = np.array(lows), np.array(highs)
    count = len(lows)
    cuboids = primitives.Cuboids((highs - lows) / 2, [[1, 0, 0, 0]] * count, (highs + lows) / 2, [True] * count)
    areas = io.Mesh(vertices, faces).face_areas()
    nearest = segmentation.face_labels(vertices, faces, cuboids)
    cut = segmentation.segment_mesh(vertices, faces, cuboids, labelling="graphcut").face_labels
    assert _label_changes(vertices, faces, cut) < _label_changes(vertices, faces, nearest)
    assert _agreement(cut, truth, areas) >= _agreement(nearest, truth, areas) - 1e-9
    # the graph cut lowered its own energy
    edges, contact, mass = graphcut.mesh_graph(vertices, faces)
    samples = np.einsum("qc,fcd->fqd", segmentation.meshes._QUADRATURE[:4], vertices[faces])
    unary = graphcut.cuboid_costs(samples, cuboids, float(np.linalg.norm(size))) * mass[:, None]
    w = graphcut.DEFAULT_SMOOTHNESS["mesh"] * contact
    assert graphcut.mrf_energy(cut, unary, edges, w) <= graphcut.mrf_energy(nearest, unary, edges, w)


def test_voxel_and_point_labelling_run_and_keep_present_parts():
    cuboids = primitives.Cuboids([[0.5, 0.1, 0.5], [0.1, 0.5, 0.5], [0.2, 0.2, 0.2]], [[1, 0, 0, 0]] * 3,
                                 [[0, 0, 0], [0.4, 0.5, 0], [5, 5, 5]], [True, True, False])
    occupancy = np.zeros((16, 16, 16), bool)
    occupancy[2:14, 6:9, 2:14] = True
    occupancy[11:14, 6:15, 2:14] = True
    grid = io.VoxelGrid(occupancy, translate=np.array([-0.8, -0.8, -0.8]), scale=1.6)
    labels = segmentation.label_voxels(grid, cuboids, labelling="graphcut")
    assert set(np.unique(labels[occupancy])) <= {0, 1}
    assert (labels[~occupancy] == -1).all()
    points = segmentation.voxel_centres(grid)[0]
    seg = segmentation.segment_points(io.PointCloud(points), cuboids, labelling="graphcut")
    assert set(np.unique(seg.labels)) <= {0, 1}


def test_unknown_labelling_is_refused():
    with pytest.raises(ValueError, match="labelling"):
        graphcut.Labelling("smooth")
    with pytest.raises(ValueError, match="smoothness"):
        graphcut.Labelling("graphcut", -1.0)


def test_cuboid_costs_match_the_primitives_distance():
    rng = np.random.default_rng(5)
    cuboids = primitives.Cuboids(rng.uniform(0.05, 0.3, (6, 3)), rng.normal(size=(6, 4)), rng.uniform(-0.5, 0.5, (6, 3)),
                                 [True, False, True, True, False, True])
    samples = rng.uniform(-1, 1, (50, 4, 3))
    d2 = primitives.point_cuboid_distance(samples.reshape(-1, 3), cuboids, squared=True)[:, cuboids.present]
    expected = d2.reshape(50, 4, -1).mean(axis=1) / 2.0**2
    np.testing.assert_allclose(graphcut.cuboid_costs(samples, cuboids, 2.0), expected, rtol=1e-9, atol=1e-15)


def test_a_part_the_cut_would_erase_keeps_its_nearest_elements():
    # a 12 x 3 x 12 voxel slab explained by one large cuboid and a small one over a 2 x 1 x 2 corner
    # (a network's thin arm): the cut's boundary around the small part costs more than its data term
    # saves, so without `keep` it goes to the large part; with it, it gets exactly its nearest-rule
    # voxels back and every other voxel keeps the cut's label
    cuboids = primitives.Cuboids([[0.45, 0.15, 0.45], [0.06, 0.15, 0.06]], [[1, 0, 0, 0]] * 2,
                                 [[-0.1, -0.05, -0.1], [0.5, -0.05, 0.5]], [True, True])
    occupancy = np.zeros((16, 16, 16), bool)
    occupancy[2:14, 6:9, 2:14] = True
    grid = io.VoxelGrid(occupancy, translate=np.array([-0.8, -0.8, -0.8]), scale=1.6)
    centres, index = segmentation.voxel_centres(grid)
    init = segmentation.meshes.point_labels(centres, cuboids)
    assert 0 < (init == 1).sum() < 0.1 * len(init)  # the corner
    edges, contact, mass = graphcut.voxel_graph(index)
    args = (centres[:, None, :], edges, contact, mass, cuboids, init, 1e-2)
    erased = graphcut.graphcut_labels(*args, keep=False)
    kept = graphcut.graphcut_labels(*args)
    assert not (erased == 1).any()
    np.testing.assert_array_equal(kept == 1, init == 1)
    np.testing.assert_array_equal(kept[init != 1], erased[init != 1])
    assert set(np.unique(segmentation.label_voxels(grid, cuboids, labelling=graphcut.Labelling("graphcut", 1e-2))[occupancy])) == {0, 1}
    # a part the cut keeps is left as the cut made it
    np.testing.assert_array_equal(graphcut.keep_parts([0, 0, 1, 1], [0, 1, 1, 0]), [0, 0, 1, 1])
    np.testing.assert_array_equal(graphcut.keep_parts([0, 0, 0, 2], [0, 1, 1, 2]), [0, 1, 1, 2])

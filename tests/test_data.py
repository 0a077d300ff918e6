"""Preparation of meshes, voxel grids and point clouds, and the content-and-settings keyed cache."""

import logging
from io import BytesIO

import numpy as np
import pytest

from primkit import data, geometry, io, synthetic


def test_prepare_mesh_is_consistent_with_geometry(chairs, prepared_chairs):
    shape, prep = chairs[0], prepared_chairs[0]
    assert prep.occupancy.shape == (32, 32, 32) and prep.closest.shape == (32, 32, 32, 3)
    assert prep.points.shape == (10000, 3)
    v = prep.frame.to_canonical(shape.vertices)
    lo, hi = v.min(0), v.max(0)
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-9)
    assert np.isclose((hi - lo).max(), 1.0)
    # labels of samples are the labels of their faces
    assert np.array_equal(prep.point_labels, shape.face_labels[prep.point_faces])
    # solid is inside the network input, which also holds every surface cell
    assert not (prep.solid & ~prep.occupancy).any()
    surf = geometry.surface_voxels(v, shape.faces)
    assert np.array_equal(prep.occupancy, prep.solid | surf)
    # distances derived from the closest points match an independent library: to float32 within
    # 2 cells of a surface cell, and within the far cells' declared 3e-3 beyond (never nearer)
    import igl
    from scipy import ndimage

    d2, _, _ = igl.point_mesh_squared_distance(geometry.grid_centres(32).reshape(-1, 3), v, shape.faces)
    error = prep.distance.ravel() - np.sqrt(d2)
    near = ndimage.distance_transform_edt(~surf).ravel() <= 2
    assert np.abs(error[near]).max() < 1e-5 and -1e-5 < error.min() and error.max() < 3e-3


def test_prepared_shape_save_load_round_trip(tmp_path, prepared_chairs):
    p = prepared_chairs[1]
    p.save(tmp_path / "x.npz")
    q = data.PreparedShape.load(tmp_path / "x.npz")
    for key in ("occupancy", "solid", "closest", "points", "point_faces", "point_labels"):
        assert np.array_equal(getattr(p, key), getattr(q, key)), key
    np.testing.assert_allclose(q.frame.matrix, p.frame.matrix)


def test_prepare_voxels_keeps_voxels_and_frame():
    occ = np.zeros((32, 32, 32), bool)
    occ[3:13, 0:32, 5:12] = True  # 10 x 32 x 7 voxels, off centre
    occ[6:8, 10:12, 7:9] = False  # an enclosed cavity: filled by preparation
    grid = io.VoxelGrid(occ, translate=np.array([-0.3, -0.5, -0.2]), scale=0.9)
    prep = data.prepare(grid)
    assert prep.kind == "voxels"
    assert prep.solid.sum() == 10 * 32 * 7
    idx = np.argwhere(prep.solid)
    centre = (idx.min(0) + idx.max(0)) / 2.0
    assert np.all(np.abs(centre - 15.5) <= 0.5)
    # the frame maps the file's voxel centres onto the centres of the occupied cells
    src = np.argwhere(occ)
    world = grid.translate + (src + 0.5) / 32 * grid.scale
    can = prep.frame.to_canonical(world)
    cells = np.floor((can + 0.5) * 32).astype(int)
    np.testing.assert_allclose(can, -0.5 + (cells + 0.5) / 32, atol=1e-9)
    assert prep.solid[cells[:, 0], cells[:, 1], cells[:, 2]].all()
    # samples lie on the voxel boundary: distance to the grid's closest points is ~0 at those points
    assert np.abs(prep.points).max() <= 0.5 + 1e-9


def test_prepare_voxels_with_another_up_axis():
    occ = np.zeros((16, 16, 16), bool)
    occ[2:6, 4:8, 0:16] = True  # tall along z
    prep = data.prepare(io.VoxelGrid(occ, np.zeros(3), 1.0), data.PrepareSettings(resolution=16, up="+z", samples=500))
    idx = np.argwhere(prep.solid)
    extent = idx.max(0) - idx.min(0) + 1
    assert extent[1] == 16  # +z became +y


def test_prepare_points_approximates_the_mesh(chairs):
    shape = chairs[2]
    mesh_prep = data.prepare(io.Mesh(shape.vertices, shape.faces))
    pts = geometry.sample_surface(shape.vertices, shape.faces, 40000, seed=1).points
    prep = data.prepare(io.PointCloud(pts))
    assert prep.kind == "points"
    # nearest-sample distances overestimate the true distance by little
    diff = prep.distance - mesh_prep.distance
    # (the frames differ slightly: the samples' bounding box is a little inside the mesh's)
    assert diff.min() > -2e-3 and np.median(diff) < 0.01


def _keys(coll):
    return [seg.rows[j]["key"] for seg, j in coll.entries]


def _segments(cache):
    return sorted(p for p in (cache / f"v{data.CACHE_FORMAT}").iterdir() if not p.name.startswith("."))


def test_prepare_collection_cache_and_bad_files(tmp_path):
    folder = tmp_path / "shapes"
    paths = synthetic.write_collection(folder, "table", 3, seed=1)
    (folder / "broken.off").write_text("OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n")
    before = {p: p.read_bytes() for p in folder.iterdir()}
    cache = tmp_path / "cache"
    coll = data.prepare_collection(folder, cache_dir=cache, workers=2, progress=False)
    assert len(coll) == 3 and len(coll.errors) == 1
    assert coll.errors[0].startswith(str(folder / "broken.off")) and "\n" not in coll.errors[0]
    assert {p: p.read_bytes() for p in folder.iterdir()} == before  # inputs untouched
    files = set(cache.rglob("*.npy"))
    mtimes = {f: f.stat().st_mtime_ns for f in files}
    again = data.prepare_collection(folder, cache_dir=cache, workers=1, progress=False)
    assert _keys(again) == _keys(coll) and len(_segments(cache)) == 1
    assert set(cache.rglob("*.npy")) == files and {f: f.stat().st_mtime_ns for f in files} == mtimes  # nothing prepared twice
    # an edited file and a changed setting are prepared again
    shape = synthetic.table(99)
    io.write_mesh(paths[0], shape.vertices, shape.faces, overwrite=True)
    (folder / paths[0].with_suffix(".seg").name).write_text("\n".join(map(str, shape.face_labels)) + "\n")
    edited = data.prepare_collection(folder, cache_dir=cache, workers=1, progress=False)
    assert _keys(edited)[0] not in _keys(coll) and _keys(edited)[1:] == _keys(coll)[1:]
    other = data.prepare_collection(folder, data.PrepareSettings(samples=2000), cache_dir=cache, workers=1, progress=False)
    assert not set(_keys(other)) & set(_keys(edited))
    assert other[0].points.shape == (2000, 3)


@pytest.mark.parametrize("compact", [False, True])
def test_cached_shapes_are_the_prepared_ones_within_the_declared_error(tmp_path, compact):
    folder = tmp_path / "shapes"
    paths = synthetic.write_collection(folder, "chair", 2, seed=4)
    occ = np.zeros((32, 32, 32), bool)
    occ[4:28, 2:30, 9:20] = True
    occ[8:24, 10:30, 11:18] = False  # a hollow box: near and far cells inside and out
    io.write_voxels(folder / "grid.binvox", io.VoxelGrid(occ, np.zeros(3), 1.0))
    settings = data.PrepareSettings(samples=3000)
    coll = data.prepare_collection(folder, settings, cache_dir=tmp_path / "cache", workers=1, progress=False,
                                   compact=compact)
    near_err, far_err = geometry.closest_error(32) if compact else (0.0, 0.0)
    for i, path in enumerate(coll.paths):
        exact, got = data.prepare_file(path, settings), coll[i]
        assert got.name == data.shape_name(path) and got.source == str(path) and got.kind == exact.kind
        assert np.array_equal(got.occupancy, exact.occupancy) and np.array_equal(got.solid, exact.solid)
        assert np.array_equal(got.point_labels, exact.point_labels)
        assert (got.point_labels >= 0).all() == (exact.kind == "mesh")
        err = np.abs(got.closest - exact.closest).max(-1)
        offset = np.abs(exact.closest - geometry.grid_centres(32)).max(-1) * 32
        assert err[offset <= 1].max() <= near_err + 1e-6 and err.max() <= far_err + 1e-6
        point_err = np.array(geometry.POINT_ERROR) + 1e-6 if compact else 0.0
        assert (np.abs(got.points - exact.points).max(0) <= point_err).all()
        assert np.allclose(got.frame.to_canonical(np.eye(3)), exact.frame.to_canonical(np.eye(3)))
    assert len(coll) == len(paths) + 1


def test_a_cached_shape_takes_a_quarter_of_the_first_format(tmp_path):
    # the first format: PreparedShape.save's .npz (float32 closest points and samples, int32 ids)
    grid = io.VoxelGrid(np.pad(np.ones((20, 26, 12), bool), ((6, 6), (3, 3), (10, 10))), np.zeros(3), 1.0)
    settings = data.PrepareSettings()
    shape = data.prepare(grid, settings)
    shape.save(tmp_path / "first.npz")
    first = (tmp_path / "first.npz").stat().st_size
    segment = data.CacheSegment.from_rows(settings, [("k", data.cache.encode_row(shape, True))], True).save(tmp_path / "cache")
    now = sum(f.stat().st_size for f in segment.folder.iterdir())
    assert now <= first / 4, (now, first)
    exact = data.CacheSegment.from_rows(settings, [("k", data.cache.encode_row(shape, False))]).save(tmp_path / "cache")
    assert sum(f.stat().st_size for f in exact.folder.iterdir()) < first  # float32: no face ids, no labels of -1
    assert np.array_equal(exact.shape(0).closest, shape.closest) and np.array_equal(exact.shape(0).points, shape.points)
    assert np.array_equal(segment.shape(0).occupancy, shape.occupancy)


def _cache_notes(caplog) -> list:
    """The WARNING records about the cache since the last call (logger primkit.data.collection), then cleared."""
    lines = [r.getMessage() for r in caplog.records
             if r.name == "primkit.data.collection" and r.levelno == logging.WARNING and "cache" in r.getMessage()]
    caplog.clear()
    return lines


@pytest.mark.parametrize("compact", [False, True])
def test_damaged_cache_entries_are_prepared_again_and_said_once(tmp_path, caplog, monkeypatch, compact):
    monkeypatch.setenv("PRIMKIT_CACHE_CODES", "compact" if compact else "exact")
    monkeypatch.setattr(data.cache, "SEGMENT_SHAPES", 2)  # 5 shapes: segments of 2, 2 and 1
    folder = tmp_path / "shapes"
    synthetic.write_collection(folder, "chair", 5, seed=3)
    cache = tmp_path / "cache"
    settings = data.PrepareSettings(samples=500)
    first = data.prepare_collection(folder, settings, cache_dir=cache, workers=1, progress=False)
    reference = [first[i] for i in range(len(first))]
    segments = _segments(cache)
    assert len(segments) == 3
    with open(segments[0] / "closest.npy", "r+b") as fh:  # one row's bytes changed: a checksum fails
        fh.seek(-100, 2)
        fh.write(b"\xff" * 50)
    points = segments[1] / "points.npy"
    points.write_bytes(points.read_bytes()[:3000])  # truncated
    (segments[2] / "index.json").write_text("{garbage")
    caplog.clear()
    again = data.prepare_collection(folder, settings, cache_dir=cache, workers=1, progress=False)
    lines = _cache_notes(caplog)
    assert len(again) == 5 and not again.errors
    assert len(lines) == 1 and "damaged" in lines[0], lines
    for i in range(5):
        got = again[i]
        assert np.array_equal(got.closest, reference[i].closest) and np.array_equal(got.points, reference[i].points)
    data.prepare_collection(folder, settings, cache_dir=cache, workers=1, progress=False)
    assert not _cache_notes(caplog)  # repaired for good


def test_a_cache_of_the_other_codes_is_said_and_both_kinds_are_kept(tmp_path, caplog):
    folder = tmp_path / "shapes"
    synthetic.write_collection(folder, "chair", 2, seed=6)
    cache = tmp_path / "cache"
    settings = data.PrepareSettings(samples=500)
    exact = data.prepare_collection(folder, settings, cache_dir=cache, workers=1, progress=False, compact=False)
    caplog.clear()
    compact = data.prepare_collection(folder, settings, cache_dir=cache, workers=1, progress=False, compact=True)
    lines = _cache_notes(caplog)
    assert len(lines) == 1 and "2 shapes" in lines[0] and "stored as float32" in lines[0] and "as compact codes" in lines[0]
    assert len(_segments(cache)) == 2
    # each kind reads its own segment from now on, without a word
    for kind, want in ((False, exact), (True, compact)):
        again = data.prepare_collection(folder, settings, cache_dir=cache, workers=1, progress=False, compact=kind)
        assert not _cache_notes(caplog)
        assert all(np.array_equal(again[i].closest, want[i].closest) for i in range(2))
    assert not np.array_equal(exact[0].closest, compact[0].closest)  # the kinds differ, within the declared error


def test_an_old_cache_is_said_once_and_prepared_again(tmp_path, caplog):
    folder = tmp_path / "shapes"
    synthetic.write_collection(folder, "table", 2, seed=2)
    cache = tmp_path / "cache"
    (cache / "ab").mkdir(parents=True)
    table = synthetic.table(0)
    data.prepare(io.Mesh(table.vertices, table.faces), data.PrepareSettings(samples=100)).save(
        cache / "ab" / ("ab" + "0" * 62 + ".npz"))
    coll = data.prepare_collection(folder, data.PrepareSettings(samples=300), cache_dir=cache, workers=1, progress=False)
    lines = _cache_notes(caplog)
    assert len(coll) == 2 and not coll.errors
    assert len(lines) == 1 and "older format" in lines[0] and str(cache) in lines[0], lines


def test_an_unwritable_cache_prepares_in_memory(tmp_path, caplog):
    folder = tmp_path / "shapes"
    synthetic.write_collection(folder, "table", 3, seed=2)
    blocked = tmp_path / "cache"
    blocked.write_text("a file where the cache folder should be")  # mkdir fails, as on a read-only disk
    settings = data.PrepareSettings(samples=300)
    coll = data.prepare_collection(folder, settings, cache_dir=blocked, workers=2, progress=False)
    assert len(coll) == 3 and not coll.errors
    assert _cache_notes(caplog) == [f"cache: {blocked / f'v{data.CACHE_FORMAT}'} cannot be written (Not a directory): shapes prepared in memory"]
    assert coll[2].points.shape == (300, 3)
    assert blocked.read_text().startswith("a file")
    # the same values as through a cache
    cached = data.prepare_collection(folder, settings, cache_dir=tmp_path / "ok", workers=1, progress=False)
    assert all(np.array_equal(coll[i].closest, cached[i].closest) for i in range(3))


def test_label_count_mismatch_is_reported(tmp_path):
    """A .seg beside a mesh with another face count: said in a warning naming the .seg, and the
    mesh prepared without labels (labels serve only the commands that use them)."""
    shape = synthetic.chair(0)
    p = io.write_mesh(tmp_path / "c.ply", shape.vertices, shape.faces)
    (tmp_path / "c.seg").write_text("1\n2\n")
    with pytest.warns(UserWarning) as caught:
        prepared = data.prepare_file(p)
    assert str(caught[0].message).startswith(str(tmp_path / "c.seg"))
    assert "2 labels but the mesh has" in str(caught[0].message)
    assert (prepared.point_labels == -1).all() and prepared.info["labels_error"].startswith(str(tmp_path / "c.seg"))


@pytest.mark.shared
def test_shapenet_voxels_prepare(shared_data):
    files = sorted((shared_data / "shapenetvox32" / "03001627").iterdir())[:3]
    for folder in files:
        prep = data.prepare_file(folder / "model.binvox")
        vox = io.read_voxels(folder / "model.binvox")
        assert prep.solid.sum() >= vox.occupancy.sum()
        assert prep.solid.sum() == geometry.fill_voxels(vox.occupancy).sum()


@pytest.mark.parametrize("compact", [False, True], ids=["float32", "compact"])
def test_a_segment_streamed_to_disk_is_the_stacked_one(tmp_path, compact):
    """CacheSegment.write streams rows to the files; the same bytes as stacking then saving, and as
    NumPy's own np.save of the stacked arrays."""
    settings = data.PrepareSettings(samples=500)
    rng = np.random.default_rng(2)
    entries = []
    for i in range(5):
        occ = rng.random((32, 32, 32)) < 0.02
        occ[10:20, 10:22, 8:14] = True
        entries.append((f"k{i}", data.cache.encode_row(data.prepare(io.VoxelGrid(occ, np.zeros(3), 1.0), settings), compact)))
    streamed = data.CacheSegment.write(tmp_path / "a", settings, entries, compact)
    in_memory = data.CacheSegment.from_rows(settings, entries, compact)
    for name, values in in_memory.arrays.items():
        buffer = BytesIO()
        np.save(buffer, values)
        assert (streamed.folder / f"{name}.npy").read_bytes() == buffer.getvalue(), name
    stacked = in_memory.save(tmp_path / "b")
    files = sorted(p.name for p in stacked.folder.iterdir())
    assert files == sorted(p.name for p in streamed.folder.iterdir())
    for name in files:
        assert (streamed.folder / name).read_bytes() == (stacked.folder / name).read_bytes(), name
    assert all(streamed.verify(j) for j in range(len(entries)))

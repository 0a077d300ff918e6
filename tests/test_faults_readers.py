"""Readers of a user's or a worker's file answer in one line and allocate within their bounds: the
ParaView worker's ``.npz`` and the voxel label archives (truncated: a ``BadZipFile`` traceback
before; a small archive declaring GiBs: allocated before), and a labelled cloud's
``<stem>.labels.npy`` is never collected as a shape of its own."""

import io as pyio
import zipfile

import numpy as np
import pytest

from primkit import io
from primkit.data import find_shape_files
from primkit.plugins import paraview_worker
from primkit.segmentation.evaluation import VoxelLabelArchive


def _npz(path, **arrays):
    np.savez_compressed(path, **arrays)
    return path


def _lying_npz(path, name="points", shape=(400_000_000, 3)):
    """An archive whose member's header declares ``shape`` (float64) over a few bytes of data."""
    buf = pyio.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(f"{name}.npy", buf.getvalue() + b"\0" * 64)
        zf.writestr("faces.npy", _npy(np.zeros((0, 3), np.int64)))
        zf.writestr("options.npy", _npy(np.array("{}")))
    return path


def _npy(a) -> bytes:
    buf = pyio.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _worker(tmp_path, given, capsys):
    code = paraview_worker.main([str(given), str(tmp_path / "out.npz")])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err


@pytest.fixture
def good_input(tmp_path):
    return _npz(tmp_path / "in.npz", points=np.random.default_rng(0).random((50, 3)), faces=np.zeros((0, 3), np.int64),
                options=np.array('{"model": "chair"}'))


def test_a_truncated_worker_input_is_one_line(good_input, tmp_path, capsys):
    raw = good_input.read_bytes()
    for cut in (len(raw) // 2, len(raw) - 10, 30):
        bad = tmp_path / f"cut{cut}.npz"
        bad.write_bytes(raw[:cut])
        code, err = _worker(tmp_path, bad, capsys)
        assert code == 2 and len(err) == 1 and err[0].startswith("primkit segmentation: ") and str(bad) in err[0], err
        assert not (tmp_path / "out.npz").exists()


def test_a_worker_input_declaring_more_than_it_holds_allocates_nothing(tmp_path, capsys):
    code, err = _worker(tmp_path, _lying_npz(tmp_path / "lies.npz"), capsys)
    assert code == 2 and len(err) == 1 and "declares" in err[0] and "stores" in err[0], err


def test_a_small_compressed_worker_input_over_the_bound_is_refused(tmp_path, capsys, monkeypatch):
    """Zeros compress a thousandfold: 2.4 MB of points in a few kB, over a bound lowered to 1,000
    faces (24 kB); at the default bound the same holds for a 7 MB archive of 6.7 GiB."""
    given = _npz(tmp_path / "zeros.npz", points=np.zeros((100_000, 3)), faces=np.zeros((0, 3), np.int64),
                 options=np.array("{}"))
    assert given.stat().st_size < 20_000
    monkeypatch.setenv("PRIMKIT_MAX_FACES", "1000")
    code, err = _worker(tmp_path, given, capsys)
    assert code == 2 and len(err) == 1 and "over the bound" in err[0] and "'points'" in err[0], err


def test_npz_members_reads_headers_only(tmp_path):
    path = _npz(tmp_path / "a.npz", x=np.zeros((4, 3), np.float32), y=np.arange(5))
    assert io.limits.npz_members(path, max_bytes=1000) == {"x": ((4, 3), np.dtype("float32")),
                                                            "y": ((5,), np.arange(5).dtype)}


def test_a_truncated_voxel_label_archive_is_one_line(tmp_path):
    path = _npz(tmp_path / "voxlabels.npz", **{f"shape{i}": np.full((8, 8, 8), i, np.int8) for i in range(3)})
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(io.ShapeFileError) as info:
        VoxelLabelArchive(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value) and "truncated" in str(info.value)


def test_a_voxel_label_archive_member_over_the_largest_grid_is_refused(tmp_path):
    path = _lying_npz(tmp_path / "voxlabels.npz", name="shape0", shape=(2000, 2000, 2000))
    with pytest.raises(io.ShapeFileError, match="declares"):
        VoxelLabelArchive(path)


def test_a_labelled_clouds_labels_are_not_a_shape(tmp_path):
    np.savetxt(tmp_path / "c0.xyz", np.random.default_rng(0).random((20, 3)))
    np.save(tmp_path / "c0.labels.npy", np.ones(20, np.int64))
    np.save(tmp_path / "grid.npy", np.ones((4, 4, 4), bool))  # a shape of its own
    np.save(tmp_path / "lonely.labels.npy", np.ones((4, 4, 4), bool))  # no shape of that stem: a shape
    assert [p.name for p in find_shape_files(tmp_path)] == ["c0.xyz", "grid.npy", "lonely.labels.npy"]

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


# ------------------------------------------------------------------ leftovers: one line each

@pytest.mark.parametrize("suffix", [".off", ".obj"])
def test_a_mesh_scaled_1e200_is_one_line_from_read_shape(tmp_path, suffix):
    """Its area overflowed: a bare OverflowError before."""
    from primkit import synthetic

    chair = synthetic.generate("chair", 1, seed=0)[0]
    path = tmp_path / f"huge{suffix}"
    io.write_mesh(path, chair.vertices * 1e200, chair.faces)
    with pytest.raises(io.ShapeFileError) as info:
        io.read_shape(path)
    assert str(path) in str(info.value) and "beyond" in str(info.value) and "\n" not in str(info.value)


def test_an_all_true_grid_in_memory_is_refused_like_the_file_reader():
    import primkit

    with pytest.raises(io.ShapeFileError, match="every voxel is occupied"):
        primkit.abstract(np.ones((16, 16, 16), bool))


def test_a_model_answering_nan_names_its_file(tmp_path):
    """A model file whose weights hold a NaN: its network's answer names the file (it was
    "`half_extents` must be finite", no file named)."""
    import primkit
    from primkit.model import modelfile
    from primkit.model.bundled import resolve_model

    weights, meta = modelfile.load_model_file(resolve_model("chair"))
    name = next(k for k, v in weights.items() if v.is_floating_point() and v.ndim > 1)
    weights[name] = weights[name].clone()
    weights[name].view(-1)[0] = float("nan")
    damaged = modelfile.save_model(tmp_path / "nan.safetensors", weights, meta)
    chair = primkit.synthetic.generate("chair", 1, seed=0)[0]
    with pytest.raises(modelfile.ModelFileError) as info:
        primkit.abstract((chair.vertices, chair.faces), model=damaged)
    assert str(damaged) in str(info.value) and "NaN or inf" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("variables", [{"RANK": "abc", "WORLD_SIZE": "2"}, {"RANK": "0", "WORLD_SIZE": "two"},
                                       {"SLURM_PROCID": "x", "SLURM_NTASKS": "2"}])
def test_a_rank_variable_that_is_not_a_number_is_named(monkeypatch, variables):
    from primkit.parallel import parse_shard

    for key in ("RANK", "WORLD_SIZE", "SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "SLURM_PROCID", "SLURM_NTASKS"):
        monkeypatch.delenv(key, raising=False)
    for key, value in variables.items():
        monkeypatch.setenv(key, value)
    bad = next(k for k, v in variables.items() if not v.isdigit())
    with pytest.raises(ValueError, match=f"{bad}="):
        parse_shard("auto")


@pytest.mark.parametrize("edit", [{"scale": {0: 1e308}}, {"scale": {0: 1e-308}}, {"move": {0: (0, 1e308, 0)}},
                                  {"rotate": {0: float("inf")}}, {"lengthen": {0: 1e308}}])
def test_an_edit_beyond_the_bounds_is_one_line(edit):
    """``edit --scale legs=1e308`` ended in a rotation-matrix error."""
    from primkit.deformation.edits import edit_cuboids
    from primkit.primitives import Cuboids

    cuboids = Cuboids(np.full((2, 3), 0.1), np.tile([1.0, 0, 0, 0], (2, 1)), [[0, 0.1, 0], [0, -0.2, 0]], [True, True])
    with pytest.raises(ValueError, match="must be"):
        edit_cuboids(cuboids, **edit)

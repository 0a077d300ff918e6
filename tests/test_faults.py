"""Faults that lose nothing (issue 19): each case as a user meets it, through the command line.

Unwritable locations are made real in ways the root user (who runs these tests here, and whom file
modes do not stop) cannot write either: a path under a regular file, and a folder made immutable
with ``chattr +i`` (skipped where the file system or the container does not allow it). Hostile model
files are real files, edited copies of the bundled chair model. Kills are in ``test_kills.py``.
"""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from primkit import data, io, synthetic
from primkit.cli import main
from primkit.model.bundled import resolve_model


def tree(folder) -> dict:
    """``relative path -> sha256`` of every file under ``folder``."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def one_error_line(err: str, *needles) -> str:
    """The single ``primkit: error:`` line of ``err`` (nothing else on stderr, no traceback)."""
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("primkit: error: "), err
    for needle in needles:
        assert str(needle) in lines[0], (needle, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    """Two folders of three procedural chairs with the same file names (different chairs)."""
    root = tmp_path_factory.mktemp("faults")
    synthetic.write_collection(root / "a", "chair", 3, seed=0)
    synthetic.write_collection(root / "b", "chair", 3, seed=7)
    return root


@pytest.fixture
def cache(shapes):
    return ["--cache", str(shapes / "cache"), "--workers", "1"]


@contextmanager
def immutable_folder(path: Path):
    """A folder nobody, root included, can create files in (``chattr +i``); skips where unavailable."""
    path.mkdir()
    if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode:
        pytest.skip("chattr +i is not available here (needs CAP_LINUX_IMMUTABLE and ext2/3/4, xfs, btrfs)")
    try:
        yield path
    finally:
        subprocess.run(["chattr", "-i", str(path)], check=True)


@pytest.fixture(params=["under a regular file", "immutable folder"])
def unwritable(request, tmp_path):
    """A folder path that cannot be written: ``(folder, the path the message names)``."""
    if request.param == "under a regular file":
        (tmp_path / "afile").write_text("a regular file\n")
        yield tmp_path / "afile" / "models", tmp_path / "afile"
    else:
        with immutable_folder(tmp_path / "ro") as folder:
            yield folder, folder


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if a command prepares a shape or runs a training iteration."""
    def refuse(*args, **kwargs):
        raise AssertionError("work started before the outputs were checked")

    from primkit.model import training

    monkeypatch.setattr(data, "prepare_collection", refuse)
    monkeypatch.setattr(training, "shape_losses", refuse)


# ------------------------------------------------------------------ 1. unwritable model outputs


def test_train_refuses_an_unwritable_output_before_any_work(shapes, unwritable, no_work, capsys, cache):
    folder, named = unwritable
    code = main(["train", str(shapes / "a"), "-o", str(folder / "m.safetensors"), "--stage1", "2", "--stage2", "2", *cache])
    assert code == 2
    one_error_line(capsys.readouterr().err, folder / "m.safetensors", named, "cannot be written")


def test_library_train_refuses_before_the_first_iteration(prepared_chairs, unwritable, no_work):
    from primkit.model import training

    folder, named = unwritable
    shapes = training.ShapeTensors(prepared_chairs[:2])
    config = training.TrainConfig(stage1_iterations=4, stage2_iterations=4, batch_size=2, parts=4, checkpoint_every=2)
    with pytest.raises(io.OutputError, match="cannot be written"):
        training.train(shapes, folder / "m.safetensors", config, progress=False)


def test_train_creates_missing_folders(shapes, tmp_path, cache):
    out = tmp_path / "no" / "such" / "dir" / "m.safetensors"
    assert main(["train", str(shapes / "a"), "-o", str(out), "--stage1", "2", "--stage2", "2", "--parts", "4",
                 "--batch-size", "3", *cache]) == 0
    assert out.is_file() and out.with_name("m.training.png").is_file() and out.with_name("m.history.json").is_file()


def test_a_checkpoint_that_cannot_be_written_does_not_stop_training(prepared_chairs, tmp_path, monkeypatch):
    """The disk fills during training (simulated: the checkpoint's write raises ENOSPC): the run goes on;
    when the model itself cannot be written at the end, it is saved in the temporary folder instead."""
    import errno

    from primkit.model import modelfile, training

    real_save = modelfile.save_model

    def full_disk(path, *args, **kwargs):
        if Path(path).parent == tmp_path:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_save(path, *args, **kwargs)

    monkeypatch.setattr(modelfile, "save_model", full_disk)
    shapes = training.ShapeTensors(prepared_chairs[:2])
    config = training.TrainConfig(stage1_iterations=3, stage2_iterations=3, batch_size=2, parts=4, checkpoint_every=2,
                                  points_per_shape=100, samples_per_cuboid=24)
    with pytest.raises(OSError, match="saved to") as info, pytest.warns(RuntimeWarning, match="could not write the checkpoint"):
        training.train(shapes, tmp_path / "m.safetensors", config, progress=False)
    rescued = Path(str(info.value).rsplit("saved to ", 1)[1].split(" instead")[0])
    from primkit.model.network import load_network

    net, meta = load_network(rescued)
    assert meta["training"]["iterations"] == 6
    shutil.rmtree(rescued.parent)


# ------------------------------------------------------------------ 2. two inputs with one name


def test_two_inputs_with_one_name_keep_both_outputs(shapes, tmp_path, capsys, cache):
    a, b = shapes / "a" / "chair_0000.ply", shapes / "b" / "chair_0000.ply"
    for force in ([], ["--force"]):
        out = tmp_path / f"out{len(force)}"
        assert main(["abstract", str(a), str(b), "--model", "chair", "-o", str(out), *force, *cache]) == 0
        err = capsys.readouterr().err
        assert "2 inputs are named chair_0000" in err and "a-chair_0000, b-chair_0000" in err
        assert sorted(p.name for p in out.iterdir()) == ["a-chair_0000.cuboids.json", "a-chair_0000.cuboids.ply",
                                                         "b-chair_0000.cuboids.json", "b-chair_0000.cuboids.ply"]
        ja, jb = (json.loads((out / f"{n}-chair_0000.cuboids.json").read_text()) for n in "ab")
        assert (ja["name"], ja["source"]) == ("a-chair_0000", str(a)) and (jb["name"], jb["source"]) == ("b-chair_0000", str(b))
        assert ja["parts"] != jb["parts"]  # two different chairs: two abstractions


def test_shape_names_are_unique_and_stable():
    names = data.shape_names
    assert names(["a/x.ply", "b/x.ply", "c/y.ply"]) == ["a-x", "b-x", "y"]
    assert names(["d/x.ply", "d/x.obj"]) == ["x-ply", "x-obj"]  # same folder: the suffix tells them apart
    assert names(["d/x.ply", "d/x.ply"]) == ["x", "x-2"]  # the same file twice
    assert names(["s/03/ab/model.binvox", "s/04/ab/model.binvox"]) == ["03-ab", "04-ab"]  # ShapeNet's generic stems
    assert names(["p/v1/x.ply", "p/v2/x.ply", "v1-x.ply"]) == ["v1-x", "v2-x", "v1-x-2"]  # never another shape's name
    many = [f"f{i}/x.ply" for i in range(50)] + ["x.ply"]
    assert len(set(names(many))) == 51 and names(many) == names(list(many))


def test_segment_names_shared_inputs_alike(shapes, tmp_path, capsys, cache):
    a, b = shapes / "a" / "chair_0001.ply", shapes / "b" / "chair_0001.ply"
    out = tmp_path / "seg"
    assert main(["segment", str(a), str(b), "--model", "chair", "-o", str(out), *cache]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"a-chair_0001.seg", "b-chair_0001.seg", "a-chair_0001.parts.ply", "b-chair_0001.cuboids.json"} <= names
    assert io.read_labels(out / "a-chair_0001.seg").shape == (len(io.read_mesh(a).faces),)


# ------------------------------------------------------------------ 4. --force never touches inputs


def test_segment_into_its_input_folder_with_force_is_refused(shapes, tmp_path, no_work, capsys, cache):
    same = tmp_path / "same"
    shutil.copytree(shapes / "a", same)
    before = tree(same)
    assert main(["segment", str(same), "--model", "chair", "-o", str(same), "--force", *cache]) == 2
    one_error_line(capsys.readouterr().err, same / "chair_0000.seg", "is an input", "--force never replaces inputs")
    assert tree(same) == before


def test_train_over_an_input_mesh_is_refused(shapes, tmp_path, no_work, capsys, cache):
    folder = tmp_path / "dir"
    shutil.copytree(shapes / "a", folder)
    before = tree(folder)
    assert main(["train", str(folder), "-o", str(folder / "chair_0000.ply"), "--force", *cache]) == 2
    one_error_line(capsys.readouterr().err, folder / "chair_0000.ply", "written as .safetensors")
    # a .safetensors name that is an input (here through a symbolic link) is refused as an input
    (folder / "model.safetensors").symlink_to(folder / "chair_0000.ply")
    assert main(["train", str(folder), "-o", str(folder / "model.safetensors"), "--force", *cache]) == 2
    one_error_line(capsys.readouterr().err, "is an input")
    (folder / "model.safetensors").unlink()
    assert tree(folder) == before


def test_deform_and_name_parts_never_replace_their_inputs(shapes, tmp_path, capsys, cache):
    src = tmp_path / "src.ply"
    shutil.copy(shapes / "a" / "chair_0000.ply", src)
    os.link(src, tmp_path / "hardlink.ply")  # the same file under another name
    model = tmp_path / "chair.safetensors"
    shutil.copy(resolve_model("chair"), model)
    before = tree(tmp_path)
    for out in (src, tmp_path / "hardlink.ply"):
        assert main(["deform", str(src), str(shapes / "a" / "chair_0001.ply"), "--model", "chair", "-o", str(out),
                     "--force", *cache]) == 2
        one_error_line(capsys.readouterr().err, out, "is an input")
    assert main(["name-parts", str(shapes / "a"), "--model", str(model), "-o", str(model), "--force", *cache]) == 2
    one_error_line(capsys.readouterr().err, model, "is an input")
    assert tree(tmp_path) == before


# ------------------------------------------------------------------ 5. nothing replaced without --force


def test_segment_replaces_nothing_without_force(shapes, tmp_path, no_work, capsys, cache):
    for name in ("chair_0000.cuboids.json", "labels.csv", "evaluation.json"):
        out = tmp_path / name.split(".")[0]
        out.mkdir()
        (out / name).write_text("mine\n")
        assert main(["segment", str(shapes / "a"), "--model", "chair", "-o", str(out), "--semantic",
                     "--gt", str(shapes / "a"), *cache]) == 2
        one_error_line(capsys.readouterr().err, out / name, "exists", "--force")
        assert tree(out) == {name: hashlib.sha256(b"mine\n").hexdigest()}


def test_train_replaces_no_history_or_plot_without_force(shapes, tmp_path, no_work, capsys, cache):
    for name in ("m.history.json", "m.training.png", "m.safetensors.checkpoint.safetensors"):
        (tmp_path / name).write_text("mine\n")
        assert main(["train", str(shapes / "a"), "-o", str(tmp_path / "m.safetensors"), *cache]) == 2
        one_error_line(capsys.readouterr().err, tmp_path / name, "--force")
        assert (tmp_path / name).read_text() == "mine\n"
        (tmp_path / name).unlink()


def test_abstract_draws_no_picture_when_it_refuses_the_rest(shapes, tmp_path, no_work, capsys, cache):
    out = tmp_path / "out"
    out.mkdir()
    (out / "chair_0001.cuboids.json").write_text("mine\n")
    assert main(["abstract", str(shapes / "a"), "--model", "chair", "-o", str(out), "--png", str(out / "a.png"), *cache]) == 2
    one_error_line(capsys.readouterr().err, out / "chair_0001.cuboids.json", "exists")
    assert [p.name for p in out.iterdir()] == ["chair_0001.cuboids.json"]


def test_outputs_with_the_wrong_suffix_or_twice_are_refused(shapes, tmp_path, no_work, capsys, cache):
    assert main(["abstract", str(shapes / "a"), "--model", "chair", "-o", str(tmp_path), "--png", str(tmp_path / "a.jpg"), *cache]) == 2
    one_error_line(capsys.readouterr().err, "a.jpg", "written as .png")
    with pytest.raises(io.OutputError, match="written twice"):
        io.check_outputs([tmp_path / "x.png", tmp_path / "." / "x.png"])
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ 6. model files checked before allocation


def _hostile(path: Path, change_meta=None, change_weights=None, raw_meta=None) -> Path:
    """A copy of the bundled chair model with its metadata or weights edited."""
    from safetensors import safe_open
    from safetensors.torch import save_file

    with safe_open(str(resolve_model("chair")), "pt") as f:
        meta = json.loads(f.metadata()["primkit"])
        weights = {k: f.get_tensor(k) for k in f.keys()}
    if change_meta:
        change_meta(meta)
    if change_weights:
        change_weights(weights)
    save_file(weights, str(path), metadata={"primkit": raw_meta(meta) if raw_meta else json.dumps(meta)})
    return path


def _set_network(**fields):
    return lambda m: m["network"].update(fields)


HOSTILE = {
    "fc_width 20000": (dict(change_meta=_set_network(fc_width=20000)), "fc_width"),
    "fc_width 8000 (in bounds)": (dict(change_meta=_set_network(fc_width=8000)), "needs [8000"),
    "parts 10^7": (dict(change_meta=_set_network(parts=10**7)), "parts"),
    "grid 2^30": (dict(change_meta=_set_network(grid=2**30)), "grid"),
    "encoder a list": (dict(change_meta=_set_network(encoder=["paper"])), "encoder"),
    "network a string": (dict(change_meta=lambda m: m.update(network="paper")), "network"),
    "part_names of 3": (dict(change_meta=lambda m: m.update(part_names=["a", "b", "c"])), "part_names"),
    "a wrong tensor shape": (dict(change_weights=lambda w: w.update({"encoder.0.bias": w["encoder.0.bias"][:3]})), "encoder.0.bias"),
    "a missing tensor": (dict(change_weights=lambda w: w.pop("translation_head.weight")), "lacks the tensors translation_head.weight"),
    "an extra tensor": (dict(change_weights=lambda w: w.update(extra=w["head_scales"].clone())), "does not have: extra"),
    "a tensor of ints": (dict(change_weights=lambda w: w.update({"head_scales": w["head_scales"].long()})), "I64"),
    "JSON nested 100000 deep": (dict(raw_meta=lambda m: json.dumps(m)[:-1] + ', "x": ' + "[" * 100000 + "]" * 100000 + "}"), "nested"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_model_files_fail_in_one_line(case, shapes, tmp_path, capsys, cache):
    kwargs, reason = HOSTILE[case]
    path = _hostile(tmp_path / "hostile.safetensors", **kwargs)
    assert main(["abstract", str(shapes / "a" / "chair_0000.ply"), "--model", str(path), "-o", str(tmp_path / "o"), *cache]) == 2
    one_error_line(capsys.readouterr().err, path, reason)
    assert main(["info", str(path)]) == 2  # info runs the same checks
    one_error_line(capsys.readouterr().err, path, reason)
    assert not (tmp_path / "o").exists()


@pytest.mark.integration  # a child process watched for its memory: seconds, left to the default suite
@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux's /proc/self/clear_refs")
def test_a_hostile_width_allocates_nothing(tmp_path):
    """fc_width 8000 is within the bounds; its 8000 x 8000 layer alone would be 256 MB: the header's
    tensor shapes refuse it before anything is built. Measured as the growth of the peak resident
    memory (VmHWM, reset through /proc/self/clear_refs) of a fresh process that has loaded a model
    once; the same measure sees a real 256 MB."""
    path = _hostile(tmp_path / "wide.safetensors", change_meta=_set_network(fc_width=8000))
    script = textwrap.dedent(f"""
        import torch
        from primkit.model.bundled import resolve_model
        from primkit.model.modelfile import ModelFileError
        from primkit.model.network import load_network

        def peak_kb():
            return int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1])

        def grown(fn):
            open("/proc/self/clear_refs", "w").write("5")  # the peak starts again from the current size
            before = peak_kb()
            fn()
            return peak_kb() - before

        def attempt():
            try:
                load_network({str(path)!r})
            except ModelFileError as exc:
                print("refused:", exc)

        load_network(resolve_model("chair"))  # the one-time costs of a first load (libraries, kernels) paid first
        print("grew_kb", grown(attempt))
        print("real_kb", grown(lambda: torch.ones(8000, 8000)))
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert "refused:" in proc.stdout, proc.stdout + proc.stderr
    grew = int(proc.stdout.split("grew_kb")[1].split()[0])
    real = int(proc.stdout.split("real_kb")[1].split()[0])
    assert real > 200 * 1024 and grew < 32 * 1024, (grew, real)


def test_the_bundled_models_pass_the_checks():
    from primkit.image.inference import read_image_network
    from primkit.model.bundled import bundled_models
    from primkit.model.modelfile import read_metadata
    from primkit.model.network import read_network

    for name, path in bundled_models().items():
        check = read_image_network if read_metadata(path).get("kind") == "image-abstractor" else read_network
        config, meta = check(path)
        assert config.parts == len(meta["part_names"]) == 20, name


@pytest.fixture(scope="module")
def checkpoint(prepared_chairs, tmp_path_factory):
    """A real checkpoint: a training run (parts 8) stopped by Ctrl-C in its 5th iteration."""
    from primkit.model import training

    folder = tmp_path_factory.mktemp("ckpt")
    shapes = training.ShapeTensors(prepared_chairs[:2])
    config = training.TrainConfig(stage1_iterations=4, stage2_iterations=4, batch_size=2, parts=8, points_per_shape=100,
                                  samples_per_cuboid=24, encoder="paper", fc_width=100)
    original = training.ShapeTensors.batch
    calls = {"n": 0}

    def interrupt(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:
            signal.raise_signal(signal.SIGINT)
        return original(self, *args, **kwargs)

    training.ShapeTensors.batch = interrupt
    try:
        assert training.train(shapes, folder / "m.safetensors", config, progress=False).interrupted
    finally:
        training.ShapeTensors.batch = original
    return folder / "m.safetensors.checkpoint.safetensors"


@pytest.mark.parametrize("flags, reason", [(["--parts", "6"], "parts 8 (--parts 8)"),
                                           (["--parts", "8", "--encoder", "released"], "encoder paper (--encoder paper)"),
                                           ([], "parts 8")])
def test_resume_with_another_network_is_refused_in_one_line(checkpoint, shapes, tmp_path, no_work, capsys, cache, flags, reason):
    code = main(["train", str(shapes / "a"), "-o", str(tmp_path / "m.safetensors"), "--resume", str(checkpoint), *flags, *cache])
    assert code == 2
    one_error_line(capsys.readouterr().err, checkpoint, reason, "start afresh")


def test_resume_from_a_model_or_a_damaged_checkpoint_is_refused(checkpoint, shapes, tmp_path, no_work, capsys, cache):
    damaged = tmp_path / "damaged.safetensors"
    damaged.write_bytes(checkpoint.read_bytes()[: checkpoint.stat().st_size // 2])
    for resume, reason in ((resolve_model("chair"), "not a training checkpoint"), (damaged, "truncated")):
        code = main(["train", str(shapes / "a"), "-o", str(tmp_path / "m.safetensors"), "--resume", str(resume), *cache])
        assert code == 2
        one_error_line(capsys.readouterr().err, resume, reason)


# ------------------------------------------------------------------ 7. inputs


def test_obj_face_index_zero_is_an_error_naming_the_line(shapes, tmp_path, capsys, cache):
    bad = tmp_path / "in" / "zero.obj"
    bad.parent.mkdir()
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 0 2 4\nf 2 3 4\n")
    with pytest.raises(io.ShapeFileError, match="line 6: face index 0"):
        io.read_mesh(bad)
    # negative (relative) indices stay valid OBJ: -1 is the last vertex
    good = tmp_path / "neg.obj"
    good.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf -4 -3 -2\nf 2 3 4\n")
    assert io.read_mesh(good).faces.tolist() == [[0, 1, 2], [1, 2, 3]]
    shutil.copy(shapes / "a" / "chair_0000.ply", bad.parent)
    assert main(["abstract", str(bad.parent), "--model", "chair", "-o", str(tmp_path / "o"), *cache]) == 1
    err = capsys.readouterr().err
    assert "zero.obj: cannot parse as OBJ: line 6: face index 0" in err
    assert (tmp_path / "o" / "chair_0000.cuboids.json").is_file()  # the rest of the batch


def test_a_folder_without_shapes_is_an_error(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no shapes here\n")
    for argv in (["abstract", str(empty), "--model", "chair", "-o", str(tmp_path / "o")], ["prepare", str(empty)]):
        assert main(argv) == 2
        one_error_line(capsys.readouterr().err, empty, "no shape files in this folder")
    from primkit.model.abstraction import abstract_shapes

    assert abstract_shapes(empty, "chair").errors == [f"{empty}: no shape files in this folder"]


def test_shapes_behind_symlinked_folders_are_found(shapes, tmp_path, capsys, cache):
    folder = tmp_path / "links"
    folder.mkdir()
    (folder / "chairs").symlink_to(shapes / "a", target_is_directory=True)
    (folder / "again").symlink_to(shapes / "a", target_is_directory=True)  # the same folder twice: searched once
    (folder / "loop").symlink_to(folder, target_is_directory=True)  # a link back up: no endless search
    found = data.find_shape_files(folder)
    assert len(found) == 3 and sorted(p.name for p in found) == [f"chair_{i:04d}.ply" for i in range(3)]
    assert main(["abstract", str(folder), "--model", "chair", "-o", str(tmp_path / "o"), *cache]) == 0
    assert len(list((tmp_path / "o").glob("*.cuboids.json"))) == 3


# ------------------------------------------------------------------ 8. smaller


def test_the_temporary_of_a_killed_write_is_not_an_input(shapes, tmp_path, capsys, cache):
    """A process killed (SIGKILL) in the middle of an atomic write leaves its hidden temporary; the
    next run over the folder does not take it for a shape."""
    folder = tmp_path / "in"
    shutil.copytree(shapes / "a", folder)
    half = (folder / "chair_0000.ply").read_bytes()[:500]
    script = textwrap.dedent(f"""
        import os, signal
        from primkit import io
        with io.atomic_output({str(folder / "chair_0003.ply")!r}) as tmp:
            tmp.write_bytes({half!r})
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL
    left = [p for p in folder.iterdir() if p.name.startswith(".")]
    assert len(left) == 1 and io.is_temporary(left[0]) and not (folder / "chair_0003.ply").exists()
    assert data.find_shape_files(folder) == sorted(folder.glob("chair_*.ply"))
    assert main(["abstract", str(folder), "--model", "chair", "-o", str(tmp_path / "o"), *cache]) == 0


def test_many_errors_end_with_a_count_by_reason(shapes, tmp_path, capsys, cache):
    folder = tmp_path / "broken"
    folder.mkdir()
    for i in range(20):
        (folder / f"g{i:02d}.ply").write_text("garbage\n")
    for i in range(12):
        (folder / f"e{i:02d}.off").write_bytes(b"")
    shutil.copy(shapes / "a" / "chair_0000.ply", folder)
    assert main(["abstract", str(folder), "--model", "chair", "-o", str(tmp_path / "o"), *cache]) == 1
    err = capsys.readouterr().err.splitlines()
    assert sum(line.startswith("primkit: skipped ") for line in err) == 32  # every file still named
    assert "32 input(s) could not be used, by reason (2):" in err[-3]
    counts = {line.split()[1]: int(line.split()[0]) for line in err[-2:]}
    assert counts == {"cannot": 20, "empty": 12}
    assert (tmp_path / "o" / "chair_0000.cuboids.json").is_file()


def test_outputs_get_the_permissions_of_any_new_file(prepared_chairs, tmp_path):
    """Model files, like every output, are 0666 less the umask (0644 here), as a plain ``open``
    makes a file (safetensors writes 0600); a replaced file keeps its own mode."""
    from primkit.model import training

    plain = tmp_path / "plain.txt"
    plain.write_text("")
    shapes = training.ShapeTensors(prepared_chairs[:2])
    config = training.TrainConfig(stage1_iterations=2, stage2_iterations=2, batch_size=2, parts=4, points_per_shape=100,
                                  samples_per_cuboid=24)
    out = tmp_path / "m.safetensors"
    training.train(shapes, out, config, progress=False)
    mode = lambda p: oct(os.stat(p).st_mode & 0o777)  # noqa: E731
    assert mode(out) == mode(plain) == mode(tmp_path / "m.history.json") == mode(tmp_path / "m.training.png")
    os.chmod(out, 0o600)
    training.train(shapes, out, config, progress=False, overwrite=True)
    assert mode(out) == "0o600"


def test_an_inside_out_mesh_keeps_its_interior():
    """A box mesh with every face turned (and one of two boxes turned) fills the same cells as the
    box; those cells are the ones whose centre lies inside the box (closed form)."""
    import trimesh

    from primkit.geometry import grid_centres

    box = trimesh.creation.box(extents=(1.0, 0.5, 0.25))
    v, f = np.asarray(box.vertices), np.asarray(box.faces)
    inside = (np.abs(grid_centres(32)) < np.array([0.5, 0.25, 0.125])).all(-1)
    for faces in (f, f[:, ::-1]):
        solid = data.prepare(io.Mesh(v, faces)).solid
        assert np.array_equal(solid, inside)
    # two boxes side by side, the second inside out
    two_v = np.vstack([v * 0.5 - [0.3, 0, 0], v * 0.5 + [0.3, 0, 0]])
    two_f = np.vstack([f, f[:, ::-1] + len(v)])
    solid = data.prepare(io.Mesh(two_v, two_f)).solid
    turned = data.prepare(io.Mesh(two_v, np.vstack([f, f + len(v)]))).solid
    assert solid.sum() > 0 and np.array_equal(solid, turned)

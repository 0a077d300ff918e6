"""Training loses no work (issue 36): any error of the checkpoint writer, a failing final save, and
two runs into one model file. SIGTERM is in ``test_kills.py``."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from safetensors import SafetensorError

from primkit import synthetic
from primkit.cli import main
from primkit.model import modelfile, training

CONFIG = dict(stage1_iterations=3, stage2_iterations=3, batch_size=2, parts=4, checkpoint_every=2,
              points_per_shape=100, samples_per_cuboid=24)


@pytest.fixture
def shapes(prepared_chairs):
    return training.ShapeTensors(prepared_chairs[:2])


def failing_writer(monkeypatch, fails):
    """``modelfile.save_model`` raising SafetensorError (what safetensors raises on a full disk) for
    the paths ``fails(path)`` picks; the others are written."""
    real = modelfile.save_model

    def save(path, *args, **kwargs):
        if fails(Path(path)):
            raise SafetensorError("Error while serializing: IoError(Os { code: 28, kind: StorageFull, "
                                  "message: \"No space left on device\" })")
        return real(path, *args, **kwargs)

    monkeypatch.setattr(modelfile, "save_model", save)


def test_a_safetensor_error_in_a_checkpoint_does_not_stop_training(shapes, tmp_path, monkeypatch, capfd):
    """The checkpoint at iteration 4 does not fit (SafetensorError, not an OSError: training
    stopped at that iteration with nothing saved): the run goes on, says the one of iteration 2
    stands (a RuntimeWarning, nothing printed), and the model is written."""
    written = []

    def fails(path):
        if path.name.endswith(".checkpoint.safetensors"):
            written.append(path)
            return len(written) > 1
        return False

    failing_writer(monkeypatch, fails)
    config = training.TrainConfig(**{**CONFIG, "stage2_iterations": 5})
    with pytest.warns(RuntimeWarning, match="could not write the checkpoint") as caught:
        result = training.train(shapes, tmp_path / "m.safetensors", config)
    assert capfd.readouterr() == ("", "")  # said through warnings only
    assert result.model_path == tmp_path / "m.safetensors" and result.model_path.is_file()
    notes = [str(w.message) for w in caught if "could not write the checkpoint" in str(w.message)]
    assert len(notes) == 2  # iterations 4 and 6
    assert all("SafetensorError" in note and "earlier iteration stands" in note for note in notes)
    assert len(written) == 3  # iterations 2, 4 and 6 of 8


def test_a_failing_final_save_keeps_a_checkpoint_that_resumes_to_the_same_model(shapes, tmp_path, monkeypatch):
    """The model file does not fit at the end, nor in the temporary folder (the model was lost):
    the error names a checkpoint of the finished run, and resuming from it writes the model an
    undisturbed run writes, bit for bit."""
    config = training.TrainConfig(**CONFIG)
    reference = training.train(shapes, tmp_path / "ref.safetensors", config, progress=False)
    out = tmp_path / "m.safetensors"
    failing_writer(monkeypatch, lambda p: p.name == "m.safetensors")
    with pytest.raises(OSError) as info:
        training.train(shapes, out, config, progress=False)
    ckpt = out.with_name(out.name + ".checkpoint.safetensors")
    message = str(info.value)
    assert "\n" not in message and str(out) in message and "checkpoint of the finished run" in message, message
    assert str(ckpt) in message and ckpt.is_file() and not out.exists()
    assert not out.with_name(out.name + ".lock").exists()
    monkeypatch.undo()
    result = training.train(shapes, out, config, progress=False, resume=ckpt)
    got, _ = modelfile.load_model_file(out)
    want, _ = modelfile.load_model_file(reference.model_path)
    assert sorted(got) == sorted(want)
    assert all(np.array_equal(got[k].numpy(), want[k].numpy()) for k in want)
    assert result.history == reference.history


def test_a_failing_final_save_through_the_cli_exits_non_zero_naming_the_checkpoint(tmp_path, monkeypatch, capsys):
    synthetic.write_collection(tmp_path / "in", "chair", 3, seed=0)
    out = tmp_path / "m.safetensors"
    failing_writer(monkeypatch, lambda p: p.name == "m.safetensors")
    monkeypatch.setattr("tempfile.mkdtemp", lambda *a, **k: str(tmp_path / "no" / "tmp"))  # the temporary folder too
    code = main(["train", str(tmp_path / "in"), "-o", str(out), "--stage1", "2", "--stage2", "2", "--parts", "4",
                 "--batch-size", "3", "--workers", "1", "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err
    assert code != 0
    line = [x for x in err.splitlines() if x.startswith("primkit: error: ")]
    assert len(line) == 1 and str(out) + ".checkpoint.safetensors" in line[0], err
    assert "wrote" not in err


HOLDER = """
import sys, time
from primkit.model.modelfile import claim_output
with claim_output(sys.argv[1]):
    print("held", flush=True)
    time.sleep(60)
"""


def _holder(out):
    """The first run, still at work: a process holding the lock of ``out``."""
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdout=subprocess.PIPE)
    assert proc.stdout.readline().strip() == b"held"
    return proc


def test_a_second_run_into_the_same_output_is_refused(tmp_path, capsys):
    """A run holds a lock on ``<model>.lock`` from its start to its end: a second run into the
    same ``-o`` is refused in one line (both finished and printed "wrote", the first model
    replaced); the lock file of a killed run is taken over, and gone at the end."""
    synthetic.write_collection(tmp_path / "in", "chair", 3, seed=0)
    out = tmp_path / "m.safetensors"
    lock = tmp_path / "m.safetensors.lock"
    args = ["train", str(tmp_path / "in"), "-o", str(out), "--stage1", "2", "--stage2", "2", "--parts", "4",
            "--batch-size", "3", "--workers", "1", "--cache", str(tmp_path / "cache")]
    other = _holder(out)
    try:
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "another primkit run" in err[0] and str(other.pid) in err[0], err
        assert not out.exists() and lock.exists()
    finally:
        other.kill()
        other.wait()
    assert lock.exists()  # the first run was killed: its lock file stays, free, and is taken over
    assert main(args) == 0
    assert out.is_file() and not lock.exists()


def test_library_train_claims_its_output(shapes, tmp_path):
    out = tmp_path / "m.safetensors"
    other = _holder(out)
    try:
        with pytest.raises(FileExistsError, match="another primkit run"):
            training.train(shapes, out, training.TrainConfig(**CONFIG), progress=False)
        assert not out.exists()
    finally:
        other.kill()
        other.wait()

"""Every model file is written one way (``modelfile.write_model``, ``modelfile.claim_output``):
``train``, ``adapt``, ``name-parts`` and ``train-image`` write atomically, say in one line why a
final write failed and where the model went instead, stop on SIGTERM as on Ctrl-C, and hold an
operating-system lock on their output that a run in another PID namespace sees.

The faults are real: a file-size limit (``RLIMIT_FSIZE``) on the command, a small ``tmpfs`` mounted
in a user namespace (``unshare``) as the output's folder, a real SIGTERM, a lock holder in another
PID namespace. Where the machine refuses namespaces the tests that need one skip, saying so.
"""

import contextlib
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from primkit import synthetic
from primkit.cli import main
from primkit.model import modelfile, training

PRIMKIT = Path(sys.executable).with_name("primkit")
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Three synthetic chairs with their labels, prepared once into a cache the tests share."""
    root = tmp_path_factory.mktemp("writes")
    synthetic.write_collection(root / "in", "chair", 3, seed=2)
    from primkit import data

    data.prepare_collection(sorted((root / "in").glob("*.ply")), data.PrepareSettings(), cache_dir=root / "cache",
                            workers=1)
    return root


def _unshare_works(*flags) -> bool:
    if shutil.which("unshare") is None:
        return False
    return subprocess.run(["unshare", *flags, "true"], capture_output=True).returncode == 0


def _adapt(folder, out, *more):
    return ["adapt", str(folder / "in"), "--model", "chair", "-o", str(out), "--steps", "1", "--workers", "1",
            "--cache", str(folder / "cache"), *more]


def _name_parts(folder, out, *more):
    return ["name-parts", str(folder / "in"), "--model", "chair", "-o", str(out), "--refine", "0",
            "--index-names-only", "--workers", "1", "--cache", str(folder / "cache"), *more]


def _limit_file_size(limit):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def _one_error_line(stderr: str) -> str:
    assert "Traceback" not in stderr, stderr[-3000:]
    lines = [x for x in stderr.splitlines() if x.startswith("primkit: error:")]
    assert len(lines) == 1, stderr[-3000:]
    return lines[0]


@pytest.mark.integration
@pytest.mark.parametrize("command", [_adapt, _name_parts], ids=["adapt", "name-parts"])
def test_a_file_size_limit_at_the_final_write_is_one_line(folder, tmp_path, command):
    """The model file (1 MB) is over the file-size limit (256 kB; the temporary folder is under it
    too): one line naming the model file and the reason, no traceback (a SafetensorError traceback
    before), no model left, no lock left."""
    out = tmp_path / "m.safetensors"
    proc = subprocess.run([str(PRIMKIT), *command(folder, out)], capture_output=True, text=True, env=ENV,
                          preexec_fn=_limit_file_size(256 * 1024), timeout=600)
    line = _one_error_line(proc.stderr)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert str(out) in line and "File too large" in line and "could not be saved elsewhere" in line, line
    assert not out.exists() and not out.with_name(out.name + ".lock").exists()
    assert not [p for p in tmp_path.iterdir() if p.name != "rescue"]  # no temporary left either


@pytest.mark.integration
@pytest.mark.parametrize("command", [_adapt, _name_parts], ids=["adapt", "name-parts"])
def test_a_full_disk_at_the_final_write_keeps_a_rescue_copy(folder, tmp_path, command):
    """The output folder is a 256 kB tmpfs (a model is 1 MB): one line saying the disk is full and
    where the model was saved instead; that copy is a whole model file."""
    if not _unshare_works("--user", "--map-root-user", "--mount"):
        pytest.skip("this machine does not allow user and mount namespaces (unshare), so no small file system")
    small, rescue = tmp_path / "small", tmp_path / "rescue"
    small.mkdir()
    rescue.mkdir()
    out = small / "m.safetensors"
    script = f"mount -t tmpfs -o size=256k tmpfs {small} && exec {PRIMKIT} \"$@\""
    proc = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", script, "sh",
                           *command(folder, out)], capture_output=True, text=True,
                          env={**ENV, "TMPDIR": str(rescue)}, timeout=600)
    line = _one_error_line(proc.stderr)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert str(out) in line and "No space left on device" in line and "saved to" in line, line
    copies = list(rescue.glob("primkit-*/m.safetensors"))
    assert len(copies) == 1 and str(copies[0]) in line
    weights, meta = modelfile.load_model_file(copies[0])
    assert weights and meta["network"]


@pytest.mark.integration
def test_sigterm_to_adapt_stops_in_one_line(folder, tmp_path):
    """SIGTERM during ``adapt``'s training ends it as Ctrl-C does: status 130 and one line (status
    143 and no word before), no model and no lock left."""
    out = tmp_path / "m.safetensors"
    proc = subprocess.Popen([str(PRIMKIT), *_adapt(folder, out)[:-6], "--steps", "100000", "--workers", "1",
                             "--cache", str(folder / "cache")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, start_new_session=True)
    lock = out.with_name(out.name + ".lock")
    deadline = time.monotonic() + 300
    while not lock.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(8.0)  # the model loaded, the shapes read, the steps under way
    proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    err = err.decode(errors="replace")
    line = _one_error_line(err)
    assert proc.returncode == 130 and "interrupted" in line, (proc.returncode, err[-2000:])
    assert not out.exists() and not lock.exists()


# ------------------------------------------------------------------ the lock

HOLDER = """
import sys, time
from primkit.model.modelfile import claim_output
with claim_output(sys.argv[1]):
    print("held", flush=True)
    time.sleep(120)
"""


def _holder(out, namespace: bool):
    """A process holding the lock of ``out`` (in a new PID namespace when ``namespace``), ready."""
    prefix = ["unshare", "--user", "--map-root-user", "--pid", "--fork"] if namespace else []
    proc = subprocess.Popen([*prefix, sys.executable, "-c", HOLDER, str(out)], stdout=subprocess.PIPE, env=ENV,
                            start_new_session=True)
    assert proc.stdout.readline().strip() == b"held"
    return proc


def _end(proc, out=None):
    """Kill the holder; with ``out``, wait until its lock is free (a namespace's first process is
    torn down after ``unshare`` itself has ended)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 30
    while out is not None and time.monotonic() < deadline:
        try:
            with modelfile.claim_output(out):
                return
        except FileExistsError:
            time.sleep(0.1)


@pytest.mark.parametrize("namespace", [False, True], ids=["same-namespace", "other-pid-namespace"])
def test_a_run_holding_the_output_in_any_pid_namespace_is_seen(prepared_chairs, tmp_path, namespace):
    """The lock is the kernel's, not a process id: a holder in another PID namespace (another
    container; its process id means nothing here) keeps library ``train`` and ``--force`` out."""
    if namespace and not _unshare_works("--user", "--map-root-user", "--pid", "--fork"):
        pytest.skip("this machine does not allow user and PID namespaces (unshare)")
    out = tmp_path / "m.safetensors"
    holder = _holder(out, namespace)
    try:
        config = training.TrainConfig(stage1_iterations=1, stage2_iterations=1, batch_size=2, parts=4)
        for force in (False, True):
            with pytest.raises(FileExistsError, match="another primkit run"):
                training.train(training.ShapeTensors(prepared_chairs[:2]), out, config, overwrite=force)
        assert not out.exists()
    finally:
        os.killpg(holder.pid, signal.SIGKILL)
        holder.wait()
    # the holder is gone (killed: its lock file stays), so the lock is free once the kernel let it go
    lock = out.with_name(out.name + ".lock")
    assert lock.exists()
    _end(holder, out)
    assert not lock.exists()


@pytest.mark.parametrize("command", ["adapt", "name-parts", "train-image", "train"])
def test_every_model_writing_command_is_refused_while_another_run_holds_its_output(folder, tmp_path, capsys,
                                                                                    command):
    out = tmp_path / "m.safetensors"
    args = {"adapt": _adapt(folder, out), "name-parts": _name_parts(folder, out),
            "train-image": ["train-image", str(folder / "in"), "--teacher", "chair", "-o", str(out)],
            "train": ["train", str(folder / "in"), "-o", str(out)]}[command]
    holder = _holder(out, False)
    try:
        assert main(args) == 2
    finally:
        _end(holder)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another primkit run" in err[0] and str(out) in err[0], err
    assert not out.exists()


def test_nested_claims_in_one_process_hold_one_lock(tmp_path):
    out = tmp_path / "m.safetensors"
    with modelfile.claim_output(out) as lock:
        with modelfile.claim_output(out):  # the train command, then the library's train
            assert lock.exists()
        assert lock.exists()  # still held by the outer claim
    assert not lock.exists()

"""The library speaks through ``warnings`` and ``logging``, never by printing (issue 34).

A library call writes nothing to stdout or stderr by default: no progress bar (``progress=False``),
no note. Something the caller should act on comes as a warning; a step worth knowing comes as a
log record of the module's logger, which the command line shows and a script may ignore.
"""

import logging
import signal
from dataclasses import replace

import pytest

import primkit
from primkit import synthetic
from primkit.model import training
from primkit.segmentation import Segmenter

TINY = training.TrainConfig(stage1_iterations=3, stage2_iterations=3, batch_size=2, parts=4, points_per_shape=100,
                            samples_per_cuboid=24, log_every=2, checkpoint_every=2)


@pytest.fixture(scope="module")
def collection(tmp_path_factory):
    folder = tmp_path_factory.mktemp("quiet") / "chairs"
    synthetic.write_collection(folder, "chair", 2, seed=3)
    return folder


def test_abstract_segment_and_train_print_nothing_by_default(collection, prepared_chairs, tmp_path, capfd):
    capfd.readouterr()
    out = primkit.abstract_shapes(collection, "chair", cache=tmp_path / "cache", workers=1)
    one = primkit.abstract(sorted(collection.glob("*.ply"))[0], model="chair")
    segs, errors = Segmenter("chair").segment_files(sorted(collection.glob("*.ply")), cache_dir=tmp_path / "cache",
                                                    workers=1)
    result = training.train(training.ShapeTensors(prepared_chairs[:2]), tmp_path / "m.safetensors", TINY)
    assert len(out.shapes) == 2 and one.cuboids.count > 0 and len(segs) == 2 and not errors
    assert result.model_path.is_file()
    assert capfd.readouterr() == ("", "")  # no bar, no note: the caller decides what is shown


def test_the_progress_bars_are_there_when_asked_for(collection, tmp_path, capfd):
    """The same call with ``progress=True`` draws its bars on stderr (so the silence above is the
    default, not a broken bar)."""
    capfd.readouterr()
    primkit.abstract_shapes(collection, "chair", cache=tmp_path / "cache", workers=1, progress=True)
    err = capfd.readouterr().err
    assert "preparing" in err or "abstracting" in err or "%" in err, err


def _checkpoint(shapes, path, monkeypatch):
    """A checkpoint of an interrupted TINY run into ``path`` (Ctrl-C during iteration 4)."""
    calls = {"n": 0}
    original = training.ShapeTensors.batch

    def interrupted(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 4:
            signal.raise_signal(signal.SIGINT)  # the iteration finishes, a checkpoint is written
        return original(self, *args, **kwargs)

    monkeypatch.setattr(training.ShapeTensors, "batch", interrupted)
    result = training.train(shapes, path, TINY)
    monkeypatch.setattr(training.ShapeTensors, "batch", original)
    assert result.interrupted
    return path.with_name(path.name + ".checkpoint.safetensors")


def test_resuming_with_other_settings_is_a_warning_and_the_interrupt_a_log_record(prepared_chairs, tmp_path,
                                                                                  monkeypatch, caplog, capfd):
    shapes = training.ShapeTensors(prepared_chairs[:2])
    out = tmp_path / "m.safetensors"
    with caplog.at_level(logging.INFO, logger="primkit"):
        ckpt = _checkpoint(shapes, out, monkeypatch)
    records = [r for r in caplog.records if r.name.startswith("primkit")]
    assert {r.name for r in records} == {"primkit.model.training"}
    started = [r.getMessage() for r in records if r.levelno == logging.INFO]
    assert started == ["training: iterations 1 to 6 on 2 shapes (cpu)"]  # once Ctrl-C is handled
    (said,) = [r.getMessage() for r in records if r.levelno == logging.WARNING]
    assert "interrupted after iteration 4" in said and str(ckpt) in said
    with pytest.warns(UserWarning, match="settings that differ from its own: log_every 2 -> 3"):
        training.train(shapes, out, replace(TINY, log_every=3), resume=ckpt)
    assert capfd.readouterr() == ("", "")
    assert out.is_file()


def test_the_demo_says_a_refusal_as_an_error_record(tmp_path, caplog, capfd):
    """``run_demo`` into a folder holding one of its outputs, without ``force``: nothing is done, the
    reason is an ERROR record of ``primkit.demo`` naming the file, and nothing is printed."""
    from primkit.demo import run_demo

    out = tmp_path / "demo"
    out.mkdir()
    (out / "bundled.json").write_text("{}")
    capfd.readouterr()
    with caplog.at_level(logging.INFO, logger="primkit"):
        assert run_demo(out, quick=True) == 2
    (said,) = [r for r in caplog.records if r.name == "primkit.demo"]
    assert said.levelno == logging.ERROR and "bundled.json" in said.getMessage()
    assert capfd.readouterr() == ("", "") and not (out / "shapes").exists()

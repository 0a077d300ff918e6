"""The preparation cache cannot hang or lie: only regular files are read from it (a FIFO there hung
every command using the cache), every byte that changes an answer is inside a row's checksum (an
edited frame in ``index.json`` gave cuboids ten times smaller), and an empty ``PRIMKIT_CACHE`` is
an error naming it (it put the cache in the working folder). A property test flips any byte of any
cache file, or puts a FIFO, a folder or a link in its place: the answer is the clean cache's."""

import contextlib
import json
import logging
import os
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest

from primkit import data, synthetic
from primkit.cli import main

SETTINGS = data.PrepareSettings(samples=500)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """Two chairs prepared once into a clean cache: ``(files, cache, answers)``."""
    root = tmp_path_factory.mktemp("cache")
    synthetic.write_collection(root / "in", "chair", 2, seed=3)
    files = sorted((root / "in").glob("*.ply"))
    coll = data.prepare_collection(files, SETTINGS, cache_dir=root / "cache", workers=1)
    return files, root / "cache", _answers(coll)


def _answers(coll) -> list:
    out = []
    for shape in coll:
        out.append({"occupancy": shape.occupancy, "solid": shape.solid, "closest": shape.closest,
                    "points": shape.points, "labels": shape.point_labels, "frame": json.dumps(shape.frame.to_dict())})
    return out


def _same(got, want) -> bool:
    return len(got) == len(want) and all(
        a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) if k != "frame" else a[k] == b[k] for k in a)
        for a, b in zip(got, want))


@contextlib.contextmanager
def _no_hang(seconds=60):
    """SIGALRM after ``seconds``: a blocked open (a FIFO) raises instead of hanging the test."""
    def ring(signum, frame):
        raise TimeoutError(f"hung for {seconds} s")
    previous = signal.signal(signal.SIGALRM, ring)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _copy(cache, tmp_path) -> Path:
    dest = tmp_path / "cache"
    shutil.copytree(cache, dest, symlinks=True)
    return dest


def _segment_files(cache) -> list:
    return sorted(p for p in (cache / f"v{data.CACHE_FORMAT}").rglob("*") if p.is_file())


def _prepare(files, cache, caplog):
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="primkit"), _no_hang():
        coll = data.prepare_collection(files, SETTINGS, cache_dir=cache, workers=1)
    notes = [r.getMessage() for r in caplog.records if r.getMessage().startswith("cache:")]
    return coll, notes


@pytest.mark.parametrize("name", ["index.json", "occupancy.npy", "labels.npy"])
def test_a_fifo_in_the_cache_is_refused_in_one_line_not_a_hang(clean, tmp_path, caplog, name):
    files, cache, want = clean
    cache = _copy(cache, tmp_path)
    target = next(p for p in _segment_files(cache) if p.name == name)
    target.unlink()
    os.mkfifo(target)
    coll, notes = _prepare(files, cache, caplog)
    assert _same(_answers(coll), want) and not coll.errors
    assert len(notes) == 1 and "FIFO" in notes[0] and name in notes[0], notes
    # the damaged segment is gone: the next run reads the new one and says nothing
    coll, notes = _prepare(files, cache, caplog)
    assert _same(_answers(coll), want) and notes == []


def test_a_segment_linked_out_of_the_cache_is_not_read(clean, tmp_path, caplog):
    files, cache, want = clean
    cache = _copy(cache, tmp_path)
    segment = next((cache / f"v{data.CACHE_FORMAT}").iterdir())
    outside = tmp_path / "elsewhere"
    shutil.move(segment, outside)
    segment.symlink_to(outside, target_is_directory=True)
    coll, notes = _prepare(files, cache, caplog)
    assert _same(_answers(coll), want)
    assert len(notes) == 1 and "symbolic link" in notes[0], notes
    assert not segment.is_symlink() and (outside / "index.json").is_file()  # the link removed, not its target


def test_an_edited_frame_is_caught_by_the_checksum(clean, tmp_path, caplog):
    """The frame of a row scaled tenfold in ``index.json`` (outside the checksum, it was read as it
    stood: cuboids ten times smaller and shifted): the row is damaged, prepared again, said."""
    files, cache, want = clean
    cache = _copy(cache, tmp_path)
    index = next(p for p in _segment_files(cache) if p.name == "index.json")
    doc = json.loads(index.read_text())
    doc["rows"][0]["meta"]["frame"]["scale"] *= 10
    doc["rows"][0]["meta"]["frame"]["centre"][1] += 0.5
    index.write_text(json.dumps(doc))
    coll, notes = _prepare(files, cache, caplog)
    assert _same(_answers(coll), want)
    assert len(notes) == 1 and "damaged" in notes[0], notes


@pytest.mark.parametrize("value", ["", "  ", "file"])
def test_an_empty_or_unusable_primkit_cache_is_an_error_naming_it(tmp_path, monkeypatch, capsys, value):
    synthetic.write_collection(tmp_path / "in", "chair", 1, seed=3)
    if value == "file":
        value = str(tmp_path / "a-file")
        Path(value).write_text("not a folder")
    monkeypatch.setenv("PRIMKIT_CACHE", value)
    monkeypatch.chdir(tmp_path)
    before = sorted(os.listdir(tmp_path))
    assert main(["prepare", str(tmp_path / "in"), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "PRIMKIT_CACHE" in err[0], err
    assert sorted(os.listdir(tmp_path)) == before  # no cache written in the working folder


# ------------------------------------------------------------------ property: any damage, the clean answer

hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is in the dev extra")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402


@settings(max_examples=12, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(pick=st.integers(0, 10**6), action=st.sampled_from(["flip", "flip", "flip", "fifo", "folder", "link"]),
       where=st.floats(0, 1, exclude_max=True), xor=st.integers(1, 255))
def test_any_damaged_cache_file_gives_the_clean_answer(clean, tmp_path_factory, caplog, pick, action, where, xor):
    """One file of the cache damaged (one byte flipped, or the file replaced by a FIFO, a folder or
    a link to a copy outside the cache): no hang, no exception, and the clean cache's answer."""
    files, cache, want = clean
    cache = _copy(cache, tmp_path_factory.mktemp("damaged"))
    targets = _segment_files(cache)
    target = targets[pick % len(targets)]
    if action == "flip":
        raw = bytearray(target.read_bytes())
        raw[int(where * len(raw))] ^= xor
        target.write_bytes(bytes(raw))
    else:
        copy = cache.parent / "outside"
        shutil.copy(target, copy)
        target.unlink()
        {"fifo": lambda: os.mkfifo(target), "folder": lambda: target.mkdir(),
         "link": lambda: target.symlink_to(copy)}[action]()
    coll, notes = _prepare(files, cache, caplog)
    assert not coll.errors, coll.errors
    assert _same(_answers(coll), want), (target.name, action, notes)
    if action != "flip":
        assert len(notes) == 1 and target.name in notes[0], notes

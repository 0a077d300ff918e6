"""What the command line shows on stderr: progress bars only when stderr is a terminal and not with
``--quiet`` (the library draws none unless asked); the library's notes (logging, INFO) as
``primkit: note: ...`` unless ``--quiet``; its warnings always."""

from __future__ import annotations

import sys

import pytest

from primkit import synthetic
from primkit.cli import build_parser, main


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    root = tmp_path_factory.mktemp("quiet")
    # the same file names in two folders: the run plan says so, as a note
    synthetic.write_collection(root / "a", "chair", 1, seed=1)
    synthetic.write_collection(root / "b", "chair", 1, seed=2)
    return root


def _prepare(root, cache, *flags):
    return main(["prepare", str(root / "a"), str(root / "b"), "--cache", str(cache), "--workers", "1", *flags])


def test_bars_only_on_a_terminal_and_never_with_quiet(twins, tmp_path, capsys, monkeypatch):
    assert _prepare(twins, tmp_path / "c1") == 0
    assert "preparing" not in capsys.readouterr().err  # stderr is no terminal here: no bars in the log
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert _prepare(twins, tmp_path / "c2") == 0
    err = capsys.readouterr().err
    assert "preparing" in err and "\r" in err  # a terminal: the bar
    assert _prepare(twins, tmp_path / "c3", "--quiet") == 0
    assert "preparing" not in capsys.readouterr().err


def test_notes_unless_quiet_and_warnings_always(twins, tmp_path, capsys):
    assert _prepare(twins, tmp_path / "c") == 0
    err = capsys.readouterr().err
    assert "primkit: note: 2 inputs are named chair_0000" in err
    assert _prepare(twins, tmp_path / "c", "--quiet") == 0
    assert capsys.readouterr().err == ""
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where the cache folder should be")
    assert _prepare(twins, blocked, "--quiet") == 0
    err = capsys.readouterr().err.splitlines()
    assert err == [f"primkit: cache: {blocked / 'v3'} cannot be written (Not a directory): shapes prepared in memory"]


def test_every_command_that_shows_progress_takes_quiet():
    import argparse

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    progress = ("demo", "prepare", "train", "abstract", "eval", "segment", "name-parts", "embed", "similar", "report", "adapt",
                "train-image", "deform", "edit")
    for name in progress:
        dests = {a.dest for a in sub.choices[name]._actions}
        assert "quiet" in dests, f"primkit {name} has no --quiet"

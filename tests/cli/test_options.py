"""The command line's options: edits parsed from their flags."""

import numpy as np
import pytest

from primkit.cli.deform import parse_edit


def test_parse_edit_resolves_part_names():
    names = ["seat", "legs", "legs", "back"]
    assert parse_edit("legs=1.3", names, kind="scale") == {1: 1.3, 2: 1.3}
    r = parse_edit("part3,seat=0,0.05,0", names, kind="move")
    assert sorted(r) == [0, 3] and np.allclose(r[3], [0, 0.05, 0])
    assert parse_edit("3=15", names, kind="rotate") == {3: 15.0}
    with pytest.raises(ValueError, match="unknown part 'arms'.*seat, legs, back"):
        parse_edit("arms=2", names, kind="scale")
    with pytest.raises(ValueError, match="expected 3 number"):
        parse_edit("seat=0.1", names, kind="move")


def _subcommands(parser, prefix=()):
    """(command path, parser) for every leaf subcommand (``view abstraction`` is one)."""
    import argparse

    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield prefix, parser
        return
    for name, sub in subs[0].choices.items():
        yield from _subcommands(sub, prefix + (name,))


def _signature(action, dest):
    fields = ["option_strings", "type", "choices", "nargs", "metavar", "default", "required", "help"]
    if dest == "output":  # -o names what the command writes: a folder or a file
        fields = ["option_strings", "type", "choices", "nargs", "metavar"]
    return tuple((f, repr(getattr(action, f))) for f in fields) + (("action", type(action).__name__),)


def test_shared_options_are_defined_once_and_identical_everywhere():
    from primkit.cli import build_parser
    from primkit.cli._common import SHARED_OPTIONS

    seen = {}
    commands = dict(_subcommands(build_parser()))
    for path, parser in commands.items():
        for action in parser._actions:
            if action.dest in SHARED_OPTIONS and action.option_strings:
                seen.setdefault(action.dest, {})[" ".join(path)] = _signature(action, action.dest)
    for dest, by_command in seen.items():
        distinct = set(by_command.values())
        assert len(distinct) == 1, f"--{dest} differs between commands: {sorted(by_command)}"
    # every command that abstracts with a model has the whole set, spelled the same
    abstracting = [p for p, parser in commands.items() if any(a.dest == "model" and a.option_strings for a in parser._actions)]
    assert len(abstracting) >= 12
    for path in abstracting:
        dests = {a.dest for a in commands[path]._actions}
        missing = {"model", "up", "front", "align", "refine", "cache", "workers", "force"} - dests
        assert not missing, f"primkit {' '.join(path)} lacks {sorted(missing)}"
    # pictures are asked for one way: --png PATH, off unless given
    for path, parser in commands.items():
        for a in parser._actions:
            assert "--no-png" not in a.option_strings, path
            if "--png" in a.option_strings:
                assert a.default is None and a.metavar == "PATH", path


def test_segment_keeps_an_existing_evaluation_without_force(tmp_path, capsys):
    from primkit import synthetic
    from primkit.cli import main

    folder = tmp_path / "in"
    synthetic.write_collection(folder, "chair", 1, seed=2)
    out = tmp_path / "out"
    out.mkdir()
    (out / "evaluation.json").write_text("{}")
    code = main(["segment", str(folder), "--model", "chair", "-o", str(out), "--gt", str(folder), "--workers", "1",
                 "--cache", str(tmp_path / "cache")])
    assert code == 2 and "evaluation.json: exists" in capsys.readouterr().err
    assert (out / "evaluation.json").read_text() == "{}"

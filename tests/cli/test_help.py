"""``primkit SUBCOMMAND --help`` explains itself: every subcommand (``view``'s viewers too) has a
description, an epilog whose examples are commands of that subcommand which parse, and a help
string for every argument."""

from __future__ import annotations

import argparse
import shlex

import pytest

from primkit.cli import build_parser, main


def _subcommands(parser, path=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from _subcommands(sub, (*path, name))


SUBCOMMANDS = list(_subcommands(build_parser()))
IDS = [" ".join(p) for p, _ in SUBCOMMANDS]


def _examples(parser) -> list[str]:
    epilog = parser.epilog or ""
    return [line.strip() for line in epilog.splitlines() if line.strip().startswith("primkit ")]


def test_every_subcommand_is_walked():
    names = {p for p, _ in SUBCOMMANDS}
    for expected in (("segment",), ("demo",), ("view",), ("view", "open3d"), ("train-image",), ("name-parts",)):
        assert expected in names
    assert len(names) >= 22


@pytest.mark.parametrize("path,parser", SUBCOMMANDS, ids=IDS)
def test_subcommand_has_a_description(path, parser):
    assert parser.description and len(parser.description) > 40, f"primkit {' '.join(path)}: no description"


@pytest.mark.parametrize("path,parser", SUBCOMMANDS, ids=IDS)
def test_subcommand_epilog_shows_examples_that_parse(path, parser):
    examples = _examples(parser)
    assert examples, f"primkit {' '.join(path)}: no example in its epilog"
    assert issubclass(parser.formatter_class, argparse.RawDescriptionHelpFormatter), "the examples would be re-wrapped"
    for example in examples:
        argv = shlex.split(example)[1:]
        assert tuple(argv[: len(path)]) == path, f"the example {example!r} is not of primkit {' '.join(path)}"
        args = build_parser().parse_args(argv)  # an example that no longer parses fails here (SystemExit)
        assert callable(getattr(args, "func", None))


@pytest.mark.parametrize("path,parser", SUBCOMMANDS, ids=IDS)
def test_every_argument_has_help(path, parser):
    missing = [a.option_strings[0] if a.option_strings else a.dest for a in parser._actions
               if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) and not a.help]
    assert not missing, f"primkit {' '.join(path)}: arguments without help: {missing}"


def test_help_prints_description_and_examples(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["segment", "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "Co-segment a collection" in out
    assert "examples:\n  primkit segment chairs/" in out  # the epilog's lines are kept, not re-wrapped


def test_model_defaults_to_the_librarys_default_everywhere():
    """``--model`` left out means what ``model`` left out means in the library: one default."""
    import inspect

    import primkit

    library = {inspect.signature(f).parameters["model"].default for f in (primkit.abstract, primkit.segment)}
    assert len(library) == 1
    seen = 0
    for path, parser in SUBCOMMANDS:
        for action in parser._actions:
            if "--model" in action.option_strings:
                seen += 1
                assert not action.required, path
                assert action.default in library, path
    assert seen >= 8

"""Shared pieces of the ``primkit`` subcommands: one-line errors, batch error reports, input
collection, and the options the commands share.

Every shared option is defined once, here (the ``add_*`` functions), so that a flag means the same
thing, with the same default and help, in every command that has it; ``tests/cli/test_options.py``
walks every subcommand's parser and checks it. Each subcommand module under :mod:`primkit.cli`
defines ``register(subparsers)`` and stays a thin wrapper over library calls; it imports the
library when its command runs (the model layer imports torch, the drawing kit VTK, and
``primkit --help`` needs neither).
"""

from __future__ import annotations

import argparse

import contextlib
import logging
import re
import sys
from pathlib import Path
from typing import TypedDict

__all__ = [
    "err",
    "add_command",
    "DeprecatedAlias",
    "command_logging",
    "report_errors",
    "collect",
    "output_names",
    "input_paths",
    "check_command_outputs",
    "model_file",
    "settings_from_args",
    "abstraction_options",
    "AbstractionOptions",
    "add_model",
    "add_output",
    "add_force",
    "add_axes",
    "add_align",
    "add_refine",
    "add_cache",
    "add_workers",
    "add_scale_out",
    "add_png",
    "add_quiet",
    "progress_of",
    "add_prepare_options",
    "add_abstraction_options",
    "add_adapt",
    "SHARED_OPTIONS",
]

#: the shared options' destinations, as ``tests/cli/test_options.py`` checks them
SHARED_OPTIONS = ("model", "output", "force", "up", "front", "align", "refine", "cache", "workers", "png", "executor",
                  "shard", "quiet")


def err(msg: str) -> None:
    print(f"primkit: error: {msg}", file=sys.stderr)


class _StderrHandler(logging.Handler):
    """The library's log records on the command's stderr (the one in place when each is written):
    ``primkit: note: ...`` for notes (INFO), ``primkit: ...`` for warnings (their message names
    what they are about: ``cache: ...``)."""

    def emit(self, record) -> None:
        try:
            text = record.getMessage()
            prefix = "primkit: note: " if record.levelno < logging.WARNING else "primkit: "
            print(prefix + text, file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must never stop the command
            self.handleError(record)


@contextlib.contextmanager
def command_logging(quiet: bool = False):
    """Within the block (a command's run), the library's notes (INFO) and warnings of the
    ``primkit`` loggers on stderr; with ``quiet``, the warnings only. Afterwards the loggers are as
    they were (a program calling :func:`primkit.cli.main` keeps its own logging)."""
    logger = logging.getLogger("primkit")
    handler, level = _StderrHandler(), logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING if quiet else logging.INFO)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


#: above this many errors, report_errors ends with a count of each reason
SUMMARY_ABOVE = 10


def report_errors(errors) -> int:
    """Print one line per input that could not be used (``primkit: skipped <path>: <reason>``);
    for more than :data:`SUMMARY_ABOVE` of them, then the reasons with how many inputs each stopped
    and one of them. Returns the exit status: 1 when there were errors, else 0."""
    errors = [str(e) for e in errors]
    for e in errors:
        print(f"primkit: skipped {e}", file=sys.stderr)
    if not errors:
        return 0
    print(f"primkit: {len(errors)} input(s) could not be used", file=sys.stderr, end="")
    if len(errors) <= SUMMARY_ABOVE:
        print(file=sys.stderr)
        return 1
    groups = {}
    for e in errors:
        path, sep, reason = e.partition(": ")
        key = re.sub(r"\d+", "N", reason if sep else e)  # "12 labels for 30 faces" and "9 labels ..." alike
        groups.setdefault(key, []).append(path)
    print(f", by reason ({len(groups)}):", file=sys.stderr)
    for key, paths in sorted(groups.items(), key=lambda kv: -len(kv[1])):
        print(f"  {len(paths):7d}  {key}  (e.g. {paths[0]})", file=sys.stderr)
    return 1


def collect(inputs) -> list[Path]:
    """The shape files of the command line's inputs (:func:`primkit.data.collect_files`: files as
    given, folders searched recursively; a missing input or an empty folder is a one-line error)."""
    from ..data import collect_files

    return collect_files(inputs)


def output_names(files) -> list[str]:
    """The names outputs take after each of ``files`` (the run plan's, :func:`primkit.data.plan_run`,
    which notes which inputs shared a name and what they are called instead)."""
    from ..data import plan_run

    return plan_run(files).names


def input_paths(files, *extra) -> list[Path]:
    """Every file a run reads: the shape files with their labels and attributes
    (:func:`primkit.data.input_files`), and ``extra`` (models, label folders' files; None skipped)."""
    from ..data import input_files

    out = [p for f in files for p in input_files(f)]
    for item in extra:
        if item is None:
            continue
        item = Path(item)
        out.extend(sorted(item.iterdir()) if item.is_dir() else [item])
    return out


def model_file(model) -> Path | None:
    """The file of ``--model`` (a path or a bundled model's name); None when there is none (loading
    it reports that)."""
    from ..model.bundled import resolve_model

    try:
        return resolve_model(model)
    except FileNotFoundError:
        return None


def check_command_outputs(args, outputs, inputs=()) -> list[Path]:
    """:func:`primkit.io.check_outputs` with the command's ``--force``: before any work, every
    output can be written, is no input, and replaces nothing without ``--force``."""
    from ..io import check_outputs as check

    return check(outputs, inputs=inputs, overwrite=getattr(args, "force", False))


def settings_from_args(args, base=None):
    """Preparation settings: ``base`` (a model's or a preset's; the defaults when None) with the
    options given on the command line."""
    from dataclasses import replace

    from ..data import PrepareSettings

    base = base or PrepareSettings()
    given = {k: getattr(args, k, None) for k in ("resolution", "samples", "up", "front")}
    return replace(base, **{k: v for k, v in given.items() if v is not None})


class AbstractionOptions(TypedDict, total=False):
    """Keyword arguments of :func:`primkit.model.abstraction.abstract_shapes` (and of
    ``Abstractor.abstract``'s shared ones) that the shared options give; not a result."""

    align: str | None
    refine: int
    cache: str | None
    workers: int | None
    progress: bool
    executor: str
    up: str
    front: str
    adapt: int | bool


def abstraction_options(args) -> AbstractionOptions:
    """The keyword arguments of :func:`primkit.model.abstraction.abstract_shapes` that the shared
    options give (the inputs' axes only when given, so the library's defaults stand otherwise;
    ``progress``: :func:`progress_of`)."""
    options: AbstractionOptions = {"align": args.align, "refine": args.refine, "cache": args.cache, "workers": args.workers,
               "progress": progress_of(args)}
    if getattr(args, "executor", None) is not None:
        options["executor"] = args.executor
    options.update({k: getattr(args, k) for k in ("up", "front") if getattr(args, k, None) is not None})
    if getattr(args, "adapt", None):
        options["adapt"] = args.adapt
    return options


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Raw descriptions and examples, and every option's default said: `` (default: X)`` after
    the help of an option that has a default (not None, not a flag's False) and does not say it
    already. An option whose default is computed (None) says what it is in its own help."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (action.option_strings and default is not None and default is not False and default != argparse.SUPPRESS
                and "default" not in text
                and not isinstance(action, (argparse._StoreConstAction, argparse._CountAction))):
            text += " (default: %(default)s)"
        return text


def add_command(subparsers, name: str, *, examples, **kwargs):
    """A subcommand whose ``--help`` ends with its ``examples`` (one command line each, shown as
    written: argparse's raw description formatter keeps their line breaks), and whose options say
    their defaults."""
    epilog = "examples:\n" + "".join(f"  {line}\n" for line in examples)
    return subparsers.add_parser(name, epilog=epilog, formatter_class=_HelpFormatter, **kwargs)


class DeprecatedAlias(argparse.Action):
    """A hidden old name of an option: stores into the new one's ``dest`` and says on stderr that
    ``new`` replaces it (``primkit: note: --scale is deprecated here: use --units``)."""

    def __init__(self, option_strings, dest, *, new: str, **kwargs):
        self.new = new
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"primkit: note: {option_string} is deprecated here: use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_model(p) -> None:
    p.add_argument("--model", default="chair", help="a model file, or a bundled model's name (primkit models); "
                   "default: chair, as in the library and the plugins")


def add_output(p, help: str, **kwargs) -> None:
    kwargs.setdefault("required", True)
    p.add_argument("-o", "--output", help=help, **kwargs)


def add_force(p) -> None:
    p.add_argument("--force", action="store_true", help="replace existing outputs")


def add_axes(p) -> None:
    p.add_argument("--up", default=None, help="the inputs' up axis, e.g. +z (default: +y unless a shape clearly lies on "
                   "a side; ShapeNet and COSEG are +y)")
    p.add_argument("--front", default=None, help="the inputs' front axis, e.g. +x for ShapeNet, +z for COSEG (default: "
                   "found by the model among the turns about the up axis)")


def add_align(p) -> None:
    p.add_argument("--align", choices=["none", "front", "auto", "any"], default=None,
                   help="how each shape's orientation is found: auto (+Y up unless the shape clearly lies on a side, "
                        "the front found among the 4 turns about the up axis), front (only the front), any (all 24 "
                        "axis-aligned turns, the model's best), none (as given or declared). Default: auto, or front "
                        "when --up is given, or none when --up and --front are; the choice is recorded in the output")


def add_refine(p) -> None:
    p.add_argument("--refine", type=int, default=0, metavar="N",
                   help="N gradient steps per shape on its own losses after the network (default 0: the network's "
                        "answer; 100-200 fit the cuboids closer, at 0.4-1.3 s per shape per 100 steps on one core)")


def add_cache(p) -> None:
    p.add_argument("--cache", default=None, help="preparation cache folder (default $PRIMKIT_CACHE or ~/.cache/primkit/prepared)")


def add_workers(p) -> None:
    p.add_argument("--workers", type=int, default=None, help="processes for preparation (default: all cores)")


def add_scale_out(p, shard: bool = True) -> None:
    """``--executor`` and (``shard``) ``--shard``, for the commands that map over files (prepare,
    abstract, segment; embed's abstraction step takes ``--executor`` only: its outputs are the collection's)."""
    p.add_argument("--executor", default=None, metavar="ADDRESS",
                   help="run the per-file work on a cluster (preparation; segment's labelling too): a Dask scheduler "
                        "(tcp://HOST:8786; dask: a local cluster) or Ray (ray: the cluster RAY_ADDRESS or `ray start` "
                        "names, else a local one; ray:auto, ray:HOST:6379, ray://HOST:10001); the results come back "
                        "and are written here, the workers need primkit and the files")
    if not shard:
        return
    p.add_argument("--shard", default=None, metavar="K/N",
                   help="only the K-th of N shards of the inputs (every N-th file from the K-th), for job arrays; "
                        "auto: from torchrun's RANK/WORLD_SIZE or SLURM's array or task variables. The shards' outputs "
                        "are named as one run's and merge without clashes")


def add_quiet(p) -> None:
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars and no notes (warnings and errors still show)")


def progress_of(args) -> bool:
    """Whether the command shows progress bars: only when its stderr is a terminal (no carriage
    returns in a log or a pipe), and not with ``--quiet``. The library draws none unless asked."""
    if getattr(args, "quiet", False):
        return False
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # a closed or replaced stream
        return False


def add_png(p) -> None:
    p.add_argument("--png", default=None, metavar="PATH", help="also draw the command's picture into this PNG file")


def add_prepare_options(p) -> None:
    """How shapes are prepared: grid resolution, surface samples, the inputs' axes, cache, processes."""
    p.add_argument("--resolution", type=int, default=None, help="grid cells per axis (default 32, or the model's)")
    p.add_argument("--samples", type=int, default=None, help="surface samples per shape (default 10000)")
    add_axes(p)
    add_cache(p)
    add_workers(p)
    add_quiet(p)


def add_abstraction_options(p) -> None:
    """What a command that abstracts shapes with a model takes: the model, the inputs' axes,
    align, refine, cache and processes."""
    add_model(p)
    add_axes(p)
    add_align(p)
    add_refine(p)
    add_cache(p)
    add_workers(p)
    add_adapt(p)
    add_quiet(p)


def _adapt_steps(text: str):
    """``--adapt``'s value: a number of steps, or True (no number: the steps follow the inputs' count)."""
    return True if text == "auto" else int(text)


def add_adapt(p) -> None:
    p.add_argument("--adapt", type=_adapt_steps, nargs="?", const="auto", default=None, metavar="STEPS",
                   help="adapt the model to these inputs first, without labels (experimental; without a number "
                        "the steps follow the inputs' count, 200 to 600; primkit adapt writes the adapted model to a file)")

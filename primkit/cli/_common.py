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

import sys
from pathlib import Path

__all__ = [
    "err",
    "report_errors",
    "collect",
    "settings_from_args",
    "abstraction_options",
    "add_model",
    "add_output",
    "add_force",
    "add_axes",
    "add_align",
    "add_refine",
    "add_cache",
    "add_workers",
    "add_png",
    "add_prepare_options",
    "add_abstraction_options",
    "SHARED_OPTIONS",
]

#: the shared options' destinations, as ``tests/cli/test_options.py`` checks them
SHARED_OPTIONS = ("model", "output", "force", "up", "front", "align", "refine", "cache", "workers", "png")


def err(msg: str) -> None:
    print(f"primkit: error: {msg}", file=sys.stderr)


def report_errors(errors) -> int:
    for e in errors:
        print(f"primkit: skipped {e}", file=sys.stderr)
    if errors:
        print(f"primkit: {len(errors)} input(s) could not be used", file=sys.stderr)
    return 1 if errors else 0


def collect(inputs) -> list[Path]:
    from ..data import find_shape_files

    files = []
    for item in inputs:
        files.extend(find_shape_files(item))
    return files


def settings_from_args(args, base=None):
    """Preparation settings: ``base`` (a model's or a preset's; the defaults when None) with the
    options given on the command line."""
    from dataclasses import replace

    from ..data import PrepareSettings

    base = base or PrepareSettings()
    given = {k: getattr(args, k, None) for k in ("resolution", "samples", "up", "front")}
    return replace(base, **{k: v for k, v in given.items() if v is not None})


def abstraction_options(args) -> dict:
    """The keyword arguments of :func:`primkit.model.abstraction.abstract_shapes` that the shared
    options give (the inputs' axes only when given, so the library's defaults stand otherwise)."""
    options = {"align": args.align, "refine": args.refine, "cache": args.cache, "workers": args.workers}
    options.update({k: getattr(args, k) for k in ("up", "front") if getattr(args, k, None) is not None})
    return options


def add_model(p) -> None:
    p.add_argument("--model", required=True, help="a model file, or a bundled model's name (primkit models)")


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


def add_png(p) -> None:
    p.add_argument("--png", default=None, metavar="PATH", help="also draw the command's picture into this PNG file")


def add_prepare_options(p) -> None:
    """How shapes are prepared: grid resolution, surface samples, the inputs' axes, cache, processes."""
    p.add_argument("--resolution", type=int, default=None, help="grid cells per axis (default 32, or the model's)")
    p.add_argument("--samples", type=int, default=None, help="surface samples per shape (default 10000)")
    add_axes(p)
    add_cache(p)
    add_workers(p)


def add_abstraction_options(p) -> None:
    """What a command that abstracts shapes with a model takes: the model, the inputs' axes,
    align, refine, cache and processes."""
    add_model(p)
    add_axes(p)
    add_align(p)
    add_refine(p)
    add_cache(p)
    add_workers(p)

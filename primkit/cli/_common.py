"""Shared pieces of the ``primkit`` subcommands: one-line errors, batch error reports, input
collection and preparation options. Each subcommand module under :mod:`primkit.cli` defines
``register(subparsers)`` and a ``run(args) -> int`` and stays a thin wrapper over library calls."""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["err", "report_errors", "collect", "settings_from_args", "add_prepare_options"]


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


def add_prepare_options(p) -> None:
    p.add_argument("--resolution", type=int, default=32, help="grid cells per axis (default 32)")
    p.add_argument("--samples", type=int, default=10000, help="surface samples per shape (default 10000)")
    p.add_argument("--up", default=None, help="the inputs' up axis, e.g. +y (COSEG, ShapeNet; the default) or +z")
    p.add_argument("--front", default=None, help="the inputs' front axis (default +x)")
    p.add_argument("--cache", default=None, help="cache folder (default $PRIMKIT_CACHE or ~/.cache/primkit/prepared)")
    p.add_argument("--workers", type=int, default=None, help="processes for preparation (default: all cores)")

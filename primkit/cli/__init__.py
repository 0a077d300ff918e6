"""The ``primkit`` command: each subcommand is a thin wrapper over one library call.

The top layer: it may import every part of primkit, and nothing imports it. This module only
dispatches: the shared options are defined once, in :mod:`primkit.cli._common`; the commands live
in the modules beside it (the core ones in :mod:`primkit.cli.core`).

Exit codes: 0 success; 1 some inputs could not be used (each reported on one line, the batch goes
on); 2 bad usage or a fatal error (one line: ``primkit: error: ...``); 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

__all__ = ["main", "build_parser"]

from ._common import command_logging, err


def build_parser() -> argparse.ArgumentParser:
    from ..version import __version__

    parser = argparse.ArgumentParser(prog="primkit", description="Explain 3D shapes with a few cuboids (Tulsiani et al. 2017).")
    parser.add_argument("-V", "--version", action="version", version=f"primkit {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    # The commands live in the modules beside this one: the core ones (core.py) first, then the
    # application commands (segment.py, embed.py, ...); each defines ``register(subparsers)``, and
    # every public module of this package is one.
    for name in ["core"] + [m for m in _command_modules() if m != "core"]:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def _command_modules() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def main(argv=None) -> int:
    from ..io import ShapeFileError
    from ..model.modelfile import ModelFileError
    from ..parallel import ExecutorError

    parser = build_parser()
    args = parser.parse_args(argv)
    for stream in (sys.stdout, sys.stderr):  # file names that are not UTF-8 are printed with their bytes
        try:
            stream.reconfigure(errors="surrogateescape")
        except (AttributeError, ValueError, OSError):  # a stream that is not a TextIOWrapper
            pass
    from ..parallel import sigterm_as_interrupt

    try:  # SIGTERM (SLURM, Kubernetes, timeout) stops a command as Ctrl-C does: outputs whole, one line, 130
        with sigterm_as_interrupt(), command_logging(quiet=getattr(args, "quiet", False)):
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        err("interrupted")
        return 130
    except (ShapeFileError, ModelFileError, ExecutorError, OSError, ValueError) as exc:  # OSError: FileExistsError, a full disk...
        err(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        return 2


if __name__ == "__main__":
    sys.exit(main())

"""Bounds on what one file may make the readers allocate, checked before the memory is spent.

A few megabytes of file can declare far more than they hold: a binvox header saying ``dim 1024 1024
1024`` (8 MB of run lengths, 1 GB decoded, about 10 GB once prepared), a GLB placing one mesh 3,000
times (1 MB, 61M faces once expanded). Past a bound the reader raises a one-line
:class:`~primkit.io.ShapeFileError` naming the file, the bound and how to raise it; a batch skips that
file and goes on.

=====================  ==========================  ============================================
bound                  default                     raise it with
=====================  ==========================  ============================================
faces of one mesh      20,000,000 (instances       ``PRIMKIT_MAX_FACES=50000000`` or
                       of a scene counted)         ``primkit.io.limits.MAX_FACES = 50_000_000``
voxel grid side        512 cells (512^3 voxels)    ``PRIMKIT_MAX_GRID=1024`` or
                                                   ``primkit.io.limits.MAX_GRID = 1024``
=====================  ==========================  ============================================

The environment variable, when set, wins over the module attribute (so that a command line can
raise a bound without code). Meshes of 5M faces and 256^3 grids prepare on a 24 GiB machine.
"""

from __future__ import annotations

import os

from .values import ShapeFileError

__all__ = ["MAX_FACES", "MAX_GRID", "max_faces", "max_grid", "check_faces", "check_grid"]

#: largest number of faces of one mesh (a scene's instances counted); ``PRIMKIT_MAX_FACES`` overrides
MAX_FACES = 20_000_000
#: largest side of a voxel grid in cells; ``PRIMKIT_MAX_GRID`` overrides
MAX_GRID = 512


def _bound(variable: str, default: int) -> int:
    text = os.environ.get(variable)
    if text is None or not text.strip():
        return int(default)
    try:
        value = int(text.strip().replace("_", ""))
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{variable} must be a positive integer, got {text!r}")
    return value


def max_faces() -> int:
    """The bound on faces: ``PRIMKIT_MAX_FACES`` when set, else :data:`MAX_FACES`."""
    return _bound("PRIMKIT_MAX_FACES", MAX_FACES)


def max_grid() -> int:
    """The bound on a voxel grid's side: ``PRIMKIT_MAX_GRID`` when set, else :data:`MAX_GRID`."""
    return _bound("PRIMKIT_MAX_GRID", MAX_GRID)


def check_faces(path, count: int, what: str = "") -> None:
    """ShapeFileError naming ``path`` when ``count`` faces exceed :func:`max_faces`."""
    bound = max_faces()
    if count > bound:
        what = f" {what}" if what else ""
        raise ShapeFileError(
            path,
            f"{count:,} faces{what} exceed the bound of {bound:,} "
            f"(raise it with PRIMKIT_MAX_FACES=N or primkit.io.limits.MAX_FACES)",
        )


def check_grid(path, side: int) -> None:
    """ShapeFileError naming ``path`` when a grid of ``side``^3 cells exceeds :func:`max_grid`."""
    bound = max_grid()
    if side > bound:
        raise ShapeFileError(
            path,
            f"a {side}^3 voxel grid exceeds the bound of {bound}^3 "
            f"(raise it with PRIMKIT_MAX_GRID=N or primkit.io.limits.MAX_GRID)",
        )

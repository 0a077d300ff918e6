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

__all__ = ["MAX_FACES", "MAX_GRID", "max_faces", "max_grid", "check_faces", "check_grid", "npz_members",
           "read_npz_member"]

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


def npz_members(path, max_bytes: int) -> dict[str, tuple]:
    """``{name: (shape, dtype)}`` of the arrays of the ``.npz`` archive ``path``, read from each
    member's ``.npy`` header (a few bytes decompressed each), before any array is loaded.

    Raises :class:`~primkit.io.ShapeFileError` (one line naming ``path``) when the file is not a
    whole archive (truncated, damaged: ``BadZipFile`` before), a member is not a plain ``.npy``
    (objects, a damaged header), declares more bytes than it stores, or more than ``max_bytes``:
    a 7 MB archive of zeros can declare 6.7 GiB, which ``np.load`` would allocate.
    """
    import math
    import zipfile

    import numpy as np

    fmt = np.lib.format
    try:
        with zipfile.ZipFile(path) as zf:
            out = {}
            for info in zf.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                with zf.open(info) as fh:
                    version = fmt.read_magic(fh)
                    read = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}.get(version)
                    if read is None:
                        raise ValueError(f"member {name!r}: .npy version {version}")
                    shape, _, dtype = read(fh)
                if dtype.hasobject:
                    raise ValueError(f"member {name!r} holds Python objects")
                size = math.prod(shape) * dtype.itemsize
                if size > info.file_size:
                    raise ValueError(f"member {name!r} declares {size:,} bytes ({dtype} {shape}) but stores "
                                     f"{info.file_size:,}")
                if size > max_bytes:
                    raise ValueError(f"member {name!r} declares {size / 2**20:,.0f} MiB ({dtype} {shape}), over the "
                                     f"bound of {max_bytes / 2**20:,.0f} MiB")
                out[name] = (tuple(shape), dtype)
            return out
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError, NotImplementedError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if isinstance(exc, (zipfile.BadZipFile, EOFError)):
            reason = f"not a whole .npz archive (truncated or damaged: {reason})"
        raise ShapeFileError(path, reason) from None


def read_npz_member(archive, path, name: str):
    """``archive[name]`` of an open ``np.load`` archive, a damaged member (a bad CRC, a truncated
    stream) raising :class:`~primkit.io.ShapeFileError` naming ``path`` instead of zipfile's or
    zlib's own errors."""
    import zipfile
    import zlib

    try:
        return archive[name]
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
        raise ShapeFileError(path, f"member {name!r} cannot be read ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None

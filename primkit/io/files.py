"""Writing files safely: nothing a user made is replaced without ``overwrite`` (``--force``), and
a file appears complete or not at all."""

from __future__ import annotations

import os
import secrets
from contextlib import contextmanager
from pathlib import Path

__all__ = ["refuse_existing", "atomic_output"]


def refuse_existing(paths, overwrite: bool = False) -> None:
    """Raise ``FileExistsError("<path>: exists (use --force to overwrite)")`` for the first of
    ``paths`` (one path or several; None entries skipped) that exists, unless ``overwrite``.

    Writers call it before they start work, so that nothing a user made is replaced without
    ``--force``; :func:`atomic_output` makes the same check when it writes.
    """
    if overwrite or paths is None:
        return
    for path in [paths] if isinstance(paths, (str, os.PathLike)) else paths:
        if path is not None and os.path.lexists(path):
            raise FileExistsError(f"{path}: exists (use --force to overwrite)")


@contextmanager
def atomic_output(path, *, overwrite=False):
    """Write a file so that it appears complete or not at all.

    Yields a temporary path in the same folder, with the same suffix; when the block ends
    without an exception the temporary is moved onto ``path`` with ``os.replace``. On an
    exception the temporary is removed and ``path`` is untouched.

    Parameters
    ----------
    path : str or Path
      Final location.
    overwrite : bool
      Replace an existing file. Without it an existing ``path`` raises
      ``FileExistsError(f"{path}: exists (use --force to overwrite)")``.

    Yields
    ------
    temporary : Path
      An empty file to write to.
    """
    path = Path(path)
    refuse_existing(path, overwrite)
    temporary = _create_temporary(path)
    try:
        yield temporary
        refuse_existing(path, overwrite)  # appeared while we were writing
        os.replace(temporary, path)
    except BaseException:
        try:
            temporary.unlink()
        except FileNotFoundError:
            pass
        raise


def _create_temporary(path: Path) -> Path:
    """Create an empty, uniquely named file beside ``path`` with the same suffix."""
    while True:
        temporary = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp{path.suffix}")
        try:
            os.close(os.open(temporary, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            continue
        return temporary

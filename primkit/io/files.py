"""Writing files safely, with one policy for every writer of primkit:

* every output is checked before any work (:func:`check_outputs`): its folder can be written, it is
  not one of the run's inputs, no two outputs of the run are the same file, and it does not exist
  yet unless ``overwrite`` (``--force``) is given;
* ``overwrite`` never replaces an input: an output that is an input is refused whatever the flags;
* a file appears complete or not at all (:func:`atomic_output`), with the permissions of any other
  new file (``0666`` less the umask, ``0644`` usually), or those of the file it replaces.

A write killed half-way leaves at most a hidden temporary beside its target
(``.primkit.<8 hex digits>.tmp<suffix>``, :func:`is_temporary`), which is never taken for an input.
"""

from __future__ import annotations

import errno
import functools
import os
import re
import secrets
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["OutputError", "check_outputs", "check_suffix", "refuse_existing", "atomic_output", "write_array", "is_temporary"]

#: the name of :func:`atomic_output`'s temporaries: ``.primkit.<8 hex digits>.tmp<suffix>`` (and
#: ``.<name>.<8 hex digits>.tmp<suffix>``, which earlier versions wrote)
_TEMPORARY = re.compile(r"^\..+\.[0-9a-f]{8}\.tmp(\.[^.]*)?$")


class OutputError(ValueError):
    """An output that cannot or must not be written; ``str(err)`` is ``"<path>: <reason>"``, one line."""

    def __init__(self, path, reason: str) -> None:
        self.path = path
        self.reason = " ".join(str(reason).split())
        super().__init__(f"{path}: {self.reason}")

    def __reduce__(self):
        return (type(self), (self.path, self.reason))


def is_temporary(path) -> bool:
    """True for the name of a temporary that :func:`atomic_output` writes (and a killed write leaves)."""
    return bool(_TEMPORARY.match(Path(path).name))


def refuse_existing(paths, overwrite: bool = False) -> None:
    """Raise ``FileExistsError("<path>: exists (use --force to overwrite)")`` for the first of
    ``paths`` (one path or several; None entries skipped) that exists, unless ``overwrite``.

    :func:`check_outputs` makes this check with the others; :func:`atomic_output` makes it again
    when it writes.
    """
    if overwrite or paths is None:
        return
    for path in _as_list(paths):
        if path is not None and os.path.lexists(path):
            raise FileExistsError(f"{path}: exists (use --force to overwrite)")


def check_suffix(path, suffixes, what: str) -> Path:
    """``Path(path)``, or :class:`OutputError` when its suffix is none of ``suffixes`` (lower case,
    with the dot): ``"m.ply: a model file is written as .safetensors, not '.ply'"``."""
    path = Path(path)
    suffixes = (suffixes,) if isinstance(suffixes, str) else tuple(suffixes)
    if path.suffix.lower() not in suffixes:
        raise OutputError(path, f"{what} is written as {' or '.join(suffixes)}, not '{path.suffix or '(no suffix)'}'")
    return path


def check_outputs(outputs, *, inputs=(), overwrite: bool = False, resumed=()) -> list[Path]:
    """Check, before any work, that a run may write every path of ``outputs``.

    Parameters
    ----------
    outputs : paths (None entries skipped)
        Every file the run will write (for an output folder: the files it will write in it).
    inputs : paths
        Every file the run reads (shape files, their label files, models...). An output that is one
        of them (the same path, through symbolic links, or the same file by another hard link) is
        refused even with ``overwrite``.
    overwrite : bool
        ``--force``: outputs that exist may be replaced (inputs never).
    resumed : paths
        Outputs that may exist because the run goes on from them (a training checkpoint).

    Raises
    ------
    OutputError
        An output that is an input, a folder, written twice, or in a location that cannot be
        written (under a regular file, a read-only or full file system, no permission).
    FileExistsError
        Outputs that exist, without ``overwrite``: the first named, with how many more.

    Returns the outputs as :class:`Path` s. Missing folders are not created here (the writers create
    them); the nearest existing one is checked instead.
    """
    # plain strings inside: pathlib's parsing cost more than the system calls for large batches
    paths = [p if isinstance(p, Path) else Path(p) for p in _as_list(outputs) if p is not None]
    protected = {ident for ident in map(_identity, _as_list(inputs)) if ident is not None}
    folders: dict = {}  # each folder's real path, and the first output in it
    seen, existing = {}, []
    for path in paths:
        text = os.fspath(path)
        parent, name = os.path.split(text)
        if parent not in folders:
            folders[parent] = (os.path.realpath(parent or "."), path)
        real = os.path.join(folders[parent][0], name)
        try:
            st = os.lstat(path)
        except OSError:  # not there (or under a file: the folder check below says so)
            st = None
        if st is not None and stat.S_ISLNK(st.st_mode):
            real = os.path.realpath(path)
            try:
                st = os.stat(path)
            except OSError:  # a dangling link: it exists, and points nowhere an input is
                existing.append(path)
                st = None
        if real in seen:
            raise OutputError(path, f"written twice by this run (also as {seen[real]}); choose other output names")
        seen[real] = path
        if st is None:
            continue
        # an input by the same path, through links, or by another hard link: the same (device, inode)
        if (st.st_dev, st.st_ino) in protected:
            raise OutputError(path, "is an input of this run; choose another output (--force never replaces inputs)")
        if stat.S_ISDIR(st.st_mode):
            raise OutputError(path, "is a folder; give a file name")
        existing.append(path)
    for folder, (_, path) in folders.items():
        _check_writable(Path(folder or "."), path)
    resumed = {os.path.realpath(p) for p in _as_list(resumed) if p is not None}
    existing = [p for p in existing if os.path.realpath(p) not in resumed]
    if existing and not overwrite:
        more = f"; {len(existing) - 1} more of this run's outputs exist too" if len(existing) > 1 else ""
        raise FileExistsError(f"{existing[0]}: exists (use --force to overwrite{more})")
    return paths


@contextmanager
def atomic_output(path, *, overwrite=False):
    """Write a file so that it appears complete or not at all.

    Yields a temporary path in the same folder (created if missing), with the same suffix; when the
    block ends without an exception the temporary is moved onto ``path`` with ``os.replace``. On an
    exception the temporary is removed and ``path`` is untouched. The file gets the permissions of
    the file it replaces, or those of a new file (``0666`` less the umask) whatever the writer used.

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

    An ``OSError`` raised inside the block without a file name (``No space left on device`` from a
    write) comes out as the same error naming ``path``.
    """
    path = Path(path)
    refuse_existing(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = _create_temporary(path)
    try:
        yield temporary
        refuse_existing(path, overwrite)  # appeared while we were writing
        try:
            mode = stat.S_IMODE(os.stat(path).st_mode)
        except OSError:
            mode = _new_file_mode()
        # some writers (safetensors) make their file 0600 whatever was there
        os.chmod(temporary, mode)
        os.replace(temporary, path)
    except BaseException as exc:
        try:
            temporary.unlink()
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError) and exc.errno and exc.filename in (None, str(temporary)) \
                and str(path) not in str(exc):
            # a write's error (ENOSPC, EIO) names no file, or the hidden temporary: name the output
            raise OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(path)) from exc
        raise


def write_array(path, array, *, overwrite=False) -> Path:
    """Write one NumPy array as ``.npy`` through :func:`atomic_output`; returns the path."""
    path = Path(path)
    with atomic_output(path, overwrite=overwrite) as temporary:
        with open(temporary, "wb") as fh:
            np.save(fh, np.asarray(array))
    return path


def _as_list(paths) -> list:
    return [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)


def _identity(path):
    """(device, inode) of an existing file, else None."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_dev, st.st_ino)


def _check_writable(folder: Path, path: Path) -> None:
    """OutputError naming ``path`` unless files can be created in ``folder`` (or, when it does not
    exist yet, in its nearest existing ancestor, where the writer will create it).

    Tried by creating (and removing at once) an empty hidden file, so that the answer is the file
    system's (read-only mounts, immutable folders, root's rights), not a guess from mode bits."""
    existing = folder
    while not os.path.lexists(existing) and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(path, f"cannot be written: {existing} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".primkit-probe-", suffix=".tmp", dir=existing)
    except OSError as exc:
        reason = {errno.EROFS: "is on a read-only file system", errno.ENOSPC: "is on a full file system",
                  errno.EDQUOT: "is over its disk quota"}.get(exc.errno, f"is not writable ({exc.strerror or exc})")
        raise OutputError(path, f"cannot be written: {existing or '.'} {reason}") from None
    os.close(fd)
    os.unlink(probe)


@functools.cache
def _new_file_mode() -> int:
    """``0o666`` less the process's umask (read from /proc on Linux; elsewhere set and restored)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def _create_temporary(path: Path) -> Path:
    """Create an empty, uniquely named file beside ``path`` with the same suffix (see :func:`is_temporary`).

    The name is short and does not grow with ``path``'s (``.primkit.<8 hex digits>.tmp<suffix>``,
    the suffix left out past 16 bytes), so that an output whose own name the file system allows
    can always be written (a 234-byte name plus 25 bytes of temporary was too long)."""
    suffix = path.suffix if len(os.fsencode(path.suffix)) <= 16 else ""
    while True:
        temporary = path.with_name(f".primkit.{secrets.token_hex(4)}.tmp{suffix}")
        try:
            os.close(os.open(temporary, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            continue
        return temporary

"""Model files: one ``.safetensors`` file per model, loaded without executing any code.

A model file is a plain safetensors file: the weights (a flat ``name -> tensor`` state dict) plus,
in the safetensors header's string metadata, one entry ``"primkit"`` whose value is a JSON object.
Reading it parses a JSON header and copies raw tensor bytes; nothing is unpickled, so a model file
from a stranger cannot run code (unlike ``torch.load`` of a pickle). ``read_metadata`` reads the
header alone, without touching the weights.

Metadata keys
-------------
Written by ``save_model`` itself:

``format`` : ``"primkit-model"``, marks the file as ours.
``format_version`` : int, ``FORMAT_VERSION``; files from a newer primkit are refused on load.
``primkit_version`` : the primkit version that wrote the file (filled in if the caller did not).
``created`` : ISO 8601 UTC time of writing (filled in if the caller did not).

Required from the caller (``REQUIRED_KEYS``):

``network`` : dict, ``NetworkConfig.to_dict()``: enough to rebuild the network for the weights.

Expected from the caller (not enforced here):

``canonical_frame`` : dict, how input shapes are put into the frame the model was trained in
    (up and front axes, centring, scaling).
``grid`` : int, the occupancy grid resolution the model reads.
``training`` : dict, the data description (source, categories, number of shapes), the data terms
    and their weights, iterations per stage, seed, training time.
``metrics`` : dict, evaluation results with the protocol named (e.g. Chamfer convention).
``part_names`` : list of ``m`` strings (one per part slot, ``""`` for unnamed) or ``None``.

All values must be JSON: dicts with string keys, lists / tuples, str, int, finite float, bool, None,
nested at most ``MAX_DEPTH`` levels.

Validation before allocation
----------------------------
Nothing in a file is trusted before it is checked: :func:`read_header` reads the metadata and the
tensors' names, shapes and dtypes from the safetensors header without reading any weight, and the
network modules (:func:`primkit.model.network.read_network`, the image model's likewise) check
their architecture's fields (bounded) and the tensors the architecture implies against that header
(:func:`check_tensors`) before a network is built, so that a hostile ``fc_width`` costs nothing.
Every failure is one :class:`ModelFileError` line naming the file.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import math
import os
import re
import socket
from pathlib import Path

import torch
from torch import Tensor
from ..version import __version__
from ..io import atomic_output

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "METADATA_KEY",
    "REQUIRED_KEYS",
    "MAX_DEPTH",
    "ModelFileError",
    "ModelWriteError",
    "claim_output",
    "check_tensors",
    "load_model_file",
    "read_header",
    "read_metadata",
    "save_model",
    "update_metadata",
    "write_model",
]

#: Version of the file layout and metadata schema written by this primkit.
FORMAT_VERSION = 1
#: Value of the ``format`` metadata key.
FORMAT = "primkit-model"
#: Key of the safetensors header metadata that holds primkit's JSON.
METADATA_KEY = "primkit"
#: Metadata keys a model file must have, beyond ``format`` and ``format_version``.
REQUIRED_KEYS = ("network",)
#: Deepest nesting of dicts and lists the metadata may have (primkit's own files use 5).
MAX_DEPTH = 32


class ModelFileError(ValueError):
    """A file that is not a model file this primkit can read; ``str(err)`` is ``"{path}: {reason}"``."""

    def __init__(self, path, reason: str) -> None:
        self.path = Path(path)
        self.reason = " ".join(str(reason).split())  # one line, whatever the cause said
        super().__init__(f"{self.path}: {self.reason}")


class ModelWriteError(OSError):
    """A model file that could not be written (:func:`write_model`): one line naming the file, the
    reason, and where the model was saved instead, if anywhere (``rescue``, else None)."""

    def __init__(self, errno_: int, message: str, rescue=None) -> None:
        super().__init__(errno_, message)
        self.rescue = rescue

    def __str__(self) -> str:
        return self.strerror


def _check_json(value, where: str) -> None:
    """Raise TypeError (ValueError for non-finite floats) naming ``where`` if ``value`` is not JSON."""
    if value is None or isinstance(value, (bool, str, int)):
        return
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"metadata {where} is {value}; JSON has no NaN or infinity (use None)")
        return
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError(f"metadata {where} has a non-string key {key!r}")
            _check_json(item, f"{where}[{key!r}]")
        return
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _check_json(item, f"{where}[{i}]")
        return
    hint = " (convert with .item() or .tolist())" if hasattr(value, "tolist") else ""
    raise TypeError(
        f"metadata {where} is a {type(value).__name__}, which is not JSON-serialisable{hint}"
    )


def save_model(
    path, state_dict: dict[str, Tensor], metadata: dict, *, overwrite: bool = False
) -> Path:
    """Write ``state_dict`` and ``metadata`` to the model file ``path``; return its ``Path``.

    state_dict : ``name -> Tensor``; tensors are copied to the CPU (shared storage is fine).
    metadata : JSON-serialisable dict holding at least ``REQUIRED_KEYS`` (see the module docstring);
        ``format`` and ``format_version`` are set here, ``primkit_version`` and ``created`` filled in
        when absent. The caller's dict is not modified.
    overwrite : replace an existing file; otherwise an existing ``path`` raises FileExistsError.

    The file is written to a temporary file in the same folder and moved into place with
    ``os.replace``, so a crash never leaves a half-written model at ``path``.
    """
    path = Path(path)
    if path.suffix.lower() != ".safetensors":
        raise ValueError(f"{path}: a model file is written as .safetensors, not '{path.suffix or '(no suffix)'}'")
    if not isinstance(metadata, dict):
        raise TypeError(f"`metadata` must be a dict, got {type(metadata).__name__}")
    for key in metadata:
        if not isinstance(key, str):
            raise TypeError(f"metadata has a non-string key {key!r}")
        _check_json(metadata[key], f"[{key!r}]")
    missing = [key for key in REQUIRED_KEYS if key not in metadata]
    if missing:
        raise ValueError(f"metadata lacks the required keys {missing}")
    if not isinstance(state_dict, dict) or not all(
        isinstance(k, str) and isinstance(v, Tensor) for k, v in state_dict.items()
    ):
        raise TypeError("`state_dict` must be a dict of str -> torch.Tensor")
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"{path}: file exists; pass overwrite=True (--force on the command line) to replace it"
        )

    from safetensors.torch import save_file

    full = dict(metadata)
    full.setdefault("primkit_version", __version__)
    full.setdefault(
        "created", _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    )
    full["format"] = FORMAT
    full["format_version"] = FORMAT_VERSION
    header = {METADATA_KEY: json.dumps(full, allow_nan=False, sort_keys=True)}
    # clone: safetensors refuses tensors sharing storage and needs contiguous CPU memory.
    tensors = {k: v.detach().to("cpu").contiguous().clone() for k, v in state_dict.items()}

    with atomic_output(path, overwrite=True) as tmp:
        save_file(tensors, str(tmp), metadata=header)
    return path


def write_model(path, state_dict: dict[str, Tensor], metadata: dict, *, overwrite: bool = False) -> Path:
    """Write a model file as :func:`save_model` does, or say in one line why not and where the model
    went instead: the one way primkit writes a model (``train``, ``adapt``, ``name-parts``,
    ``train-image``).

    When the writer fails (a full disk or a file-size limit: safetensors raises ``SafetensorError``,
    not ``OSError``; a folder removed or made read-only), the model is written to a new folder of
    the system's temporary folder, and :class:`ModelWriteError` (an ``OSError``) is raised:
    ``"m.safetensors: cannot write it (No space left on device); the model was saved to
    /tmp/primkit-x/m.safetensors instead"``. Invalid arguments (a wrong suffix, metadata that is not
    JSON, an existing file without ``overwrite``) raise as in :func:`save_model`, with nothing saved.
    """
    path = Path(path)
    try:
        return save_model(path, state_dict, metadata, overwrite=overwrite)
    except (TypeError, ValueError, FileExistsError):  # the caller's mistake, not the disk's
        raise
    except Exception as exc:  # noqa: BLE001 - SafetensorError on a full disk is not an OSError
        import tempfile

        number, reason = _write_failure(exc)
        rescue = None
        try:
            rescue = Path(tempfile.mkdtemp(prefix="primkit-")) / path.name
            save_model(rescue, state_dict, metadata)
            saved = f"the model was saved to {rescue} instead"
        except Exception:  # noqa: BLE001 - the temporary folder may be full too
            rescue, saved = None, "it could not be saved elsewhere either"
        raise ModelWriteError(number, f"{path}: cannot write it ({reason}); {saved}", rescue) from None


def _write_failure(exc: BaseException) -> tuple[int, str]:
    """(errno, one-line reason) of a writer's exception; safetensors' errors carry the system's
    code in their text (``IoError(Os { code: 28, ... })``)."""
    number = getattr(exc, "errno", None)
    if not number:
        found = re.search(r"\bcode: (\d+)", str(exc))
        number = int(found.group(1)) if found else 0
    reason = getattr(exc, "strerror", None) or (os.strerror(number) if number else "")
    if not reason:
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0]}" if str(exc) else type(exc).__name__
    return number, reason


#: the locks this process holds: absolute path of ``<output>.lock`` -> its open file descriptor
_HELD: dict[str, int] = {}


@contextlib.contextmanager
def claim_output(output, overwrite: bool = False):
    """Hold an operating-system lock on ``<output>.lock`` for a block, so that a second run into the
    same model file is refused in one line before it does any work, instead of both writing it.

    The lock is ``flock`` on the lock file: the kernel (or the file server of a shared folder)
    releases it when its holder ends however it ends, and it holds across processes, PID
    namespaces (containers) and hosts, which a process id written in a file does not. The file
    names its holder (process id and host) for the message, nothing else reads it. A claim this
    process already holds is kept as it is (:func:`primkit.model.training.train` claims again what
    the ``train`` command claimed). ``overwrite`` (``--force``) does not take a lock held by a
    live run. A folder that does not exist yet or cannot be written claims nothing (the output
    checks say which), nor does a system without ``fcntl``. Yields the lock's path.
    """
    output = Path(output)
    lock = output.with_name(output.name + ".lock")
    key = os.path.abspath(lock)
    if key in _HELD:
        yield lock
        return
    try:
        fd = _lock(lock, output)
    except FileExistsError:
        raise
    except OSError:  # a folder not made yet, or not writable: check_outputs says which
        fd = None
    if fd is None:
        yield lock
        return
    _HELD[key] = fd
    try:
        yield lock
    finally:
        del _HELD[key]
        with contextlib.suppress(OSError):
            os.unlink(lock)  # removed while held: a run waiting on this file checks it is still there
        os.close(fd)


def _lock(lock: Path, output: Path):
    """Open ``lock`` and take its flock without waiting; returns the descriptor (None where the
    system has no ``fcntl``), raises FileExistsError naming the holder."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return None
    for _ in range(20):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "a process"
            except OSError:
                holder = "a process"
            os.close(fd)
            raise FileExistsError(f"{output}: another primkit run ({holder}) is writing it; wait for it to end "
                                  "or choose another -o") from None
        except OSError as exc:  # a file system without locks
            os.close(fd)
            raise OSError(exc.errno, f"{lock}: cannot lock it ({exc.strerror})") from None
        try:  # the previous holder may have removed the file between our open and our lock
            here, now = os.fstat(fd), os.stat(lock)
            current = (here.st_dev, here.st_ino) == (now.st_dev, now.st_ino)
        except FileNotFoundError:
            current = False
        if current:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"process {os.getpid()} on host {socket.gethostname()}\n".encode(), 0)
            return fd
        os.close(fd)
    raise FileExistsError(f"{output}: could not claim {lock} (other runs keep taking it)")


def _open(path, device: str = "cpu"):
    """Open ``path`` with safetensors' ``safe_open``, turning every failure into ModelFileError."""
    from safetensors import safe_open

    path = Path(path)
    if not path.exists():
        raise ModelFileError(path, "no such file")
    if path.is_dir():
        raise ModelFileError(path, "is a directory, not a model file")
    try:
        return safe_open(str(path), framework="pt", device=device)
    except Exception as err:  # safetensors raises its own error types and OSError
        raise ModelFileError(
            path, f"not a readable safetensors model file (corrupt, truncated or another format: {err})"
        ) from None


def _parse_metadata(path, header: dict | None) -> dict:
    """Check the header metadata of ``path`` and return primkit's JSON as a dict."""
    if not header or METADATA_KEY not in header:
        raise ModelFileError(path, "not a primkit model file (no primkit metadata in the header)")
    try:
        metadata = json.loads(header[METADATA_KEY])
    except json.JSONDecodeError as err:
        raise ModelFileError(path, f"primkit metadata is not valid JSON ({err})") from None
    except RecursionError:
        raise ModelFileError(path, f"primkit metadata is nested deeper than {MAX_DEPTH} levels") from None
    if _depth(metadata) > MAX_DEPTH:
        raise ModelFileError(path, f"primkit metadata is nested deeper than {MAX_DEPTH} levels")
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
        raise ModelFileError(path, f"not a primkit model file (format is not {FORMAT!r})")
    version = metadata.get("format_version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise ModelFileError(path, f"invalid format_version {version!r}")
    if version > FORMAT_VERSION:
        raise ModelFileError(
            path,
            f"format version {version} is newer than this primkit supports ({FORMAT_VERSION}); "
            "upgrade primkit",
        )
    missing = [key for key in REQUIRED_KEYS if key not in metadata]
    if missing:
        raise ModelFileError(path, f"metadata lacks the required keys {missing}")
    if "fit_reference" in metadata and not _is_fit_reference(metadata["fit_reference"]):
        raise ModelFileError(path, "fit_reference must be an object with a positive median, a non-negative "
                                   "log_spread, shapes (an integer of at least 2) and data (a string)")
    return metadata


def _is_fit_reference(value) -> bool:
    """Whether ``value`` is a ``fit_reference`` (:func:`primkit.model.abstraction.fit_reference`)."""
    def number(x):
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)

    return (isinstance(value, dict) and set(value) == {"median", "log_spread", "shapes", "data"}
            and number(value["median"]) and value["median"] > 0 and number(value["log_spread"])
            and value["log_spread"] >= 0 and isinstance(value["shapes"], int) and not isinstance(value["shapes"], bool)
            and value["shapes"] >= 2 and isinstance(value["data"], str))


def _depth(value) -> int:
    """Nesting depth of dicts and lists in a JSON value (iterative: a hostile depth cannot overflow the stack)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, depth)
            if deepest > MAX_DEPTH:
                return deepest
            stack.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict) else item))
    return deepest


def read_header(path) -> tuple[dict, dict]:
    """The metadata and the tensors of the model file ``path``, from its header alone (no weight is read).

    Returns ``(metadata, tensors)``: ``tensors`` maps each name to ``(shape, dtype)``, ``shape`` a
    tuple of ints and ``dtype`` safetensors' name (``"F32"``, ``"F64"``, ``"I64"``, ...).
    """
    handle = _open(path)
    with handle as f:
        metadata = _parse_metadata(path, f.metadata())
        try:
            tensors = {}
            for name in f.keys():
                view = f.get_slice(name)
                tensors[name] = (tuple(int(n) for n in view.get_shape()), str(view.get_dtype()))
        except Exception as err:  # safetensors' own error types
            raise ModelFileError(path, f"cannot read the tensor header ({err})") from None
    return metadata, tensors


#: safetensors' dtype names of the floating dtypes (a network's float tensors may be stored in any)
_FLOAT_DTYPES = {"F16", "BF16", "F32", "F64"}
_DTYPE_NAMES = {torch.float16: "F16", torch.bfloat16: "BF16", torch.float32: "F32", torch.float64: "F64",
                torch.int64: "I64", torch.int32: "I32", torch.uint8: "U8", torch.bool: "BOOL"}


def check_tensors(path, expected: dict, found: dict, what: str = "network") -> None:
    """Raise ModelFileError naming ``path`` unless the tensors ``found`` in its header
    (:func:`read_header`) are those ``expected``: the same names, the same shapes, and dtypes
    that load into them (any floating dtype for a floating tensor).

    expected : ``name -> (shape, torch.dtype)`` (a state dict's, e.g. of a network built on the
        ``meta`` device, which allocates nothing).
    what : how the message calls the architecture (``"network"``, ``"image network"``).
    """
    missing = sorted(set(expected) - set(found))
    extra = sorted(set(found) - set(expected))

    def listed(names):
        return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")

    if missing:
        raise ModelFileError(path, f"lacks the tensors {listed(missing)} of its {what}")
    if extra:
        raise ModelFileError(path, f"has tensors its {what} does not have: {listed(extra)}")
    for name, (shape, dtype) in expected.items():
        got_shape, got_dtype = found[name]
        if tuple(got_shape) != tuple(shape):
            raise ModelFileError(path, f"tensor {name} is {list(got_shape)}, but the {what} the metadata describes "
                                       f"needs {list(shape)}")
        want = _DTYPE_NAMES.get(dtype, str(dtype))
        if got_dtype != want and not (want in _FLOAT_DTYPES and got_dtype in _FLOAT_DTYPES):
            raise ModelFileError(path, f"tensor {name} is {got_dtype}, expected {want}")


def read_metadata(path) -> dict:
    """The metadata of the model file ``path``, read from the header without loading the weights."""
    handle = _open(path)
    with handle as f:
        return _parse_metadata(path, f.metadata())


def load_model_file(path, map_location="cpu") -> tuple[dict[str, Tensor], dict]:
    """Read the model file ``path``: ``(state_dict, metadata)``.

    map_location : device for the tensors (``"cpu"``, ``"cuda:0"``, a ``torch.device``).
    Raises ModelFileError (one line, starting with the path) for a missing file, a file that is not
    safetensors (a pickle, random bytes) or is corrupt or truncated, a safetensors file without
    primkit metadata, a newer format version, or missing required keys.
    """
    device = str(torch.device(map_location))
    handle = _open(path, device)
    with handle as f:
        metadata = _parse_metadata(path, f.metadata())
        try:
            weights = {name: f.get_tensor(name) for name in f.keys()}
        except Exception as err:
            raise ModelFileError(path, f"cannot read the weights ({err})") from None
    return weights, metadata


def update_metadata(path, output, changes: dict, *, overwrite: bool = False) -> Path:
    """Copy the model file ``path`` to ``output`` with ``changes`` merged into its metadata
    (the weights are copied unchanged; ``path`` itself is never modified: an ``output`` that is
    ``path`` is refused, ``overwrite`` or not). Returns ``output``."""
    from ..io import check_outputs

    check_outputs([output], inputs=[path], overwrite=overwrite)
    weights, metadata = load_model_file(path)
    metadata = {**metadata, **changes}
    metadata.pop("created", None)
    return write_model(output, weights, metadata, overwrite=overwrite)

"""``<name>.cuboids.json``: one shape's cuboids with what they mean, one schema for every command.

``primkit abstract``, ``primkit segment``, ``primkit image abstract``, the GLB export and the
Open3D viewer's export all write this file through :func:`write_cuboids_file`;
:func:`read_cuboids_file` reads it back, and also reads the files primkit wrote before the schema
had a version of its own.

Schema version 2 (keys in this order)::

    {
      "schema_version": 2,
      "type": "cuboids",
      "name": "chair_0001",                 # the shape's output name
      "source": "chairs/chair_0001.off",     # the input it came from ("" when given in memory)
      "frame": "input",                     # the frame of "parts": "input" (the shape's own) or
                                            #   "canonical" (the network's: +Y up, front +X, longest side 1)
      "canonical_frame": {"rotation", "centre", "scale"} or null,
                                            # input -> canonical (primkit.geometry.CanonicalFrame);
                                            #   null when the writer does not know it
      "model": "chair",                     # the model: a bundled name or the model file's path as given
      "part_names": ["back", "seat", ...],  # one per part slot (part<k> for unnamed slots)
      "present": [0, 3, 7],                 # the slots of the present parts
      "parts": [{"index", "present", "half_extents", "quaternion_wxyz", "translation", "probability"}, ...],
      ...                                   # then what the writer adds: "alignment", "refinement"
                                            #   (primkit abstract), "viewpoint" (image abstract)
    }

``parts`` is :meth:`primkit.primitives.Cuboids.to_dict`'s list (half extents, quaternions real part
first, acting on column vectors). Before version 2 there were two layouts, both with
``"schema_version": 1``: ``primkit abstract`` wrote ``name``, ``source``, ``frame``,
``canonical_frame`` and ``alignment`` beside ``parts``; ``primkit segment`` and the Open3D viewer
wrote ``parts`` alone. The reader takes both: the missing ``part_names`` become ``part<k>``, a
missing ``frame`` is ``"input"`` (both wrote the cuboids in the input's frame), a missing model is
None.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from ..geometry import CanonicalFrame
from ..io import atomic_output, refuse_existing
from ..primitives import Cuboids
from .parts import default_part_names

__all__ = ["CUBOIDS_FILE_VERSION", "FRAMES", "CuboidsFile", "cuboids_document", "write_cuboids_file",
           "read_cuboids_file"]

#: the schema version :func:`write_cuboids_file` writes (see the module notes)
CUBOIDS_FILE_VERSION = 2

#: what ``"frame"`` may say: the frame the cuboids are given in
FRAMES = ("input", "canonical")

_KNOWN = ("schema_version", "type", "name", "source", "frame", "canonical_frame", "model", "part_names", "present",
          "parts")


@dataclass(frozen=True, eq=False)
class CuboidsFile:
    """A ``<name>.cuboids.json`` file read back (:func:`read_cuboids_file`).

    Attributes
    ----------
    cuboids : primitives.Cuboids
        In ``frame``.
    name, source : str
    frame : str
        ``"input"`` or ``"canonical"`` (:data:`FRAMES`).
    canonical_frame : geometry.CanonicalFrame or None
        Input -> canonical, when the writer knew it.
    model : str or None
        The model as given to the writer (a bundled name or a path); None in files before version 2.
    part_names : list of str
        One per part slot.
    schema_version : int
        As written (1 or 2).
    extra : dict
        The writer's other entries as stored (``alignment``, ``refinement``, ``viewpoint``), JSON values.
    """

    cuboids: Cuboids
    name: str
    source: str
    frame: str
    canonical_frame: CanonicalFrame | None
    model: str | None
    part_names: list
    schema_version: int
    extra: dict

    @property
    def present(self):
        """``(k,) int``: the slots of the present parts."""
        return self.cuboids.present


def cuboids_document(cuboids: Cuboids, *, name: str, source: str = "", frame: str = "input",
                     canonical_frame: CanonicalFrame | None = None, model: str | None = None, part_names=None,
                     **extra) -> dict:
    """The JSON document of :func:`write_cuboids_file` (the module notes list its keys).

    ``part_names``: one per slot (default ``part<k>``); ``extra``: JSON-ready entries written after
    the schema's own keys (``alignment``, ``refinement``, ``viewpoint``).
    """
    if frame not in FRAMES:
        raise ValueError(f"`frame` must be one of {', '.join(FRAMES)}, got {frame!r}")
    names = [str(n) for n in part_names] if part_names is not None else default_part_names(cuboids.count)
    if len(names) != cuboids.count:
        raise ValueError(f"`part_names` must have one name per part slot ({cuboids.count}), got {len(names)}")
    clash = sorted(set(extra) & set(_KNOWN))
    if clash:
        raise ValueError(f"extra entries may not replace the schema's own: {', '.join(clash)}")
    layout = cuboids.to_dict()
    return {
        "schema_version": CUBOIDS_FILE_VERSION,
        "type": "cuboids",
        "name": str(name),
        "source": str(source),
        "frame": frame,
        "canonical_frame": None if canonical_frame is None else canonical_frame.to_dict(),
        "model": None if model is None else str(model),
        "part_names": names,
        "present": [int(k) for k in cuboids.present],
        "parts": layout["parts"],
        **extra,
    }


def write_cuboids_file(path, cuboids: Cuboids, *, overwrite: bool = False, **fields) -> Path:
    """Write ``path`` (a ``<name>.cuboids.json``) atomically; ``fields`` as :func:`cuboids_document`.

    Raises FileExistsError when ``path`` exists and ``overwrite`` is False.
    """
    path = Path(path)
    refuse_existing((path,), overwrite)
    text = json.dumps(cuboids_document(cuboids, **fields), indent=1)
    with atomic_output(path, overwrite=overwrite) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path


def read_cuboids_file(path: str | os.PathLike) -> CuboidsFile:
    """Read a ``<name>.cuboids.json`` of any schema primkit wrote (see the module notes).

    Raises ValueError naming the file for anything else (a newer schema included).
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read a cuboids file ({str(exc).splitlines()[0]})") from exc
    if not isinstance(d, dict):
        raise ValueError(f"{path}: a cuboids file holds a JSON object")
    version = d.get("schema_version")
    if isinstance(version, int) and not isinstance(version, bool) and version > CUBOIDS_FILE_VERSION:
        raise ValueError(f"{path}: cuboids schema_version {version} is newer than this primkit reads "
                         f"({CUBOIDS_FILE_VERSION}); upgrade primkit")
    try:
        cuboids = Cuboids.from_dict(d)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    frame = d.get("frame") or "input"
    if frame not in FRAMES:
        raise ValueError(f"{path}: `frame` must be one of {', '.join(FRAMES)}, got {frame!r}")
    names = d.get("part_names")
    if names is None:
        names = default_part_names(cuboids.count)
    elif not isinstance(names, list) or len(names) != cuboids.count:
        raise ValueError(f"{path}: `part_names` must list one name per part slot ({cuboids.count})")
    present = d.get("present")
    if present is not None and sorted(int(k) for k in present) != cuboids.present.tolist():
        raise ValueError(f"{path}: `present` disagrees with the parts' `present` flags")
    try:
        frame_of = None if d.get("canonical_frame") is None else CanonicalFrame.from_dict(d["canonical_frame"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: malformed `canonical_frame` ({exc!r})") from exc
    model = d.get("model")
    return CuboidsFile(cuboids=cuboids, name=str(d.get("name") or path.name.removesuffix(".cuboids.json")),
                       source=str(d.get("source") or ""), frame=frame, canonical_frame=frame_of,
                       model=None if model is None else str(model), part_names=[str(n) for n in names],
                       schema_version=int(version), extra={k: v for k, v in d.items() if k not in _KNOWN})

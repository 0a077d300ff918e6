"""How many faces a mesh file declares, to tell when reading it triangulated polygons.

:func:`primkit.io.read_mesh` returns triangles; a file whose faces are quads or other polygons
comes back with more faces than it holds, and per-face outputs (a ``.seg``) then have one line per
triangle. :func:`declared_face_count` reads the count the file itself gives (the header of an OFF
or PLY file, the ``f`` lines of an OBJ) so that callers can say so.
"""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["declared_face_count"]

_OBJ_FACE = re.compile(rb"^[ \t]*f[ \t]", re.M)
_PLY_FACE = re.compile(rb"^element[ \t]+face[ \t]+(\d+)", re.M)


def declared_face_count(path) -> int | None:
    """The number of faces a ``.off``, ``.ply`` or ``.obj`` file declares, or None for other
    formats (STL and glTF hold triangles) and for files whose count cannot be read.

    Compare it with the faces :func:`~primkit.io.read_mesh` gives: more triangles than declared
    faces means polygons were triangulated (OFF and PLY headers are read; an OBJ's ``f`` lines are
    counted)."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            return len(_OBJ_FACE.findall(path.read_bytes()))
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError:
        return None
    if suffix == ".ply":
        end = head.find(b"end_header")
        found = _PLY_FACE.search(head[: end if end >= 0 else len(head)])
        return int(found.group(1)) if found else None
    if suffix == ".off":
        words = []  # the keyword (OFF, COFF, ...; optional) and the counts: vertices, faces, edges
        for line in head.splitlines():
            words += line.split(b"#")[0].split()
            if len(words) >= (4 if words and words[0].upper().endswith(b"OFF") else 3):
                break
        counts = words[1:] if words and words[0].upper().endswith(b"OFF") else words
        try:
            return int(counts[1])
        except (IndexError, ValueError):
            return None
    return None

"""The :class:`Cuboids` value type: ``m`` cuboids with stable part slots, validated on
construction, with its mesh and its JSON form (conventions in :mod:`primkit.primitives`)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic_output
from .rotations import matrix_to_quaternion, quaternion_to_matrix

__all__ = ["SCHEMA_VERSION", "CORNER_SIGNS", "Cuboids", "as_points", "check_cuboids"]


#: Version of the JSON layout written by :meth:`Cuboids.to_dict`.
SCHEMA_VERSION = 1

#: The newest schema :meth:`Cuboids.from_dict` reads: version 2 is a ``<name>.cuboids.json`` file
#: (:mod:`primkit.model.cuboids_file`), whose ``parts`` are version 1's.
_NEWEST_READ = 2


# Corner c of the unit cube, as signs: bit 0 -> x, bit 1 -> y, bit 2 -> z.
CORNER_SIGNS = np.array(
    [[1.0 if c & (1 << a) else -1.0 for a in range(3)] for c in range(8)]
)


# Two triangles per face, in face order +x, -x, +y, -y, +z, -z, counter-clockwise seen from outside.
_FACE_TRIANGLES = np.array(
    [
        [1, 3, 7], [1, 7, 5],  # +x
        [0, 4, 6], [0, 6, 2],  # -x
        [2, 6, 7], [2, 7, 3],  # +y
        [0, 1, 5], [0, 5, 4],  # -y
        [4, 5, 7], [4, 7, 6],  # +z
        [0, 2, 3], [0, 3, 1],  # -z
    ],
    dtype=np.int64,
)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Cuboids:
    """A set of ``m`` cuboids with stable part indices.

    Attributes
    ----------
    half_extents : (m, 3) float
        Half sizes along the local axes, all > 0.
    quaternions : (m, 4) float
        Unit rotations ``(w, x, y, z)``, local to world; normalised on construction.
    translations : (m, 3) float
        Centres in world coordinates.
    existence : (m,) bool
        Whether part ``k`` is present. Absent parts keep their slot.
    probabilities : (m,) float or None
        Existence probabilities in [0, 1], when known.

    The arrays are copied and made read-only on construction.
    """

    half_extents: np.ndarray
    quaternions: np.ndarray
    translations: np.ndarray
    existence: np.ndarray
    probabilities: np.ndarray | None = None

    def __post_init__(self) -> None:
        z = _float_array(self.half_extents, "half_extents", (None, 3), "(m, 3) float")
        m = z.shape[0]
        if np.any(z <= 0):
            raise ValueError("`half_extents` must be > 0")
        q = _float_array(self.quaternions, "quaternions", (m, 4), "(m, 4) float")
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
        if np.any(norm < 1e-12):
            raise ValueError("`quaternions` must be nonzero")
        # already-unit rows are kept bit for bit, so a JSON round trip is exact
        q = np.where(np.abs(norm - 1.0) > 1e-12, q / norm, q)
        t = _float_array(self.translations, "translations", (m, 3), "(m, 3) float")
        e = np.asarray(self.existence)
        if e.shape != (m,):
            raise ValueError(f"`existence` must be (m,) bool with m = {m}, got shape {e.shape}")
        if e.dtype != bool:
            if e.dtype.kind not in "iuf" or not np.all((e == 0) | (e == 1)):
                raise ValueError("`existence` must be (m,) bool")
            e = e != 0
        p = self.probabilities
        if p is not None:
            p = _float_array(p, "probabilities", (m,), "(m,) float")
            if np.any((p < 0) | (p > 1)):
                raise ValueError("`probabilities` must lie in [0, 1]")
            p = _readonly(p.copy())
        object.__setattr__(self, "half_extents", _readonly(z.copy()))
        object.__setattr__(self, "quaternions", _readonly(q))
        object.__setattr__(self, "translations", _readonly(t.copy()))
        object.__setattr__(self, "existence", _readonly(e.astype(bool, copy=True)))
        object.__setattr__(self, "probabilities", p)

    # ---- properties ---------------------------------------------------------------------------

    @property
    def count(self) -> int:
        """Number of part slots ``m`` (present or not)."""
        return int(self.half_extents.shape[0])

    @property
    def rotations(self) -> np.ndarray:
        """(m, 3, 3) float: local-to-world rotation matrices."""
        return quaternion_to_matrix(self.quaternions)

    @property
    def volumes(self) -> np.ndarray:
        """(m,) float: ``8 z0 z1 z2`` for every slot (absent ones included)."""
        return 8.0 * np.prod(self.half_extents, axis=-1)

    @property
    def present(self) -> np.ndarray:
        """(p,) int: indices of the present parts, ascending."""
        return np.flatnonzero(self.existence)

    def __len__(self) -> int:
        return self.count

    def __repr__(self) -> str:
        return f"Cuboids(count={self.count}, present={self.present.tolist()})"

    # ---- derived sets -------------------------------------------------------------------------

    def with_existence(self, mask: Any) -> Cuboids:
        """The same slots with ``existence`` replaced by ``mask`` ((m,) bool); indices kept."""
        return Cuboids(self.half_extents, self.quaternions, self.translations, mask, self.probabilities)

    def subset(self, index: Any) -> Cuboids:
        """A new set holding only the slots ``index`` ((m,) bool mask or (p,) int), in that order.

        The result is renumbered ``0 .. p-1``; use :meth:`with_existence` to keep indices.
        """
        index = np.asarray(index)
        if index.dtype == bool and index.shape != (self.count,):
            raise ValueError(f"a boolean `index` must be (m,) bool with m = {self.count}")
        p = None if self.probabilities is None else self.probabilities[index]
        return Cuboids(
            self.half_extents[index],
            self.quaternions[index],
            self.translations[index],
            self.existence[index],
            p,
        )

    def transformed(self, matrix: Any) -> Cuboids:
        """Apply a similarity transform ``x -> s A x + b`` to every cuboid.

        Parameters
        ----------
        matrix : (4, 4) float or (3, 3) float
            A homogeneous matrix (bottom row ``0 0 0 1``) or a linear part alone. Its linear part
            must be a positive multiple ``s`` of an orthogonal matrix ``A``; a reflection
            (``det A = -1``) is fine because a cuboid is mirror symmetric.

        Returns
        -------
        Cuboids
            Half extents scaled by ``s``, rotations ``A R`` (with a local axis flipped for a
            reflection) and translations ``s A t + b``; existence and probabilities unchanged.
        """
        mat = np.asarray(matrix, dtype=float)
        if mat.shape == (4, 4):
            if not np.allclose(mat[3], [0.0, 0.0, 0.0, 1.0]):
                raise ValueError("`matrix` (4, 4) must have bottom row (0, 0, 0, 1)")
            lin, offset = mat[:3, :3], mat[:3, 3]
        elif mat.shape == (3, 3):
            lin, offset = mat, np.zeros(3)
        else:
            raise ValueError("`matrix` must be (4, 4) or (3, 3) float")
        if not np.all(np.isfinite(mat)):
            raise ValueError("`matrix` must be finite")
        det = np.linalg.det(lin)
        if abs(det) < 1e-300:
            raise ValueError("`matrix` must be a similarity transform (it is singular)")
        scale = abs(det) ** (1.0 / 3.0)
        ortho = lin / scale
        if not np.allclose(ortho.T @ ortho, np.eye(3), atol=1e-6):
            raise ValueError(
                "`matrix` must be a similarity transform (rotation, uniform scale, translation)"
            )
        rot = ortho @ self.rotations
        if det < 0:
            rot = rot * np.array([-1.0, 1.0, 1.0])  # flip local x: same solid, proper rotation
        return Cuboids(
            self.half_extents * scale,
            matrix_to_quaternion(rot),
            self.translations @ lin.T + offset,
            self.existence,
            self.probabilities,
        )

    # ---- mesh ---------------------------------------------------------------------------------

    def to_mesh(self, include_absent: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Triangle mesh of the cuboids: 8 vertices and 12 outward-facing triangles per cuboid.

        Returns
        -------
        vertices : (v, 3) float
        faces : (f, 3) int
            Counter-clockwise seen from outside; each cuboid is closed and separate.
        part : (f,) int
            The part index (slot) of each triangle.
        """
        idx = np.arange(self.count) if include_absent else self.present
        local = CORNER_SIGNS[None] * self.half_extents[idx, None, :]  # (p, 8, 3)
        rot = self.rotations[idx]
        verts = np.einsum("pij,pcj->pci", rot, local) + self.translations[idx, None, :]
        faces = _FACE_TRIANGLES[None] + 8 * np.arange(len(idx))[:, None, None]
        part = np.repeat(idx, len(_FACE_TRIANGLES))
        return verts.reshape(-1, 3), faces.reshape(-1, 3), part.astype(np.int64)

    # ---- serialisation ------------------------------------------------------------------------

    def to_dict(self) -> dict:
        """A JSON-ready dict: ``schema_version`` and one entry per part slot."""
        parts = []
        for k in range(self.count):
            parts.append(
                {
                    "index": k,
                    "present": bool(self.existence[k]),
                    "half_extents": [float(v) for v in self.half_extents[k]],
                    "quaternion_wxyz": [float(v) for v in self.quaternions[k]],
                    "translation": [float(v) for v in self.translations[k]],
                    "probability": None if self.probabilities is None else float(self.probabilities[k]),
                }
            )
        return {"schema_version": SCHEMA_VERSION, "type": "cuboids", "parts": parts}

    @classmethod
    def from_dict(cls, d: dict) -> Cuboids:
        """Inverse of :meth:`to_dict`. Raises ValueError for an unknown or newer schema."""
        if not isinstance(d, dict):
            raise ValueError("cuboids data must be a dict")
        version = d.get("schema_version")
        if not isinstance(version, int) or isinstance(version, bool):
            raise ValueError("cuboids data has no integer `schema_version`")
        if version > _NEWEST_READ:
            raise ValueError(
                f"cuboids schema_version {version} is newer than this primkit reads ({_NEWEST_READ}); "
                "upgrade primkit"
            )
        if version < 1:
            raise ValueError(f"unknown cuboids schema_version {version}")
        if d.get("type", "cuboids") != "cuboids":
            raise ValueError(f"expected type 'cuboids', got {d.get('type')!r}")
        parts = d.get("parts")
        if not isinstance(parts, list):
            raise ValueError("cuboids data must have a `parts` list")
        try:
            order = sorted(range(len(parts)), key=lambda i: int(parts[i]["index"]))
            indices = [int(parts[i]["index"]) for i in order]
            if indices != list(range(len(parts))):
                raise ValueError(f"part indices must be 0 .. {len(parts) - 1}, each once")
            parts = [parts[i] for i in order]
            probs = [p.get("probability") for p in parts]
            if all(p is None for p in probs):
                probabilities = None
            elif any(p is None for p in probs):
                raise ValueError("either every part has a `probability` or none has")
            else:
                probabilities = np.array(probs, dtype=float)
            return cls(
                half_extents=np.array([p["half_extents"] for p in parts], dtype=float).reshape(-1, 3),
                quaternions=np.array([p["quaternion_wxyz"] for p in parts], dtype=float).reshape(-1, 4),
                translations=np.array([p["translation"] for p in parts], dtype=float).reshape(-1, 3),
                existence=np.array([bool(p["present"]) for p in parts], dtype=bool),
                probabilities=probabilities,
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"malformed cuboids data: {exc!r}") from exc

    def save_json(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write :meth:`to_dict` as JSON, atomically (temporary file then ``os.replace``).

        Raises FileExistsError if ``path`` exists and ``overwrite`` is False. Returns the path.
        """
        path = Path(path)
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
        text = json.dumps(self.to_dict(), indent=2)

        with atomic_output(path, overwrite=True) as tmp:
            Path(tmp).write_text(text + "\n", encoding="utf-8")
        return path

    @classmethod
    def load_json(cls, path: str | os.PathLike) -> Cuboids:
        """Read a file written by :meth:`save_json`."""
        with open(path, encoding="utf-8") as fh:
            return cls.from_dict(json.load(fh))


def _float_array(value: Any, name: str, shape: tuple, text: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"`{name}` must be {text}") from exc
    ok = a.ndim == len(shape) and all(s is None or s == d for s, d in zip(shape, a.shape))
    if not ok:
        raise ValueError(f"`{name}` must be {text}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"`{name}` must be finite")
    return a


def as_points(points: Any) -> np.ndarray:
    return _float_array(points, "points", (None, 3), "(n, 3) float")


def check_cuboids(cuboids: Any) -> Cuboids:
    if not isinstance(cuboids, Cuboids):
        raise TypeError(f"`cuboids` must be a Cuboids, got {type(cuboids).__name__}")
    return cuboids

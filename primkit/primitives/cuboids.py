"""Cuboid primitives: the value type, their geometry, and differentiable versions for training.

A set of ``m`` cuboids is one :class:`Cuboids` value. Part ``k`` is slot ``k`` of the arrays, for
good: parts that do not exist keep their slot (``existence[k]`` is False) and are never renumbered,
so an index names the same part across shapes predicted by one model.

Conventions (the ones that bite)
--------------------------------
* **Half extents.** ``half_extents[k] = (z0, z1, z2)``: the cuboid spans ``[-z_i, z_i]`` along its
  local axis ``i``, so its full size is ``2 z`` and its volume ``8 z0 z1 z2``.
* **Quaternions** are unit and real part first: ``q = (w, x, y, z)``. ``q`` and ``-q`` are the same
  rotation; :func:`matrix_to_quaternion` returns the one with ``w >= 0``.
* **Rotation matrices** ``R = quaternion_to_matrix(q)`` act on column vectors and map local to
  world coordinates::

      x_world = R @ x_local + t          x_local = R.T @ (x_world - t)

* **Distance** from a point to a cuboid is to the *solid*: ``|| max(|x_local| - z, 0) ||``, zero
  inside. The distance to a set of parts is the minimum over the *present* parts.

Corners and faces in local coordinates (used by :meth:`Cuboids.to_mesh` and the surface sampling)::

                 y
                 |
                 2 ---------------- 3          corner c = (±z0, ±z1, ±z2) with
                /|                 /|          bit 0 of c -> +x, bit 1 -> +y, bit 2 -> +z:
               / |                / |            0 (-,-,-)   1 (+,-,-)
              6 ---------------- 7  |            2 (-,+,-)   3 (+,+,-)
              |  |               |  |            4 (-,-,+)   5 (+,-,+)
              |  0 --------------|- 1 --- x      6 (-,+,+)   7 (+,+,+)
              | /                | /
              |/                 |/            face f: axis f // 2, side + if f is even
              4 ---------------- 5               0 +x   1 -x   2 +y   3 -y   4 +z   5 -z
             /
            z                                  mesh triangles 2f and 2f+1 lie on face f

Surface samples are split equally over the six faces (``k`` samples per cuboid, ``k`` a multiple
of 6, face ``f`` owning samples ``f*k/6 .. (f+1)*k/6 - 1``); each carries the importance weight
``area(face) / (k/6)``, so the weights of one cuboid sum to its surface area (the paper's appendix
A1). A sample is reparametrised: the face's fixed coordinate is ``±z_axis`` and the two others are
``u * z_i`` with ``u ~ U[-1, 1]``, then it is rotated and translated, so gradients reach ``z``,
``q`` and ``t``.

NumPy functions take and return arrays (``n`` points, ``m`` parts). The ``*_torch`` functions are
for training: batch first (``B``), differentiable, and follow the device and dtype of their inputs;
torch is imported only when one of them is called.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import torch

__all__ = [
    "SCHEMA_VERSION",
    "Cuboids",
    "SurfaceSamples",
    "quaternion_to_matrix",
    "matrix_to_quaternion",
    "world_to_local",
    "local_to_world",
    "point_cuboid_distance",
    "union_distance",
    "contains",
    "sample_surface",
    "sample_volume",
    "fraction_inside_others",
    "prune_covered",
    "assign_points",
    "quaternion_to_matrix_torch",
    "world_to_local_torch",
    "cuboid_distance_sq_torch",
    "sample_surface_torch",
]

#: Version of the JSON layout written by :meth:`Cuboids.to_dict`.
SCHEMA_VERSION = 1

# Corner c of the unit cube, as signs: bit 0 -> x, bit 1 -> y, bit 2 -> z.
_CORNER_SIGNS = np.array(
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


# --------------------------------------------------------------------------------------------
# The value type
# --------------------------------------------------------------------------------------------


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
        local = _CORNER_SIGNS[None] * self.half_extents[idx, None, :]  # (p, 8, 3)
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
        if version > SCHEMA_VERSION:
            raise ValueError(
                f"cuboids schema_version {version} is newer than this primkit reads ({SCHEMA_VERSION}); "
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
        from ..io import atomic_output  # temporary beside the target, created with the user's umask

        with atomic_output(path, overwrite=True) as tmp:
            Path(tmp).write_text(text + "\n", encoding="utf-8")
        return path

    @classmethod
    def load_json(cls, path: str | os.PathLike) -> Cuboids:
        """Read a file written by :meth:`save_json`."""
        with open(path, encoding="utf-8") as fh:
            return cls.from_dict(json.load(fh))


@dataclass(frozen=True, eq=False)
class SurfaceSamples:
    """Points on the surfaces of cuboids, with importance weights (see the module notes).

    Attributes
    ----------
    points : (m, k, 3) float
        World coordinates.
    weights : (m, k) float
        ``area(face) / (k / 6)``; they sum to each cuboid's surface area.
    face : (m, k) int
        Face of each sample, 0..5 (+x, -x, +y, -y, +z, -z).
    """

    points: np.ndarray
    weights: np.ndarray
    face: np.ndarray


# --------------------------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------------------------


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


def _as_points(points: Any) -> np.ndarray:
    return _float_array(points, "points", (None, 3), "(n, 3) float")


def _check_cuboids(cuboids: Any) -> Cuboids:
    if not isinstance(cuboids, Cuboids):
        raise TypeError(f"`cuboids` must be a Cuboids, got {type(cuboids).__name__}")
    return cuboids


# --------------------------------------------------------------------------------------------
# Rotations
# --------------------------------------------------------------------------------------------


def quaternion_to_matrix(q: Any) -> np.ndarray:
    """Rotation matrices from quaternions.

    Parameters
    ----------
    q : (..., 4) float
        ``(w, x, y, z)``, real part first; normalised here.

    Returns
    -------
    (..., 3, 3) float
        Acting on column vectors.
    """
    q = np.asarray(q, dtype=float)
    if q.ndim < 1 or q.shape[-1] != 4:
        raise ValueError("`q` must be (..., 4) float")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("`q` must be nonzero")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quaternion(R: Any) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` with ``w >= 0`` from rotation matrices.

    Parameters
    ----------
    R : (..., 3, 3) float
        Proper rotations acting on column vectors.

    Returns
    -------
    (..., 4) float
    """
    R = np.asarray(R, dtype=float)
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ValueError("`R` must be (..., 3, 3) float")
    r = {(i, j): R[..., i, j] for i in range(3) for j in range(3)}
    # 2|w|, 2|x|, 2|y|, 2|z| from the diagonal; build from the largest for stability.
    big = np.sqrt(
        np.maximum(
            np.stack(
                [
                    1 + r[0, 0] + r[1, 1] + r[2, 2],
                    1 + r[0, 0] - r[1, 1] - r[2, 2],
                    1 - r[0, 0] + r[1, 1] - r[2, 2],
                    1 - r[0, 0] - r[1, 1] + r[2, 2],
                ],
                axis=-1,
            ),
            0.0,
        )
    )
    wx, wy, wz = r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]
    xy, xz, yz = r[1, 0] + r[0, 1], r[0, 2] + r[2, 0], r[2, 1] + r[1, 2]
    b0, b1, b2, b3 = np.moveaxis(big, -1, 0)
    candidates = np.stack(
        [
            np.stack([b0 * b0, wx, wy, wz], axis=-1),
            np.stack([wx, b1 * b1, xy, xz], axis=-1),
            np.stack([wy, xy, b2 * b2, yz], axis=-1),
            np.stack([wz, xz, yz, b3 * b3], axis=-1),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4)
    best = np.argmax(big, axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


# --------------------------------------------------------------------------------------------
# Frames, distances, containment
# --------------------------------------------------------------------------------------------


def world_to_local(points: Any, cuboids: Cuboids) -> np.ndarray:
    """Points in every cuboid's local frame: ``R.T @ (x - t)``.

    points : (n, 3) float  ->  (m, n, 3) float
    """
    points = _as_points(points)
    c = _check_cuboids(cuboids)
    d = points[None, :, :] - c.translations[:, None, :]
    return np.einsum("mji,mnj->mni", c.rotations, d)


def local_to_world(points_local: Any, cuboids: Cuboids) -> np.ndarray:
    """Inverse of :func:`world_to_local`: ``R @ x + t``.

    points_local : (m, n, 3) float  ->  (m, n, 3) float
    """
    c = _check_cuboids(cuboids)
    pl = np.asarray(points_local, dtype=float)
    if pl.ndim != 3 or pl.shape[0] != c.count or pl.shape[2] != 3:
        raise ValueError(f"`points_local` must be (m, n, 3) float with m = {c.count}, got {pl.shape}")
    return np.einsum("mij,mnj->mni", c.rotations, pl) + c.translations[:, None, :]


def point_cuboid_distance(points: Any, cuboids: Cuboids, squared: bool = False) -> np.ndarray:
    """Distance from each point to each solid cuboid, absent parts included (the caller masks).

    points : (n, 3) float  ->  (n, m) float, zero inside.
    """
    local = world_to_local(points, cuboids)
    excess = np.maximum(np.abs(local) - cuboids.half_extents[:, None, :], 0.0)
    d2 = np.einsum("mni,mni->nm", excess, excess)
    return d2 if squared else np.sqrt(d2)


def union_distance(points: Any, cuboids: Cuboids, squared: bool = False) -> np.ndarray:
    """Distance from each point to the union of the present cuboids.

    points : (n, 3) float  ->  (n,) float; ``inf`` when no part is present.
    """
    points = _as_points(points)
    c = _check_cuboids(cuboids)
    if not c.existence.any():
        return np.full(len(points), np.inf)
    return point_cuboid_distance(points, c.subset(c.present), squared=squared).min(axis=1)


def contains(points: Any, cuboids: Cuboids) -> np.ndarray:
    """Whether each point lies in each solid cuboid (boundary included), absent parts included.

    points : (n, 3) float  ->  (n, m) bool; equal to ``point_cuboid_distance(...) == 0``.
    """
    local = world_to_local(points, cuboids)
    return np.all(np.abs(local) <= cuboids.half_extents[:, None, :], axis=-1).T


def assign_points(points: Any, cuboids: Cuboids, *, return_distance: bool = False, chunk: int = 8192):
    """Index (slot) of the nearest present cuboid for each point: the co-segmentation rule.

    Ties (several cuboids at the same distance, e.g. 0 for a point inside several) go to the
    larger volume, then to the lower index.

    points : (n, 3) float  ->  (n,) int, and with ``return_distance`` also (n,) float, the
    distance to that cuboid. Raises ValueError when no part is present.

    Speed: the points are taken in chunks of ``chunk``; for each chunk the local coordinates in
    all present cuboids come from one ``(c, 3) @ (3, 3k)`` product, and the excess over the
    half-extents, its squared norm and the arg-min are whole-array operations, so memory stays
    ``O(chunk * k)`` and a million points against 20 cuboids take a fraction of a second
    (``benchmarks/bench_segment.py``). Neither Open3D nor libigl offers point-to-oriented-box
    distances for many boxes at once; this is the closed form of the paper's distance.
    """
    points = _as_points(points)
    c = _check_cuboids(cuboids)
    if not c.existence.any():
        raise ValueError("no present cuboid to assign points to")
    present = c.present
    order = present[np.argsort(-c.volumes[present], kind="stable")]
    k = len(order)
    rot = c.rotations[order]  # (k, 3, 3) local -> world; local = R.T (x - t)
    # column j * k + i holds local axis j of cuboid i, so the three axes are contiguous blocks
    stacked = rot.transpose(1, 2, 0).reshape(3, 3 * k)
    offset = np.einsum("kij,ki->jk", rot, c.translations[order]).reshape(3 * k)
    extents = c.half_extents[order].T.reshape(3 * k)
    labels = np.empty(len(points), dtype=np.int64)
    dist = np.empty(len(points)) if return_distance else None
    for start in range(0, len(points), chunk):
        block = points[start : start + chunk]
        excess = block @ stacked
        excess -= offset
        np.abs(excess, out=excess)
        excess -= extents
        np.maximum(excess, 0.0, out=excess)
        excess *= excess
        d2 = excess[:, :k] + excess[:, k : 2 * k]
        d2 += excess[:, 2 * k :]
        best = np.argmin(d2, axis=1)
        labels[start : start + len(block)] = order[best]
        if dist is not None:
            dist[start : start + len(block)] = np.sqrt(np.take_along_axis(d2, best[:, None], 1)[:, 0])
    return (labels, dist) if return_distance else labels


# --------------------------------------------------------------------------------------------
# Sampling
# --------------------------------------------------------------------------------------------


def _surface_layout(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed per-sample layout for ``k`` surface samples per cuboid.

    Returns face (k,) int, fixed (k, 3) float (the face's ±1 at its axis, 0 elsewhere) and
    spread (k, 2, 3) float (one-hot rows placing the two free coordinates ``u`` on the face).
    """
    if k <= 0 or k % 6:
        raise ValueError(f"`samples_per_cuboid` must be a positive multiple of 6, got {k}")
    face = np.repeat(np.arange(6), k // 6)
    axis = face // 2
    sign = np.where(face % 2 == 0, 1.0, -1.0)
    fixed = np.zeros((k, 3))
    fixed[np.arange(k), axis] = sign
    free = np.stack([(axis + 1) % 3, (axis + 2) % 3], axis=-1)  # (k, 2)
    spread = np.zeros((k, 2, 3))
    spread[np.arange(k)[:, None], np.arange(2)[None, :], free] = 1.0
    return face, fixed, spread


def _face_area_pairs() -> np.ndarray:
    """(3,) int pairs: face on axis a has area 4 z_b z_c with (b, c) = the other axes."""
    return np.array([[1, 2], [2, 0], [0, 1]])


def _surface_from_uv(cuboids: Cuboids, uv: np.ndarray) -> SurfaceSamples:
    """Surface samples from given coefficients ``uv`` (m, k, 2) in [-1, 1]."""
    m, k = uv.shape[:2]
    face, fixed, spread = _surface_layout(k)
    z = cuboids.half_extents
    unit = fixed[None] + np.einsum("mkc,kcd->mkd", uv, spread)  # (m, k, 3)
    local = unit * z[:, None, :]
    points = local_to_world(local, cuboids) if m else np.zeros((0, k, 3))
    pairs = _face_area_pairs()
    areas = 4.0 * z[:, pairs[:, 0]] * z[:, pairs[:, 1]]  # (m, 3)
    weights = areas[:, face // 2] / (k // 6)
    return SurfaceSamples(points, weights, np.broadcast_to(face, (m, k)).copy())


def sample_surface(cuboids: Cuboids, samples_per_cuboid: int = 150, seed: Any = None) -> SurfaceSamples:
    """Reparametrised surface samples of every cuboid (absent ones included; the caller masks).

    Parameters
    ----------
    cuboids : Cuboids
    samples_per_cuboid : int
        ``k``, a positive multiple of 6: ``k / 6`` samples on each face.
    seed : None, int or numpy Generator

    Returns
    -------
    SurfaceSamples
        ``points`` (m, k, 3), ``weights`` (m, k) summing to each surface area, ``face`` (m, k).
    """
    c = _check_cuboids(cuboids)
    k = int(samples_per_cuboid)
    _surface_layout(k)  # validates k
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-1.0, 1.0, size=(c.count, k, 2))
    return _surface_from_uv(c, uv)


def sample_volume(cuboids: Cuboids, samples_per_cuboid: int = 1000, seed: Any = None) -> np.ndarray:
    """Uniform samples inside every solid cuboid (absent ones included).

    Returns (m, k, 3) float world coordinates.
    """
    c = _check_cuboids(cuboids)
    k = int(samples_per_cuboid)
    if k <= 0:
        raise ValueError(f"`samples_per_cuboid` must be positive, got {k}")
    rng = np.random.default_rng(seed)
    local = rng.uniform(-1.0, 1.0, size=(c.count, k, 3)) * c.half_extents[:, None, :]
    return local_to_world(local, c)


def _containment(cuboids: Cuboids, k: int, seed: Any) -> np.ndarray:
    """(m, k, m) bool: volume sample s of part i lies inside part j (computed among present parts
    only; entries involving an absent part are False)."""
    pts = sample_volume(cuboids, k, seed)
    m = cuboids.count
    out = np.zeros((m, k, m), dtype=bool)
    idx = cuboids.present
    if len(idx):
        sub = cuboids.subset(idx)
        out[np.ix_(idx, np.arange(k), idx)] = contains(pts[idx].reshape(-1, 3), sub).reshape(len(idx), k, len(idx))
    return out


def _fractions(inside: np.ndarray, existence: np.ndarray) -> np.ndarray:
    m = len(existence)
    others = existence[None, :] & ~np.eye(m, dtype=bool)  # (m, m): the present parts other than i
    frac = np.any(inside & others[:, None, :], axis=-1).mean(axis=-1) if inside.shape[1] else np.zeros(m)
    return np.where(existence, frac, np.nan)


def fraction_inside_others(cuboids: Cuboids, samples_per_cuboid: int = 1000, seed: Any = None) -> np.ndarray:
    """Monte Carlo fraction of each present part's volume inside the union of the other present parts.

    Returns (m,) float in [0, 1]; ``nan`` for absent parts.
    """
    c = _check_cuboids(cuboids)
    return _fractions(_containment(c, int(samples_per_cuboid), seed), c.existence)


def prune_covered(
    cuboids: Cuboids, threshold: float = 0.6, samples_per_cuboid: int = 1000, seed: Any = 0
) -> Cuboids:
    """Remove redundant parts: while the largest :func:`fraction_inside_others` exceeds
    ``threshold``, mark that part absent and recompute (the published test-time pruning).

    The volume samples are drawn once and reused at each step. Indices are kept (removed parts
    become absent slots).
    """
    c = _check_cuboids(cuboids)
    inside = _containment(c, int(samples_per_cuboid), seed)
    existence = c.existence.copy()
    while existence.sum() > 1:
        frac = _fractions(inside, existence)
        worst = int(np.nanargmax(frac))
        if not frac[worst] > threshold:
            break
        existence[worst] = False
    return c.with_existence(existence)


# --------------------------------------------------------------------------------------------
# torch versions (training)
# --------------------------------------------------------------------------------------------


def quaternion_to_matrix_torch(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices from quaternions ``(w, x, y, z)``; ``q`` is normalised here.

    q : (..., 4)  ->  (..., 3, 3), acting on column vectors; differentiable.
    """
    import torch

    if q.shape[-1:] != (4,):
        raise ValueError("`q` must be (..., 4)")
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def _check_points_and_poses(points, quaternions, translations) -> None:
    """Shapes of the torch functions' batched inputs: (B, n, 3), (B, m, 4), (B, m, 3)."""
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError("`points` must be (B, n, 3)")
    if quaternions.ndim != 3 or quaternions.shape[-1] != 4:
        raise ValueError("`quaternions` must be (B, m, 4)")
    if translations.shape != quaternions.shape[:2] + (3,):
        raise ValueError("`translations` must be (B, m, 3), matching `quaternions`")


def world_to_local_torch(
    points: torch.Tensor, quaternions: torch.Tensor, translations: torch.Tensor
) -> torch.Tensor:
    """Points in every cuboid's local frame, ``R.T @ (x - t)``.

    points (B, n, 3), quaternions (B, m, 4), translations (B, m, 3)  ->  (B, m, n, 3)
    """
    import torch

    _check_points_and_poses(points, quaternions, translations)
    rot = quaternion_to_matrix_torch(quaternions)  # (B, m, 3, 3)
    d = points[:, None, :, :] - translations[:, :, None, :]
    return torch.einsum("bmji,bmnj->bmni", rot, d)


def cuboid_distance_sq_torch(
    points: torch.Tensor,
    half_extents: torch.Tensor,
    quaternions: torch.Tensor,
    translations: torch.Tensor,
    *,
    parts_first: bool = False,
) -> torch.Tensor:
    """Squared distance from each point to each solid cuboid (0 inside).

    points (B, n, 3), half_extents (B, m, 3), quaternions (B, m, 4), translations (B, m, 3)
    ->  (B, n, m), or (B, m, n) with ``parts_first``. No square root, so the gradient is finite
    everywhere (and continuous: the kink of ``max(., 0)`` is squared away and ``|x|`` only kinks
    at 0, inside the cuboid).

    Computed coordinate-planar, as ``(B, m, 3, n)`` local coordinates ``R^T x - R^T t`` from one
    batched matrix product: the per-point sums then run over a middle axis with ``n`` contiguous
    values, which vectorises (a trailing axis of length 3, as in :func:`world_to_local_torch`'s
    layout, made this 4x slower on CPU).
    """
    if half_extents.shape != translations.shape:
        raise ValueError("`half_extents` must be (B, m, 3), matching `translations`")
    _check_points_and_poses(points, quaternions, translations)
    rot_t = quaternion_to_matrix_torch(quaternions).transpose(-1, -2)  # (B, m, 3, 3), R^T
    local = rot_t @ points.transpose(1, 2)[:, None] - rot_t @ translations[..., None]  # (B, m, 3, n)
    excess = (local.abs() - half_extents[..., None]).clamp_min(0.0)
    d2 = excess.square().sum(dim=2)  # (B, m, n)
    return d2 if parts_first else d2.transpose(1, 2)


def _sample_surface_from_uv_torch(
    half_extents: torch.Tensor, quaternions: torch.Tensor, translations: torch.Tensor, uv: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Surface points and weights from coefficients ``uv`` (B, m, k, 2) in [-1, 1]."""
    import torch

    k = uv.shape[2]
    face, fixed, spread = _surface_layout(k)
    opts = {"dtype": half_extents.dtype, "device": half_extents.device}
    fixed_t = torch.as_tensor(fixed, **opts)
    spread_t = torch.as_tensor(spread, **opts)
    unit = fixed_t + torch.einsum("bmkc,kcd->bmkd", uv.to(**opts), spread_t)  # (B, m, k, 3)
    local = unit * half_extents[:, :, None, :]
    rot = quaternion_to_matrix_torch(quaternions)
    points = torch.einsum("bmij,bmkj->bmki", rot, local) + translations[:, :, None, :]
    pairs = _face_area_pairs()
    areas = 4.0 * half_extents[..., pairs[:, 0]] * half_extents[..., pairs[:, 1]]  # (B, m, 3)
    axis = torch.as_tensor(face // 2, device=half_extents.device)
    weights = areas[..., axis] / (k // 6)
    return points, weights


def sample_surface_torch(
    half_extents: torch.Tensor,
    quaternions: torch.Tensor,
    translations: torch.Tensor,
    samples_per_cuboid: int = 150,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparametrised surface samples, differentiable in ``z``, ``q`` and ``t``.

    Parameters
    ----------
    half_extents : (B, m, 3)
    quaternions : (B, m, 4)
    translations : (B, m, 3)
    samples_per_cuboid : int
        ``k``, a positive multiple of 6; ``k / 6`` samples per face, in the face order of the
        module notes (as :func:`sample_surface`).
    generator : torch.Generator, optional
        Source of the coefficients ``u``; they are drawn on the generator's device and moved.

    Returns
    -------
    points : (B, m, k, 3)
        World coordinates.
    weights : (B, m, k)
        ``area(face) / (k / 6)``, differentiable in ``z``; they sum to each surface area.
    """
    import torch

    k = int(samples_per_cuboid)
    _surface_layout(k)  # validates k
    if half_extents.ndim != 3 or half_extents.shape[-1] != 3:
        raise ValueError("`half_extents` must be (B, m, 3)")
    if quaternions.shape != half_extents.shape[:2] + (4,):
        raise ValueError("`quaternions` must be (B, m, 4), matching `half_extents`")
    if translations.shape != half_extents.shape:
        raise ValueError("`translations` must be (B, m, 3), matching `half_extents`")
    B, m = half_extents.shape[:2]
    device = half_extents.device if generator is None else generator.device
    uv = torch.rand((B, m, k, 2), generator=generator, device=device, dtype=half_extents.dtype)
    uv = (2.0 * uv - 1.0).to(half_extents.device)
    return _sample_surface_from_uv_torch(half_extents, quaternions, translations, uv)

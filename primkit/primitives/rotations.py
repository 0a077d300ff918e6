"""Rotations of cuboids: unit quaternions ``(w, x, y, z)``, real part first, and the matrices
that act on column vectors (local to world)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["quaternion_to_matrix", "matrix_to_quaternion"]


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

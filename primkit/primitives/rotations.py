"""Rotations of cuboids: unit quaternions ``(w, x, y, z)``, real part first, and the matrices
that act on column vectors (local to world)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["quaternion_to_matrix", "matrix_to_quaternion"]


def _quaternions(q: Any) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.ndim < 1 or q.shape[-1] != 4:
        raise ValueError("`q` must be (..., 4) float")
    if np.any(np.linalg.norm(q, axis=-1) < 1e-12):
        raise ValueError("`q` must be nonzero")
    return q


def quaternion_to_matrix(q: Any) -> np.ndarray:
    """Rotation matrices from quaternions.

    scipy's ``Rotation.from_quat(q, scalar_first=True)``: real part first, normalised, matrices
    acting on column vectors, as everywhere in primkit (``tests/primitives`` checks both against the
    formula primkit used before; scipy is 2-3x faster).

    Parameters
    ----------
    q : (..., 4) float
        ``(w, x, y, z)``, real part first; normalised here.

    Returns
    -------
    (..., 3, 3) float
        Acting on column vectors.
    """
    from scipy.spatial.transform import Rotation  # scipy: imported on first use

    q = _quaternions(q)
    flat = q.reshape(-1, 4)
    if len(flat) == 0:
        return np.zeros(q.shape[:-1] + (3, 3))
    return Rotation.from_quat(flat, scalar_first=True).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_to_quaternion(R: Any) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` with ``w >= 0`` from rotation matrices.

    scipy's ``Rotation.from_matrix(R).as_quat(scalar_first=True, canonical=True)``: ``w >= 0``,
    and where ``w = 0`` the first non-zero of ``x, y, z`` positive (q and -q are one rotation).

    Parameters
    ----------
    R : (..., 3, 3) float
        Proper rotations acting on column vectors.

    Returns
    -------
    (..., 4) float
    """
    from scipy.spatial.transform import Rotation  # scipy: imported on first use

    R = np.asarray(R, dtype=float)
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ValueError("`R` must be (..., 3, 3) float")
    flat = R.reshape(-1, 3, 3)
    if len(flat) == 0:
        return np.zeros(R.shape[:-2] + (4,))
    q = Rotation.from_matrix(flat).as_quat(scalar_first=True, canonical=True)
    return q.reshape(R.shape[:-2] + (4,))

"""Compiled kernels of the distance-field lookup and the consistency loss (Numba; imported on
first use, CPU tensors only).

``nearest_cells``: the winner search of :func:`primkit.model.distance_field.lookup_distance_sq_torch`.
For each query point, the cell of the 8 around it whose stored closest point is nearest: the
part of the lookup that needs no gradient. The torch version forms it from 8 gathers of
``(B, 3, n)`` rows and a dozen element-wise passes over them; here each point is one pass over
its 8 cells. The arithmetic is the torch version's, step for step in the tensors' own precision
(the cell from ``floor((p + 0.5) R - 0.5)``, NaN read as cell 0 and infinities clamped;
``d^2 = dx^2 + dy^2 + dz^2``; corners in (x, y, z) order with z fastest, a tie keeps the first, a
NaN distance poisons the running minimum as ``torch.minimum`` does), so the same cells are chosen
(``tests/model/test_field_kernels.py``).

``consistency_forward`` / ``consistency_backward``: the consistency loss of every part in one
pass per part, for :func:`primkit.model.losses.surface_consistency` (the torch form draws the
part's surface samples as ``(B, m, k, 3)`` tensors, looks each up, and differentiates a few
dozen element-wise steps). Forward: each sample ``s = R (unit * z) + t`` (the torch form's
products and sums in its order, so the same points and the same winning cells), its winner's
squared distance, and the area-weighted mean per part. Backward, in closed form with the
winners held: with ``g = 2 (s - c)`` and ``w`` the sample's weight, ``d/dt = sum w g / S``,
``d/dR = sum w g (unit * z)^T / S``, ``d/dz`` through ``unit * z`` and through the face areas
``4 z_b z_c`` that make the weights (``S`` their sum); the rotation's gradient goes on to the
quaternion through torch. Checked against torch's autograd of the torch form in float64 (to
1e-14, ``tests/model/test_field_kernels.py``).
"""

import numba
import numpy as np

from ._compiled import over_batch

__all__ = ["nearest_cells", "consistency_forward", "consistency_backward"]


@numba.njit(cache=True, nogil=True, inline="always")
def _cells(p, zero, one, half, res, top):
    """The lower and upper cell along one axis, as the torch lookup clamps them."""
    base = np.floor((p + half) * res - half)
    if base != base:  # NaN: torch's nan_to_num reads it as 0
        base = zero
    return int(min(max(base, zero), top)), int(min(max(base + one, zero), top))


@numba.njit(cache=True, nogil=True, inline="always")
def _winner(gx, gy, gz, px, py, pz, resolution, zero, one, half, res, top):
    """(squared distance, flat cell) of the point's winning cell among the 8 around it: corners in
    (x, y, z) order with z fastest, a tie keeps the first, a NaN distance poisons the minimum."""
    x0, x1 = _cells(px, zero, one, half, res, top)
    y0, y1 = _cells(py, zero, one, half, res, top)
    z0, z1 = _cells(pz, zero, one, half, res, top)
    plane = resolution * resolution
    best = zero
    best_cell = 0
    for corner in range(8):
        cell = (x1 if corner & 4 else x0) * plane + (y1 if corner & 2 else y0) * resolution + (z1 if corner & 1 else z0)
        dx = gx[cell] - px
        dy = gy[cell] - py
        dz = gz[cell] - pz
        d2 = dx * dx + dy * dy + dz * dz
        if corner == 0 or d2 < best:
            best, best_cell = d2, cell
        elif d2 != d2:
            best = d2
    return best, best_cell


@numba.njit(cache=True, nogil=True)
def _nearest_cells(planar, points, resolution, zero, one, half, res, top, out_cell, out_point):
    """``planar`` (B, 3, R^3) closest points, ``points`` (B, 3, n) -> ``out_cell`` (B, n): the flat
    index of each point's winning cell, ``out_point`` (B, 3, n): its closest point. The scalars
    0, 1, 0.5, R and R - 1 come in the arrays' precision, so that the arithmetic stays in it."""
    for b in range(points.shape[0]):
        gx, gy, gz = planar[b, 0], planar[b, 1], planar[b, 2]
        for i in range(points.shape[2]):
            _, best_cell = _winner(gx, gy, gz, points[b, 0, i], points[b, 1, i], points[b, 2, i], resolution, zero, one,
                                   half, res, top)
            out_cell[b, i] = best_cell
            out_point[b, 0, i] = gx[best_cell]
            out_point[b, 1, i] = gy[best_cell]
            out_point[b, 2, i] = gz[best_cell]


def nearest_cells(planar: np.ndarray, points: np.ndarray, resolution: int):
    """(cells (B, n) int64, their closest points (B, 3, n)) for ``planar`` (B, 3, R^3) and
    ``points`` (B, 3, n), both C-contiguous of one float dtype."""
    out_cell = np.empty((points.shape[0], points.shape[2]), np.int64)
    out_point = np.empty(points.shape, planar.dtype)
    t = planar.dtype.type
    _nearest_cells(planar, points, resolution, t(0.0), t(1.0), t(0.5), t(resolution), t(resolution - 1), out_cell,
                   out_point)
    return out_cell, out_point


@numba.njit(cache=True, nogil=True, inline="always")
def _surface_point(R, z0, z1, z2, t0, t1, t2, axis, sign, u, v):
    """The face point of coefficients (u, v) on the face of ``axis`` and ``sign``: its unit-cube
    coordinates, then ``R (unit * z) + t`` in the order of
    :func:`primkit.primitives.differentiable.surface_samples_from_coefficients_torch`."""
    if axis == 0:
        u0, u1, u2 = sign, u, v
    elif axis == 1:
        u0, u1, u2 = v, sign, u
    else:
        u0, u1, u2 = u, v, sign
    lx = u0 * z0
    ly = u1 * z1
    lz = u2 * z2
    sx = R[0, 0] * lx + R[0, 1] * ly + R[0, 2] * lz + t0
    sy = R[1, 0] * lx + R[1, 1] * ly + R[1, 2] * lz + t1
    sz = R[2, 0] * lx + R[2, 1] * ly + R[2, 2] * lz + t2
    return u0, u1, u2, sx, sy, sz


@numba.njit(cache=True, nogil=True, inline="always")
def _face_area(axis, four, z0, z1, z2):
    """Area of a face on ``axis``, ``(4 z_b) z_c`` with (b, c) as ``face_area_pairs`` gives them."""
    if axis == 0:
        return four * z1 * z2
    if axis == 1:
        return four * z2 * z0
    return four * z0 * z1


@numba.njit(cache=True, nogil=True)
def _consistency_forward(rot, z, t, uv, planar, resolution, zero, one, half, res, top, four, per_face, tiny,
                         out, winners):
    """rot (B, m, 3, 3), z and t (B, m, 3), uv (B, m, k, 2) in [-1, 1], planar (B, 3, R^3) ->
    out (B, m): each part's area-weighted mean squared distance; winners (B, m, k, 3): the closest
    point each sample's distance was measured to."""
    share = uv.shape[2] // 6
    for b in range(uv.shape[0]):
        gx, gy, gz = planar[b, 0], planar[b, 1], planar[b, 2]
        for j in range(uv.shape[1]):
            R = rot[b, j]
            z0, z1, z2 = z[b, j, 0], z[b, j, 1], z[b, j, 2]
            t0, t1, t2 = t[b, j, 0], t[b, j, 1], t[b, j, 2]
            total = zero
            weight = zero
            for face in range(6):
                axis = face // 2
                sign = one if face % 2 == 0 else -one
                w = _face_area(axis, four, z0, z1, z2) / per_face
                for i in range(face * share, (face + 1) * share):
                    _, _, _, sx, sy, sz = _surface_point(R, z0, z1, z2, t0, t1, t2, axis, sign, uv[b, j, i, 0],
                                                         uv[b, j, i, 1])
                    best, best_cell = _winner(gx, gy, gz, sx, sy, sz, resolution, zero, one, half, res, top)
                    winners[b, j, i, 0] = gx[best_cell]
                    winners[b, j, i, 1] = gy[best_cell]
                    winners[b, j, i, 2] = gz[best_cell]
                    total += w * best
                    weight += w
            out[b, j] = total / max(weight, tiny)


@numba.njit(cache=True, nogil=True)
def _consistency_backward(rot, z, t, uv, winners, grad_out, zero, one, four, per_face, tiny, grad_rot, grad_z,
                          grad_t):
    """The gradients of :func:`_consistency_forward`'s ``out`` (winners held) with respect to rot,
    z and t, given ``grad_out`` (B, m). Per part, one pass over its samples accumulates
    ``sum g``, ``sum g unit^T`` and ``sum |s - c|^2`` per face (all weights of a face are equal),
    and the gradients follow from those sums."""
    share = uv.shape[2] // 6
    outer = np.empty((3, 3), z.dtype)  # sum over the part of w g unit^T (g without its factor 2)
    face_outer = np.empty((3, 3), z.dtype)
    per_axis = np.empty(3, z.dtype)  # sum of |s - c|^2 over each axis's two faces
    for b in range(uv.shape[0]):
        for j in range(uv.shape[1]):
            R = rot[b, j]
            z0, z1, z2 = z[b, j, 0], z[b, j, 1], z[b, j, 2]
            t0, t1, t2 = t[b, j, 0], t[b, j, 1], t[b, j, 2]
            total = zero
            weight = zero
            outer[:, :] = zero
            per_axis[:] = zero
            g0 = zero
            g1 = zero
            g2 = zero
            for face in range(6):
                axis = face // 2
                sign = one if face % 2 == 0 else -one
                w = _face_area(axis, four, z0, z1, z2) / per_face
                face_outer[:, :] = zero
                f0 = zero
                f1 = zero
                f2 = zero
                squares = zero
                for i in range(face * share, (face + 1) * share):
                    u0, u1, u2, sx, sy, sz = _surface_point(R, z0, z1, z2, t0, t1, t2, axis, sign, uv[b, j, i, 0],
                                                            uv[b, j, i, 1])
                    dx = sx - winners[b, j, i, 0]
                    dy = sy - winners[b, j, i, 1]
                    dz = sz - winners[b, j, i, 2]
                    squares += dx * dx + dy * dy + dz * dz
                    f0 += dx
                    f1 += dy
                    f2 += dz
                    face_outer[0, 0] += dx * u0
                    face_outer[0, 1] += dx * u1
                    face_outer[0, 2] += dx * u2
                    face_outer[1, 0] += dy * u0
                    face_outer[1, 1] += dy * u1
                    face_outer[1, 2] += dy * u2
                    face_outer[2, 0] += dz * u0
                    face_outer[2, 1] += dz * u1
                    face_outer[2, 2] += dz * u2
                total += w * squares
                weight += w * share
                per_axis[axis] += squares
                g0 += w * f0
                g1 += w * f1
                g2 += w * f2
                for r in range(3):
                    for c in range(3):
                        outer[r, c] += w * face_outer[r, c]
            clamped = max(weight, tiny)
            d_total = grad_out[b, j] / clamped  # d out / d total
            d_weight = -grad_out[b, j] * total / (clamped * clamped) if weight > tiny else zero
            twice = (one + one) * d_total
            grad_t[b, j, 0] = twice * g0
            grad_t[b, j, 1] = twice * g1
            grad_t[b, j, 2] = twice * g2
            extents = (z0, z1, z2)
            for c in range(3):
                for r in range(3):
                    grad_rot[b, j, r, c] = twice * outer[r, c] * extents[c]
                grad_z[b, j, c] = twice * (R[0, c] * outer[0, c] + R[1, c] * outer[1, c] + R[2, c] * outer[2, c])
            # the weights: area / per_face on each of an axis's two faces, area = 4 z_b z_c
            for axis in range(3):
                d_area = (d_total * per_axis[axis] + d_weight * (2 * share)) / per_face
                p, q = (1, 2) if axis == 0 else ((2, 0) if axis == 1 else (0, 1))
                grad_z[b, j, p] += d_area * four * extents[q]
                grad_z[b, j, q] += d_area * four * extents[p]


def _scalars(dtype, *values):
    t = np.dtype(dtype).type
    return tuple(t(v) for v in values)


def consistency_forward(rot, z, t, uv, planar, resolution: int):
    """(out (B, m), winners (B, m, k, 3)) for NumPy arrays of one float dtype, C-contiguous:
    ``rot`` (B, m, 3, 3), ``z`` and ``t`` (B, m, 3), ``uv`` (B, m, k, 2), ``planar`` (B, 3, R^3)."""
    out = np.empty(z.shape[:2], z.dtype)
    winners = np.empty(uv.shape[:3] + (3,), z.dtype)
    k = uv.shape[2]
    zero, one, half, res, top, four, per_face, tiny = _scalars(z.dtype, 0.0, 1.0, 0.5, resolution, resolution - 1,
                                                               4.0, k // 6, 1e-12)
    over_batch(_consistency_forward, (rot, z, t, uv, planar), (resolution, zero, one, half, res, top, four, per_face, tiny),
               (out, winners))
    return out, winners


def consistency_backward(rot, z, t, uv, winners, grad_out):
    """(grad_rot, grad_z, grad_t) of :func:`consistency_forward`'s ``out`` given ``grad_out`` (B, m)."""
    grad_rot = np.empty(rot.shape, z.dtype)
    grad_z = np.empty(z.shape, z.dtype)
    grad_t = np.empty(t.shape, z.dtype)
    zero, one, four, per_face, tiny = _scalars(z.dtype, 0.0, 1.0, 4.0, uv.shape[2] // 6, 1e-12)
    over_batch(_consistency_backward, (rot, z, t, uv, winners, grad_out), (zero, one, four, per_face, tiny),
               (grad_rot, grad_z, grad_t))
    return grad_rot, grad_z, grad_t

"""Compiled kernels of the coverage loss: squared distances of points to the union of present
cuboids (Numba; imported on first use, CPU tensors only; :func:`primkit.model.losses._union_distance_sq`).

Forward, for each point: its squared distance to every cuboid, ``|max(|R^T x - R^T t| - z, 0)|^2``
(the local coordinates in the order of ``losses._nearest_distance_sq``, from the ``R^T t`` that
torch computes), the nearest present cuboid (absent ones pushed away by their absence term, as
the torch form masks them; a tie goes to the lower index) and, when asked, each part's presence
effect: removing a present part moves its points to their second nearest part, adding an absent
one pulls in the points nearer to it. The torch form finds the ``(B, m, n)`` distances with one
batched matrix product (MKL), whose rounding differs from these sums, so the two agree to float
rounding (and the nearest part can differ where two are equally near to that rounding); the
winner's distance is summed as the torch form sums it. Backward, that distance in closed form,
the winner held: with ``l = R^T x - R^T t`` and ``e = max(|l| - z, 0)``, ``d/dl = 2 e sign(l)``,
``d/dz = -2 e``, ``d/dR[r, c] = x_r d/dl_c`` and ``d/d(R^T t) = -d/dl``; torch takes ``R`` and
``R^T t`` on to the quaternion and the translation.
"""

import numba
import numpy as np

from ._compiled import over_batch

__all__ = ["union_forward", "union_backward"]


@numba.njit(cache=True, nogil=True, inline="always")
def _local(R, offset, j, c, x, y, w):
    """Local coordinate c of the point (x, y, w) in cuboid j: ``sum_r R[r, c] x_r - (R^T t)_c``."""
    return R[j, 0, c] * x + R[j, 1, c] * y + R[j, 2, c] * w - offset[j, c]


@numba.njit(cache=True, nogil=True)
def _union_forward(rot, offset, z, absent, present, points, toggles, zero, far, out, nearest, effect):
    """out (B, n): each point's squared distance to its nearest present cuboid (plus that cuboid's
    absence term); nearest (B, n); effect (B, m), with ``toggles``: the mean over the points of the
    change in distance when part j is removed (present) or added (absent), others as they are."""
    m = rot.shape[1]
    n = points.shape[1]
    d2 = np.empty(m, rot.dtype)
    removal = np.empty(m, rot.dtype)
    addition = np.empty(m, rot.dtype)
    # the cuboids' numbers as rows over the parts, so that the distances to all parts vectorise
    cols = np.empty((15, m), rot.dtype)
    for b in range(points.shape[0]):
        R, off, zz, ab = rot[b], offset[b], z[b], absent[b]
        for j in range(m):
            for c in range(3):
                cols[c, j] = R[j, 0, c]
                cols[3 + c, j] = R[j, 1, c]
                cols[6 + c, j] = R[j, 2, c]
                cols[9 + c, j] = off[j, c]
                cols[12 + c, j] = zz[j, c]
        removal[:] = zero
        addition[:] = zero
        for i in range(n):
            x, y, w = points[b, i, 0], points[b, i, 1], points[b, i, 2]
            for j in range(m):
                e0 = max(abs(cols[0, j] * x + cols[3, j] * y + cols[6, j] * w - cols[9, j]) - cols[12, j], zero)
                e1 = max(abs(cols[1, j] * x + cols[4, j] * y + cols[7, j] * w - cols[10, j]) - cols[13, j], zero)
                e2 = max(abs(cols[2, j] * x + cols[5, j] * y + cols[8, j] * w - cols[11, j]) - cols[14, j], zero)
                d2[j] = e0 * e0 + e1 * e1 + e2 * e2
            first = d2[0] + ab[0]
            best = 0
            for j in range(1, m):
                masked = d2[j] + ab[j]
                if masked < first:
                    first, best = masked, j
            nearest[b, i] = best
            # as losses._nearest_distance_sq sums it: the absence term first
            total = ab[best]
            for c in range(3):
                e = max(abs(_local(R, off, best, c, x, y, w)) - zz[best, c], zero)
                total = total + e * e
            out[b, i] = total
            if toggles:
                second = far  # the torch form's stand-in when there is no other part
                if m > 1:
                    second = np.inf
                    for j in range(m):
                        if j != best:
                            second = min(second, d2[j] + ab[j])
                removal[best] += second - first
                for j in range(m):
                    addition[j] += min(d2[j] - first, zero)
        if toggles:
            for j in range(m):
                effect[b, j] = (-removal[j] if present[b, j] > 0.5 else addition[j]) / n


@numba.njit(cache=True, nogil=True)
def _union_backward(rot, offset, z, points, nearest, grad_out, zero, grad_rot, grad_offset, grad_z):
    """Gradients of :func:`_union_forward`'s ``out`` (winners held) given ``grad_out`` (B, n)."""
    for b in range(points.shape[0]):
        R, off, zz = rot[b], offset[b], z[b]
        grad_rot[b] = zero
        grad_offset[b] = zero
        grad_z[b] = zero
        for i in range(points.shape[1]):
            g = grad_out[b, i]
            if g == zero:
                continue
            j = nearest[b, i]
            x, y, w = points[b, i, 0], points[b, i, 1], points[b, i, 2]
            for c in range(3):
                local = _local(R, off, j, c, x, y, w)
                e = max(abs(local) - zz[j, c], zero)
                if e > zero:
                    ge = (g + g) * e
                    gl = ge if local > zero else -ge
                    grad_rot[b, j, 0, c] += gl * x
                    grad_rot[b, j, 1, c] += gl * y
                    grad_rot[b, j, 2, c] += gl * w
                    grad_offset[b, j, c] -= gl
                    grad_z[b, j, c] -= ge


def union_forward(rot, offset, z, absent, present, points, toggles: bool, far: float):
    """(out (B, n), nearest (B, n), effect (B, m)) for C-contiguous NumPy arrays of one float dtype:
    ``rot`` (B, m, 3, 3), ``offset`` = R^T t and ``z`` (B, m, 3), ``absent`` (the absence term) and
    ``present`` (B, m), ``points`` (B, n, 3); ``far``: the second distance when there is one part."""
    t = rot.dtype.type
    out = np.empty(points.shape[:2], rot.dtype)
    nearest = np.empty(points.shape[:2], np.int64)
    effect = np.zeros(rot.shape[:2], rot.dtype)
    over_batch(_union_forward, (rot, offset, z, absent, present, points), (bool(toggles), t(0.0), t(far)),
               (out, nearest, effect))
    return out, nearest, effect


def union_backward(rot, offset, z, points, nearest, grad_out):
    """(grad_rot, grad_offset, grad_z) of :func:`union_forward`'s ``out`` given ``grad_out`` (B, n)."""
    grad_rot = np.empty(rot.shape, rot.dtype)
    grad_offset = np.empty(offset.shape, rot.dtype)
    grad_z = np.empty(z.shape, rot.dtype)
    over_batch(_union_backward, (rot, offset, z, points, nearest, grad_out), (rot.dtype.type(0.0),),
               (grad_rot, grad_offset, grad_z))
    return grad_rot, grad_offset, grad_z

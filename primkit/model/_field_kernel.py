"""Compiled winner search of :func:`primkit.model.distance_field.lookup_distance_sq` (Numba;
imported on first use, CPU tensors only).

For each query point, the cell of the 8 around it whose stored closest point is nearest: the
part of the lookup that needs no gradient. The torch version forms it from 8 gathers of
``(B, 3, n)`` rows and a dozen element-wise passes over them; here each point is one pass over
its 8 cells. The arithmetic is the torch version's, step for step in the tensors' own precision
(the cell from ``floor((p + 0.5) R - 0.5)``, NaN read as cell 0 and infinities clamped;
``d^2 = dx^2 + dy^2 + dz^2``; corners in (x, y, z) order with z fastest, a tie keeps the first, a
NaN distance poisons the running minimum as ``torch.minimum`` does), so the same cells are chosen
(``tests/model/test_distance_field.py``).
"""

import numba
import numpy as np

__all__ = ["nearest_cells"]


@numba.njit(cache=True, nogil=True, inline="always")
def _cells(p, zero, one, half, res, top):
    """The lower and upper cell along one axis, as the torch lookup clamps them."""
    base = np.floor((p + half) * res - half)
    if base != base:  # NaN: torch's nan_to_num reads it as 0
        base = zero
    return int(min(max(base, zero), top)), int(min(max(base + one, zero), top))


@numba.njit(cache=True, nogil=True)
def _nearest_cells(planar, points, resolution, zero, one, half, res, top, out_cell, out_point):
    """``planar`` (B, 3, R^3) closest points, ``points`` (B, 3, n) -> ``out_cell`` (B, n): the flat
    index of each point's winning cell, ``out_point`` (B, 3, n): its closest point. The scalars
    0, 1, 0.5, R and R - 1 come in the arrays' precision, so that the arithmetic stays in it."""
    plane = resolution * resolution
    for b in range(points.shape[0]):
        gx, gy, gz = planar[b, 0], planar[b, 1], planar[b, 2]
        for i in range(points.shape[2]):
            px, py, pz = points[b, 0, i], points[b, 1, i], points[b, 2, i]
            x0, x1 = _cells(px, zero, one, half, res, top)
            y0, y1 = _cells(py, zero, one, half, res, top)
            z0, z1 = _cells(pz, zero, one, half, res, top)
            best = zero
            best_cell = 0
            for corner in range(8):
                cell = (x1 if corner & 4 else x0) * plane + (y1 if corner & 2 else y0) * resolution \
                    + (z1 if corner & 1 else z0)
                dx = gx[cell] - px
                dy = gy[cell] - py
                dz = gz[cell] - pz
                d2 = dx * dx + dy * dy + dz * dz
                if corner == 0 or d2 < best:
                    best, best_cell = d2, cell
                elif d2 != d2:
                    best = d2
            out_cell[b, i] = best_cell
            out_point[b, 0, i] = gx[best_cell]
            out_point[b, 1, i] = gy[best_cell]
            out_point[b, 2, i] = gz[best_cell]


def nearest_cells(planar: np.ndarray, points: np.ndarray, resolution: int, threads: int = 1):
    """(cells (B, n) int64, their closest points (B, 3, n)) for ``planar`` (B, 3, R^3) and
    ``points`` (B, 3, n), both C-contiguous of one float dtype. ``threads`` > 1 splits the shapes
    among Python threads (the kernel releases the GIL; no thread pool of Numba's own, so that it
    is safe in forked workers)."""
    batch = points.shape[0]
    out_cell = np.empty((batch, points.shape[2]), np.int64)
    out_point = np.empty(points.shape, planar.dtype)
    t = planar.dtype.type
    scalars = (t(0.0), t(1.0), t(0.5), t(resolution), t(resolution - 1))

    def run(lo, hi):
        _nearest_cells(planar[lo:hi], points[lo:hi], resolution, *scalars, out_cell[lo:hi], out_point[lo:hi])

    threads = max(1, min(int(threads), batch))
    if threads == 1:
        run(0, batch)
    else:
        from concurrent.futures import ThreadPoolExecutor

        cuts = np.linspace(0, batch, threads + 1).astype(int)
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(run, cuts[:-1], cuts[1:]))
    return out_cell, out_point

"""What rises beside the seat: the side features of the labeller.

The profile features (:mod:`primkit.labelling.profile`) place an element in its shape's bounding
box and in its own slab, column and row. Arms are told apart from a seat's edge or a back's wing by
where they sit against the *seat*: beside it (out past the middle of its width), over its
front-to-back span, in a column that rises above it. These features measure that, the seat taken
as the densest horizontal slab (as the profile's column 5 does), in the same coarse grid over the
bounding box (``bins`` cells a side, canonical frame: +Y up, +X front, Z across):

====  =====================================================================================
col   meaning
====  =====================================================================================
0     the top of its vertical column (the highest occupied cell) above the densest slab, in
      cells over ``bins`` (negative: the column ends below it)
1     the bottom of its column above the densest slab, the same units
2     its distance across from the middle of the densest slab's width, over half that width
      (about 1 at the seat's sides, more past them)
3     the width across of its own slab over the densest slab's (a sofa's sides widen the
      slabs above the seat where a plain chair's back narrows them)
4     where it sits front to back over the densest slab's span (0 its back, 1 its front)
====  =====================================================================================

Each comes from one pass over the shape's cells (a Numba loop: each column's top and bottom, each
slab's extent across, the densest slab and its span), read back per element by another (about
0.35 ms on a chair's voxels). Written here because no dependency reads a point set's column and
slab extents back per point.
"""

from __future__ import annotations

import numpy as np

from .profile import PROFILE_BINS, box_cells

__all__ = ["SIDE_FEATURES", "side_features", "side_columns"]

#: Columns :func:`side_features` returns.
SIDE_FEATURES = 5


def side_features(points, context=None, bins: int = PROFILE_BINS) -> np.ndarray:
    """``(n, 5)`` float: where each of ``points`` sits against the densest slab of ``context``
    (the table in the module notes).

    Parameters
    ----------
    points : (n, 3) float
        The elements, canonical frame (+Y up, +X front).
    context : (c, 3) float or None
        The points that stand for the shape (a mesh's surface samples; None: ``points``); the
        bounding box, the occupied cells and the slabs are theirs. An element in a column no
        context point occupies reads the densest slab as its column's top and bottom.
    bins : int
        Cells a side of the binning grid (over each axis of the bounding box).
    """
    return side_columns(points, context, bins)[:, :SIDE_FEATURES]


def side_columns(points, context=None, bins: int = PROFILE_BINS) -> np.ndarray:
    """``(n, 6)``: :func:`side_features` and, last, each element's height above the densest slab's
    centre in the box's height (the profile's column 5, :func:`primkit.labelling.profile.profile_features`,
    from the same histogram: what :func:`primkit.labelling.presence.side_region` reads)."""
    points = np.asarray(points, float)
    ctx = points if context is None else np.asarray(context, float)
    if points.ndim != 2 or points.shape[1] != 3 or ctx.ndim != 2 or ctx.shape[1] != 3:
        raise ValueError(f"`points` and `context` must be (n, 3) float, got {points.shape} and {ctx.shape}")
    if len(points) == 0:
        return np.zeros((0, SIDE_FEATURES + 1))
    if len(ctx) == 0:
        raise ValueError("`context` is empty: no shape to read the sides from")
    if not (np.isfinite(ctx).all() and np.isfinite(points).all()):
        raise ValueError("`points` and `context` must be finite")
    lo, extent, c = box_cells(ctx, bins)  # the profile's box and cells
    top, bottom = np.full((bins, bins), -1, np.int64), np.full((bins, bins), bins, np.int64)  # [x, z]
    z_lo, z_hi = np.full(bins, bins, np.int64), np.full(bins, -1, np.int64)  # per slab
    found = np.zeros(3, np.int64)  # the densest slab, its first and last x cell
    _extents_kernel()(c, top, bottom, z_lo, z_hi, found)
    out = np.empty((len(points), SIDE_FEATURES + 1))
    _read_kernel()(np.ascontiguousarray(points), lo, extent, top, bottom, z_lo, z_hi, found, out)
    return out


_EXTENTS = None


def _extents_kernel():
    """One pass over the context's cells ``c`` (``(c, 3) int``, ``[x, y, z]``): each column's top and
    bottom occupied cell, each slab's first and last cell across, the densest slab (the first of
    the densest, as ``np.argmax`` of the slab counts) and its first and last x cell; compiled on
    first use (cached on disk): NumPy's reductions over the ``bins**3`` histogram took four fifths
    of the features' time."""
    global _EXTENTS
    if _EXTENTS is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def extents(c, top, bottom, z_lo, z_hi, found):
            bins = z_lo.shape[0]
            slab = np.zeros(bins, np.int64)
            for q in range(c.shape[0]):
                x, y, z = c[q, 0], c[q, 1], c[q, 2]
                slab[y] += 1
                top[x, z] = max(top[x, z], y)
                bottom[x, z] = min(bottom[x, z], y)
                z_lo[y] = min(z_lo[y], z)
                z_hi[y] = max(z_hi[y], z)
            seat = 0
            for y in range(bins):
                if slab[y] > slab[seat]:
                    seat = y
            x_lo, x_hi = bins, -1
            for q in range(c.shape[0]):
                if c[q, 1] == seat:
                    x_lo = min(x_lo, c[q, 0])
                    x_hi = max(x_hi, c[q, 0])
            found[0], found[1], found[2] = seat, x_lo, x_hi

        _EXTENTS = extents
    return _EXTENTS


_READ = None


def _read_kernel():
    """Each point's columns of :func:`side_columns` from :func:`_extents_kernel`'s extents (a column
    no context point occupies reads the densest slab as its top and bottom, an empty slab width
    0), compiled on first use (cached on disk): a dozen NumPy gathers over the points cost more
    than the extents."""
    global _READ
    if _READ is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def read(points, lo, extent, top, bottom, z_lo, z_hi, found, out):
            bins = z_lo.shape[0]
            seat, x_lo, x_hi = found[0], found[1], found[2]
            middle = (z_lo[seat] + z_hi[seat] + 1) / 2.0
            seat_width = z_hi[seat] - z_lo[seat] + 1  # the densest slab is never empty
            half = seat_width / 2.0
            for p in range(points.shape[0]):
                r0 = (points[p, 0] - lo[0]) / extent[0] * bins
                r1 = (points[p, 1] - lo[1]) / extent[1] * bins
                r2 = (points[p, 2] - lo[2]) / extent[2] * bins
                i = min(max(int(r0), 0), bins - 1)
                j = min(max(int(r1), 0), bins - 1)
                k = min(max(int(r2), 0), bins - 1)
                t, b = top[i, k], bottom[i, k]
                if t < 0:  # a column no context point occupies
                    t = b = seat
                out[p, 0] = (t - seat) / bins
                out[p, 1] = (b - seat) / bins
                out[p, 2] = abs(r2 - middle) / half
                out[p, 3] = max(z_hi[j] - z_lo[j] + 1, 0) / seat_width
                out[p, 4] = (r0 - x_lo) / (x_hi - x_lo + 1)
                out[p, 5] = (points[p, 1] - lo[1]) / extent[1] - (seat + 0.5) / bins

        _READ = read
    return _READ

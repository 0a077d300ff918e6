"""What rises beside the seat: the side features of the labeller.

The profile features (:mod:`primkit.segmentation.profile`) place an element in its shape's bounding
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

Each is one histogram of the shape and a few reductions of it, read per element (well under a
millisecond on a chair's voxels). Written here because no dependency reads a point set's column
and slab extents back per point.
"""

from __future__ import annotations

import numpy as np

from .profile import PROFILE_BINS

__all__ = ["SIDE_FEATURES", "side_features"]

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
    centre in the box's height (the profile's column 5, :func:`primkit.segmentation.profile.profile_features`,
    from the same histogram: what :func:`primkit.segmentation.presence.side_region` reads)."""
    points = np.asarray(points, float)
    ctx = points if context is None else np.asarray(context, float)
    if points.ndim != 2 or points.shape[1] != 3 or ctx.ndim != 2 or ctx.shape[1] != 3:
        raise ValueError(f"`points` and `context` must be (n, 3) float, got {points.shape} and {ctx.shape}")
    if len(points) == 0:
        return np.zeros((0, SIDE_FEATURES + 1))
    if len(ctx) == 0:
        raise ValueError("`context` is empty: no shape to read the sides from")
    lo = ctx.min(axis=0)
    extent = np.maximum(ctx.max(axis=0) - lo, 1e-9)
    c = np.clip(((ctx - lo) / extent * bins).astype(np.int64), 0, bins - 1)
    counts = np.bincount((c[:, 0] * bins + c[:, 1]) * bins + c[:, 2], minlength=bins**3).reshape(bins, bins, bins)
    occupied = counts > 0  # [x, y, z]
    seat = int(np.argmax(counts.sum(axis=(0, 2))))  # the densest slab (its first on a tie, as the profile's)
    column = occupied.any(axis=1)  # (x, z)
    top = np.where(column, bins - 1 - np.argmax(occupied[:, ::-1, :], axis=1), seat)
    bottom = np.where(column, np.argmax(occupied, axis=1), seat)
    across = occupied.any(axis=0)  # (y, z): which cells across each slab holds
    filled = across.any(axis=1)
    z_lo = np.argmax(across, axis=1)
    z_hi = bins - 1 - np.argmax(across[:, ::-1], axis=1)
    width = np.where(filled, z_hi - z_lo + 1, 0)
    middle, half = (z_lo[seat] + z_hi[seat] + 1) / 2.0, width[seat] / 2.0  # the densest slab is never empty
    along = occupied[:, seat, :].any(axis=1)  # the x cells of the densest slab
    x_lo, x_hi = np.argmax(along), bins - 1 - np.argmax(along[::-1])
    rel = (points - lo) / extent * bins  # in cells
    i, j, k = np.clip(rel.astype(np.int64), 0, bins - 1).T
    out = np.empty((len(points), SIDE_FEATURES + 1))
    out[:, 0] = (top[i, k] - seat) / bins
    out[:, 1] = (bottom[i, k] - seat) / bins
    out[:, 2] = np.abs(rel[:, 2] - middle) / half
    out[:, 3] = width[j] / width[seat]
    out[:, 4] = (rel[:, 0] - x_lo) / (x_hi - x_lo + 1)
    out[:, 5] = (points[:, 1] - lo[1]) / extent[1] - (seat + 0.5) / bins
    return out

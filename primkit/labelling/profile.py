"""Where an element sits in its shape's occupancy: the shape-profile features of the labeller.

The primitive frame (:func:`primkit.labelling.features.frame_features`) tells a labeller where an
element sits among the cuboids; when the cuboids fit a shape loosely (a seat cuboid that swallows
the top of the legs) it says little about the shape itself. These features read the shape's own
elements instead, binned in a coarse grid over their bounding box (``bins`` cells a side, in the
canonical frame: +Y up, +X front), and tell for each element:

====  =====================================================================================
col   meaning
====  =====================================================================================
0-2   its position in the bounding box, each axis 0 (min) to 1 (max)
3     how far it is from the middle plane across the shape, ``|2 z' - 1|`` (0: on it, 1: a side)
4     the share of the shape in its horizontal slab (its height cell) over the largest slab's
      (1 in the densest slab: on a chair, mostly the seat)
5     its height above the centre of that densest slab, in the box's height (negative: below)
6, 7  the shares of its vertical column's elements above and below its own cell
8, 9  the shares of its front-to-back row's elements in front of (+X) and behind its own cell
====  =====================================================================================

A seat voxel sees a full slab and a column with legs below, a leg little in its slab and nothing
above it, an arm the seat below it and nothing in front of a back. Each costs one histogram of the
elements and a few cumulative sums (a few milliseconds on a 4,000-voxel chair), not a neighbour
search. Written here because no dependency bins a point set this way and reads it back per point
(``np.histogramdd`` gives the counts but not each point's cell).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PROFILE_FEATURES", "PROFILE_BINS", "profile_features", "box_cells", "column_range"]

#: Columns :func:`profile_features` returns.
PROFILE_FEATURES = 10
#: Cells a side of the grid the elements are binned in (chosen on the PartNet validation chairs).
PROFILE_BINS = 24


def profile_features(points, context=None, bins: int = PROFILE_BINS) -> np.ndarray:
    """``(n, 10)`` float: where each of ``points`` sits in the occupancy of ``context`` (the table
    in the module notes).

    Parameters
    ----------
    points : (n, 3) float
        The elements, canonical frame (+Y up, +X front).
    context : (c, 3) float or None
        The points that stand for the shape (a mesh's surface samples; None: ``points``); the
        bounding box and the counts are theirs.
    bins : int
        Cells a side of the binning grid (over each axis of the bounding box).
    """
    points = np.asarray(points, float)
    ctx = points if context is None else np.asarray(context, float)
    if points.ndim != 2 or points.shape[1] != 3 or ctx.ndim != 2 or ctx.shape[1] != 3:
        raise ValueError(f"`points` and `context` must be (n, 3) float, got {points.shape} and {ctx.shape}")
    if len(points) == 0:
        return np.zeros((0, PROFILE_FEATURES))
    if len(ctx) == 0:
        raise ValueError("`context` is empty: no shape to read the profile from")
    if not (np.isfinite(ctx).all() and np.isfinite(points).all()):
        raise ValueError("`points` and `context` must be finite")
    kernels = _profile_kernel()
    points, ctx = np.ascontiguousarray(points), np.ascontiguousarray(ctx)
    lo, hi = column_range(ctx)
    extent = np.maximum(hi - lo, 1e-9)
    counts = np.zeros((bins, bins, bins))  # [x, y, z]
    out = np.empty((len(points), PROFILE_FEATURES))
    cells = np.empty((len(points), 3), np.int64)
    ctx_cells = cells if context is None else np.empty((len(ctx), 3), np.int64)
    kernels[0](points, lo, extent, bins, out, cells)  # columns 0-3, 5 and the cells
    if context is not None:
        kernels[0](ctx, lo, extent, bins, None, ctx_cells)
    kernels[1](ctx_cells, cells, counts, out)  # columns 4 and 6-9; 5 less the densest slab
    return out


def column_range(a) -> tuple[np.ndarray, np.ndarray]:
    """``(a.min(axis=0), a.max(axis=0))`` of a non-empty, NaN-free 2-D array in one Numba pass,
    int64 for an integer array, float64 otherwise (NumPy's reductions along axis 0 of an ``(n, 3)``
    array stride through it: about a tenth of the speed). The profile's box, the side features'
    and the labeller's grid extents all take it."""
    global _RANGE
    if _RANGE is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def columns(a, low, high):
            for j in range(a.shape[1]):
                low[j] = high[j] = a[0, j]
            for i in range(1, a.shape[0]):
                for j in range(a.shape[1]):
                    v = a[i, j]
                    if v < low[j]:
                        low[j] = v
                    elif v > high[j]:
                        high[j] = v

        _RANGE = columns
    a = np.asarray(a)
    a = np.ascontiguousarray(a, np.int64 if a.dtype.kind in "iub" else np.float64)
    low, high = np.empty(a.shape[1], a.dtype), np.empty(a.shape[1], a.dtype)
    _RANGE(a, low, high)
    return low, high


_RANGE = None


def box_cells(points, bins: int = PROFILE_BINS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lo, extent, cells)``: the bounding box of finite ``(n, 3)`` points (its lower corner and
    its size, at least 1e-9 on each axis) and each point's ``(n, 3) int`` cell of the ``bins``-a-side
    grid over it, as :func:`profile_features` bins its context (the side features bin the same
    way, :mod:`primkit.labelling.sides`)."""
    place, _ = _profile_kernel()
    points = np.ascontiguousarray(points, float)
    lo, hi = column_range(points)
    extent = np.maximum(hi - lo, 1e-9)
    cells = np.empty((len(points), 3), np.int64)
    place(points, lo, extent, bins, None, cells)
    return lo, extent, cells


_PROFILE = None


def _profile_kernel():
    """``(place, profile)``, compiled on first use (cached on disk). ``place``: the points' columns
    0-3 and 5 (before the slab) and their cells, the same operations as NumPy's expressions in
    :func:`_profile_reference`; ``profile``: columns 4 and 6-9 from the context's and the points'
    cells, and column 5 gets the densest slab's centre subtracted.
    The counts are whole numbers, so every sum is exact: the same numbers as the NumPy sums and
    cumulative sums over the ``bins**3`` grid (:func:`_profile_reference`), in a fifth of the time
    (each point sums its own column and row, up to ``bins`` cells)."""
    global _PROFILE
    if _PROFILE is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def place(points, lo, extent, bins, out, cells):
            # rel = (p - lo) / extent (columns 0-2, 3, and 5 before the slab), the cell
            # clip(int(rel * bins), 0, bins - 1) as NumPy's astype and clip give it (NaN: 0)
            for p in range(points.shape[0]):
                for a in range(3):
                    rel = (points[p, a] - lo[a]) / extent[a]
                    v = rel * bins
                    cells[p, a] = 0 if not v > 0 else (bins - 1 if v >= bins else int(v))
                    if out is not None:
                        out[p, a] = rel
                if out is not None:
                    out[p, 3] = abs(2.0 * out[p, 2] - 1.0)
                    out[p, 5] = out[p, 1]

        @numba.njit(cache=True, nogil=True)
        def profile(ctx_cells, cells, counts, out):
            bins = counts.shape[0]
            for q in range(ctx_cells.shape[0]):
                counts[ctx_cells[q, 0], ctx_cells[q, 1], ctx_cells[q, 2]] += 1.0
            slab = np.zeros(bins)
            for x in range(bins):
                for y in range(bins):
                    for z in range(bins):
                        slab[y] += counts[x, y, z]
            densest = (np.argmax(slab) + 0.5) / bins
            top = slab.max()
            for p in range(cells.shape[0]):
                i, j, k = cells[p, 0], cells[p, 1], cells[p, 2]
                own = counts[i, j, k]
                below = col = 0.0
                for y in range(bins):
                    if y < j:
                        below += counts[i, y, k]
                    col += counts[i, y, k]
                behind = rw = 0.0
                for x in range(bins):
                    if x < i:
                        behind += counts[x, j, k]
                    rw += counts[x, j, k]
                safe_col, safe_row = max(col, 1.0), max(rw, 1.0)  # an element outside the context: zeros
                out[p, 4] = slab[j] / top
                out[p, 5] -= densest
                out[p, 6] = max(col - below - own, 0.0) / safe_col
                out[p, 7] = below / safe_col
                out[p, 8] = max(rw - behind - own, 0.0) / safe_row
                out[p, 9] = behind / safe_row

        _PROFILE = (place, profile)
    return _PROFILE


def _profile_reference(points, context=None, bins: int = PROFILE_BINS) -> np.ndarray:
    """:func:`profile_features` by NumPy sums over the whole grid (what it computed before the
    Numba loop; the tests compare the two)."""
    points = np.asarray(points, float)
    ctx = points if context is None else np.asarray(context, float)
    lo = ctx.min(axis=0)
    extent = np.maximum(ctx.max(axis=0) - lo, 1e-9)
    rel = (points - lo) / extent

    def cells(p):
        return np.clip(((p - lo) / extent * bins).astype(np.int64), 0, bins - 1)

    c = cells(ctx)
    counts = np.bincount((c[:, 0] * bins + c[:, 1]) * bins + c[:, 2], minlength=bins**3).reshape(bins, bins, bins)
    counts = counts.astype(float)  # [x, y, z]
    i, j, k = cells(points).T
    own = counts[i, j, k]
    slab = counts.sum(axis=(0, 2))  # per height cell
    densest = (np.argmax(slab) + 0.5) / bins
    column = counts.sum(axis=1)  # (x, z): everything above and below
    below = np.cumsum(counts, axis=1)[i, j, k] - own
    col = column[i, k]
    row = counts.sum(axis=0)  # (y, z): everything in front and behind
    behind = np.cumsum(counts, axis=0)[i, j, k] - own
    rw = row[j, k]
    safe_col, safe_row = np.maximum(col, 1.0), np.maximum(rw, 1.0)  # an element outside the context: zeros
    return np.column_stack([rel, np.abs(2.0 * rel[:, 2] - 1.0), slab[j] / slab.max(), rel[:, 1] - densest,
                            (col - below - own).clip(0) / safe_col, below / safe_col,
                            (rw - behind - own).clip(0) / safe_row, behind / safe_row])

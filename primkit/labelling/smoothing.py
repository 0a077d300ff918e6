"""Voxel-grid numerics of the labeller: neighbours by index arithmetic, the sampled
classification and its fill, the probabilities' mean over neighbours, and a grid's normals.

Each is a Numba loop compiled on first use (cached on disk) with the plain NumPy computation it
replaces described beside it; the tests compare the two.
"""

from __future__ import annotations

import functools

import numpy as np

from .profile import column_range

__all__ = ["grid_neighbours", "grid_sampling", "grid_normals", "sample_grid", "check_sampling", "fill_unsampled",
           "smooth_over", "pad4", "flat_offsets"]


def flat_offsets(offsets, shape) -> np.ndarray:
    """``(b,) int64``: 3-D grid offsets as offsets into the flattened C-order grid of ``shape``
    (the Numba lookups index one flat array: a third of the time of three-index lookups)."""
    return np.ascontiguousarray(offsets @ np.array([shape[1] * shape[2], shape[2], 1], np.int64))


_MEAN = None


def _mean_kernel():
    """``out[i] = proba[idx[i, :k]].mean(axis=0)`` (the neighbours summed in order, then divided, as
    NumPy's ``proba[idx[:, :k]].mean(axis=1)``), compiled on first use: the gather NumPy does makes
    an ``(n, k, classes)`` copy and costs ten times as much on a chair's voxels. The classes come
    four at a time (``proba`` has a multiple of 4 columns, :func:`pad4`), their sums in registers:
    half the time of one class at a time; each class's sum in the same order."""
    global _MEAN
    if _MEAN is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def mean_over(proba, idx, k, out):
            for i in range(idx.shape[0]):
                for c in range(0, proba.shape[1], 4):
                    t0 = t1 = t2 = t3 = 0.0
                    for j in range(k):
                        p = idx[i, j]
                        t0 += proba[p, c]
                        t1 += proba[p, c + 1]
                        t2 += proba[p, c + 2]
                        t3 += proba[p, c + 3]
                    out[i, c], out[i, c + 1], out[i, c + 2], out[i, c + 3] = t0 / k, t1 / k, t2 / k, t3 / k

        _MEAN = mean_over
    return _MEAN


def pad4(proba) -> np.ndarray:
    """``proba`` as contiguous float64 with zero columns added up to a multiple of 4 (for
    :func:`_mean_kernel` and the fill of :func:`_sample_fill_kernels`)."""
    proba = np.ascontiguousarray(proba, np.float64)
    extra = -proba.shape[1] % 4
    return np.hstack([proba, np.zeros((len(proba), extra))]) if extra else proba


_SAMPLE_FILL = None


def _sample_fill_kernels():
    """``(sample, fill)``, compiled on first use (cached on disk): :func:`grid_sampling`'s
    ``classify`` and ``sampled`` from the voxel indices and the 27 neighbours in one loop, and the
    fill of :meth:`primkit.labelling.labeller.Labeller.predict_proba` read straight from the
    neighbours (each unclassified
    voxel's classes: the mean of its neighbours ``1:27`` that are other sampled voxels, summed in
    order, as the ``around``/``use`` arrays of :func:`grid_sampling` give it) without building
    those arrays; ``proba`` with a multiple of 4 columns (:func:`pad4`), as :func:`_mean_kernel`."""
    global _SAMPLE_FILL
    if _SAMPLE_FILL is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def sample(index, neighbours, step, sampled, classify):
            n = index.shape[0]
            for i in range(n):
                a, b, c = index[i, 0] % 2, index[i, 1] % 2, index[i, 2] % 2
                if step == 1:
                    sampled[i] = True
                elif step == 2:
                    sampled[i] = (a + b + c) % 2 == 0
                elif step == 4:
                    sampled[i] = a == b and b == c
                else:
                    sampled[i] = a == 0 and b == 0 and c == 0
            for i in range(n):
                classify[i] = sampled[i]
                if not sampled[i]:
                    found = False
                    for j in range(1, 27):
                        p = neighbours[i, j]
                        if p != i and sampled[p]:
                            found = True
                            break
                    classify[i] = not found

        @numba.njit(cache=True, nogil=True)
        def fill(proba, neighbours, sampled, classify):
            for i in range(proba.shape[0]):
                if classify[i]:
                    continue
                for c in range(0, proba.shape[1], 4):
                    t0 = t1 = t2 = t3 = 0.0
                    count = 0
                    for j in range(1, 27):
                        p = neighbours[i, j]
                        if p != i and sampled[p]:
                            t0 += proba[p, c]
                            t1 += proba[p, c + 1]
                            t2 += proba[p, c + 2]
                            t3 += proba[p, c + 3]
                            count += 1
                    proba[i, c], proba[i, c + 1], proba[i, c + 2], proba[i, c + 3] = \
                        t0 / count, t1 / count, t2 / count, t3 / count

        _SAMPLE_FILL = (sample, fill)
    return _SAMPLE_FILL


def fill_unsampled(proba, neighbours, sampled, classify) -> None:
    """Fill in place the rows of ``proba`` ((n, c) float64, c a multiple of 4: :func:`pad4`) that
    were not classified: each the mean of its neighbours ``1:27`` that are other sampled voxels
    (:func:`grid_sampling`'s ``around[use]``, summed in order)."""
    _sample_fill_kernels()[1](proba, neighbours, sampled, classify)


def smooth_over(proba, idx, k: int, rounds: int) -> np.ndarray:
    """``(n, classes)``: ``proba`` averaged ``rounds`` times over each row's first ``k`` neighbours
    ``idx`` ((n, >= k) int, itself first): ``proba[idx[:, :k]].mean(axis=1)`` each round, without
    the ``(n, k, classes)`` copy (a Numba loop)."""
    idx = np.ascontiguousarray(idx, np.int64)
    k = min(k, idx.shape[1])
    classes = proba.shape[1]
    proba = pad4(proba)
    for _ in range(rounds):
        out = np.empty_like(proba)
        _mean_kernel()(proba, idx, k, out)
        proba = out
    return proba[:, :classes]


def sample_grid(index, neighbours, step: int):
    """``(classify (n,) bool, sampled (n,) bool)`` of :func:`grid_sampling` (its checks done by
    the caller or there)."""
    n = len(index)
    sampled, classify = np.empty(n, bool), np.empty(n, bool)
    if n:
        _sample_fill_kernels()[0](index, neighbours, int(step), sampled, classify)
    return classify, sampled


def grid_neighbours(index, shape) -> np.ndarray:
    """``(n, 27) int``: for the occupied voxels at ``index`` (``(n, 3) int``, e.g. ``np.argwhere``),
    the positions in ``index`` of the occupied voxels of their 3 x 3 x 3 neighbourhood, nearest
    first (the voxel itself, its 6 face neighbours, 12 edge and 8 corner neighbours; the voxel
    itself where a neighbour is empty or off the grid). The first ``k`` columns are the ``k``
    nearest voxel centres where the grid is full, found by index arithmetic instead of a k-d tree."""
    index = np.ascontiguousarray(index, np.int64).reshape(-1, 3)
    _check_inside(index, shape)
    where = np.full(tuple(np.asarray(shape) + 2), -1, np.int64)  # padded: no bounds checks
    where[tuple((index + 1).T)] = np.arange(len(index))
    near = np.empty((len(index), len(_OFFSETS)), np.int64)
    if len(index):  # where[index + 1 + offset], the voxel itself where empty (a tenth of NumPy's gathers' time)
        _block_kernel()(index, where.reshape(-1), flat_offsets(_OFFSETS, where.shape), where.shape[1], where.shape[2], near)
    return near


def _check_inside(index, shape) -> None:
    """ValueError unless the ``(n, 3)`` voxel indices lie inside a grid of ``shape`` (the Numba
    loops read the grid unchecked)."""
    if len(index):
        low, high = column_range(index)
        if low.min() < 0 or np.any(high >= np.asarray(shape)[:3]):
            raise ValueError(f"voxel indices outside the grid of shape {tuple(shape)}")


_BLOCK = None


def _block_kernel():
    """The lookup of :func:`grid_neighbours`, compiled on first use (cached on disk)."""
    global _BLOCK
    if _BLOCK is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def block(index, where, offsets, b, c, near):  # where: the padded (a, b, c) lookup, flat
            for i in range(index.shape[0]):
                base = ((index[i, 0] + 1) * b + index[i, 1] + 1) * c + index[i, 2] + 1
                for o in range(offsets.shape[0]):
                    p = where[base + offsets[o]]
                    near[i, o] = p if p >= 0 else i

        _BLOCK = block
    return _BLOCK


def grid_sampling(index, neighbours, step: int):
    """Which voxels a labeller classifies when it reads one in ``step`` (``LabellerSettings.grid_sample``).

    Returns ``(classify (n,) bool, around (f, 26) int, use (f, 26) bool)``: the voxels classified
    (step 2: ``i + j + k`` even; 4: all three indices even or all odd; 8: all three even; 1:
    all), and for the ``f`` others,
    their 26 neighbours' positions (``neighbours[:, 1:]``, from :func:`grid_neighbours`) and which
    of them are classified occupied voxels (the mean of those is theirs). A voxel with no such
    neighbour is classified itself, so every ``use`` row has at least one True.
    """
    index, neighbours = check_sampling(index, neighbours, step)
    # step 4: a body-centred lattice, every voxel has one of them in its 3 x 3 x 3 block; a voxel
    # with no sampled neighbour (an empty neighbour is the voxel itself) is classified itself
    classify, sampled = sample_grid(index, neighbours, step)
    around = neighbours[~classify, 1:27]
    use = sampled[around] & (around != np.flatnonzero(~classify)[:, None])
    return classify, around, use


def check_sampling(index, neighbours, step: int):
    """The arguments of :func:`grid_sampling` as contiguous int64, or ValueError."""
    index = np.ascontiguousarray(index, np.int64).reshape(-1, 3)
    if step not in (1, 2, 4, 8):
        raise ValueError(f"grid sampling one voxel in {step}: only 1, 2, 4 or 8")
    n = len(index)
    neighbours = np.ascontiguousarray(neighbours, np.int64)
    low, high = column_range(neighbours) if n and neighbours.shape == (n, 27) else (np.zeros(1), np.zeros(1))
    if neighbours.shape != (n, 27) or low.min() < 0 or (n and high.max() >= n):
        raise ValueError(f"`neighbours` must be grid_neighbours' (n, 27) positions, got shape {neighbours.shape}")
    return index, neighbours


#: the 27 offsets of a 3 x 3 x 3 block, nearest first (ties in a fixed order)
_OFFSETS = np.array(sorted(((i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)),
                           key=lambda o: (sum(x * x for x in o), o)))


def grid_normals(occupancy, index=None) -> np.ndarray:
    """``(R, R, R, 3)`` outward unit normals of an occupancy grid, in its index axes: minus the
    gradient of the occupancy smoothed by a Gaussian of one voxel (scipy.ndimage), zero where flat
    (deep inside). ``index`` (``(n, 3) int``): only those voxels' normals, ``(n, 3)``, the same
    numbers (``np.gradient``'s differences taken at those voxels alone: a chair's occupied voxels
    are a tenth of its grid)."""
    from scipy import ndimage

    occupancy = np.asarray(occupancy)
    if index is None or occupancy.ndim != 3 or min(occupancy.shape) <= _GAUSS_RADIUS:
        smooth = ndimage.gaussian_filter(np.asarray(occupancy, float), 1.0)
    else:  # the same numbers, in about half the time
        smooth = _grid_gaussian(occupancy)
    if index is None:
        grad = -np.stack(np.gradient(smooth), axis=-1)
    else:
        index = np.ascontiguousarray(index, np.int64).reshape(-1, 3)
        _check_inside(index, smooth.shape)
        if min(smooth.shape) < 2:
            raise ValueError("grid_normals needs at least 2 voxels along each axis")
        out = np.zeros((len(index), 3))
        if len(index):  # the same differences and norms as below, one voxel at a time
            _normals_kernel()(smooth, index, out)
        return out
    norm = np.linalg.norm(grad, axis=-1, keepdims=True)
    return np.divide(grad, norm, out=np.zeros_like(grad), where=norm > 1e-6)


#: the radius of :func:`grid_normals`' Gaussian (scipy's ``truncate`` 4 at sigma 1)
_GAUSS_RADIUS = 4


@functools.lru_cache(maxsize=1)
def _gauss_weights() -> np.ndarray:
    """``(5,)`` float64: scipy's one-voxel Gaussian weights at offsets 0-4, read off its response
    to a unit impulse (each output there is one weight times 1 plus zeros: the weights exactly)."""
    from scipy import ndimage

    impulse = np.zeros(4 * _GAUSS_RADIUS + 1)
    impulse[2 * _GAUSS_RADIUS] = 1.0
    w = ndimage.gaussian_filter1d(impulse, 1.0)[2 * _GAUSS_RADIUS : 3 * _GAUSS_RADIUS + 1].copy()
    w.flags.writeable = False
    return w


def _grid_gaussian(occupancy) -> np.ndarray:
    """``ndimage.gaussian_filter(occupancy.astype(float), 1.0)`` of a 3-D grid at least 5 voxels a
    side, the same numbers (the tests check bit for bit): its three passes (axes 0, 1, 2, mode
    "reflect", scipy's symmetric-kernel sum ``x[l] w0 + sum_{d=4..1} (x[l-d] + x[l+d]) w_d``) by a
    Numba loop (vectorised along the last axis; the last pass leaves a row of zeros at zero): about
    0.28 against 0.49 ms on a 32^3 chair grid. Hand-written because scipy's filter, general over
    dtypes, modes and kernels, runs line by line through a buffer."""
    grid = np.ascontiguousarray(occupancy, np.float64)
    out = np.empty_like(grid)
    _gauss_kernel()(grid, out, np.empty_like(grid), np.asarray(_gauss_weights()))
    return out


_GAUSS = None


def _gauss_kernel():
    """The passes of :func:`_grid_gaussian`, compiled on first use (cached on disk). Each output
    takes the same operations in the same order as scipy's loop; the first two passes run along
    rows of the last axis (contiguous, vectorised), the third skips the rows that are all zero."""
    global _GAUSS
    if _GAUSS is None:
        import numba

        @numba.njit(cache=True, nogil=True, inline="always")
        def reflect(l, d, n):  # the indices d before and after l, mirrored at the ends as scipy's "reflect"
            lo, hi = l - d, l + d
            if lo < 0:
                lo = -lo - 1
            if hi >= n:
                hi = 2 * n - 1 - hi
            return lo, hi

        @numba.njit(cache=True, nogil=True)
        def across(inp, res, w):  # (A, n, B): filter along the middle axis, B contiguous
            r = w.shape[0] - 1
            n, m = inp.shape[1], inp.shape[2]
            for i in range(inp.shape[0]):
                for l in range(n):
                    for v in range(m):
                        res[i, l, v] = inp[i, l, v] * w[0]
                    for d in range(r, 0, -1):
                        lo, hi = reflect(l, d, n)
                        for v in range(m):
                            res[i, l, v] += (inp[i, lo, v] + inp[i, hi, v]) * w[d]

        @numba.njit(cache=True, nogil=True)
        def along(inp, res, w):  # (R, n): filter each row, a row of zeros left zero
            r = w.shape[0] - 1
            n = inp.shape[1]
            for i in range(inp.shape[0]):
                empty = True
                for l in range(n):
                    if inp[i, l] != 0.0:
                        empty = False
                        break
                if empty:
                    for l in range(n):
                        res[i, l] = 0.0
                    continue
                for l in range(n):
                    t = inp[i, l] * w[0]
                    for d in range(r, 0, -1):
                        lo, hi = reflect(l, d, n)
                        t += (inp[i, lo] + inp[i, hi]) * w[d]
                    res[i, l] = t

        @numba.njit(cache=True, nogil=True)
        def passes(grid, out, tmp, w):
            a, b, c = grid.shape
            across(grid.reshape(1, a, b * c), out.reshape(1, a, b * c), w)  # axis 0
            across(out, tmp, w)  # axis 1
            along(tmp.reshape(a * b, c), out.reshape(a * b, c), w)  # axis 2

        _GAUSS = passes
    return _GAUSS


_NORMALS = None


def _normals_kernel():
    """:func:`grid_normals` at some voxels, compiled on first use (cached on disk): per voxel and
    axis ``np.gradient``'s difference (central inside, one-sided at the grid's two ends), then
    the unit vector of minus the gradient (zero where its norm is at most 1e-6), as the NumPy
    expressions over the whole grid compute them; a loop instead of six gathers of the grid."""
    global _NORMALS
    if _NORMALS is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def normals(smooth, index, out):
            g = np.empty(3)
            for q in range(index.shape[0]):
                for axis in range(3):
                    size = smooth.shape[axis]
                    i = index[q, axis]
                    hi0, hi1, hi2 = index[q, 0], index[q, 1], index[q, 2]
                    lo0, lo1, lo2 = hi0, hi1, hi2
                    up, down = min(i + 1, size - 1), max(i - 1, 0)
                    if axis == 0:
                        hi0, lo0 = up, down
                    elif axis == 1:
                        hi1, lo1 = up, down
                    else:
                        hi2, lo2 = up, down
                    diff = smooth[hi0, hi1, hi2] - smooth[lo0, lo1, lo2]
                    g[axis] = -(diff / 2.0 if 0 < i < size - 1 else diff)
                norm = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
                if norm > 1e-6:
                    for axis in range(3):
                        out[q, axis] = g[axis] / norm

        _NORMALS = normals
    return _NORMALS

"""Differentiable lookup of a shape's distance field (torch; used by the training losses).

The field is stored as the closest surface point of every cell centre of the canonical grid
(:class:`primkit.geometry.DistanceGrid`). At an arbitrary point ``x`` we return

    d(x)^2 = min over the 8 cells around x of || x - closest[cell] ||^2

* Every ``closest[cell]`` is a point of the surface, so ``d(x)`` is an upper bound of the true
  distance, exact whenever x's own closest point is stored at one of its 8 neighbouring cells (in
  particular at every cell centre), and within a fraction of a cell elsewhere.
* It is continuous (a minimum of continuous functions) and its gradient is ``2 (x - closest)`` for
  the winning cell, the same direction as the published implementation's "x minus closest point".
* Points outside the grid use the clamped border cells but their own position, so the distance keeps
  growing outside the grid (it is not clamped to the border's value), and so does the gradient.

Compared with trilinear interpolation of the distance values this keeps the kink of the unsigned
distance at the surface sharp (trilinear interpolation smooths it over a cell, which reads a point
on the surface as up to half a cell away).
"""

from __future__ import annotations

import torch

from ._compiled import kernels

__all__ = ["lookup_distance_sq_torch", "lookup_distance_torch"]


def lookup_distance_sq_torch(closest: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Squared distance to the surface at arbitrary points, differentiable in ``points``.

    Parameters
    ----------
    closest : (B, R, R, R, 3) float tensor
        Closest surface point of each cell centre, canonical grid convention (``[i, j, k]`` along
        X, Y, Z; cell centres at ``-0.5 + (index + 0.5) / R``).
    points : (B, n, 3) float tensor
        Query points in the canonical frame (anywhere, inside or outside the grid).

    Returns
    -------
    (B, n) float tensor
    """
    if closest.dim() != 5 or closest.shape[-1] != 3:
        raise ValueError("`closest` must be (B, R, R, R, 3)")
    if points.dim() != 3 or points.shape[-1] != 3:
        raise ValueError("`points` must be (B, n, 3)")
    if closest.shape[1] != closest.shape[2] or closest.shape[1] != closest.shape[3] or closest.shape[1] < 1:
        raise ValueError(f"`closest` must be (B, R, R, R, 3), got {tuple(closest.shape)}")
    if points.shape[0] != closest.shape[0]:  # the compiled search would read grids past the last one
        raise ValueError(f"`points` {tuple(points.shape)} and `closest` {tuple(closest.shape)} differ in batch size")
    batch, res = closest.shape[0], closest.shape[1]
    # Which of the 8 surrounding cells wins is found without building a graph; the distance is
    # then recomputed with gradients for the winner only. The minimum's gradient flows to its
    # argument alone, so this is the same function and the same gradient, with one (B, n, 3)
    # term in the backward pass instead of eight. Coordinates are laid out planar, (B, 3, ...),
    # so that gathers and sums run over long contiguous rows (measured 20% faster on CPU); a
    # grid already stored planar (a (B, 3, R, R, R) tensor seen through ``permute(0, 2, 3, 4, 1)``,
    # as :class:`primkit.model.training.ShapeTensors` hands out) is used without a copy.
    planar = closest.reshape(batch, res ** 3, 3).transpose(1, 2)  # (B, 3, R^3)
    if not planar.is_contiguous():
        planar = planar.contiguous()
    cp = _winners_compiled(planar, points, res)
    if cp is None:
        cp = _winners(planar, points, res)
    return (points.transpose(1, 2) - cp).square().sum(1)


def _winners_compiled(planar, points, res):
    """(B, 3, n) closest point of each point's winning cell by the compiled search
    (:mod:`primkit.model._field_kernels`: the same cells as :func:`_winners`), None where Numba is
    missing or the tensors are not theirs (:func:`primkit.model._compiled.kernels`). On the training batch the lookup with its gradient took 7.9 ms against 13.5 with
    torch on 2 threads, 9.3 against 21.3 on one (``benchmarks/bench_abstractor.py``, section 2b).
    It runs on this thread alone: split over Python threads beside torch's OpenMP pool, whose
    threads spin for a while after each parallel region, it took 1 ms off a training step on 2
    cores instead of 3-5."""
    compiled = kernels("_field_kernels", planar, points, data=(planar,))
    if compiled is None:
        return None
    with torch.no_grad():
        pp = points.detach().transpose(1, 2).contiguous()  # (B, 3, n)
        _, cp = compiled.nearest_cells(planar.numpy(), pp.numpy(), res)
    return torch.from_numpy(cp)


def _winners(planar, points, res):
    """(B, 3, n) closest point of each point's winning cell, in torch (any device)."""
    batch, n = planar.shape[0], points.shape[1]
    with torch.no_grad():
        pp = points.detach().transpose(1, 2).contiguous()  # (B, 3, n)
        # continuous index of the point; the 8 surrounding cell centres are floor and floor + 1.
        # Cell indices are computed as floats (exact: integers far below 2^24) and the running
        # choice of the winner as arithmetic, not torch.where: both measured several times
        # faster on CPU than integer and boolean-select kernels of the same size.
        base = torch.floor((pp + 0.5) * res - 0.5).nan_to_num_(0.0)  # a NaN point stays NaN below
        stride = torch.tensor([res * res, res, 1], dtype=pp.dtype, device=pp.device)[None, :, None]
        lo = (base.clamp(0, res - 1) * stride).to(torch.int64)  # (B, 3, n): row offsets per axis
        hi = ((base + 1).clamp_(0, res - 1) * stride).to(torch.int64)
        best, best_lin = None, None
        for ix in (lo[:, 0], hi[:, 0]):  # corner order (x, y, z) with z fastest; ties keep the first
            for iy in (lo[:, 1], hi[:, 1]):
                ixy = ix + iy
                for iz in (lo[:, 2], hi[:, 2]):
                    lin = ixy + iz  # (B, n)
                    cp = torch.gather(planar, 2, lin[:, None, :].expand(batch, 3, n))
                    d2 = cp.sub_(pp).square_().sum(1)
                    if best is None:
                        best, best_lin = d2, lin
                    else:
                        closer = d2 < best
                        best = torch.minimum(best, d2)
                        best_lin = best_lin + (lin - best_lin) * closer
        return torch.gather(planar, 2, best_lin[:, None, :].expand(batch, 3, n))  # (B, 3, n)


def lookup_distance_torch(closest: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Distance (not squared) to the surface; see :func:`lookup_distance_sq_torch`. Returns (B, n)."""
    return lookup_distance_sq_torch(closest, points).clamp_min(1e-20).sqrt()

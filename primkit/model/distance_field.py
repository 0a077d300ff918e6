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

__all__ = ["lookup_distance_sq", "lookup_distance"]


def lookup_distance_sq(closest: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
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
    batch, res = closest.shape[0], closest.shape[1]
    n = points.shape[1]
    # Which of the 8 surrounding cells wins is found without building a graph; the distance is
    # then recomputed with gradients for the winner only. The minimum's gradient flows to its
    # argument alone, so this is the same function and the same gradient, with one (B, n, 3)
    # term in the backward pass instead of eight. Coordinates are laid out planar, (B, 3, ...),
    # so that gathers and sums run over long contiguous rows (measured 20% faster on CPU).
    planar = closest.reshape(batch, res ** 3, 3).transpose(1, 2).contiguous()  # (B, 3, R^3)
    with torch.no_grad():
        pp = points.transpose(1, 2).contiguous()  # (B, 3, n)
        # continuous index of the point; the 8 surrounding cell centres are floor and floor + 1
        base = torch.floor((pp + 0.5) * res - 0.5).long()
        best, best_lin = None, None
        for corner in range(8):
            ix = (base[:, 0] + ((corner >> 2) & 1)).clamp_(0, res - 1)
            iy = (base[:, 1] + ((corner >> 1) & 1)).clamp_(0, res - 1)
            iz = (base[:, 2] + (corner & 1)).clamp_(0, res - 1)
            lin = (ix * res + iy) * res + iz  # (B, n)
            cp = torch.gather(planar, 2, lin[:, None, :].expand(batch, 3, n))
            d2 = (pp - cp).square_().sum(1)
            if best is None:
                best, best_lin = d2, lin
            else:
                closer = d2 < best
                best = torch.where(closer, d2, best)
                best_lin = torch.where(closer, lin, best_lin)
    cp = torch.gather(planar, 2, best_lin[:, None, :].expand(batch, 3, n)).transpose(1, 2)  # (B, n, 3)
    return ((points - cp) ** 2).sum(-1)


def lookup_distance(closest: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Distance (not squared) to the surface; see :func:`lookup_distance_sq`. Returns (B, n)."""
    return lookup_distance_sq(closest, points).clamp_min(1e-20).sqrt()

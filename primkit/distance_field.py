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
    # continuous index of the point; the 8 surrounding cell centres are floor and floor + 1
    u = (points.detach() + 0.5) * res - 0.5
    base = torch.floor(u).long()
    flat = closest.reshape(batch, res * res * res, 3)
    best = None
    for corner in range(8):
        offset = torch.tensor([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1], device=points.device)
        idx = (base + offset).clamp_(0, res - 1)
        lin = (idx[..., 0] * res + idx[..., 1]) * res + idx[..., 2]  # (B, n)
        cp = torch.gather(flat, 1, lin.unsqueeze(-1).expand(batch, n, 3))
        d2 = ((points - cp) ** 2).sum(-1)
        best = d2 if best is None else torch.minimum(best, d2)
    return best


def lookup_distance(closest: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Distance (not squared) to the surface; see :func:`lookup_distance_sq`. Returns (B, n)."""
    return lookup_distance_sq(closest, points).clamp_min(1e-20).sqrt()

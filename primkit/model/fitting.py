"""The method's losses for given cuboids on given shapes, and per-shape refinement (torch inside).

Two uses at inference time, both on prepared shapes in the canonical frame:

* :func:`fit_losses` scores cuboids against shapes with the training losses (coverage +
  consistency, present parts only). ``--align auto`` uses it to pick the orientation the model
  explains best.
* :func:`refine` runs a few hundred Adam steps on those losses for each shape, starting from the
  network's cuboids (``primkit abstract --refine N``). Part indices and existence are kept; only
  the present parts' half-extents (log-parametrised, so they stay positive), rotations (a free
  quaternion, normalised) and translations move. All shapes of a call are refined together as one
  batch.

Inputs and outputs are NumPy (:class:`primkit.primitives.Cuboids`); torch stays in here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from .losses import coverage_loss, surface_consistency

__all__ = ["FitLosses", "Refined", "fit_losses", "refine"]


@dataclass(frozen=True, eq=False)
class FitLosses:
    """The losses of :func:`fit_losses`, one value per shape.

    Attributes
    ----------
    coverage, consistency : (n,) float
    total : (n,) float
        ``coverage + consistency``.
    """

    coverage: np.ndarray
    consistency: np.ndarray
    total: np.ndarray


@dataclass(frozen=True, eq=False)
class Refined:
    """What :func:`refine` returns.

    Attributes
    ----------
    cuboids : list of primitives.Cuboids
        Same part slots and existence as given; absent parts unchanged.
    loss_before, loss_after : (n,) float
        Total losses (:attr:`FitLosses.total`) of the given and of the refined cuboids.
    """

    cuboids: list
    loss_before: np.ndarray
    loss_after: np.ndarray


def _stack(cuboids, shapes, points: int, generator: torch.Generator):
    if len(cuboids) != len(shapes):
        raise ValueError(f"{len(cuboids)} cuboid sets for {len(shapes)} shapes")
    m = {c.count for c in cuboids}
    if len(m) != 1:
        raise ValueError("every cuboid set must have the same number of part slots")
    z = torch.tensor(np.stack([c.half_extents for c in cuboids]), dtype=torch.float32)
    q = torch.tensor(np.stack([c.quaternions for c in cuboids]), dtype=torch.float32)
    t = torch.tensor(np.stack([c.translations for c in cuboids]), dtype=torch.float32)
    present = torch.tensor(np.stack([c.existence for c in cuboids]), dtype=torch.float32)
    closest = torch.from_numpy(np.stack([np.asarray(s.closest, np.float32) for s in shapes]))
    n = min(len(s.points) for s in shapes)
    pts = torch.from_numpy(np.stack([np.asarray(s.points[:n], np.float32) for s in shapes]))
    if points and points < n:
        pick = torch.randint(0, n, (len(shapes), points), generator=generator)
        pts = torch.gather(pts, 1, pick.unsqueeze(-1).expand(-1, -1, 3))
    return z, q, t, present, closest, pts


def _losses(z, q, t, present, closest, pts, samples_per_cuboid, generator):
    cov = coverage_loss(pts, z, q, t, present)
    cons = (surface_consistency(closest, z, q, t, samples_per_cuboid, generator) * present).sum(dim=1)
    return cov, cons


def fit_losses(cuboids, shapes, *, samples_per_cuboid: int = 300, points: int = 4000, seed: int = 0) -> FitLosses:
    """Coverage and consistency losses of cuboids on shapes (canonical frame, present parts only).

    Parameters
    ----------
    cuboids : list of primitives.Cuboids
        One set per shape, all with the same number of part slots.
    shapes : list of primkit.data.PreparedShape
    samples_per_cuboid, points : int
        Samples on each cuboid's surface and surface points of each shape (a fixed random subset,
        the same for every cuboid set given the seed).

    Returns
    -------
    FitLosses: ``(n,) float`` arrays ``coverage``, ``consistency`` and ``total`` (their sum).
    """
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        z, q, t, present, closest, pts = _stack(cuboids, shapes, points, g)
        cov, cons = _losses(z, q, t, present, closest, pts, samples_per_cuboid, g)
    cov, cons = cov.double().numpy(), cons.double().numpy()
    return FitLosses(cov, cons, cov + cons)


def refine(
    cuboids,
    shapes,
    steps: int = 300,
    *,
    learning_rate: float = 0.01,
    samples_per_cuboid: int = 150,
    points: int = 1000,
    seed: int = 0,
    device: str = "cpu",
) -> Refined:
    """Refine each shape's cuboids by gradient descent on its own coverage + consistency losses.

    Parameters
    ----------
    cuboids : list of primitives.Cuboids
        Starting cuboids in the canonical frame (the network's answer), one set per shape.
    shapes : list of primkit.data.PreparedShape
    steps : int
        Adam steps (``0`` returns the input).
    learning_rate : float
        Adam's step size, for log half-extents, quaternion components and translations alike.
    samples_per_cuboid, points : int
        Fresh samples on each cuboid and fresh surface points of each shape at every step.

    Returns
    -------
    Refined: the refined cuboids (same part slots and existence; absent parts unchanged) and the
    total losses of :func:`fit_losses` before and after.
    """
    cuboids = list(cuboids)
    shapes = list(shapes)
    before = fit_losses(cuboids, shapes, seed=seed).total
    if steps <= 0 or not cuboids:
        return Refined(cuboids, before, before)
    g = torch.Generator().manual_seed(seed)
    z, q, t, present, closest, all_pts = _stack(cuboids, shapes, 0, g)
    log_z = torch.log(z.clamp_min(1e-4)).to(device).requires_grad_(True)
    q = q.to(device).requires_grad_(True)
    t = t.to(device).requires_grad_(True)
    present, closest, all_pts = present.to(device), closest.to(device), all_pts.to(device)
    opt = torch.optim.Adam([log_z, q, t], lr=learning_rate)
    n = all_pts.shape[1]
    with torch.enable_grad():
        for _ in range(int(steps)):
            pick = torch.randint(0, n, (len(shapes), min(points, n)), generator=g).to(device)
            pts = torch.gather(all_pts, 1, pick.unsqueeze(-1).expand(-1, -1, 3))
            qn = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-8)
            cov, cons = _losses(log_z.exp(), qn, t, present, closest, pts, samples_per_cuboid, g)
            loss = (cov + cons).sum()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
    with torch.no_grad():
        z_new = log_z.exp().double().cpu().numpy()
        q_new = (q / q.norm(dim=-1, keepdim=True)).double().cpu().numpy()
        t_new = t.double().cpu().numpy()
    refined = []
    for i, c in enumerate(cuboids):
        keep = ~np.asarray(c.existence, bool)  # absent parts stay exactly as predicted
        refined.append(replace(
            c,
            half_extents=np.where(keep[:, None], c.half_extents, z_new[i]),
            quaternions=np.where(keep[:, None], c.quaternions, q_new[i]),
            translations=np.where(keep[:, None], c.translations, t_new[i]),
        ))
    after = fit_losses(refined, shapes, seed=seed).total
    return Refined(refined, before, after)

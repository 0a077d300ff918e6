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

from ._compiled import kernels
from .losses import coverage_loss, surface_consistency

__all__ = ["FitLosses", "Refined", "fit_losses", "fit_losses_of_sets", "refine"]


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


def _coefficients(seed: int, sets: int, m: int, samples: int, draws: dict | None) -> torch.Tensor:
    """The cuboid surface coefficients :func:`fit_losses` draws for ``sets`` cuboid sets of ``m``
    parts (:func:`primkit.primitives.surface_coefficients_torch` on a generator seeded ``seed``),
    read from ``draws`` when as many sets or more were drawn before (torch's CPU generator fills
    a tensor in order, so a smaller draw is the first rows of a larger one; tested), else drawn
    and kept there."""
    key = (int(seed), int(m), int(samples))
    if draws is not None and key in draws and len(draws[key]) >= sets:
        return draws[key][:sets]
    g = torch.Generator().manual_seed(int(seed))
    uv = 2.0 * torch.rand((sets, m, samples, 2), generator=g, dtype=torch.float32) - 1.0
    if draws is not None:
        draws[key] = uv
    return uv


def _present_first(present: np.ndarray) -> np.ndarray:
    """(rows, p) column indices: each row's present parts first, in order, then its absent ones,
    cut at the most present parts of any row (all columns when a row has none present)."""
    order = np.argsort(~present, axis=1, kind="stable")
    count = present.sum(axis=1)
    return order if count.min() == 0 else order[:, : max(int(count.max()), 1)]


def _present_losses(z, q, t, present, closest, pts, uv, s: int, k: int):
    """Coverage and consistency of :func:`fit_losses_of_sets` by the compiled kernels, on the
    present parts only. The kernels' per-part and per-point arithmetic is that of
    :func:`primkit.model.losses.coverage_loss` and :func:`~primkit.model.losses.surface_consistency`
    (the rotations and ``R^T t`` are formed by the same torch calls on all parts, then the present
    ones gathered), so the losses are the same bit for bit: an absent part never wins a point
    (its absence term, 100, exceeds any distance in the unit cube; a set with no present part is
    scored on all its parts, as the torch form does) and adds ``0 * value`` to the consistency sum.
    Measured: half the parts of the chair model's 24 turns are absent."""
    from ..primitives import quaternion_to_matrix_torch
    from ._compiled import kernels
    from .losses import ABSENT_PENALTY

    union_kernels, field_kernels = kernels("_union_kernels", z), kernels("_field_kernels", z)

    sk, m = present.shape
    rot = quaternion_to_matrix_torch(q)  # (s k, m, 3, 3)
    offset = (rot.transpose(-1, -2) @ t[..., None])[..., 0]  # R^T t, as losses._union_distance_sq forms it
    absent = (1.0 - present) * ABSENT_PENALTY
    rot, offset, z, t = rot.numpy(), offset.numpy(), z.numpy(), t.numpy()
    mask = present.numpy() > 0.5
    cols = _present_first(mask)
    rows = np.arange(sk)[:, None]
    points = np.ascontiguousarray(np.repeat(pts.numpy(), k, axis=0))
    pick = (rows, cols)
    union, _, _ = union_kernels.union_forward(
        np.ascontiguousarray(rot[pick]), np.ascontiguousarray(offset[pick]), np.ascontiguousarray(z[pick]),
        np.ascontiguousarray(absent.numpy()[pick]), np.ascontiguousarray(mask[pick].astype(np.float32)), points,
        False, ABSENT_PENALTY)
    cov = torch.from_numpy(union).mean(dim=1)
    # consistency: every set's parts are parts of its shape (one distance grid each), present ones only
    flat = mask.reshape(s, k * m)
    parts = np.argsort(~flat, axis=1, kind="stable")[:, : max(int(flat.sum(axis=1).max()), 1)]
    pick = (np.arange(s)[:, None], parts)
    res = closest.shape[1]
    planar = closest.reshape(s, res ** 3, 3).transpose(1, 2).contiguous().numpy()
    out, _ = field_kernels.consistency_forward(
        np.ascontiguousarray(rot.reshape(s, k * m, 3, 3)[pick]), np.ascontiguousarray(z.reshape(s, k * m, 3)[pick]),
        np.ascontiguousarray(t.reshape(s, k * m, 3)[pick]), np.ascontiguousarray(uv.numpy().reshape(s, k * m, -1, 2)[pick]),
        planar, res)
    per_part = np.zeros((s, k * m), np.float32)
    taken = flat[pick]
    per_part[pick[0].repeat(parts.shape[1], axis=1)[taken], parts[taken]] = out[taken]
    cons = (torch.from_numpy(per_part).reshape(sk, m) * present).sum(dim=1)
    return cov, cons


def fit_losses_of_sets(half_extents, quaternions, translations, existence, shapes, *,
                       samples_per_cuboid: int = 300, seed: int = 0, draws: dict | None = None) -> FitLosses:
    """:func:`fit_losses` of ``k`` cuboid sets on each of ``s`` shapes, from arrays, each shape's
    distance grid read once for all its sets (what ``align`` scores: a shape's 24 turns).

    Parameters
    ----------
    half_extents, quaternions, translations : (s, k, m, 3), (s, k, m, 4), (s, k, m, 3) float
        The sets, in their shape's canonical frame; quaternions unit (real part first), half
        extents > 0, as :class:`primkit.primitives.Cuboids` holds them.
    existence : (s, k, m) bool
    shapes : list of s primkit.data.PreparedShape
        All their surface points are used (the first ``n``, the fewest any of them has).
    samples_per_cuboid, seed : int
        As :func:`fit_losses`.
    draws : dict, optional
        Kept by a caller across calls: the random coefficients already drawn for as many sets or
        more are read from it (they depend on the seed and the sizes only). The frame search
        scores every 16 shapes' turns with the same draw; drawing it each time took a tenth of the
        search.

    Returns
    -------
    FitLosses of ``(s, k)`` arrays: bit for bit what :func:`fit_losses` gives the ``s k`` sets as a
    list (shape-major), each shape repeated ``k`` times, with ``points=0``. The random samples on
    the cuboids are the same (one ``(s k, m, K, 2)`` draw, read as ``(s, k m, K, 2)``: every set's
    parts become parts of its shape for the consistency loss, which is per part), and so is each
    part's arithmetic (``tests/model/test_fitting.py``). ``fit_losses`` would stack ``k`` copies of
    every distance grid: on 16 shapes' 24 turns that copy took longer than the losses.
    """
    z = np.asarray(half_extents, float)
    if z.ndim != 4 or z.shape[-1] != 3:
        raise ValueError("`half_extents` must be (s, k, m, 3) float")
    s, k, m, _ = z.shape
    e = np.asarray(existence)
    if e.shape != (s, k, m) or len(shapes) != s:
        raise ValueError(f"`existence` must be (s, k, m) = {(s, k, m)} and `shapes` hold s = {s} shapes")
    n = min(len(sh.points) for sh in shapes)
    with torch.no_grad():
        zt = torch.tensor(z, dtype=torch.float32).reshape(s * k, m, 3)
        qt = torch.tensor(np.asarray(quaternions, float), dtype=torch.float32).reshape(s * k, m, 4)
        tt = torch.tensor(np.asarray(translations, float), dtype=torch.float32).reshape(s * k, m, 3)
        present = torch.tensor(e.reshape(s * k, m), dtype=torch.float32)
        closest = torch.from_numpy(np.stack([np.asarray(sh.closest, np.float32) for sh in shapes]))
        pts = torch.from_numpy(np.stack([np.asarray(sh.points[:n], np.float32) for sh in shapes]))
        if kernels("_union_kernels", zt) and kernels("_field_kernels", zt):
            uv = _coefficients(seed, s * k, m, int(samples_per_cuboid), draws)
            cov, cons = _present_losses(zt, qt, tt, present, closest, pts, uv, s, k)
        else:  # the torch forms (fit_losses's own calls), on the sets as parts of their shape
            g = torch.Generator().manual_seed(seed)
            cov = coverage_loss(pts.repeat_interleave(k, dim=0), zt, qt, tt, present)
            per_part = surface_consistency(closest, zt.reshape(s, k * m, 3), qt.reshape(s, k * m, 4),
                                           tt.reshape(s, k * m, 3), samples_per_cuboid, g).reshape(s * k, m)
            cons = (per_part * present).sum(dim=1)
    cov, cons = cov.double().numpy().reshape(s, k), cons.double().numpy().reshape(s, k)
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

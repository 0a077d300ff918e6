"""The method's losses (torch): coverage, consistency, reflection symmetry, and REINFORCE for existence.

Notation: ``B`` shapes in a batch, ``m`` part slots, ``n`` surface points per shape, ``k`` samples
per cuboid. ``present`` is the sampled existence ``z_e`` of each part, a ``(B, m)`` float tensor of
0s and 1s (all ones in stage 1).

* **Coverage** (shape inside the union of parts): for each surface point of the shape, the squared
  distance to the union of present cuboids, which is the minimum over present cuboids of
  ``|| max(|R^T (x - t)| - z, 0) ||^2``; averaged over the shape's points.
* **Consistency** (parts inside the shape): for each present cuboid, ``k`` points on its surface
  by reparametrisation (equal samples per face, importance weight = face area), the squared distance
  of each to the shape's surface looked up in the shape's closest-point grid
  (:mod:`primkit.model.distance_field`); the area-weighted mean over each part's surface, summed over
  present parts (the paper's sum over primitives of an expectation over each primitive's surface).
* **Symmetry** (optional): the union of present cuboids should be mirror-symmetric about the plane
  Z = 0 of the canonical frame (left-right, with +Y up and +X front): surface samples of each part,
  mirrored, are pulled onto the union (area-weighted mean of their squared union distance).
* **REINFORCE**: the existence choices are discrete, so their probabilities get the score-function
  gradient ``(cost - baseline) * d log P(z_e)``, where the cost of a choice is the shape's total
  loss minus a small parsimony reward for choosing "absent", and the baseline is a moving average
  of the mean loss (:class:`MovingBaseline`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from ._compiled import kernels
from .distance_field import lookup_distance_sq_torch
from ..primitives import (cuboid_distance_sq_torch, quaternion_to_matrix_torch, sample_cuboid_surfaces_torch,
                          surface_coefficients_torch, surface_samples_from_coefficients_torch)

__all__ = [
    "ABSENT_PENALTY",
    "coverage_loss",
    "consistency_loss",
    "symmetry_loss",
    "LossWeights",
    "ShapeLosses",
    "shape_losses",
    "MovingBaseline",
    "reinforce_surrogate",
    "local_existence_surrogate",
    "consistency_per_part",
    "surface_consistency",
    "SlotPlacement",
]

#: squared distance standing in for "no present part" (far beyond anything inside the unit cube)
ABSENT_PENALTY = 1.0e2


def _same_batch(**tensors) -> None:
    """ValueError unless the tensors agree in batch size (and the cuboid ones in part count): the
    compiled kernels index one by the other's sizes and would read past the smaller."""
    sizes = {name: tuple(t.shape) for name, t in tensors.items()}
    batch = {s[0] if len(s) else None for s in sizes.values()}
    parts = {s[1] for name, s in sizes.items() if name in ("half_extents", "quaternions", "translations", "present")
             and len(s) > 1}
    if len(batch) != 1 or len(parts) > 1:
        raise ValueError("tensors differ in batch size or part count: "
                         + ", ".join(f"{name} {s}" for name, s in sizes.items()))


def _union_distance_sq(points, half_extents, quaternions, translations, present, *, toggles: bool = False):
    """(B, n) squared distance of points to the union of present cuboids.

    The nearest present cuboid of each point is found without building a graph (all ``m``
    cuboids, ``(B, n, m)``); the distance is then recomputed with gradients for that cuboid only.
    The minimum's gradient flows to its argument alone, so values and gradients are those of
    ``min over cuboids``, while the backward pass handles ``(B, n)`` terms instead of
    ``(B, n, m)`` (``benchmarks/bench_abstractor.py`` times both).

    With ``toggles`` also returns ``(B, m)``: the mean over the points with part ``j`` present minus
    the same with part ``j`` absent, every other part's choice held (:func:`_toggle_deltas`).

    On the CPU, for points that are data (no gradient), the same in one compiled pass per point
    with the winner's gradient in closed form (:mod:`primkit.model._union_kernels`; values to float
    rounding of this form's, which finds the distances with one batched matrix product).
    """
    _same_batch(points=points, half_extents=half_extents, quaternions=quaternions, translations=translations,
                present=present)
    if kernels("_union_kernels", points, half_extents, quaternions, translations, present, data=(points,)):
        rot = quaternion_to_matrix_torch(quaternions)
        offset = (rot.transpose(-1, -2) @ translations[..., None])[..., 0]  # R^T t, as _nearest_distance_sq
        absent = ((1.0 - present) * ABSENT_PENALTY).detach()
        union, deltas = _UnionDistance.apply(rot, offset, half_extents, absent, present.detach(), points, toggles)
        return (union, deltas) if toggles else union
    return _union_distance_sq_torch(points, half_extents, quaternions, translations, present, toggles=toggles)


def _union_distance_sq_torch(points, half_extents, quaternions, translations, present, *, toggles: bool = False):
    """:func:`_union_distance_sq` in torch (any device; the reference of the compiled form)."""
    with torch.no_grad():
        d2 = cuboid_distance_sq_torch(points.detach(), half_extents.detach(), quaternions.detach(),
                                      translations.detach(), parts_first=True)  # (B, m, n)
        masked = d2 + (1.0 - present)[:, :, None] * ABSENT_PENALTY
        first, nearest = masked.min(dim=1)  # (B, n); min's indices measured faster than argmin here
        deltas = _toggle_deltas(d2, masked, present, first, nearest) if toggles else None
    union = _nearest_distance_sq(points, half_extents, quaternions, translations, present, nearest)
    return (union, deltas) if toggles else union


class _UnionDistance(torch.autograd.Function):
    """:func:`_union_distance_sq` on the CPU: forward and backward by the compiled kernels."""

    @staticmethod
    def forward(ctx, rot, offset, half_extents, absent, present, points, toggles):
        from ._union_kernels import union_forward

        arrays = [x.detach().contiguous().numpy() for x in (rot, offset, half_extents, absent, present, points)]
        union, nearest, deltas = union_forward(*arrays, toggles, ABSENT_PENALTY)
        ctx.arrays, ctx.nearest = (arrays[0], arrays[1], arrays[2], arrays[5]), nearest
        deltas = torch.from_numpy(deltas)
        ctx.mark_non_differentiable(deltas)
        return torch.from_numpy(union), deltas

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_union, grad_deltas):
        from ._union_kernels import union_backward

        grads = union_backward(*ctx.arrays, ctx.nearest, grad_union.contiguous().numpy())
        return (*(torch.from_numpy(g) for g in grads), None, None, None, None)


def _toggle_deltas(d2, masked, present, d1, k1):
    """(B, m) mean union distance with part ``j`` present minus with part ``j`` absent, others held.

    ``d2`` (B, m, n) distances to every cuboid, ``masked`` the same with absent parts pushed to
    ``ABSENT_PENALTY``, ``d1`` and ``k1`` (B, n) the nearest present distance of each point and its part.
    With ``d1'`` the second-nearest present distance: removing a present part ``j`` changes the
    point's distance by ``d1' - d1`` where ``k1 = j`` (else 0); adding an absent part ``j`` by
    ``min(d_j - d1, 0)``. The second-nearest is the minimum once the nearest is set aside (one
    more minimum over the parts, without its index: measured 4x faster than ``topk(2)``).
    """
    b, m, n = d2.shape
    if m > 1:
        second = masked.scatter(1, k1[:, None, :], float("inf")).amin(dim=1)
    else:
        second = torch.full_like(d1, ABSENT_PENALTY)
    removal = torch.zeros(b, m, dtype=d2.dtype, device=d2.device)
    removal.scatter_add_(1, k1, second - d1)
    addition = (d2 - d1[:, None, :]).clamp_max_(0.0).sum(-1)
    return torch.where(present > 0.5, -removal, addition) / n


def _nearest_distance_sq(points, half_extents, quaternions, translations, present, nearest):
    """(B, n) squared distance of each point to its cuboid ``nearest`` (B, n), plus ``ABSENT_PENALTY``
    where that cuboid is absent; differentiable in the cuboids and the points.

    Each cuboid's ``R`` (9), ``R^T t`` (3), half-extents (3) and absence term (1) are laid out as
    16 rows of a ``(B, 16, m)`` table and gathered for every point in one call, then the local
    coordinates ``R^T x - R^T t`` are formed coordinate by coordinate on ``(B, n)`` rows: one
    gather (and one scatter in the backward pass) instead of three, and no ``(B, n, 3, 3)``
    matrices (measured 2x faster than gathering the matrices and an einsum).
    """
    b, n = nearest.shape
    m = half_extents.shape[1]
    rot = quaternion_to_matrix_torch(quaternions)  # (B, m, 3, 3)
    offset = (rot.transpose(-1, -2) @ translations[..., None])[..., 0]  # R^T t, (B, m, 3)
    absent = ((1.0 - present) * ABSENT_PENALTY)[..., None]
    table = torch.cat([rot.reshape(b, m, 9), offset, half_extents, absent], dim=-1)  # (B, m, 16)
    # unbind, not 16 slices: each slice's backward would add a (B, 16, n) gradient of zeros
    rows = torch.gather(table.transpose(1, 2), 2, nearest[:, None, :].expand(b, 16, n)).unbind(1)  # 16 x (B, n)
    x, y, z = points.transpose(1, 2).unbind(1)  # (B, n) each
    total = rows[15]
    for i in range(3):  # local_i = sum_j R[j, i] x_j - (R^T t)_i, R row-major in rows 0..8
        local = rows[i] * x + rows[3 + i] * y + rows[6 + i] * z - rows[9 + i]
        total = total + (local.abs() - rows[12 + i]).clamp_min(0.0).square()
    return total


def coverage_loss(points, half_extents, quaternions, translations, present) -> torch.Tensor:
    """Mean squared distance of each shape's surface points to the union of its present cuboids.

    Parameters
    ----------
    points : (B, n, 3) tensor
    half_extents, quaternions, translations : (B, m, 3), (B, m, 4), (B, m, 3) tensors
    present : (B, m) tensor of 0/1

    Returns
    -------
    (B,) tensor
    """
    return _union_distance_sq(points, half_extents, quaternions, translations, present).mean(dim=1)


def _weighted_part_means(values, weights):
    """(B, m, k) values and weights -> (B, m) weighted means over k."""
    return (values * weights).sum(-1) / weights.sum(-1).clamp_min(1e-12)


def consistency_loss(closest, samples, weights, present) -> torch.Tensor:
    """Sum over present parts of the area-weighted mean squared distance of the part's surface to the shape.

    Parameters
    ----------
    closest : (B, R, R, R, 3) tensor
        Each shape's closest-point grid.
    samples : (B, m, k, 3) tensor
        Points on each cuboid's surface (:func:`primkit.primitives.sample_cuboid_surfaces_torch`).
    weights : (B, m, k) tensor
        Their importance weights (face areas).
    present : (B, m) tensor of 0/1

    Returns
    -------
    (B,) tensor
    """
    return (consistency_per_part(closest, samples, weights) * present).sum(dim=1)


def consistency_per_part(closest, samples, weights) -> torch.Tensor:
    """(B, m) area-weighted mean squared distance of each cuboid's surface to the shape, present
    or not (:func:`consistency_loss` sums the present ones)."""
    batch, m, k, _ = samples.shape
    d2 = lookup_distance_sq_torch(closest, samples.reshape(batch, m * k, 3)).reshape(batch, m, k)
    return _weighted_part_means(d2, weights)


def surface_consistency(closest, half_extents, quaternions, translations, samples_per_cuboid: int = 150,
                        generator: torch.Generator | None = None) -> torch.Tensor:
    """(B, m) :func:`consistency_per_part` of fresh surface samples of every cuboid, present or not.

    The samples' face coefficients come from ``generator`` as :func:`sample_cuboid_surfaces_torch` draws
    them, so this is ``consistency_per_part(closest, *sample_cuboid_surfaces_torch(...))``. On the CPU the
    samples, their lookup and the gradient are one compiled pass per part
    (:mod:`primkit.model._field_kernels`: the same sample points and winning cells, the gradient in
    closed form; the weighted sums in another order, so values agree to float rounding, 2e-6
    relative in float32): 9-11 ms against 15-20 for the torch form with its gradient on the
    training batch (``benchmarks/bench_abstractor.py``, section 2b). Elsewhere, and where Numba
    is missing, the torch form.

    Parameters
    ----------
    closest : (B, R, R, R, 3) tensor
    half_extents, quaternions, translations : (B, m, 3), (B, m, 4), (B, m, 3) tensors
    """
    _same_batch(closest=closest, half_extents=half_extents, quaternions=quaternions, translations=translations)
    uv = surface_coefficients_torch(half_extents, quaternions, translations, samples_per_cuboid, generator)
    if not kernels("_field_kernels", closest, half_extents, quaternions, translations, data=(closest,)):
        samples, weights = surface_samples_from_coefficients_torch(half_extents, quaternions, translations, uv)
        return consistency_per_part(closest, samples, weights)
    b, res = closest.shape[0], closest.shape[1]
    planar = closest.reshape(b, res ** 3, 3).transpose(1, 2).contiguous()
    rot = quaternion_to_matrix_torch(quaternions)
    return _SurfaceConsistency.apply(rot, half_extents.contiguous(), translations.contiguous(), uv.contiguous(),
                                     planar, res)


class _SurfaceConsistency(torch.autograd.Function):
    """:func:`surface_consistency` on the CPU: forward and backward by the compiled kernels."""

    @staticmethod
    def forward(ctx, rot, half_extents, translations, uv, planar, resolution):
        from ._field_kernels import consistency_forward

        arrays = [x.detach().contiguous().numpy() for x in (rot, half_extents, translations, uv, planar)]
        out, winners = consistency_forward(*arrays, resolution)
        ctx.arrays, ctx.winners = arrays[:4], winners
        return torch.from_numpy(out)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out):
        from ._field_kernels import consistency_backward

        grads = consistency_backward(*ctx.arrays, ctx.winners, grad_out.contiguous().numpy())
        return (*(torch.from_numpy(g) for g in grads), None, None, None)


def symmetry_loss(samples, weights, half_extents, quaternions, translations, present, axis: int = 2) -> torch.Tensor:
    """Area-weighted mean squared distance of the mirrored part surfaces to the union of parts.

    The mirror plane is ``x[axis] = 0`` (Z by default: left-right in the canonical frame).

    Returns
    -------
    (B,) tensor
    """
    batch, m, k, _ = samples.shape
    mirror = torch.ones(3, dtype=samples.dtype, device=samples.device)
    mirror[axis] = -1.0
    mirrored = (samples * mirror).reshape(batch, m * k, 3)
    d2 = _union_distance_sq(mirrored, half_extents, quaternions, translations, present).reshape(batch, m, k)
    per_part = _weighted_part_means(d2, weights)
    return (per_part * present).sum(1) / present.sum(1).clamp_min(1.0)


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms; ``symmetry=0`` turns the symmetry loss off."""

    coverage: float = 1.0
    consistency: float = 1.0
    symmetry: float = 0.0


@dataclass
class ShapeLosses:
    """Per-shape loss terms, each (B,)."""

    coverage: torch.Tensor
    consistency: torch.Tensor
    symmetry: torch.Tensor
    total: torch.Tensor
    #: (B, m) or None: ``total`` with part ``j`` present minus ``total`` with it absent, every other
    #: part's choice held (coverage and consistency terms; asked for with ``presence_effects``)
    presence_effect: torch.Tensor | None = None


def shape_losses(
    prediction,
    present,
    points,
    closest,
    weights: LossWeights = LossWeights(),
    samples_per_cuboid: int = 150,
    generator: torch.Generator | None = None,
    presence_effects: bool = False,
) -> ShapeLosses:
    """All loss terms for a batch, per shape.

    Parameters
    ----------
    prediction : primkit.model.network.PrimitivePrediction
    present : (B, m) tensor of 0/1
    points : (B, n, 3) tensor
        Surface points of each shape.
    closest : (B, R, R, R, 3) tensor
    presence_effects : bool
        Also compute ``presence_effect`` (no gradient), for :func:`local_existence_surrogate`.
    """
    z, q, t = prediction.half_extents, prediction.quaternions, prediction.translations
    if weights.symmetry:  # the symmetry term reads the samples themselves
        samples, w = sample_cuboid_surfaces_torch(z, q, t, samples_per_cuboid, generator=generator)
        per_part = consistency_per_part(closest, samples, w)
    else:
        per_part = surface_consistency(closest, z, q, t, samples_per_cuboid, generator)
    cons = (per_part * present).sum(dim=1)
    effect = None
    if presence_effects:
        union, cov_effect = _union_distance_sq(points, z, q, t, present, toggles=True)
        cov = union.mean(dim=1)
        effect = weights.coverage * cov_effect + weights.consistency * per_part.detach()
    else:
        cov = coverage_loss(points, z, q, t, present)
    if weights.symmetry:
        sym = symmetry_loss(samples, w, z, q, t, present)
    else:
        sym = torch.zeros_like(cov)
    total = weights.coverage * cov + weights.consistency * cons + weights.symmetry * sym
    return ShapeLosses(cov, cons, sym, total, effect)


class SlotPlacement:
    """Where each part slot usually sits: a moving average of the mean centre of every slot over
    the shapes it is present in, and the cost of a part being away from it.

    ``cost = sum_j present_j * ||t_j - mean_j||^2`` per shape (the means treated as constants).
    Added to the losses with a small weight, it makes the choice of *which* slot explains a
    region prefer the slot that usually sits there: without it, a slot whose usual part is absent
    from a shape (a chair's front leg on a sofa) is free to move to another part (the sofa's arm)
    and takes that part's place, so the index no longer means one part. With ``present`` the
    sampled choices, it enters the presence effect of each part as well.
    """

    def __init__(self, momentum: float = 0.99):
        self.momentum = momentum
        self.means: torch.Tensor | None = None  # (m, 3)
        self.seen: torch.Tensor | None = None  # (m,) bool: a slot with a mean yet

    def update(self, translations, present) -> None:
        """Fold a batch in: ``translations`` (B, m, 3), ``present`` (B, m) of 0/1."""
        with torch.no_grad():
            t = translations.detach().double()
            w = present.detach().double()
            count = w.sum(0)  # (m,)
            batch = (w[..., None] * t).sum(0) / count.clamp_min(1.0)[:, None]
            has = count > 0
            if self.means is None:
                self.means = torch.zeros_like(batch)
                self.seen = torch.zeros_like(has)
            first = has & ~self.seen
            old = has & self.seen
            self.means[first] = batch[first]
            self.means[old] = self.momentum * self.means[old] + (1.0 - self.momentum) * batch[old]
            self.seen |= has

    def costs(self, translations) -> torch.Tensor:
        """(B, m) squared distance of each slot's centre from its usual place (0 for unseen slots)."""
        if self.means is None:
            return torch.zeros(translations.shape[:2], dtype=translations.dtype, device=translations.device)
        means = self.means.to(device=translations.device, dtype=translations.dtype)
        d2 = (translations - means).square().sum(-1)
        return d2 * self.seen.to(device=translations.device, dtype=translations.dtype)

    def state_dict(self) -> dict:
        return {"momentum": self.momentum,
                "means": None if self.means is None else self.means.tolist(),
                "seen": None if self.seen is None else self.seen.tolist()}

    def load_state_dict(self, d: dict) -> None:
        self.momentum = float(d["momentum"])
        self.means = None if d["means"] is None else torch.tensor(d["means"], dtype=torch.float64)
        self.seen = None if d["seen"] is None else torch.tensor(d["seen"], dtype=torch.bool)


class MovingBaseline:
    """Moving average of the mean loss, the REINFORCE baseline: ``b <- momentum * b + (1 - momentum) * mean``.

    The first update sets ``b`` to the mean itself.
    """

    def __init__(self, momentum: float = 0.9):
        self.momentum = momentum
        self.value: float | None = None

    def update(self, mean_loss: float) -> float:
        if self.value is None:
            self.value = float(mean_loss)
        else:
            self.value = self.momentum * self.value + (1.0 - self.momentum) * float(mean_loss)
        return self.value

    def state_dict(self) -> dict:
        return {"momentum": self.momentum, "value": self.value}

    def load_state_dict(self, d: dict) -> None:
        self.momentum = float(d["momentum"])
        self.value = None if d["value"] is None else float(d["value"])


def reinforce_surrogate(logits, present, loss, baseline: float, parsimony: float) -> torch.Tensor:
    """Surrogate whose gradient is the REINFORCE estimate for the existence probabilities.

    ``d/dtheta E[cost] = E[(cost - baseline) * d/dtheta log P(z)]``, with the cost of part ``j`` of
    shape ``b`` being ``loss[b] - parsimony * (1 - z[b, j])`` (a reward for choosing "absent").
    A positive advantage (costlier than usual) lowers the probability of the choices made.

    Parameters
    ----------
    logits : (B, m) tensor
        Existence logits (``p = sigmoid(logits)``); using them keeps ``log p`` accurate near 1.
    present : (B, m) tensor of 0/1
        The sampled choices.
    loss : (B,) tensor
        Each shape's total loss (treated as a constant).
    """
    log_p = present * F.logsigmoid(logits) + (1.0 - present) * F.logsigmoid(-logits)
    cost = loss.detach()[:, None] - parsimony * (1.0 - present)
    advantage = (cost - baseline).detach()
    return (advantage * log_p).sum(dim=1).mean()


def local_existence_surrogate(logits, presence_effect, parsimony: float) -> torch.Tensor:
    """Surrogate whose gradient is the local-expectation estimate for the existence probabilities.

    The expected cost ``E_z[loss(z) - parsimony * #absent]`` has, for part ``j``, the exact
    derivative ``d/dp_j = E_{z_-j}[loss(z_j = 1) - loss(z_j = 0)] + parsimony``: REINFORCE's
    score-function estimate with the expectation over ``z_j`` itself taken in closed form
    (Titsias & Lazaro-Gredilla 2015, "local expectation gradients"). The effect of one part's
    choice on the coverage and consistency terms is cheap to compute exactly with the other
    choices held (``ShapeLosses.presence_effect``), so each part is credited with its own effect
    instead of the whole shape's loss, which in REINFORCE drowns a parsimony reward of the size of
    the losses in the noise of the other parts' choices. Same objective, far lower variance.

    Parameters
    ----------
    logits : (B, m) tensor
        Existence logits (``p = sigmoid(logits)``).
    presence_effect : (B, m) tensor
        ``loss(z_j = 1) - loss(z_j = 0)`` per part, other choices as sampled (treated as a constant).
    """
    advantage = (presence_effect + parsimony).detach()
    return (advantage * torch.sigmoid(logits)).sum(dim=1).mean()

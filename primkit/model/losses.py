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

from .distance_field import lookup_distance_sq
from ..primitives import cuboid_distance_sq_torch, quaternion_to_matrix_torch, sample_surface_torch

__all__ = [
    "coverage_loss",
    "consistency_loss",
    "symmetry_loss",
    "LossWeights",
    "ShapeLosses",
    "shape_losses",
    "MovingBaseline",
    "reinforce_surrogate",
]

#: squared distance standing in for "no present part" (far beyond anything inside the unit cube)
_ABSENT = 1.0e2


def _union_distance_sq(points, half_extents, quaternions, translations, present):
    """(B, n) squared distance of points to the union of present cuboids.

    The nearest present cuboid of each point is found without building a graph (all ``m``
    cuboids, ``(B, n, m)``); the distance is then recomputed with gradients for that cuboid only.
    The minimum's gradient flows to its argument alone, so values and gradients are those of
    ``min over cuboids``, while the backward pass handles ``(B, n)`` terms instead of
    ``(B, n, m)`` (``benchmarks/bench_abstractor.py`` times both).
    """
    with torch.no_grad():
        d2 = cuboid_distance_sq_torch(points.detach(), half_extents.detach(), quaternions.detach(),
                                      translations.detach(), parts_first=True)  # (B, m, n)
        d2 += (1.0 - present)[:, :, None] * _ABSENT
        nearest = d2.min(dim=1).indices  # (B, n); min's indices measured faster than argmin here
    return _nearest_distance_sq(points, half_extents, quaternions, translations, present, nearest)


def _nearest_distance_sq(points, half_extents, quaternions, translations, present, nearest):
    """(B, n) squared distance of each point to its cuboid ``nearest`` (B, n), plus ``_ABSENT``
    where that cuboid is absent; differentiable in the cuboids and the points."""
    b, n = nearest.shape
    rot = quaternion_to_matrix_torch(quaternions).reshape(b, -1, 9)  # (B, m, 9)

    def pick(x):  # (B, m, c) -> (B, n, c)
        return torch.gather(x, 1, nearest[..., None].expand(b, n, x.shape[-1]))

    r = pick(rot).reshape(b, n, 3, 3)
    local = torch.einsum("bnji,bnj->bni", r, points - pick(translations))  # R^T (x - t)
    excess = (local.abs() - pick(half_extents)).clamp_min(0.0)
    return excess.square().sum(-1) + (1.0 - torch.gather(present, 1, nearest)) * _ABSENT


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
        Points on each cuboid's surface (:func:`primkit.primitives.sample_surface_torch`).
    weights : (B, m, k) tensor
        Their importance weights (face areas).
    present : (B, m) tensor of 0/1

    Returns
    -------
    (B,) tensor
    """
    batch, m, k, _ = samples.shape
    d2 = lookup_distance_sq(closest, samples.reshape(batch, m * k, 3)).reshape(batch, m, k)
    return (_weighted_part_means(d2, weights) * present).sum(dim=1)


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


def shape_losses(
    prediction,
    present,
    points,
    closest,
    weights: LossWeights = LossWeights(),
    samples_per_cuboid: int = 150,
    generator: torch.Generator | None = None,
) -> ShapeLosses:
    """All loss terms for a batch, per shape.

    Parameters
    ----------
    prediction : primkit.model.network.PrimitivePrediction
    present : (B, m) tensor of 0/1
    points : (B, n, 3) tensor
        Surface points of each shape.
    closest : (B, R, R, R, 3) tensor
    """
    z, q, t = prediction.half_extents, prediction.quaternions, prediction.translations
    cov = coverage_loss(points, z, q, t, present)
    samples, w = sample_surface_torch(z, q, t, samples_per_cuboid, generator=generator)
    cons = consistency_loss(closest, samples, w, present)
    if weights.symmetry:
        sym = symmetry_loss(samples, w, z, q, t, present)
    else:
        sym = torch.zeros_like(cov)
    total = weights.coverage * cov + weights.consistency * cons + weights.symmetry * sym
    return ShapeLosses(cov, cons, sym, total)


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

"""Distillation: the image network trained to reproduce the volume model's cuboids from pictures
(the loss is written out in :mod:`primkit.image`)."""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from ..model.abstractor import RawCuboids
from ..model.losses import shape_losses
from ..model.network import PrimitivePrediction
from ..model.training import isolated_torch_state
from .backgrounds import composite, training_backgrounds
from .camera import viewpoint_targets
from .network import ImageNet, ImageNetConfig, ImagePrediction, images_to_float

__all__ = ["DistillWeights", "DistillationLoss", "distillation_loss", "rotation_distance", "ImageTrainConfig", "ImageTrainResult",
           "train_image_model"]


def rotation_distance(q: torch.Tensor, q_ref: torch.Tensor) -> torch.Tensor:
    """``1 - |<q, q_ref>|`` for unit quaternions ``(..., 4)``: 0 for the same rotation (q or -q),
    ``1 - cos(theta / 2)`` for rotations ``theta`` apart. Returns ``(...)``."""
    return 1.0 - (q * q_ref).sum(-1).abs().clamp(max=1.0)


@dataclass(frozen=True)
class DistillWeights:
    existence: float = 0.2
    half_extents: float = 1.0
    translations: float = 1.0
    rotation: float = 0.5
    viewpoint: float = 0.05

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class DistillationLoss:
    """The student-teacher loss of a batch (:func:`distillation_loss`).

    Attributes
    ----------
    total : scalar tensor
        The weighted sum of the terms (what is minimised).
    terms : dict name -> scalar tensor
        ``existence``, ``half_extents``, ``translations``, ``rotation``, and ``viewpoint`` when a
        viewpoint target is given (``geometric`` when the training adds it).
    """

    total: torch.Tensor
    terms: dict[str, torch.Tensor]

    def values(self) -> dict[str, float]:
        """``{"total": ..., **terms}`` as floats (a row of the training history)."""
        return {"total": float(self.total.detach()), **{k: float(v.detach()) for k, v in self.terms.items()}}


def distillation_loss(pred: ImagePrediction, teacher: RawCuboids, viewpoint: torch.Tensor | None = None,
                      weights: DistillWeights = DistillWeights()) -> DistillationLoss:
    """The student-teacher loss of a batch (see the module docstring).

    pred : the student's output (:class:`ImageNet`, an :class:`ImagePrediction` of tensors).
    teacher : :class:`~primkit.model.abstractor.RawCuboids` of tensors ``(B, m, ...)`` (existence as
        probabilities).
    viewpoint : (B, 3) target (cos az, sin az, el rad), or None to leave the term out.
    """
    p = teacher.existence
    w = p / p.sum(dim=1, keepdim=True).clamp(min=1e-6)  # (B, m), each row sums to 1
    terms = {
        "existence": F.binary_cross_entropy_with_logits(pred.existence_logits, p),
        "half_extents": ((pred.half_extents - teacher.half_extents).abs().mean(-1) * w).sum(1).mean(),
        "translations": ((pred.translations - teacher.translations).abs().mean(-1) * w).sum(1).mean(),
        "rotation": (rotation_distance(pred.quaternions, teacher.quaternions) * w).sum(1).mean(),
    }
    if viewpoint is not None:
        terms["viewpoint"] = ((pred.viewpoint - viewpoint) ** 2).sum(-1).mean()
    total = sum(getattr(weights, k) * v for k, v in terms.items())
    return DistillationLoss(total, terms)


def _learning_rate(peak: float, progress: float) -> float:
    """Linear warm-up over the first 5% of training, then a cosine decay to zero."""
    if progress < 0.05:
        return peak * (0.1 + 0.9 * progress / 0.05)
    return peak * 0.5 * (1 + math.cos(math.pi * min(1.0, (progress - 0.05) / 0.95)))


@dataclass(frozen=True)
class ImageTrainConfig:
    """Training schedule. ``time_limit_s`` (0: none) stops training after that many seconds and
    runs the learning-rate schedule on whichever of iterations or time is further along (so a
    time-limited run still ends with the rate decayed; it is then not bit-for-bit reproducible).

    ``swap_backgrounds`` (0 to 1): the fraction of each batch whose background is replaced by a
    fresh one from :func:`training_backgrounds` (needs views rendered with foregrounds); the rest
    keep the background they were rendered with.

    ``geometric`` (0: off): weight of the method's coverage + consistency losses of the student's
    cuboids against the shape in the picture (needs the shapes' surface points and closest-point
    grids); ``geometric_points`` surface points per shape and ``geometric_samples`` samples per
    cuboid enter each step."""

    iterations: int = 8000
    batch_size: int = 64
    learning_rate: float = 1e-3
    weight_decay: float = 1e-4
    shift_pixels: int = 4
    seed: int = 0
    log_every: int = 50
    time_limit_s: float = 0.0
    colour_shuffle: bool = False
    swap_backgrounds: float = 0.0
    geometric: float = 0.0
    geometric_points: int = 1000
    geometric_samples: int = 150
    weights: DistillWeights = field(default_factory=DistillWeights)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["weights"] = self.weights.to_dict()
        return d


def _augment(x: torch.Tensor, gen: torch.Generator, shift: int, colour: bool = False) -> torch.Tensor:
    """Random shift (edge-padded) and brightness / contrast jitter of a ``(B, 3, S, S)`` batch;
    with ``colour``, also a random permutation of the colour channels and per-channel gains."""
    b, _, s, _ = x.shape
    if colour:
        perm = torch.argsort(torch.rand(b, 3, generator=gen), dim=1)
        x = torch.gather(x, 1, perm[:, :, None, None].expand_as(x))
        x = x * (0.75 + 0.5 * torch.rand(b, 3, 1, 1, generator=gen))
    if shift:
        padded = F.pad(x, (shift,) * 4, mode="replicate")
        dx = torch.randint(0, 2 * shift + 1, (b,), generator=gen)
        dy = torch.randint(0, 2 * shift + 1, (b,), generator=gen)
        x = torch.stack([padded[i, :, dy[i]: dy[i] + s, dx[i]: dx[i] + s] for i in range(b)])
    gain = 1 + 0.25 * (torch.rand(b, 1, 1, 1, generator=gen) * 2 - 1)
    bias = 0.1 * (torch.rand(b, 1, 1, 1, generator=gen) * 2 - 1)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    return ((x - mean) * gain + mean + bias).clamp(0, 1)


def _geometric_loss(pred: ImagePrediction, used: torch.Tensor, points: torch.Tensor, closest: torch.Tensor,
                    samples_per_cuboid: int, gen: torch.Generator) -> torch.Tensor:
    """Mean over the batch of coverage + consistency (:func:`primkit.model.losses.shape_losses`, the volume
    model's own terms) of the predicted cuboids against the true shapes, the parts in ``used (B, m)
    bool`` present."""
    cuboids = PrimitivePrediction(pred.half_extents, pred.quaternions, pred.translations, used.float())
    return shape_losses(cuboids, used.float(), points, closest, samples_per_cuboid=samples_per_cuboid,
                        generator=gen).total.mean()


@dataclass
class ImageTrainResult:
    network: ImageNet
    history: list
    seconds: float


@isolated_torch_state
def train_image_model(images: np.ndarray, shape_index: np.ndarray, cameras: np.ndarray, teacher,
                      net_config: ImageNetConfig = ImageNetConfig(), config: ImageTrainConfig = ImageTrainConfig(),
                      *, progress: bool = False, network: ImageNet | None = None,
                      foreground: np.ndarray | None = None, alpha: np.ndarray | None = None,
                      surface_points: np.ndarray | None = None, closest: np.ndarray | None = None) -> ImageTrainResult:
    """Train an :class:`ImageNet` to reproduce the teacher on rendered views.

    Parameters
    ----------
    images : (k, S, S, 3) uint8
    shape_index : (k,) int, which teacher row each image shows
    cameras : (k, 4) float, camera arrays (:class:`primkit.image.camera.OrbitCamera`)
    teacher : primkit.model.abstractor.RawCuboids
        The teacher's answer for each shape, :meth:`primkit.model.abstractor.Abstractor.predict_canonical`
    progress : a tqdm bar over the iterations, on stderr (off by default)
    network : continue training this network instead of a new one
    foreground : (k, S, S, 3) uint8, alpha : (k, S, S) uint8, optional
        The views' shapes alone (:class:`primkit.image.views.RenderedViews` rendered with
        ``keep_foreground=True``); needed when ``config.swap_backgrounds > 0``.
    surface_points : (s, n, 3) float, closest : (s, R, R, R, 3) float, optional
        Each teacher row's shape in the canonical frame (:class:`primkit.data.PreparedShape`'s
        ``points`` and ``closest``); needed when ``config.geometric > 0``.
    """
    from tqdm.auto import tqdm

    images = np.asarray(images)
    if images.ndim != 4 or images.shape[1:] != (net_config.size, net_config.size, 3):
        raise ValueError(f"`images` must be (k, {net_config.size}, {net_config.size}, 3) uint8, got {images.shape}")
    torch.manual_seed(config.seed)
    gen = torch.Generator().manual_seed(config.seed)
    net = network if network is not None else ImageNet(net_config)
    net.train()
    opt = torch.optim.AdamW(net.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
    imgs = torch.from_numpy(images)
    swap = float(config.swap_backgrounds)
    if swap > 0:
        if foreground is None or alpha is None:
            raise ValueError("swap_backgrounds needs the views' foreground and alpha (render with keep_foreground=True)")
        fgs, alphas = torch.from_numpy(np.asarray(foreground)), torch.from_numpy(np.asarray(alpha))
        if fgs.shape != imgs.shape or alphas.shape != imgs.shape[:3]:
            raise ValueError(f"foreground {tuple(fgs.shape)} and alpha {tuple(alphas.shape)} do not match the images "
                             f"{tuple(imgs.shape)}")
    idx = torch.from_numpy(np.asarray(shape_index, np.int64))
    teach = RawCuboids(**{k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in teacher.arrays().items()})
    if config.geometric > 0:
        if surface_points is None or closest is None:
            raise ValueError("`geometric` > 0 needs the shapes' surface_points and closest grids")
        pts_all = torch.from_numpy(np.asarray(surface_points, np.float32))
        closest_all = torch.from_numpy(np.asarray(closest, np.float32))
        rows = len(teach.existence)
        if pts_all.dim() != 3 or pts_all.shape[0] != rows or pts_all.shape[-1] != 3:
            raise ValueError(f"`surface_points` must be ({rows}, n, 3), got {tuple(pts_all.shape)}")
        if closest_all.dim() != 5 or closest_all.shape[0] != rows or closest_all.shape[-1] != 3:
            raise ValueError(f"`closest` must be ({rows}, R, R, R, 3), got {tuple(closest_all.shape)}")
    view = torch.from_numpy(viewpoint_targets(np.asarray(cameras, float)).astype(np.float32))
    history, start = [], time.time()
    bar = tqdm(range(config.iterations), desc="distilling", unit="it", disable=not progress)
    running, values, last = None, None, -1
    for it in bar:
        progress_ = it / max(config.iterations, 1)
        if config.time_limit_s:
            progress_ = max(progress_, (time.time() - start) / config.time_limit_s)
            if progress_ >= 1.0:
                break
        for group in opt.param_groups:
            group["lr"] = _learning_rate(config.learning_rate, progress_)
        batch = torch.randint(0, len(imgs), (config.batch_size,), generator=gen)
        x = images_to_float(imgs[batch])
        if swap > 0:
            k = int(round(swap * len(batch)))
            a = alphas[batch[:k]].float()[:, None] / 255.0
            x[:k] = composite(images_to_float(fgs[batch[:k]]), a, training_backgrounds(k, x.shape[-1], gen))
        x = _augment(x, gen, config.shift_pixels, config.colour_shuffle)
        target = teach.rows(idx[batch])
        pred = net(x)
        losses = distillation_loss(pred, target, view[batch], config.weights)
        if config.geometric > 0:
            shapes = idx[batch]
            pick = torch.randint(0, pts_all.shape[1], (len(batch), config.geometric_points), generator=gen)
            points = torch.gather(pts_all[shapes], 1, pick[..., None].expand(-1, -1, 3))
            geo = _geometric_loss(pred, target.existence > 0.5, points, closest_all[shapes],
                                  config.geometric_samples, gen)
            losses = DistillationLoss(losses.total + config.geometric * geo, {**losses.terms, "geometric": geo})
        opt.zero_grad(set_to_none=True)
        losses.total.backward()
        opt.step()
        values, last = losses.values(), it
        running = values if running is None else {k: 0.95 * running[k] + 0.05 * values[k] for k in values}
        if it % config.log_every == 0 or it == config.iterations - 1:
            history.append({"iteration": it, "lr": opt.param_groups[0]["lr"], **values})
            bar.set_postfix(loss=f"{running['total']:.4f}", t=f"{running['translations']:.3f}",
                            z=f"{running['half_extents']:.3f}")
    if values is not None and history[-1]["iteration"] != last:
        history.append({"iteration": last, "lr": opt.param_groups[0]["lr"], **values})
    net.eval()
    return ImageTrainResult(net, history, time.time() - start)

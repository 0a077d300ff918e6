"""Abstraction from a single image, distilled from a volume model (the paper's Section 5.2).

The volume abstractor (:mod:`primkit.network`) reads a 32^3 grid; for a photo there is no grid. So,
as in the paper, an image network is trained to reproduce the volume network's cuboids from a
picture of the same shape: the volume model is the *teacher*, the image network the *student*,
and primitive ``k`` of the student is trained on primitive ``k`` of the teacher, so part indices
keep their meaning (seat, back, ...) across the two models.

Frames: the student predicts in the shape's canonical frame (object-centred: +Y up, front toward
+X, longest side 1), whatever the viewpoint of the picture; it also predicts the viewpoint
(azimuth and elevation of :class:`primkit.views.Camera`), which is what lets
:func:`draw_over_image` project the cuboids back onto the picture.

Network (:class:`ImageNet`; torchvision has no CPU build here and is not needed)::

    (B, 3, S, S) image, S = 64
    5 x [3x3 conv stride 2, batch norm, ReLU], channels 32, 48, 64, 96, 128  -> (B, 128, 2, 2)
    flatten, linear 512 -> 256, ReLU
    heads as the volume network's: half_extents = 0.5 sigmoid, quaternions = normalise,
    translations = 0.5 tanh, existence = sigmoid (logits kept), viewpoint (cos az, sin az, el rad)

About 0.4 M weights (1.6 MB as float32). Batch norm, unlike the volume network's paper encoder,
because backgrounds and lighting move the input statistics a lot.

Distillation loss (:func:`distillation_loss`), per part ``k`` of each image, with the teacher's
existence probability ``p_k`` weighting the shape terms (a part the teacher does not use carries
no shape information)::

    existence   BCE(student logit_k, p_k)
    extents     |z_k - z_k^T|_1 / 3
    translation |t_k - t_k^T|_1 / 3
    rotation    1 - |<q_k, q_k^T>|      (q and -q are one rotation; for unit quaternions this is
                                         1 - cos(theta / 2), theta the angle between the rotations)
    viewpoint   squared error of (cos az, sin az, el)

Optionally (``ImageTrainConfig.geometric > 0``, with each training shape's surface points and
closest-point grid), the student is also held to the shape itself: the method's coverage and
consistency losses (:mod:`primkit.losses`) of its cuboids against the true shape, over the parts
the teacher uses. The teacher's own errors are then no longer a floor for the student's.

The cuboid symmetries (a cuboid turned by 90 degrees with two extents swapped is the same solid)
are not factored out: the teacher is a continuous function of the shape and picks one
representation per part slot consistently, so matching it index by index is well posed.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .. import primitives
from ..model.losses import shape_losses
from ..model.network import PrimitivePrediction

__all__ = [
    "ImageNetConfig",
    "ImageNet",
    "DistillWeights",
    "distillation_loss",
    "rotation_distance",
    "ImageTrainConfig",
    "train_image_model",
    "ImageAbstractor",
    "ImageAbstraction",
    "read_image",
]

KIND = "image-abstractor"


@dataclass(frozen=True)
class ImageNetConfig:
    """The image network's shape: input side, channels of the strided convolutions, FC width, parts."""

    size: int = 64
    channels: tuple = (32, 48, 64, 96, 128)
    fc_width: int = 256
    parts: int = 20
    max_half_extent: float = 0.5

    def __post_init__(self):
        if self.size % (2 ** len(self.channels)):
            raise ValueError(f"`size` ({self.size}) must be divisible by 2^{len(self.channels)}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["channels"] = list(self.channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ImageNetConfig":
        d = dict(d)
        d["channels"] = tuple(d["channels"])
        return cls(**d)


class ImageNet(nn.Module):
    """2D CNN from a ``(B, 3, S, S)`` image (floats in [0, 1]) to ``m`` cuboids and a viewpoint.

    ``forward`` returns a dict of tensors: ``half_extents (B, m, 3)``, ``quaternions (B, m, 4)``,
    ``translations (B, m, 3)``, ``existence (B, m)``, ``existence_logits (B, m)``,
    ``viewpoint (B, 3)`` (cos azimuth, sin azimuth, elevation in radians).
    """

    def __init__(self, config: ImageNetConfig = ImageNetConfig()):
        super().__init__()
        self.config = config
        layers, c_in = [], 3
        for c_out in config.channels:
            layers += [nn.Conv2d(c_in, c_out, 3, stride=2, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU()]
            c_in = c_out
        side = config.size // 2 ** len(config.channels)
        layers += [nn.Flatten(), nn.Linear(c_in * side * side, config.fc_width), nn.ReLU()]
        self.encoder = nn.Sequential(*layers)
        m, w = config.parts, config.fc_width
        self.half_extent_head = nn.Linear(w, m * 3)
        self.quaternion_head = nn.Linear(w, m * 4)
        self.translation_head = nn.Linear(w, m * 3)
        self.existence_head = nn.Linear(w, m)
        self.viewpoint_head = nn.Linear(w, 3)
        with torch.no_grad():  # start as the volume network does: small cubes near identity rotation
            self.half_extent_head.bias.fill_(math.log(0.05 / (config.max_half_extent - 0.05)))
            self.quaternion_head.bias.view(m, 4).copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]))
            self.quaternion_head.weight.mul_(0.1)

    def forward(self, images: torch.Tensor) -> dict:
        x = (images - 0.5) / 0.25
        h = self.encoder(x)
        m = self.config.parts
        logits = self.existence_head(h)
        return {
            "half_extents": self.config.max_half_extent * torch.sigmoid(self.half_extent_head(h).unflatten(1, (m, 3))),
            "quaternions": F.normalize(self.quaternion_head(h).unflatten(1, (m, 4)), dim=-1, eps=1e-12),
            "translations": 0.5 * torch.tanh(self.translation_head(h).unflatten(1, (m, 3))),
            "existence": torch.sigmoid(logits),
            "existence_logits": logits,
            "viewpoint": self.viewpoint_head(h),
        }


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


def distillation_loss(pred: dict, teacher: dict, viewpoint: torch.Tensor | None = None,
                      weights: DistillWeights = DistillWeights()) -> dict:
    """The student-teacher loss of a batch (see the module docstring).

    pred : the student's output (:class:`ImageNet`).
    teacher : tensors ``half_extents (B, m, 3)``, ``quaternions (B, m, 4)``, ``translations (B, m, 3)``,
        ``existence (B, m)`` (probabilities).
    viewpoint : (B, 3) target (cos az, sin az, el rad), or None to leave the term out.
    Returns a dict of scalar tensors, ``"total"`` and one per term.
    """
    p = teacher["existence"]
    w = p / p.sum(dim=1, keepdim=True).clamp(min=1e-6)  # (B, m), each row sums to 1
    terms = {
        "existence": F.binary_cross_entropy_with_logits(pred["existence_logits"], p),
        "half_extents": ((pred["half_extents"] - teacher["half_extents"]).abs().mean(-1) * w).sum(1).mean(),
        "translations": ((pred["translations"] - teacher["translations"]).abs().mean(-1) * w).sum(1).mean(),
        "rotation": (rotation_distance(pred["quaternions"], teacher["quaternions"]) * w).sum(1).mean(),
    }
    if viewpoint is not None:
        terms["viewpoint"] = ((pred["viewpoint"] - viewpoint) ** 2).sum(-1).mean()
    total = sum(getattr(weights, k) * v for k, v in terms.items())
    return {"total": total, **terms}


def viewpoint_targets(cameras: np.ndarray) -> np.ndarray:
    """``(k, 3) float``: (cos az, sin az, el in radians) from ``(k, 4)`` camera arrays."""
    az, el = np.radians(cameras[:, 0]), np.radians(cameras[:, 1])
    return np.stack([np.cos(az), np.sin(az), el], axis=1)


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


def _hsv_to_rgb(h: torch.Tensor, s: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``(..., 3)`` RGB from hue, saturation, value tensors of the same shape, all in [0, 1]."""
    k = torch.stack([(5 + h * 6) % 6, (3 + h * 6) % 6, (1 + h * 6) % 6], dim=-1)
    return v[..., None] - v[..., None] * s[..., None] * torch.clamp(torch.minimum(k, 4 - k), 0, 1)


def _stretch(w: torch.Tensor) -> torch.Tensor:
    """Each ``(S, S)`` map of a ``(B, S, S)`` batch rescaled to span [0, 1]."""
    lo, hi = w.amin(dim=(1, 2), keepdim=True), w.amax(dim=(1, 2), keepdim=True)
    return (w - lo) / (hi - lo).clamp(min=1e-9)


def training_backgrounds(count: int, size: int, gen: torch.Generator, hues=None) -> torch.Tensor:
    """Fresh random backgrounds ``(count, 3, size, size)`` in [0, 1] for background swapping.

    The kinds and colours of the training palette (:func:`primkit.views.random_background` with
    ``palette="seen"``: solid colours, linear gradients, smooth noise of 2-5 cells, hues in
    ``views.PALETTE_HUES["seen"]``), plus two kinds of clutter the palette lacks, in seen colours
    over a gradient: a few large soft-edged discs, or many small ones (confetti: fine detail
    without the regular pattern of stripes or checkers). None of the held-out palette's kinds
    (radial gradients, stripes, checkers, fine noise) or hues is drawn here. Drawn in torch, a
    batch at a time, so that every training step sees new backgrounds at no rendering cost.
    """
    from .views import PALETTE_HUES

    lo, hi = hues if hues is not None else PALETTE_HUES["seen"]

    def colours(n):
        r = torch.rand(n, 3, generator=gen)
        return _hsv_to_rgb(lo + (hi - lo) * r[:, 0], 0.2 + 0.7 * r[:, 1], 0.25 + 0.75 * r[:, 2])  # (n, 3)

    a, b = colours(count), colours(count)
    axis = torch.linspace(0, 1, size)
    yy, xx = torch.meshgrid(axis, axis, indexing="ij")
    kind = torch.randint(0, 5, (count,), generator=gen)  # solid, gradient, noise, discs, confetti
    theta = 2 * math.pi * torch.rand(count, generator=gen)
    w = _stretch(torch.cos(theta)[:, None, None] * xx + torch.sin(theta)[:, None, None] * yy)
    cells = int(torch.randint(2, 6, (1,), generator=gen))
    noise = _stretch(F.interpolate(torch.rand(count, 1, cells + 1, cells + 1, generator=gen), size=(size, size),
                                   mode="bilinear", align_corners=True)[:, 0])
    w = torch.where((kind == 0)[:, None, None], torch.zeros_like(w), w)
    w = torch.where((kind == 2)[:, None, None], noise, w)
    bg = a[:, :, None, None] * (1 - w[:, None]) + b[:, :, None, None] * w[:, None]
    for which, discs, radii in ((3, (2, 7), (0.05, 0.3)), (4, (15, 40), (0.025, 0.07))):
        clutter = kind == which
        if not clutter.any():
            continue
        for _ in range(int(torch.randint(*discs, (1,), generator=gen))):
            centre = torch.rand(count, 2, generator=gen)
            radius = radii[0] + (radii[1] - radii[0]) * torch.rand(count, generator=gen)
            d = torch.sqrt((xx - centre[:, 0, None, None]) ** 2 + (yy - centre[:, 1, None, None]) ** 2)
            disc = torch.clamp((radius[:, None, None] - d) * size / 2, 0, 1) * clutter[:, None, None]
            bg = bg * (1 - disc[:, None]) + colours(count)[:, :, None, None] * disc[:, None]
    return bg


def composite(foreground: torch.Tensor, alpha: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """``foreground + background * (1 - alpha)``: premultiplied ``(B, 3, S, S)`` foregrounds and
    ``(B, 1, S, S)`` coverage, all float in [0, 1], over ``(B, 3, S, S)`` backgrounds."""
    return foreground + background * (1 - alpha)


def _geometric_loss(pred: dict, used: torch.Tensor, points: torch.Tensor, closest: torch.Tensor,
                    samples_per_cuboid: int, gen: torch.Generator) -> torch.Tensor:
    """Mean over the batch of coverage + consistency (:func:`primkit.losses.shape_losses`, the volume
    model's own terms) of the predicted cuboids against the true shapes, the parts in ``used (B, m)
    bool`` present."""
    cuboids = PrimitivePrediction(pred["half_extents"], pred["quaternions"], pred["translations"], used.float())
    return shape_losses(cuboids, used.float(), points, closest, samples_per_cuboid=samples_per_cuboid,
                        generator=gen).total.mean()


@dataclass
class ImageTrainResult:
    network: ImageNet
    history: list
    seconds: float


def _to_float(images_uint8: torch.Tensor) -> torch.Tensor:
    return images_uint8.permute(0, 3, 1, 2).float() / 255.0


def train_image_model(images: np.ndarray, shape_index: np.ndarray, cameras: np.ndarray, teacher: dict,
                      net_config: ImageNetConfig = ImageNetConfig(), config: ImageTrainConfig = ImageTrainConfig(),
                      *, progress: bool = True, network: ImageNet | None = None,
                      foreground: np.ndarray | None = None, alpha: np.ndarray | None = None,
                      surface_points: np.ndarray | None = None, closest: np.ndarray | None = None) -> ImageTrainResult:
    """Train an :class:`ImageNet` to reproduce the teacher on rendered views.

    Parameters
    ----------
    images : (k, S, S, 3) uint8
    shape_index : (k,) int, which teacher row each image shows
    cameras : (k, 4) float, camera arrays (:class:`primkit.views.Camera`)
    teacher : dict of (s, m, ...) arrays, :meth:`primkit.abstractor.Abstractor.predict_canonical`
    network : continue training this network instead of a new one
    foreground : (k, S, S, 3) uint8, alpha : (k, S, S) uint8, optional
        The views' shapes alone (:class:`primkit.views.RenderedViews` rendered with
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
    teach = {k: torch.from_numpy(np.asarray(teacher[k], np.float32)) for k in
             ("half_extents", "quaternions", "translations", "existence")}
    if config.geometric > 0:
        if surface_points is None or closest is None:
            raise ValueError("`geometric` > 0 needs the shapes' surface_points and closest grids")
        pts_all = torch.from_numpy(np.asarray(surface_points, np.float32))
        closest_all = torch.from_numpy(np.asarray(closest, np.float32))
        rows = len(teach["existence"])
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
        x = _to_float(imgs[batch])
        if swap > 0:
            k = int(round(swap * len(batch)))
            a = alphas[batch[:k]].float()[:, None] / 255.0
            x[:k] = composite(_to_float(fgs[batch[:k]]), a, training_backgrounds(k, x.shape[-1], gen))
        x = _augment(x, gen, config.shift_pixels, config.colour_shuffle)
        target = {k: v[idx[batch]] for k, v in teach.items()}
        pred = net(x)
        losses = distillation_loss(pred, target, view[batch], config.weights)
        if config.geometric > 0:
            shapes = idx[batch]
            pick = torch.randint(0, pts_all.shape[1], (len(batch), config.geometric_points), generator=gen)
            points = torch.gather(pts_all[shapes], 1, pick[..., None].expand(-1, -1, 3))
            geo = _geometric_loss(pred, target["existence"] > 0.5, points, closest_all[shapes],
                                  config.geometric_samples, gen)
            losses["geometric"] = geo
            losses["total"] = losses["total"] + config.geometric * geo
        opt.zero_grad(set_to_none=True)
        losses["total"].backward()
        opt.step()
        values, last = {k: float(v.detach()) for k, v in losses.items()}, it
        running = values if running is None else {k: 0.95 * running[k] + 0.05 * values[k] for k in values}
        if it % config.log_every == 0 or it == config.iterations - 1:
            history.append({"iteration": it, "lr": opt.param_groups[0]["lr"], **values})
            bar.set_postfix(loss=f"{running['total']:.4f}", t=f"{running['translations']:.3f}",
                            z=f"{running['half_extents']:.3f}")
    if values is not None and history[-1]["iteration"] != last:
        history.append({"iteration": last, "lr": opt.param_groups[0]["lr"], **values})
    net.eval()
    return ImageTrainResult(net, history, time.time() - start)


# ---------------------------------------------------------------------------------------- inference
def read_image(path, size: int) -> np.ndarray:
    """An image file as ``(size, size, 3) uint8``: transparency composited over white, the central
    square cropped, resized with antialiasing. Raises ``ValueError`` naming the file when unreadable."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("RGBA", "LA", "P"):
                im = im.convert("RGBA")
                white = Image.new("RGBA", im.size, (255, 255, 255, 255))
                im = Image.alpha_composite(white, im)
            im = im.convert("RGB")
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"{path}: not a readable image ({exc.__class__.__name__})") from None
    w, h = im.size
    side = min(w, h)
    im = im.crop(((w - side) // 2, (h - side) // 2, (w - side) // 2 + side, (h - side) // 2 + side))
    return np.asarray(im.resize((size, size), Image.LANCZOS), np.uint8)


@dataclass(frozen=True)
class ImageAbstraction:
    """The abstraction of one picture.

    cuboids : primitives.Cuboids in the canonical frame of the shape (+Y up, front +X, longest side 1)
    azimuth_deg, elevation_deg : float, the viewpoint the network reads off the picture
    image : (S, S, 3) uint8, what the network saw
    """

    name: str
    cuboids: primitives.Cuboids
    azimuth_deg: float
    elevation_deg: float
    image: np.ndarray
    source: str = ""

    def camera(self, distance: float, view_angle_deg: float):
        from .views import Camera

        return Camera(self.azimuth_deg, self.elevation_deg, distance, view_angle_deg)

    def to_dict(self) -> dict:
        d = self.cuboids.to_dict()
        d.update(name=self.name, source=self.source, frame="canonical (+Y up, front +X, longest side 1)",
                 viewpoint={"azimuth_deg": self.azimuth_deg, "elevation_deg": self.elevation_deg})
        return d


class ImageAbstractor:
    """A trained image abstractor: network plus model-file metadata.

    ``ImageAbstractor.load("chair-image")`` (a bundled name or a path); ``predict(images)`` for
    ``(s, S, S, 3) uint8`` arrays; ``predict_files(paths)`` for image files.
    """

    def __init__(self, network: ImageNet, metadata: dict):
        self.network = network.eval()
        self.metadata = metadata

    @classmethod
    def load(cls, path) -> "ImageAbstractor":
        from ..model.modelfile import ModelFileError, load_model
        from ..model.bundled import resolve_model

        path = resolve_model(path)
        weights, meta = load_model(path)
        if meta.get("kind") != KIND:
            raise ModelFileError(path, f"not an image model (kind {meta.get('kind', 'volume')!r}); use it with shape files")
        net = ImageNet(ImageNetConfig.from_dict(meta["network"]))
        net.load_state_dict(weights)
        return cls(net, meta)

    def save(self, path, metadata: dict, *, overwrite: bool = False) -> Path:
        from ..model.modelfile import save_model

        meta = {"kind": KIND, "network": self.network.config.to_dict(), **metadata}
        return save_model(path, self.network.state_dict(), meta, overwrite=overwrite)

    @property
    def size(self) -> int:
        return self.network.config.size

    @property
    def part_names(self) -> list:
        names = self.metadata.get("part_names")
        return list(names) if names else [f"part{k}" for k in range(self.network.config.parts)]

    @property
    def view_settings(self):
        from .views import ViewSettings

        v = self.metadata.get("views")
        return ViewSettings.from_dict(v) if v else ViewSettings(size=self.size)

    def predict_raw(self, images: np.ndarray, batch_size: int = 128) -> dict:
        """Raw network output for ``(s, S, S, 3) uint8`` images, as NumPy arrays ``(s, m, ...)``."""
        images = np.asarray(images)
        s = self.size
        if images.ndim != 4 or images.shape[1:] != (s, s, 3):
            raise ValueError(f"`images` must be (s, {s}, {s}, 3) uint8, got {images.shape}")
        out = {}
        with torch.no_grad():
            for i in range(0, len(images), batch_size):
                pred = self.network(_to_float(torch.from_numpy(images[i: i + batch_size])))
                for k, v in pred.items():
                    out.setdefault(k, []).append(v.double().numpy())
        return {k: np.concatenate(v) for k, v in out.items()}

    def predict(self, images: np.ndarray, names=None, sources=None, existence_threshold: float = 0.5,
                prune_threshold: float | None = 0.6) -> list[ImageAbstraction]:
        """Cuboids per image (kept and pruned as :meth:`primkit.abstractor.Abstractor.predict` does)."""
        raw = self.predict_raw(images)
        results = []
        for i in range(len(images)):
            cub = primitives.Cuboids(raw["half_extents"][i], raw["quaternions"][i], raw["translations"][i],
                                     raw["existence"][i] > existence_threshold, probabilities=raw["existence"][i])
            if prune_threshold is not None and cub.existence.sum() > 1:
                cub = primitives.prune_covered(cub, prune_threshold)
            c, s_, el = raw["viewpoint"][i]
            results.append(ImageAbstraction(
                names[i] if names is not None else f"image{i}", cub, float(np.degrees(np.arctan2(s_, c)) % 360),
                float(np.degrees(el)), np.asarray(images[i]), sources[i] if sources is not None else ""))
        return results

    def predict_files(self, paths, **kwargs):
        """Read and abstract image files; returns ``(results, errors)`` (one line per unreadable file)."""
        images, names, sources, errors = [], [], [], []
        for p in paths:
            try:
                images.append(read_image(p, self.size))
            except ValueError as exc:
                errors.append(str(exc))
                continue
            names.append(Path(p).stem)
            sources.append(str(p))
        if not images:
            return [], errors
        return self.predict(np.stack(images), names, sources, **kwargs), errors


def draw_over_image(result: ImageAbstraction, path, *, distance: float, view_angle_deg: float, scale: int = 4) -> None:
    """A PNG of the picture with the cuboids' edges drawn over it, projected with an assumed camera:
    the predicted azimuth and elevation, and the training views' mean distance and view angle (the
    network does not estimate those). Left: the picture; right: the picture with the cuboids."""
    from PIL import Image, ImageDraw

    from ..model.abstractor import part_colors
    from ..io import atomic_output
    from .views import project

    s = result.image.shape[0]
    big = Image.fromarray(result.image).resize((s * scale, s * scale), Image.BICUBIC)
    over = big.copy()
    draw = ImageDraw.Draw(over)
    cam = result.camera(distance, view_angle_deg)
    colors = part_colors(result.cuboids.count)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    c = result.cuboids
    for k in c.present:
        pts = corners * c.half_extents[k] @ c.rotations[k].T + c.translations[k]
        uv = project(pts, cam, s) * scale
        for a, b in edges:
            if np.all(np.isfinite(uv[[a, b]])):
                draw.line([tuple(uv[a]), tuple(uv[b])], fill=tuple(int(v) for v in colors[k]), width=2)
    canvas = Image.new("RGB", (2 * s * scale + 8, s * scale), (255, 255, 255))
    canvas.paste(big, (0, 0))
    canvas.paste(over, (s * scale + 8, 0))
    with atomic_output(path, overwrite=True) as tmp:
        canvas.save(str(tmp), format="PNG")

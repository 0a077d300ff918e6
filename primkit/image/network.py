"""The image network: a small 2D CNN from a picture to ``m`` cuboids and a viewpoint (the
architecture is drawn in :mod:`primkit.image`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["ImageNetConfig", "ImageNet", "ImagePrediction", "images_to_float", "image_net_state_shapes"]


@dataclass(frozen=True, eq=False)
class ImagePrediction:
    """The image network's answer for ``B`` images: tensors from :meth:`ImageNet.forward`, NumPy
    arrays (float64) from :meth:`primkit.image.inference.ImageAbstractor.predict_raw`.

    Attributes
    ----------
    half_extents : (B, m, 3)
    quaternions : (B, m, 4)
        Unit, real part first.
    translations : (B, m, 3)
    existence : (B, m)
        Probabilities; ``existence_logits`` (B, m) before the sigmoid.
    existence_logits : (B, m)
    viewpoint : (B, 3)
        cos azimuth, sin azimuth, elevation in radians.
    """

    half_extents: object
    quaternions: object
    translations: object
    existence: object
    existence_logits: object
    viewpoint: object

    def arrays(self) -> dict[str, torch.Tensor | np.ndarray]:
        """The six by field name, in field order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class ImageNetConfig:
    """The image network's shape: input side, channels of the strided convolutions, FC width, parts."""

    size: int = 64
    channels: tuple = (32, 48, 64, 96, 128)
    fc_width: int = 256
    parts: int = 20
    max_half_extent: float = 0.5

    def __post_init__(self):
        # bounded so that a model file's metadata cannot ask for an absurd network (far above use: 64 px, 256 units)
        def integer(value, low, high):
            return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high

        if not (isinstance(self.channels, tuple) and 1 <= len(self.channels) <= 8
                and all(integer(c, 1, 2048) for c in self.channels)):
            raise ValueError(f"`channels` must be 1 to 8 ints from 1 to 2048, got {self.channels!r}")
        if not integer(self.size, 2, 1024):
            raise ValueError(f"`size` must be an int from 2 to 1024, got {self.size!r}")
        if self.size % (2 ** len(self.channels)):
            raise ValueError(f"`size` ({self.size}) must be divisible by 2^{len(self.channels)}")
        if not integer(self.fc_width, 1, 8192):
            raise ValueError(f"`fc_width` must be an int from 1 to 8192, got {self.fc_width!r}")
        if not integer(self.parts, 1, 1024):
            raise ValueError(f"`parts` must be an int from 1 to 1024, got {self.parts!r}")
        if not (isinstance(self.max_half_extent, (int, float)) and not isinstance(self.max_half_extent, bool)
                and math.isfinite(self.max_half_extent) and self.max_half_extent > 0.05):
            raise ValueError(f"`max_half_extent` must be a finite number > 0.05, got {self.max_half_extent!r}")

    def to_dict(self) -> dict:
        """JSON-ready: the channels as a list."""
        return {**asdict(self), "channels": list(self.channels)}

    @classmethod
    def from_dict(cls, d: dict) -> "ImageNetConfig":
        if not isinstance(d, dict):
            raise ValueError(f"image network config must be a dict, got {type(d).__name__}")
        unknown = sorted(set(d) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown image network config keys {unknown}")
        channels = d.get("channels", cls.channels)
        if not isinstance(channels, (list, tuple)):
            raise ValueError(f"`channels` must be a list of ints, got {channels!r}")
        return cls(**{**d, "channels": tuple(channels)})


class ImageNet(nn.Module):
    """2D CNN from a ``(B, 3, S, S)`` image (floats in [0, 1]) to ``m`` cuboids and a viewpoint.

    ``forward`` returns an :class:`ImagePrediction` of tensors: ``half_extents (B, m, 3)``,
    ``quaternions (B, m, 4)``, ``translations (B, m, 3)``, ``existence (B, m)``,
    ``existence_logits (B, m)``, ``viewpoint (B, 3)`` (cos azimuth, sin azimuth, elevation in radians).
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

    def forward(self, images: torch.Tensor) -> ImagePrediction:
        x = (images - 0.5) / 0.25
        h = self.encoder(x)
        m = self.config.parts
        logits = self.existence_head(h)
        return ImagePrediction(
            half_extents=self.config.max_half_extent * torch.sigmoid(self.half_extent_head(h).unflatten(1, (m, 3))),
            quaternions=F.normalize(self.quaternion_head(h).unflatten(1, (m, 4)), dim=-1, eps=1e-12),
            translations=0.5 * torch.tanh(self.translation_head(h).unflatten(1, (m, 3))),
            existence=torch.sigmoid(logits),
            existence_logits=logits,
            viewpoint=self.viewpoint_head(h),
        )


def image_net_state_shapes(config: ImageNetConfig) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """``name -> (shape, dtype)`` of ``ImageNet(config)``'s state dict, built on the ``meta`` device (nothing allocated)."""
    with torch.device("meta"):
        net = ImageNet(config)
    return {k: (tuple(v.shape), v.dtype) for k, v in net.state_dict().items()}


def images_to_float(images_uint8: torch.Tensor) -> torch.Tensor:
    return images_uint8.permute(0, 3, 1, 2).float() / 255.0

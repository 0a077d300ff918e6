"""Backgrounds of the training views, from two palettes that share neither kinds nor hues:
``"seen"`` (training: solid colours, linear gradients, smooth noise, hues in [0, 0.5)) and
``"unseen"`` (evaluation: radial gradients, stripes, checkers, fine noise, hues in [0.5, 1)).
:func:`random_background` draws one in NumPy for rendering; :func:`training_backgrounds` draws a
batch of fresh ones in torch at every training step (background swapping). torch is imported
inside the torch functions (it is heavy), so rendering views does not load it."""

from __future__ import annotations

import colorsys
import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import torch

__all__ = ["PALETTES", "PALETTE_HUES", "random_colour", "random_background", "training_backgrounds", "composite"]


PALETTES = ("seen", "unseen")


#: hue ranges (HSV hue in [0, 1)) of the background palettes
PALETTE_HUES = {"seen": (0.0, 0.5), "unseen": (0.5, 1.0)}


def random_colour(rng, hues, saturation=(0.2, 0.9), value=(0.25, 1.0)) -> np.ndarray:
    h = rng.uniform(*hues)
    return np.array(colorsys.hsv_to_rgb(h % 1.0, rng.uniform(*saturation), rng.uniform(*value)))


def _smooth_noise(rng, size: int, cells: int) -> np.ndarray:
    """``(size, size) float`` in [0, 1]: a ``cells`` x ``cells`` random grid, bilinearly upsampled."""
    from scipy.ndimage import zoom

    g = rng.uniform(0, 1, (cells + 1, cells + 1))
    z = zoom(g, size / (cells + 1), order=1, mode="nearest")[:size, :size]
    z = np.pad(z, ((0, size - z.shape[0]), (0, size - z.shape[1])), mode="edge")
    return (z - z.min()) / max(z.max() - z.min(), 1e-9)


def random_background(size: int, rng: np.random.Generator, palette: str = "seen") -> np.ndarray:
    """A background image ``(size, size, 3) float`` in [0, 1] from one of the two palettes
    (see the module docstring: ``"seen"`` for training, ``"unseen"`` held out for evaluation)."""
    if palette not in PALETTES:
        raise ValueError(f"palette must be one of {PALETTES}, got {palette!r}")
    hues = PALETTE_HUES[palette]
    a, b = random_colour(rng, hues), random_colour(rng, hues)
    yy, xx = np.mgrid[0:size, 0:size] / max(size - 1, 1)
    if palette == "seen":
        kind = rng.integers(3)
        if kind == 0:  # solid
            w = np.zeros((size, size))
        elif kind == 1:  # linear gradient in a random direction
            t = rng.uniform(0, 2 * np.pi)
            w = np.cos(t) * xx + np.sin(t) * yy
            w = (w - w.min()) / max(w.max() - w.min(), 1e-9)
        else:  # smooth noise
            w = _smooth_noise(rng, size, int(rng.integers(2, 6)))
    else:
        kind = rng.integers(4)
        if kind == 0:  # radial gradient
            c = rng.uniform(0, 1, 2)
            w = np.clip(np.hypot(xx - c[0], yy - c[1]) / 1.2, 0, 1)
        elif kind == 1:  # stripes
            t = rng.uniform(0, np.pi)
            period = rng.uniform(0.08, 0.3)
            w = (np.floor((np.cos(t) * xx + np.sin(t) * yy) / period) % 2).astype(float)
        elif kind == 2:  # checker
            period = rng.uniform(0.08, 0.3)
            w = ((np.floor(xx / period) + np.floor(yy / period)) % 2).astype(float)
        else:  # fine noise
            w = _smooth_noise(rng, size, int(rng.integers(10, 24)))
    return a * (1 - w[..., None]) + b * w[..., None]


def _hsv_to_rgb(h: torch.Tensor, s: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``(..., 3)`` RGB from hue, saturation, value tensors of the same shape, all in [0, 1]."""
    import torch  # heavy: imported when backgrounds are drawn in torch

    k = torch.stack([(5 + h * 6) % 6, (3 + h * 6) % 6, (1 + h * 6) % 6], dim=-1)
    return v[..., None] - v[..., None] * s[..., None] * torch.clamp(torch.minimum(k, 4 - k), 0, 1)


def _stretch(w: torch.Tensor) -> torch.Tensor:
    """Each ``(S, S)`` map of a ``(B, S, S)`` batch rescaled to span [0, 1]."""
    lo, hi = w.amin(dim=(1, 2), keepdim=True), w.amax(dim=(1, 2), keepdim=True)
    return (w - lo) / (hi - lo).clamp(min=1e-9)


def training_backgrounds(count: int, size: int, gen: torch.Generator, hues=None) -> torch.Tensor:
    """Fresh random backgrounds ``(count, 3, size, size)`` in [0, 1] for background swapping.

    The kinds and colours of the training palette (:func:`primkit.image.backgrounds.random_background` with
    ``palette="seen"``: solid colours, linear gradients, smooth noise of 2-5 cells, hues in
    ``views.PALETTE_HUES["seen"]``), plus two kinds of clutter the palette lacks, in seen colours
    over a gradient: a few large soft-edged discs, or many small ones (confetti: fine detail
    without the regular pattern of stripes or checkers). None of the held-out palette's kinds
    (radial gradients, stripes, checkers, fine noise) or hues is drawn here. Drawn in torch, a
    batch at a time, so that every training step sees new backgrounds at no rendering cost.
    """
    import torch  # heavy: imported when backgrounds are drawn in torch
    import torch.nn.functional as F

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

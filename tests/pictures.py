"""What a picture shows, for tests that check a PNG by its content rather than its size: how much of
it is not background, and whether each part's palette colour is in it.

Rendered parts are shaded (diffuse light scales a colour's RGB, specular adds white), so a part's
colour is recognised by its chromaticity (RGB divided by its sum) among pixels that are neither
background nor nearly grey; palette colours that are themselves grey are not looked for."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Picture:
    rgb: np.ndarray  # (h, w, 3) uint8
    background: np.ndarray  # (3,) uint8: the most common colour on the border
    foreground: np.ndarray  # (h, w) bool: pixels away from the background colour

    @property
    def size(self) -> tuple[int, int]:
        return self.rgb.shape[1], self.rgb.shape[0]

    @property
    def foreground_fraction(self) -> float:
        return float(self.foreground.mean())

    @property
    def coloured_pixels(self) -> int:
        """Foreground pixels that are not nearly grey (shaded parts, plotted lines; not a grey mesh)."""
        return int((self.foreground & _coloured(self.rgb)).sum())

    def blobs(self, min_pixels: int = 300) -> int:
        """Connected foreground regions of at least ``min_pixels`` (thumbnails, tiles), leaving out a
        frame drawn around the whole picture (a region whose box spans most of it)."""
        from scipy import ndimage

        labels, count = ndimage.label(self.foreground)
        sizes = np.bincount(labels.ravel())[1:]
        h, w = self.foreground.shape
        kept = 0
        for k, box in enumerate(ndimage.find_objects(labels)):
            spans = (box[0].stop - box[0].start) > 0.8 * h and (box[1].stop - box[1].start) > 0.8 * w
            kept += bool(sizes[k] >= min_pixels and not spans)
        return kept

    def crop(self, left: int, right: int) -> "Picture":
        """The columns ``left:right`` (a panel of a picture laid out in a row)."""
        return Picture(self.rgb[:, left:right], self.background, self.foreground[:, left:right])

    def colour_pixels(self, colour, tolerance: float = 0.03) -> int:
        """Foreground pixels whose chromaticity is within ``tolerance`` of ``colour``'s (and that are
        not nearly grey)."""
        target = _chromaticity(np.asarray(colour, float)[None])[0]
        chroma = _chromaticity(self.rgb.reshape(-1, 3).astype(float)).reshape(*self.rgb.shape[:2], 3)
        close = np.abs(chroma - target).max(axis=-1) <= tolerance
        return int((close & self.foreground & _coloured(self.rgb)).sum())

    def part_colours_shown(self, parts, min_pixels: int = 20) -> dict[int, int]:
        """For each part index whose palette colour is not grey: the pixels showing that colour."""
        from primkit.viz.palette import part_colors

        parts = sorted({int(k) for k in parts})
        colours = part_colors(max(parts) + 1)
        return {k: self.colour_pixels(colours[k]) for k in parts if _coloured(colours[k][None])[0]}


def _chromaticity(rgb: np.ndarray) -> np.ndarray:
    return rgb / np.maximum(rgb.sum(axis=-1, keepdims=True), 1.0)


def _coloured(rgb: np.ndarray, spread: int = 40) -> np.ndarray:
    rgb = rgb.astype(int)
    return (rgb.max(axis=-1) - rgb.min(axis=-1)) >= spread


def read_picture(path) -> Picture:
    from PIL import Image

    rgb = np.asarray(Image.open(Path(path)).convert("RGB"))
    border = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
    values, counts = np.unique(border, axis=0, return_counts=True)
    background = values[np.argmax(counts)]
    foreground = np.abs(rgb.astype(int) - background.astype(int)).max(axis=-1) > 24
    return Picture(rgb, background, foreground)

"""The colour of part index ``k``: the same on every shape, every picture, every written mesh."""

from __future__ import annotations

import numpy as np

__all__ = ["part_colors"]


def part_colors(count: int) -> np.ndarray:
    """A fixed colour per part index: ``(count, 3) uint8`` (matplotlib's tab20, then repeated)."""
    from matplotlib import colormaps  # matplotlib is heavy: imported on first use

    cmap = colormaps["tab20"]
    return (np.array([cmap(i % 20)[:3] for i in range(count)]) * 255).astype(np.uint8)

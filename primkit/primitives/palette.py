"""The colour of part index ``k``: the same on every shape, every picture, every written mesh.

It lives with the primitives (part ``k`` is cuboid slot ``k``) so that the model and the
segmentation, which write coloured meshes, use it without importing the drawing kit
(:mod:`primkit.viz` sits above the model; :mod:`primkit.viz.palette` re-exports it).
"""

from __future__ import annotations

import numpy as np

__all__ = ["part_colors"]


def part_colors(count: int) -> np.ndarray:
    """A fixed colour per part index: ``(count, 3) uint8`` (matplotlib's tab20, then repeated)."""
    from matplotlib import colormaps  # matplotlib is heavy: imported on first use

    cmap = colormaps["tab20"]
    return (np.array([cmap(i % 20)[:3] for i in range(count)]) * 255).astype(np.uint8)

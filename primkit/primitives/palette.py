"""The colour of part index ``k``: the same on every shape, every picture, every written mesh.

It lives with the primitives (part ``k`` is cuboid slot ``k``) so that the model and the
segmentation, which write coloured meshes, use it without importing the drawing kit
(:mod:`primkit.viz` sits above the model; :mod:`primkit.viz.palette` re-exports it).
"""

from __future__ import annotations

import numpy as np

__all__ = ["part_colors"]


#: matplotlib's ``tab20`` as 8-bit RGB (the table is written out: importing matplotlib for it cost
#: about 0.4 s of every ``segment`` and ``abstract`` run; ``tests/primitives`` checks it against matplotlib)
TAB20 = np.array([
    [31, 119, 180], [174, 199, 232], [255, 127, 14], [255, 187, 120], [44, 160, 44],
    [152, 223, 138], [214, 39, 40], [255, 152, 150], [148, 103, 189], [197, 176, 213],
    [140, 86, 75], [196, 156, 148], [227, 119, 194], [247, 182, 210], [127, 127, 127],
    [199, 199, 199], [188, 189, 34], [219, 219, 141], [23, 190, 207], [158, 218, 229],
], np.uint8)


def part_colors(count: int) -> np.ndarray:
    """A fixed colour per part index: ``(count, 3) uint8`` (matplotlib's tab20, then repeated)."""
    return TAB20[np.arange(int(count)) % len(TAB20)].copy()

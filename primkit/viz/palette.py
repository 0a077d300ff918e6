"""The colour of part index ``k``, for the drawing kit.

Defined in :mod:`primkit.primitives.palette` (the model and the segmentation colour the meshes
they write and may not import :mod:`primkit.viz`); re-exported here, the same function.
"""

from __future__ import annotations

from ..primitives.palette import part_colors

__all__ = ["part_colors"]

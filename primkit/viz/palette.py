"""The drawing kit's colours: one per part index, one per label name.

* :func:`part_colors`: the colour of part index ``k`` (cuboid slot ``k``). Defined in
  :mod:`primkit.primitives.palette` (the model and the segmentation colour the meshes they write
  and may not import :mod:`primkit.viz`); re-exported here, the same function.
* :func:`label_colors` / :func:`label_element_colors`: the colour of a label name (a labeller's
  name, ``segment --semantic``'s codes, a name typed by hand), by its position in the model's
  label names (``labels.csv``'s code minus one): the ``png`` of ``segment --semantic``, the viewers,
  the Open3D attributes and the hand-labelling mode all draw ``back`` of the chair model in the
  same colour. Drawn from matplotlib's tab10, then the light half of tab20, so that names do not
  look like the cuboids' part colours (tab20). :data:`UNLABELLED` is the grey of an element
  without a name.
"""

from __future__ import annotations

import numpy as np

from ..primitives.palette import part_colors

__all__ = ["part_colors", "label_colors", "label_element_colors", "UNLABELLED"]

#: ``(3,) uint8``-like RGB of an element with no name (no label, or no cuboid present)
UNLABELLED = (215, 215, 215)


def label_colors(count: int) -> np.ndarray:
    """``(count, 3) uint8``: the colour of each of ``count`` label names, in the names' order
    (tab10, then the light half of tab20, then repeated)."""
    from matplotlib import colormaps  # matplotlib is heavy: imported on first use

    table = np.vstack([colormaps["tab10"].colors, colormaps["tab20"].colors[1::2]])
    return (np.asarray(table)[np.arange(count) % len(table)] * 255).round().astype(np.uint8)


def label_element_colors(labels, count: int) -> np.ndarray:
    """``(n, 3) uint8``: each element's label colour (``labels`` (n,) int, indices into the ``count``
    label names); :data:`UNLABELLED` for a negative label."""
    labels = np.asarray(labels, np.int64)
    if labels.size and labels.max() >= count:
        raise ValueError(f"labels go up to {labels.max()}, but there are {count} label names")
    table = np.vstack([label_colors(count).reshape(-1, 3), np.array([UNLABELLED], np.uint8)])
    return table[np.where(labels < 0, count, labels)]

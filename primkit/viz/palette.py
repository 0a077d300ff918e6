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
* :func:`name_colors`: names that may not follow the model's order (typed by hand): a name the
  model knows keeps the model's colour, the others take the colours after the model's.
"""

from __future__ import annotations

import numpy as np

from ..primitives.palette import part_colors

__all__ = ["part_colors", "label_colors", "label_element_colors", "name_colors", "UNLABELLED"]

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


def name_colors(names, known=()) -> np.ndarray:
    """``(len(names), 3) uint8``: the colour of each name, by name: a name of ``known`` (the model's
    label names, in their order) takes its :func:`label_colors` colour there, so ``seat`` typed by
    hand is drawn as the model's ``seat``; the others the colours after ``known``'s, in order."""
    known = [str(n) for n in known]
    table = label_colors(len(known) + len(names))
    others = [n for n in dict.fromkeys(str(n) for n in names) if n not in known]
    at = {n: len(known) + i for i, n in enumerate(others)} | {n: i for i, n in enumerate(known)}
    return table[[at[str(n)] for n in names]].reshape(-1, 3)

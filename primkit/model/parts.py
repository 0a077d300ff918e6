"""Part names: what each primitive index of a model means.

One network explains a whole category, so part ``k`` is the same part on every shape, but the
index is anonymous until it is named. A model file may carry ``part_names`` (one string per index;
several indices may share a name, as the four leg slots of a chair model all named ``legs``).
Names are learned from a few labelled shapes by :func:`names_from_labels`: each index takes the
label that covers most of the surface area assigned to it (``primkit name-parts``).

Every command that takes parts accepts names or indices (:func:`resolve_parts`):
``"back,seat"``, ``"3,7"``, ``"part3"`` or ``"all"``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["default_part_names", "resolve_parts", "names_from_labels", "label_codes", "named_labels"]


def default_part_names(count: int) -> list[str]:
    """``["part0", "part1", ...]``: the names of unnamed indices."""
    return [f"part{k}" for k in range(count)]


def resolve_parts(spec, names) -> np.ndarray:
    """Indices selected by ``spec``.

    Parameters
    ----------
    spec : None, "all", str or sequence of (str or int)
        Comma-separated names and/or indices (``"back,seat"``, ``"3,7"``, ``"part3"``). A name
        selects every index that carries it. None or ``"all"`` selects every index.
    names : sequence of str
        The model's part names, one per index (:attr:`primkit.model.abstractor.Abstractor.part_names`).

    Returns
    -------
    (k,) int, sorted, without repeats. Raises ValueError for an unknown name or an index out of
    range, listing the names the model knows.
    """
    names = [str(n) for n in names]
    count = len(names)
    if spec is None or (isinstance(spec, str) and spec.strip().lower() in ("", "all")):
        return np.arange(count)
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    lower = [n.lower() for n in names]
    chosen: list[int] = []
    for item in items:
        if isinstance(item, (int, np.integer)):
            key = str(int(item))
        else:
            key = str(item).strip()
        if not key:
            continue
        hits = [k for k, n in enumerate(lower) if n == key.lower()]
        if not hits:
            digits = key[4:] if key.lower().startswith("part") else key
            if digits.lstrip("-").isdigit():
                k = int(digits)
                if not 0 <= k < count:
                    raise ValueError(f"part index {k} is out of range: the model has {count} parts (0-{count - 1})")
                hits = [k]
        if not hits:
            known = sorted(set(names), key=names.index)
            raise ValueError(f"unknown part {key!r}: the model's parts are {', '.join(known)} (or indices 0-{count - 1})")
        chosen.extend(hits)
    return np.array(sorted(set(chosen)), dtype=np.int64)


def names_from_labels(assignments, labels, weights, label_names, count: int):
    """Name each index after the label it takes most often on labelled shapes.

    Parameters
    ----------
    assignments : list of (n_i,) int
        Per shape, the primitive index of each element (face or point), from the co-segmentation.
    labels : list of (n_i,) int
        Per shape, the ground-truth label of each element (indices into ``label_names``; -1 or a
        value past the end: unlabelled, ignored).
    weights : list of (n_i,) float or None
        Per shape, each element's weight (face area); None: 1 each.
    label_names : sequence of str
    count : int
        The model's number of indices.

    Returns
    -------
    names : list of str, one per index; indices that never hold a labelled element keep their
        default name ``part<k>``.
    table : (count, len(label_names)) float
        The weight each index holds of each label, summed over the shapes.
    """
    label_names = [str(n) for n in label_names]
    table = np.zeros((count, len(label_names)))
    for idx, lab, w in zip(assignments, labels, weights):
        idx = np.asarray(idx, dtype=np.int64)
        lab = np.asarray(lab, dtype=np.int64)
        w = np.ones(len(idx)) if w is None else np.asarray(w, float)
        if not (len(idx) == len(lab) == len(w)):
            raise ValueError(f"assignments, labels and weights differ in length ({len(idx)}, {len(lab)}, {len(w)})")
        ok = (lab >= 0) & (lab < len(label_names)) & (idx >= 0) & (idx < count)
        np.add.at(table, (idx[ok], lab[ok]), w[ok])
    names = default_part_names(count)
    for k in range(count):
        if table[k].sum() > 0:
            names[k] = label_names[int(np.argmax(table[k]))]
    return names, table


def label_codes(names) -> tuple[list[str], np.ndarray]:
    """Integer codes for named parts, for label files: ``(distinct names, code per index)``.

    Codes start at 1 (label files such as COSEG's use 1-based labels) and follow the order in
    which names first appear, so ``["seat", "legs", "legs", "back"]`` gives
    ``(["seat", "legs", "back"], [1, 2, 2, 3])``.
    """
    distinct: list[str] = []
    codes = []
    for n in names:
        if n not in distinct:
            distinct.append(n)
        codes.append(distinct.index(n) + 1)
    return distinct, np.array(codes, dtype=np.int64)


def named_labels(labels, names) -> np.ndarray:
    """Part indices (any shape, -1 for unassigned) as the 1-based codes of their names
    (:func:`label_codes`); -1 stays -1."""
    labels = np.asarray(labels)
    _, codes = label_codes(names)
    return np.where(labels >= 0, codes[np.clip(labels, 0, None)], -1)

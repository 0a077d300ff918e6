"""Co-segmentation of voxel grids, and its evaluation against per-voxel part labels.

A voxel input (binvox) has no faces to label, so its co-segmentation labels voxels: every
occupied voxel goes to its nearest present cuboid (:func:`label_voxels`, the rule of
:mod:`primkit.segmentation` applied at the voxel centres). Ground truth comes as one part label per
occupied voxel, for example PartNet's part boxes turned into voxel labels for the ShapeNetVox32
chairs (``../shared/data/partnet_chair_boxes/voxlabels.npz``: ``-1`` empty, ``0`` back, ``1``
seat, ``2`` leg/base, ``3`` arm, indexed like :func:`primkit.io.read_voxels`' occupancy).

:func:`evaluate_voxels` scores a collection, one voxel one vote:

* **Per-label IoU, per shape**: for label ``l`` on one shape, ``|P_l ∩ T_l| / |P_l ∪ T_l|`` over
  its occupied voxels, and **1 when the label is absent from both** the prediction and the truth
  (a chair without arms that gets no arm voxels is right about arms); averaged over the shapes.
  ``mean_iou`` averages the labels named in ``mean_over`` (by default every label).
* **Accuracy**: the fraction of a shape's labelled voxels whose label is right, averaged over shapes.
* **Detection** of each label: a shape *has* the label when at least one of its voxels carries it
  (in the prediction, resp. the truth); precision, recall and F1 over the shapes, and how often a
  label absent from the truth is absent from the prediction too (``absent_kept_absent``).

Two label-mapping protocols, stated in the report: ``"collection-majority"`` (the paper's: each
primitive index to the label holding most of its voxels over the evaluated collection) and
``"model-names"`` (the part names stored in the model, learned on other shapes, applied unchanged;
an index whose name is no ground-truth label counts as wrong).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import io, primitives, segmentation

__all__ = [
    "PARTNET_LABEL_NAMES",
    "VoxelGroundTruth",
    "VoxelLabelArchive",
    "voxel_centres",
    "label_voxels",
    "evaluate_voxels",
    "VOXEL_PROTOCOLS",
]

#: What the values of PartNet's chair voxel labels mean (``partnet_chair_boxes``); ``"leg/legs/base"``
#: matches a model part named ``leg``, ``legs`` or ``base``.
PARTNET_LABEL_NAMES = {0: "back", 1: "seat", 2: "leg/legs/base", 3: "arm/arms"}

VOXEL_PROTOCOLS = {
    "collection-majority": "each primitive index mapped to the label holding most of its voxels over the evaluated "
    "collection (the paper's protocol)",
    "model-names": "the part names stored in the model (learned on other shapes) matched to the label names, applied unchanged",
}


@dataclass(frozen=True)
class VoxelGroundTruth:
    """Part labels of a voxel grid's occupied voxels.

    labels : (R, R, R) int, code into ``names`` for occupied voxels, -1 for empty (or unlabelled) ones,
        indexed like the occupancy of :class:`primkit.io.VoxelGrid`.
    names : list of str (aliases separated by ``/``)
    """

    labels: np.ndarray
    names: list


class VoxelLabelArchive:
    """Per-voxel labels for many shapes in one ``.npz`` (key: shape name, e.g. the ShapeNet id).

    Opened lazily: only the arrays asked for are read. ``label_names`` maps label values to names
    (default :data:`PARTNET_LABEL_NAMES`); negative values are empty or unlabelled voxels.

    Parameters
    ----------
    path : path of the ``.npz``, or a folder holding ``voxlabels.npz``.
    """

    def __init__(self, path, label_names: dict | None = None):
        path = Path(path)
        if path.is_dir():
            path = path / "voxlabels.npz"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such voxel label archive")
        self.path = path
        try:
            self._archive = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise io.ShapeFileError(path, f"not a voxel label archive ({exc})") from None
        self.label_names = dict(PARTNET_LABEL_NAMES if label_names is None else label_names)
        values = sorted(self.label_names)
        self.names = [self.label_names[v] for v in values]
        self._code = {v: i for i, v in enumerate(values)}

    def __contains__(self, name) -> bool:
        return str(name) in self._archive.files

    def __len__(self) -> int:
        return len(self._archive.files)

    @property
    def keys(self) -> list:
        return list(self._archive.files)

    def get(self, name, shape=None) -> VoxelGroundTruth:
        """The ground truth of one shape; ``shape`` (a tuple) is checked when given."""
        raw = np.asarray(self._archive[str(name)])
        if shape is not None and raw.shape != tuple(shape):
            raise io.ShapeFileError(self.path, f"labels of {name} are {raw.shape}, the grid is {tuple(shape)}")
        codes = np.full(raw.shape, -1, np.int64)
        for value, code in self._code.items():
            codes[raw == value] = code
        return VoxelGroundTruth(codes, list(self.names))


def voxel_centres(grid: io.VoxelGrid) -> tuple[np.ndarray, np.ndarray]:
    """Centres of the occupied voxels in the grid's model coordinates.

    Returns ``(centres (n, 3) float, index (n, 3) int)``, in ``np.argwhere`` order.
    """
    index = np.argwhere(np.asarray(grid.occupancy, bool))
    res = grid.resolution
    return grid.translate + (index + 0.5) * (grid.scale / res), index


def label_voxels(grid: io.VoxelGrid, cuboids: primitives.Cuboids) -> np.ndarray:
    """Primitive index of each occupied voxel: the nearest present cuboid of its centre.

    ``cuboids`` are in the grid's model coordinates (an abstraction's ``cuboids``, in the input's
    frame). Returns ``(R, R, R) int``, -1 for empty voxels.
    """
    centres, index = voxel_centres(grid)
    out = np.full(np.asarray(grid.occupancy).shape, -1, np.int64)
    if len(index):
        out[tuple(index.T)] = segmentation.point_labels(centres, cuboids)
    return out


def _per_shape_iou(predicted, truth, label_count):
    """(label_count,) IoU of one shape's voxels, 1 where a label is absent from both."""
    iou = np.ones(label_count)
    for lab in range(label_count):
        p, t = predicted == lab, truth == lab
        union = np.count_nonzero(p | t)
        if union:
            iou[lab] = np.count_nonzero(p & t) / union
    return iou


def _detection(predicted_has, truth_has) -> dict:
    predicted_has, truth_has = np.asarray(predicted_has, bool), np.asarray(truth_has, bool)
    tp = int(np.count_nonzero(predicted_has & truth_has))
    fp = int(np.count_nonzero(predicted_has & ~truth_has))
    fn = int(np.count_nonzero(~predicted_has & truth_has))
    absent = int(np.count_nonzero(~truth_has))
    precision = tp / (tp + fp) if tp + fp else float("nan")
    recall = tp / (tp + fn) if tp + fn else float("nan")
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan")
    return {
        "shapes_with": int(truth_has.sum()), "shapes_without": absent, "true_positive": tp,
        "false_positive": fp, "false_negative": fn, "precision": precision, "recall": recall, "f1": f1,
        "absent_kept_absent": (absent - fp) / absent if absent else float("nan"),
    }


def evaluate_voxels(assignments, truths, part_count: int, *, part_names=None, names=None,
                    mean_over=None) -> dict:
    """Score voxel co-segmentations against voxel ground truth (see the module notes).

    Parameters
    ----------
    assignments : list of (R, R, R) int
        Per shape, the primitive index of each occupied voxel (:func:`label_voxels`; -1 empty).
    truths : list of VoxelGroundTruth
        Same order; their ``names`` are the same list.
    part_count : int
        The model's number of indices ``m``.
    part_names : list of str, optional
        The model's part names; the ``"model-names"`` protocol is reported when one matches a label.
    names : list of str, optional
        Shape names (for the per-shape table); ``shape<i>`` by default.
    mean_over : list of str, optional
        Labels averaged into ``mean_iou`` (by their first alias, e.g. ``["back", "seat", "leg"]``);
        every label by default.

    Returns
    -------
    dict: ``labels`` (first aliases), ``iou_rule``, and per protocol ``description``, ``mapping``
    (index -> label or None), ``iou`` ({label: mean per-shape IoU}), ``mean_iou``, ``accuracy``
    (mean over shapes), ``detection`` ({label: precision, recall, F1, ...}) and ``shapes``
    ({name: {"accuracy", "iou": {label: IoU}}}).
    """
    if len(assignments) != len(truths):
        raise ValueError(f"{len(assignments)} assignments but {len(truths)} ground truths")
    if not truths:
        raise ValueError("nothing to evaluate")
    label_names = list(truths[0].names)
    short = [str(n).split("/")[0] for n in label_names]
    count = len(label_names)
    names = list(names) if names is not None else [f"shape{i}" for i in range(len(truths))]
    flat_a, flat_t = [], []
    for a, t in zip(assignments, truths):
        a, lab = np.asarray(a), np.asarray(t.labels)
        if a.shape != lab.shape:
            raise ValueError(f"assignment {a.shape} and labels {lab.shape} differ in shape")
        occupied = lab >= 0
        if np.any(a[occupied] < 0):
            raise ValueError("a labelled voxel has no primitive index (is the assignment of the same grid?)")
        flat_a.append(a[occupied])
        flat_t.append(lab[occupied])
    weights = [np.ones(len(t)) for t in flat_t]
    mappings = {"collection-majority": segmentation.majority_mapping(flat_a, flat_t, weights, part_count, count)}
    if part_names is not None:
        named = segmentation.name_mapping(part_names, label_names)
        if (named >= 0).any():
            mappings["model-names"] = named
    if mean_over is None:
        mean_idx = list(range(count))
    else:
        unknown = [n for n in mean_over if n not in short]
        if unknown:
            raise ValueError(f"mean_over names {unknown} are not labels ({', '.join(short)})")
        mean_idx = [short.index(n) for n in mean_over]
    report = {
        "labels": short,
        "iou_rule": "per shape over its occupied voxels, 1 when a label is absent from both prediction and truth, "
        "averaged over shapes",
        "mean_over": [short[i] for i in mean_idx],
        "shapes_evaluated": len(truths),
        "protocols": {},
    }
    for protocol, mapping in mappings.items():
        per_shape, accuracies, has_p, has_t = [], [], [], []
        shapes = {}
        for name, a, t in zip(names, flat_a, flat_t):
            p = np.where(mapping[a] >= 0, mapping[a], -2)  # -2: an index mapped to no label (wrong)
            iou = _per_shape_iou(p, t, count)
            acc = float(np.mean(p == t)) if len(t) else float("nan")
            per_shape.append(iou)
            accuracies.append(acc)
            has_p.append([np.any(p == lab) for lab in range(count)])
            has_t.append([np.any(t == lab) for lab in range(count)])
            shapes[name] = {"accuracy": acc, "iou": {short[i]: float(iou[i]) for i in range(count)}}
        per_shape = np.array(per_shape)
        has_p, has_t = np.array(has_p), np.array(has_t)
        iou = per_shape.mean(axis=0)
        report["protocols"][protocol] = {
            "description": VOXEL_PROTOCOLS[protocol],
            "mapping": {str(k): (short[c] if c >= 0 else None) for k, c in enumerate(mapping)},
            "iou": {short[i]: float(iou[i]) for i in range(count)},
            "mean_iou": float(np.mean(iou[mean_idx])),
            "accuracy": float(np.nanmean(accuracies)),
            "detection": {short[i]: _detection(has_p[:, i], has_t[:, i]) for i in range(count)},
            "shapes": shapes,
        }
    return report

"""Co-segmentation of voxel grids, and its evaluation against per-voxel part labels.

A voxel input (binvox) has no faces to label, so its co-segmentation labels voxels: every
occupied voxel goes to its nearest present cuboid (:func:`label_voxels`, the rule of
:mod:`primkit.segmentation.meshes` applied at the voxel centres; :class:`VoxelSegmentation`). Ground truth comes as one part label per
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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import geometry, io, primitives
from ..model import parts
from ..primitives.palette import part_colors
from . import graphcut, meshes

__all__ = [
    "PARTNET_LABEL_NAMES",
    "VoxelSegmentation",
    "segment_voxels",
    "VoxelGroundTruth",
    "VoxelLabelArchive",
    "voxel_centres",
    "label_voxels",
    "evaluate_voxels",
    "VOXEL_PROTOCOLS",
]

#: What the values of PartNet's chair voxel labels mean (``partnet_chair_boxes``): back, seat, leg
#: (the whole base: legs, star bases, pedestals) and arm; ``"legs/leg/base"`` matches a model part
#: named ``legs``, ``leg`` or ``base`` (the first alias is the name ``name-parts`` gives).
PARTNET_LABEL_NAMES = {0: "back", 1: "seat", 2: "legs/leg/base", 3: "arms/arm"}

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


def label_voxels(grid: io.VoxelGrid, cuboids: primitives.Cuboids, *, labelling=None) -> np.ndarray:
    """Primitive index of each occupied voxel: with ``labelling="nearest"`` the nearest present
    cuboid of its centre; with ``"graphcut"`` or None (the default) a graph cut over the occupied
    voxels' 6-neighbourhood started from it (:mod:`primkit.segmentation.graphcut`; a
    :class:`~primkit.segmentation.graphcut.Labelling` also sets the smoothness).

    ``cuboids`` are in the grid's model coordinates (an abstraction's ``cuboids``, in the input's
    frame). Returns ``(R, R, R) int``, -1 for empty voxels.
    """
    centres, index = voxel_centres(grid)
    out = np.full(np.asarray(grid.occupancy).shape, -1, np.int64)
    if len(index):
        labels = meshes.point_labels(centres, cuboids)
        how = graphcut.as_labelling(labelling)
        if how.method_for("voxels") == "graphcut":
            edges, contact, mass = graphcut.voxel_graph(index)
            labels = graphcut.graphcut_labels(centres[:, None, :], edges, contact, mass, cuboids, labels,
                                              how.weight("voxels"))
        out[tuple(index.T)] = labels
    return out


@dataclass(frozen=True, eq=False)
class VoxelSegmentation:
    """The co-segmentation of one voxel grid by its abstraction.

    Attributes
    ----------
    name, source : str
    grid : io.VoxelGrid
        The input grid (model coordinates).
    labels : (R, R, R) int
        Primitive index of each occupied voxel, -1 for empty voxels (indexed like ``grid.occupancy``).
    cuboids : primitives.Cuboids
        The abstraction, in the grid's model coordinates.
    part_names : list of str
    """

    name: str
    source: str
    grid: io.VoxelGrid
    labels: np.ndarray
    cuboids: primitives.Cuboids
    part_names: list = field(default_factory=list)
    #: with a labeller in the model (:mod:`primkit.segmentation.labeller`): each occupied voxel's label, an
    #: index into ``label_names`` (-1: none), and the labeller's names; None without one
    named: np.ndarray | None = None
    label_names: list | None = None

    def part_sizes(self) -> np.ndarray:
        """Voxels assigned to each index: ``(m,) int``."""
        occupied = self.labels[self.labels >= 0]
        return np.bincount(occupied, minlength=self.cuboids.count)

    def boundary_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The voxels' surface split by part, in model coordinates, for pictures and ``.ply``
        output: ``(vertices (n, 3) float, faces (f, 3) int, face_labels (f,) int)`` (faces between
        two parts' voxels are kept, so each part is a closed block)."""
        vs, fs, ls, offset = [], [], [], 0
        size = self.grid.scale / self.grid.resolution
        for k in np.unique(self.labels[self.labels >= 0]):
            v, f = geometry.voxel_boundary_mesh(self.labels == k, voxel_size=size, origin=self.grid.translate)
            vs.append(v)
            fs.append(f + offset)
            ls.append(np.full(len(f), k, np.int64))
            offset += len(v)
        if not vs:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
        return np.vstack(vs), np.vstack(fs), np.concatenate(ls)

    def semantic_labels(self) -> tuple[list, np.ndarray]:
        """``(names, codes)``: the distinct part names and each voxel's 1-based name code (-1 empty):
        the labeller's (``named``) when the model has one, else its index's name
        (:func:`primkit.model.parts.label_codes`, the same codes on every shape of a model)."""
        return meshes.semantic_codes(self.labels, self.part_names, self.named, self.label_names)

    def save(self, folder, *, semantic: bool = False, overwrite: bool = False) -> dict:
        """Write ``<name>.voxlabels.npy`` (``(R, R, R) int16``: the part index of each occupied voxel,
        or with ``semantic`` the 1-based code of its name; -1 empty) and ``<name>.parts.ply`` (the
        voxels' surface coloured by part). Returns ``{"labels": path, "mesh": path}``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = {"labels": folder / f"{self.name}.voxlabels.npy", "mesh": folder / f"{self.name}.parts.ply"}
        io.refuse_existing(paths.values(), overwrite)
        labels = self.semantic_labels()[1] if semantic else self.labels
        io.write_array(paths["labels"], labels.astype(np.int16), overwrite=overwrite)
        v, f, lab = self.boundary_mesh()
        io.write_mesh(paths["mesh"], v, f, face_colors=part_colors(self.cuboids.count)[lab], overwrite=overwrite)
        return paths


def segment_voxels(grid: io.VoxelGrid, cuboids: primitives.Cuboids, *, name: str = "shape", source: str = "",
                   part_names=None, labelling=None) -> VoxelSegmentation:
    """Co-segment one voxel grid by its abstraction (cuboids in the grid's model coordinates;
    ``labelling`` as in :func:`label_voxels`)."""
    names = list(part_names) if part_names is not None else parts.default_part_names(cuboids.count)
    return VoxelSegmentation(name, source, grid, label_voxels(grid, cuboids, labelling=labelling), cuboids, names)


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
    mappings = {"collection-majority": meshes.majority_mapping(flat_a, flat_t, weights, part_count, count)}
    if part_names is not None:
        named = meshes.name_mapping(part_names, label_names)
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

"""Co-segmentations scored against ground-truth labels: face labels of meshes (``.seg`` files,
:func:`evaluate`) and voxel labels of voxel grids (:class:`VoxelLabelArchive`, :func:`evaluate_voxels`).

Meshes (:func:`evaluate`): accuracy by faces and by surface area and per-label IoU under stated
label-mapping protocols (:data:`PROTOCOLS`):

* ``"collection-majority"`` (the paper's): each primitive index is mapped to the ground-truth
  label holding most of its area over the evaluated collection;
* ``"leave-one-out"``: for each shape, the same majority mapping learned on the *other* shapes of
  the collection, applied unchanged;
* ``"model-names"``: the part names stored in the model file (:mod:`primkit.model.parts`, learned on
  other shapes by ``primkit name-parts``), matched to the ground truth's label names, applied
  unchanged. Indices whose name is not a ground-truth label count as wrong.

Voxel grids (:func:`evaluate_voxels`), one voxel one vote:

* **Per-label IoU, per shape**: for label ``l`` on one shape, ``|P_l ∩ T_l| / |P_l ∪ T_l|`` over
  its occupied voxels, and **1 when the label is absent from both** the prediction and the truth
  (a chair without arms that gets no arm voxels is right about arms); averaged over the shapes.
  ``mean_iou`` averages the labels named in ``mean_over`` (by default every label).
* **Accuracy**: the fraction of a shape's labelled voxels whose label is right, averaged over shapes.
* **Detection** of each label: a shape *has* the label when at least one of its voxels carries it
  (in the prediction, resp. the truth); precision, recall and F1 over the shapes, and how often a
  label absent from the truth is absent from the prediction too (``absent_kept_absent``).

Two label-mapping protocols, stated in the report (:data:`VOXEL_PROTOCOLS`): ``"collection-majority"``
and ``"model-names"``.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import io
from ..io.limits import max_grid, npz_members, read_npz_member
from .handlabels import read_label_names
from .points import PointSegmentation
from .voxels import VoxelSegmentation

__all__ = [
    "GroundTruth",
    "read_ground_truth",
    "parse_label_names",
    "majority_mapping",
    "name_mapping",
    "accuracy",
    "label_iou",
    "evaluate",
    "ShapeAccuracy",
    "ProtocolScores",
    "SegmentationEvaluation",
    "PROTOCOLS",
    "PARTNET_LABEL_NAMES",
    "VoxelGroundTruth",
    "VoxelLabelArchive",
    "evaluate_voxels",
    "Detection",
    "VoxelShapeScores",
    "VoxelProtocolScores",
    "VoxelEvaluation",
    "VOXEL_PROTOCOLS",
    "ground_truth_sources",
    "find_truth",
    "voxel_archives",
    "voxel_truth",
    "evaluate_meshes_against",
    "evaluate_grids_against",
    "read_point_truth",
    "labelled_shapes",
    "LabelledShapes",
    "POINT_LABELS",
]

#: Label-mapping protocols of :func:`evaluate`, in the order they are reported.
PROTOCOLS = {
    "collection-majority": "each primitive index mapped to the ground-truth label holding most of its area over the "
    "evaluated collection (the paper's protocol)",
    "leave-one-out": "for each shape, the majority mapping learned on the other shapes of the collection, applied unchanged",
    "model-names": "the part names stored in the model (learned on other shapes) matched to the ground-truth label "
    "names, applied unchanged",
}



@dataclass(frozen=True)
class ShapeAccuracy:
    """One shape's accuracy: the fraction of its labelled faces right, and of its labelled area."""

    faces: float
    area: float


@dataclass(frozen=True)
class ProtocolScores:
    """The scores of mesh co-segmentations under one label-mapping protocol (:data:`PROTOCOLS`).

    description : what the protocol does
    shapes : {shape name: ShapeAccuracy}
    mean_faces, mean_area : the shapes' accuracies averaged
    iou : {label: per-label IoU by area over the collection}; ``mean_iou`` their mean (nan-skipping)
    mapping : {primitive index as str: label name or None}; None for ``"leave-one-out"`` (one per shape)
    """

    description: str
    shapes: dict[str, ShapeAccuracy]
    mean_faces: float
    mean_area: float
    iou: dict[str, float]
    mean_iou: float
    mapping: dict[str, str | None] | None = None

    def to_dict(self) -> dict:
        """The protocol's entry of ``evaluation.json`` (no ``mapping`` key where there is none)."""
        out = asdict(self)
        if self.mapping is None:
            del out["mapping"]
        return out


@dataclass(frozen=True)
class SegmentationEvaluation:
    """What :func:`evaluate` returns: the ground truth's label names and the scores per protocol
    (``protocols``: {protocol name: ProtocolScores}, in the order of :data:`PROTOCOLS`)."""

    labels: list[str]
    protocols: dict[str, ProtocolScores]
    area_weighting: str = "face area"

    def to_dict(self) -> dict:
        """The JSON document of ``evaluation.json``."""
        return {"labels": list(self.labels), "area_weighting": self.area_weighting,
                "protocols": {p: e.to_dict() for p, e in self.protocols.items()}}


@dataclass(frozen=True)
class GroundTruth:
    """Ground-truth face labels of one shape, as codes into a collection-wide list of names.

    labels : (f,) int, index into ``names`` (-1: unlabelled)
    names : list of str; a name may list aliases with ``/`` (``"legs/base"`` matches a model part
        named ``legs`` or ``base``).
    """

    labels: np.ndarray
    names: list


def parse_label_names(text) -> dict:
    """What label values mean, from a command line's text: ``"back,seat,legs"`` names label values 1, 2, 3; ``"0=seat,1=back"`` names values explicitly."""
    items = [t.strip() for t in str(text).split(",") if t.strip()]
    if not items:
        raise ValueError(f"label names {text!r}: empty; name the label values ('back,seat,legs' for 1, 2, 3)")
    if all("=" in t for t in items):
        pairs = [(k.strip(), v.strip()) for k, v in (t.split("=", 1) for t in items)]
        bad = [f"{k}={v}" for k, v in pairs if not v or not k.lstrip("-").isdigit()]
        if bad:
            raise ValueError(f"label names {text!r}: {bad[0]!r} is not VALUE=NAME with an integer value and a name")
        return {int(k): v for k, v in pairs}
    if any("=" in t for t in items):
        raise ValueError(f"label names {text!r}: give either all values (1=back,2=seat) or none (back,seat)")
    return {i + 1: name for i, name in enumerate(items)}


def read_ground_truth(label_path, face_count: int, label_names=None, names=None, unnamed=None) -> GroundTruth:
    """Read a ``.seg`` file as a :class:`GroundTruth`.

    Parameters
    ----------
    label_path : path of the ``.seg`` file (one integer per face).
    face_count : the mesh's number of faces (checked).
    label_names : str or dict or None
        What each label value means: ``"back,seat,legs"`` (values 1, 2, 3, as in COSEG),
        ``"1=back,2=seat"`` or ``{1: "back"}``. None: the ``<stem>.names.json`` of hand labelling
        (:mod:`primkit.segmentation.handlabels`) beside the labels, else a ``.json`` written by
        :func:`primkit.synthetic.write_collection` beside the labels gives the part groups
        (``seat``, ``back``, ``legs``, ``arms``, ...); otherwise the values themselves are the names.
    names : list of str, optional
        A collection-wide list of names to extend (so codes agree across shapes).
    unnamed : set, optional
        Filled with the label values (0 or more) found that ``label_names`` leaves without a name.
    """
    label_path = Path(label_path)
    raw = io.read_labels(label_path, face_count)
    if isinstance(label_names, str):
        label_names = parse_label_names(label_names)
    if label_names is None:  # a names file written by hand labelling, else a procedural shape's .json
        label_names = read_label_names(label_path)
    if label_names is None:
        meta = label_path.with_suffix(".json")
        if meta.is_file():
            info = json.loads(meta.read_text())
            groups = info.get("part_groups") or {}
            label_names = {i: groups.get(n, n) for i, n in enumerate(info.get("part_names", []))}
    names = [] if names is None else names
    codes = np.full(len(raw), -1, np.int64)
    for value in np.unique(raw):
        name = str(value) if label_names is None else label_names.get(int(value))
        if name is None:
            if unnamed is not None and value >= 0:  # negative: unlabelled by convention
                unnamed.add(int(value))
            continue  # a value with no name: unlabelled
        if name not in names:
            names.append(name)
        codes[raw == value] = names.index(name)
    return GroundTruth(codes, names)


def majority_mapping(assignments, truths, weights, count: int, label_count: int) -> np.ndarray:
    """Each primitive index mapped to the ground-truth label holding most of its weight.

    assignments : list of (f_i,) int, truths : list of (f_i,) int (-1 unlabelled),
    weights : list of (f_i,) float  ->  (count,) int, -1 for an index that holds no labelled face.
    """
    table = np.zeros((count, max(label_count, 1)))
    for a, t, w in zip(assignments, truths, weights):
        ok = t >= 0
        np.add.at(table, (a[ok], t[ok]), w[ok])
    mapping = np.argmax(table, axis=1)
    mapping[table.sum(axis=1) == 0] = -1
    return mapping


def accuracy(predicted, truth, weights=None) -> float:
    """Fraction (weighted) of labelled elements whose predicted label equals the truth.

    predicted, truth : (f,) int (truth -1: unlabelled, excluded); weights : (f,) float or None.
    """
    predicted, truth = np.asarray(predicted), np.asarray(truth)
    w = np.ones(len(truth)) if weights is None else np.asarray(weights, float)
    ok = truth >= 0
    total = w[ok].sum()
    return float(w[ok][predicted[ok] == truth[ok]].sum() / total) if total > 0 else float("nan")


def label_iou(predicted_list, truth_list, weights_list, label_count: int) -> np.ndarray:
    """Per-label IoU by area over a collection: ``sum_i |P_i ∩ T_i| / sum_i |P_i ∪ T_i|``
    (areas summed over the shapes before dividing). Returns ``(label_count,) float`` (nan for a
    label that appears in neither)."""
    inter = np.zeros(label_count)
    union = np.zeros(label_count)
    for p, t, w in zip(predicted_list, truth_list, weights_list):
        labelled = t >= 0
        for lab in range(label_count):
            ip, it = (p == lab) & labelled, t == lab
            inter[lab] += w[ip & it].sum()
            union[lab] += w[ip | it].sum()
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / union, np.nan)


def name_mapping(part_names, label_names) -> np.ndarray:
    """Each primitive index mapped to the ground-truth label its stored name matches.

    part_names : (m,) str, the model's names; label_names : list of str, ground-truth names whose
    ``/``-separated aliases are matched case-insensitively (``"legs/base"``)  ->  (m,) int code
    into ``label_names``, -1 where the name is no label.
    """
    lookup = {}
    for code, name in enumerate(label_names):
        for alias in str(name).lower().split("/"):
            lookup.setdefault(alias.strip(), code)
    return np.array([lookup.get(str(n).lower(), -1) for n in part_names], dtype=np.int64)


def evaluate(segmentations, truths, *, part_names=None) -> SegmentationEvaluation:
    """Accuracy of co-segmentations against ground truth under the protocols of :data:`PROTOCOLS`.

    Parameters
    ----------
    segmentations : list of Segmentation
    truths : list of GroundTruth (same order; sharing one ``names`` list)
    part_names : list of str, optional
        The model's part names; the ``"model-names"`` protocol is reported only when some name
        matches a ground-truth label.

    Returns
    -------
    SegmentationEvaluation: ``labels`` (names), and per protocol (:class:`ProtocolScores`):
    ``description``, ``mapping`` (index -> label name or None), ``shapes`` ({name: ShapeAccuracy}),
    ``mean_faces``, ``mean_area``, ``iou`` ({label: IoU}), ``mean_iou``; ``to_dict()`` is the JSON.
    """
    if len(segmentations) != len(truths):
        raise ValueError(f"{len(segmentations)} segmentations but {len(truths)} ground truths")
    if not segmentations:
        raise ValueError("nothing to evaluate")
    names = list(truths[0].names)
    for t in truths:
        if len(t.names) > len(names):
            names = list(t.names)
    count = segmentations[0].cuboids.count
    assign = [s.face_labels for s in segmentations]
    truth = [t.labels for t in truths]
    weights = [s.face_areas for s in segmentations]
    mappings = {"collection-majority": [majority_mapping(assign, truth, weights, count, len(names))] * len(assign)}
    loo = []
    for i in range(len(assign)):
        others = [j for j in range(len(assign)) if j != i]
        loo.append(majority_mapping([assign[j] for j in others], [truth[j] for j in others],
                                    [weights[j] for j in others], count, len(names)))
    mappings["leave-one-out"] = loo
    if part_names is not None:
        named = name_mapping(part_names, names)
        if (named >= 0).any():
            mappings["model-names"] = [named] * len(assign)
    protocols = {}
    for protocol, maps in mappings.items():
        predicted = [m[a] for m, a in zip(maps, assign)]
        shapes = {}
        for s, p, t, w in zip(segmentations, predicted, truth, weights):
            shapes[s.name] = ShapeAccuracy(accuracy(p, t), accuracy(p, t, w))
        iou = label_iou(predicted, truth, weights, len(names))
        protocols[protocol] = ProtocolScores(
            description=PROTOCOLS[protocol],
            shapes=shapes,
            mean_faces=float(np.mean([v.faces for v in shapes.values()])),
            mean_area=float(np.mean([v.area for v in shapes.values()])),
            iou={n: float(x) for n, x in zip(names, iou)},
            mean_iou=float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan"),
            mapping=None if protocol == "leave-one-out" else
            {str(k): (names[c] if c >= 0 else None) for k, c in enumerate(maps[0])},
        )
    return SegmentationEvaluation(names, protocols)


# Voxel grids
# ---------------------------------------------------------------------------------------------

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
        # every member's header checked first: a truncated archive is one line (a BadZipFile
        # traceback before), and no member may declare more than the largest grid allowed
        self._members = npz_members(path, max_bytes=8 * max_grid() ** 3)
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
        raw = np.asarray(read_npz_member(self._archive, self.path, str(name)))
        if shape is not None and raw.shape != tuple(shape):
            raise io.ShapeFileError(self.path, f"labels of {name} are {raw.shape}, the grid is {tuple(shape)}")
        codes = np.full(raw.shape, -1, np.int64)
        for value, code in self._code.items():
            codes[raw == value] = code
        return VoxelGroundTruth(codes, list(self.names))


@dataclass(frozen=True)
class Detection:
    """How well one label's presence on a shape is predicted (a shape *has* a label when one of its
    voxels carries it): counts over the shapes, precision, recall, F1 (nan where undefined) and
    the fraction of the shapes without the label that are predicted without it too."""

    shapes_with: int
    shapes_without: int
    true_positive: int
    false_positive: int
    false_negative: int
    precision: float
    recall: float
    f1: float
    absent_kept_absent: float


@dataclass(frozen=True)
class VoxelShapeScores:
    """One shape's voxel accuracy and per-label IoU ({label: IoU})."""

    accuracy: float
    iou: dict[str, float]


@dataclass(frozen=True)
class VoxelProtocolScores:
    """The scores of voxel co-segmentations under one protocol (:data:`VOXEL_PROTOCOLS`, or
    ``"labeller"``): ``mapping`` (index as str -> label or None), ``iou`` ({label: mean per-shape IoU}),
    ``mean_iou`` (over the evaluation's ``mean_over``), ``accuracy`` (mean over shapes),
    ``detection`` ({label: Detection}) and ``shapes`` ({name: VoxelShapeScores})."""

    description: str
    mapping: dict[str, str | None]
    iou: dict[str, float]
    mean_iou: float
    accuracy: float
    detection: dict[str, Detection]
    shapes: dict[str, VoxelShapeScores]

    def to_dict(self) -> dict:
        """The protocol's entry of ``evaluation-voxels.json``."""
        return asdict(self)


@dataclass(frozen=True)
class VoxelEvaluation:
    """What :func:`evaluate_voxels` returns: the labels (first aliases), how IoU is counted, the
    labels averaged into ``mean_iou``, the number of shapes, and ``protocols`` ({name: VoxelProtocolScores})."""

    labels: list[str]
    iou_rule: str
    mean_over: list[str]
    shapes_evaluated: int
    protocols: dict[str, VoxelProtocolScores]

    def to_dict(self) -> dict:
        """The JSON document of ``evaluation-voxels.json``."""
        return asdict(self)


def _per_shape_iou(predicted, truth, label_count):
    """(label_count,) IoU of one shape's voxels, 1 where a label is absent from both."""
    iou = np.ones(label_count)
    for lab in range(label_count):
        p, t = predicted == lab, truth == lab
        union = np.count_nonzero(p | t)
        if union:
            iou[lab] = np.count_nonzero(p & t) / union
    return iou


def _detection(predicted_has, truth_has) -> Detection:
    predicted_has, truth_has = np.asarray(predicted_has, bool), np.asarray(truth_has, bool)
    tp = int(np.count_nonzero(predicted_has & truth_has))
    fp = int(np.count_nonzero(predicted_has & ~truth_has))
    fn = int(np.count_nonzero(~predicted_has & truth_has))
    absent = int(np.count_nonzero(~truth_has))
    precision = tp / (tp + fp) if tp + fp else float("nan")
    recall = tp / (tp + fn) if tp + fn else float("nan")
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan")
    return Detection(
        shapes_with=int(truth_has.sum()), shapes_without=absent, true_positive=tp,
        false_positive=fp, false_negative=fn, precision=precision, recall=recall, f1=f1,
        absent_kept_absent=(absent - fp) / absent if absent else float("nan"),
    )


def evaluate_voxels(assignments, truths, part_count: int, *, part_names=None, names=None,
                    mean_over=None) -> VoxelEvaluation:
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
    VoxelEvaluation: ``labels`` (first aliases), ``iou_rule``, and per protocol
    (:class:`VoxelProtocolScores`) ``description``, ``mapping`` (index -> label or None), ``iou``
    ({label: mean per-shape IoU}), ``mean_iou``, ``accuracy`` (mean over shapes), ``detection``
    ({label: Detection}) and ``shapes`` ({name: VoxelShapeScores}); ``to_dict()`` is the JSON.
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
    mappings = {"collection-majority": majority_mapping(flat_a, flat_t, weights, part_count, count)}
    if part_names is not None:
        named = name_mapping(part_names, label_names)
        if (named >= 0).any():
            mappings["model-names"] = named
    if mean_over is None:
        mean_idx = list(range(count))
    else:
        unknown = [n for n in mean_over if n not in short]
        if unknown:
            raise ValueError(f"mean_over names {unknown} are not labels ({', '.join(short)})")
        mean_idx = [short.index(n) for n in mean_over]
    protocols = {}
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
            shapes[name] = VoxelShapeScores(acc, {short[i]: float(iou[i]) for i in range(count)})
        per_shape = np.array(per_shape)
        has_p, has_t = np.array(has_p), np.array(has_t)
        iou = per_shape.mean(axis=0)
        protocols[protocol] = VoxelProtocolScores(
            description=VOXEL_PROTOCOLS[protocol],
            mapping={str(k): (short[c] if c >= 0 else None) for k, c in enumerate(mapping)},
            iou={short[i]: float(iou[i]) for i in range(count)},
            mean_iou=float(np.mean(iou[mean_idx])),
            accuracy=float(np.nanmean(accuracies)),
            detection={short[i]: _detection(has_p[:, i], has_t[:, i]) for i in range(count)},
            shapes=shapes,
        )
    return VoxelEvaluation(
        labels=short,
        iou_rule="per shape over its occupied voxels, 1 when a label is absent from both prediction and truth, "
        "averaged over shapes",
        mean_over=[short[i] for i in mean_idx],
        shapes_evaluated=len(truths),
        protocols=protocols,
    )


# A collection's segmentations against the ground truth found for them
# ---------------------------------------------------------------------------------------------


def ground_truth_sources(folders, label_names=None) -> list:
    """``[(folder, label names or None)]`` from the folders of ground truth and what their values
    mean (``--gt`` / ``--gt-names``: given once for every folder, or once per folder)."""
    folders = list(folders or [])
    names = list(label_names or [])
    if names and len(names) not in (1, len(folders)):
        raise ValueError(f"--gt-names given {len(names)} times for {len(folders)} --gt folders (give it once, or once per --gt)")
    if len(names) == 1:
        names = names * len(folders)
    return list(zip(folders, names or [None] * len(folders)))


def find_truth(seg, sources):
    """The ``.seg`` file of a segmented shape in the ``sources`` folders (same stem): (path, names) or None."""
    stem = Path(seg.source).stem
    for folder, names in sources:
        for candidate in (Path(folder) / f"{stem}.seg", Path(folder) / f"{seg.name}.seg"):
            if candidate.is_file() and candidate.resolve() != Path(seg.source).resolve():
                return candidate, names
    return None


def voxel_archives(sources) -> list:
    """The ``sources`` that are voxel label archives (an ``.npz``, or a folder holding
    ``voxlabels.npz``): ``[VoxelLabelArchive]``."""
    archives = []
    for folder, names in sources:
        path = Path(folder)
        if path.suffix == ".npz" or (path / "voxlabels.npz").is_file():
            archives.append(VoxelLabelArchive(path, parse_label_names(names) if names else None))
    return archives


def voxel_truth(seg, archives):
    """The ground truth of a voxel segmentation in the archives (by shape name), or None."""
    for archive in archives:
        if seg.name in archive:
            return archive.get(seg.name, seg.labels.shape)
    return None


def evaluate_meshes_against(meshes, sources, part_names):
    """Mesh segmentations against the ``.seg`` files of ``sources``: ``(report or None, errors)``
    (:func:`evaluate`; a shape without ground truth is an error line)."""
    pairs, names, errors = [], [], []
    for s in meshes:
        found = find_truth(s, sources)
        if found is None:
            errors.append(f"{s.source}: no ground-truth .seg named {Path(s.source).stem}.seg in the --gt folders")
            continue
        try:
            pairs.append((s, read_ground_truth(found[0], len(s.faces), found[1], names)))
        except (ValueError, OSError) as exc:
            errors.append(str(exc).splitlines()[0])
    if not pairs:
        return None, errors
    return evaluate([p[0] for p in pairs], [p[1] for p in pairs], part_names=part_names), errors


def evaluate_grids_against(grids, sources, part_count: int, part_names, *, labeller=None, mean_over=None):
    """Voxel segmentations against the archives of ``sources``: ``(report or None, errors)``
    (:func:`evaluate_voxels`; with a ``labeller``, its names scored too as protocol ``"labeller"``)."""
    archives = voxel_archives(sources)
    pairs, errors = [], []
    for s in grids:
        truth = voxel_truth(s, archives)
        if truth is None:
            errors.append(f"{s.source}: no voxel labels for {s.name} in the --gt archives")
        else:
            pairs.append((s, truth))
    if not pairs:
        return None, errors
    report = evaluate_voxels([p[0].labels for p in pairs], [p[1] for p in pairs], part_count, part_names=part_names,
                             names=[p[0].name for p in pairs], mean_over=mean_over)
    if labeller is not None:  # each voxel named by the labeller: its names are the "parts"
        names = list(labeller.names)
        by_label = evaluate_voxels([p[0].named for p in pairs], [p[1] for p in pairs], len(names), part_names=names,
                                   names=[p[0].name for p in pairs], mean_over=mean_over)
        if "model-names" in by_label.protocols:
            report.protocols["labeller"] = replace(
                by_label.protocols["model-names"],
                description="each voxel named by the model's labeller (learned on other shapes)")
    return report, errors


#: the per-point labels of a point cloud ``<stem>.xyz`` (or ``.ply``, ``.npy``): ``<stem>.labels.npy``
POINT_LABELS = ".labels.npy"


def read_point_truth(path, count: int, label_names, names: list, unnamed=None) -> np.ndarray:
    """A point cloud's labels (``(count,)`` integers in a ``.npy``, read without pickles) as codes
    into the collection-wide ``names`` (extended); values named by ``label_names`` ('back,seat'
    for 1, 2) or by themselves; a value with no name is unlabelled (-1)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no per-point label file beside the cloud")
    try:
        raw = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a NumPy label array ({exc})") from None
    if raw.shape != (count,) or raw.dtype.kind not in "iu":
        raise ValueError(f"{path}: expected ({count},) integers, one per point, got {raw.dtype} {raw.shape}")
    meaning = parse_label_names(label_names) if label_names else read_label_names(path)
    codes = np.full(count, -1, np.int64)
    for value in np.unique(raw):
        name = str(value) if meaning is None else meaning.get(int(value))
        if name is None:
            if unnamed is not None and value >= 0:  # negative: unlabelled by convention
                unnamed.add(int(value))
            continue
        if name not in names:
            names.append(name)
        codes[raw == value] = names.index(name)
    return codes


@dataclass
class LabelledShapes:
    """Segmented shapes with their ground-truth labels, for learning part names and a labeller.

    Attributes
    ----------
    names : list of str
        The collection-wide label names (what the codes index).
    assignments : list of (k,) int
        Per shape, each element's part index.
    labels : list of (k,) int
        Per shape, each element's ground-truth code (-1: unlabelled).
    weights : list of (k,) float or None
        Per shape, each element's vote (a face's area; None: one voxel or point, one vote).
    used : list of str
        The shapes' names.
    learned : list of tuple
        ``(segmentation, abstraction result, codes)`` per shape: what
        :func:`primkit.segmentation.segmenter.fit_labeller` reads.
    errors : list of str
        One line per shape whose labels could not be found or read.
    archives : list of str
        The voxel label archives read (``labels`` when it is one).
    """

    names: list
    assignments: list
    labels: list
    weights: list
    used: list
    learned: list
    errors: list
    archives: list = field(default_factory=list)


def labelled_shapes(segmentations, results, labels=None, label_names=None) -> LabelledShapes:
    """Each segmentation with its ground truth: a voxel grid's in the archive ``labels``, a point
    cloud's in ``<stem>.labels.npy`` beside it, a mesh's ``.seg`` in the folder ``labels`` or beside
    it. ``results``: the abstraction results the segmentations came from (by name).

    ``label_names`` (``--names``) must name every label value the shapes' label files hold: values
    left without a name would count as unlabelled, and the parts they cover would take the names of
    the others (``back`` for labels 1-3 named the seat "back"); negative values are unlabelled by
    convention. Names given as a list
    (``"back,seat"``) that leave values out raise ValueError naming them; names given value by value
    (``"1=back"``) leave the others out on purpose, with a warning naming them. Empty names raise."""
    unnamed: set = set()
    if label_names is not None:
        parse_label_names(label_names)  # empty or malformed: one line before any file is read
    sources = [(labels, label_names)] if labels else []
    archives = voxel_archives(sources)
    by_name = {r.name: r for r in results}
    out = LabelledShapes([], [], [], [], [], [], [], [str(a.path) for a in archives])
    names = out.names

    def add(s, assignment, codes, weights):
        out.assignments.append(assignment)
        out.labels.append(codes)
        out.weights.append(weights)
        out.used.append(s.name)
        out.learned.append((s, by_name[s.name], codes))

    for s in segmentations:
        if isinstance(s, VoxelSegmentation):
            truth = voxel_truth(s, archives)
            if truth is None:
                out.errors.append(f"{s.source}: no voxel labels for {s.name} (give --labels a voxel label archive)")
                continue
            short = [str(n).split("/")[0] for n in truth.names]
            for n in short:
                if n not in names:
                    names.append(n)
            occupied = s.labels >= 0
            codes = np.array([names.index(short[c]) if c >= 0 else -1 for c in range(len(short))] + [-1])
            add(s, s.labels[occupied], codes[truth.labels[occupied]], None)  # one voxel, one vote
            continue
        if isinstance(s, PointSegmentation):
            beside = Path(s.source).with_name(Path(s.source).stem + POINT_LABELS)
            try:
                codes = read_point_truth(beside, len(s.points), label_names, names, unnamed)
            except ValueError as exc:
                out.errors.append(str(exc).splitlines()[0])
                continue
            add(s, s.labels, codes, None)  # one point, one vote
            continue
        found = find_truth(s, sources) if sources and not archives else None
        if found is None:
            beside = Path(s.source).with_suffix(".seg")
            found = (beside, label_names) if beside.is_file() else None
        if found is None:
            out.errors.append(f"{s.source}: no label file ({Path(s.source).stem}.seg) found")
            continue
        try:
            truth = read_ground_truth(found[0], len(s.faces), found[1], names,
                                      unnamed if found[1] is label_names else None)
        except (ValueError, OSError) as exc:
            out.errors.append(str(exc).splitlines()[0])
            continue
        add(s, s.face_labels, truth.labels, s.face_areas)
    if unnamed and label_names is not None:
        values = ", ".join(map(str, sorted(unnamed)))
        if all("=" in t for t in str(label_names).split(",") if t.strip()):
            warnings.warn(f"label names {label_names!r} leave the label values {values} found in the shapes without "
                          "a name: they count as unlabelled", UserWarning, stacklevel=2)
        else:
            raise ValueError(f"label names {label_names!r} name the values "
                             f"{', '.join(map(str, sorted(parse_label_names(label_names))))}, but the shapes also hold "
                             f"the label values {values}: they would count as unlabelled and the parts they cover "
                             "take the others' names; name every value, or give VALUE=NAME pairs (1=back) to leave "
                             "some out")
    return out

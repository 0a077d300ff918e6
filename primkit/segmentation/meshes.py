"""Co-segmentation of meshes and points: each surface element goes to its nearest primitive.

Because one network explains a whole category, primitive ``k`` is the same part on every shape,
and projecting a mesh onto its abstraction parses the whole collection consistently with no labels
given (Tulsiani et al. 2017, Sec. 5.1).

The rule
--------
A point goes to the present cuboid at the smallest distance (zero inside), ties (a point inside
several cuboids) to the larger cuboid, then to the lower index: :func:`primkit.primitives.assign_points`.

* :func:`point_labels` / :func:`vertex_labels`: the rule applied to points or mesh vertices.
* :func:`face_labels`: a face takes the index that holds most of its area. The area is measured
  with a fixed quadrature rather than random samples: one midpoint subdivision splits a triangle
  into four triangles of equal area, and the centroid of each votes for a quarter of the face's
  area; a tie (2-2 or all different) goes to the index of the face's centroid. This is the
  area-weighted vote of points on the face, deterministic and exact for faces that lie in one
  part, and it costs four point projections per face (a million faces in about a second).

Evaluation against ground-truth labels (:func:`evaluate`) reports accuracy by faces and by surface
area and per-label IoU under stated label-mapping protocols:

* ``"collection-majority"`` (the paper's): each primitive index is mapped to the ground-truth
  label holding most of its area over the evaluated collection;
* ``"leave-one-out"``: for each shape, the same majority mapping learned on the *other* shapes of
  the collection, applied unchanged;
* ``"model-names"``: the part names stored in the model file (:mod:`primkit.model.parts`, learned on
  other shapes by ``primkit name-parts``), matched to the ground truth's label names, applied
  unchanged. Indices whose name is not a ground-truth label count as wrong.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import io, primitives
from ..model import parts
from ..primitives.palette import part_colors
from . import graphcut

__all__ = [
    "point_labels",
    "vertex_labels",
    "face_labels",
    "Segmentation",
    "segment_mesh",
    "surface_face_labels",
    "semantic_codes",
    "GroundTruth",
    "read_ground_truth",
    "parse_label_names",
    "majority_mapping",
    "name_mapping",
    "accuracy",
    "label_iou",
    "evaluate",
    "PROTOCOLS",
]

#: Label-mapping protocols of :func:`evaluate`, in the order they are reported.
PROTOCOLS = {
    "collection-majority": "each primitive index mapped to the ground-truth label holding most of its area over the "
    "evaluated collection (the paper's protocol)",
    "leave-one-out": "for each shape, the majority mapping learned on the other shapes of the collection, applied unchanged",
    "model-names": "the part names stored in the model (learned on other shapes) matched to the ground-truth label "
    "names, applied unchanged",
}


def point_labels(points, cuboids: primitives.Cuboids) -> np.ndarray:
    """Primitive index of each point (nearest present cuboid, ties to the larger).

    points : (n, 3) float  ->  (n,) int
    """
    return primitives.assign_points(points, cuboids)


def vertex_labels(vertices, cuboids: primitives.Cuboids) -> np.ndarray:
    """Primitive index of each mesh vertex: :func:`point_labels` of the vertices.

    vertices : (n, 3) float  ->  (n,) int
    """
    return point_labels(vertices, cuboids)


# centroids of the four equal-area triangles of one midpoint subdivision, in barycentric
# coordinates, then the face's own centroid (the tie-breaker)
_QUADRATURE = np.array(
    [[4, 1, 1], [1, 4, 1], [1, 1, 4], [2, 2, 2], [2, 2, 2]], dtype=float
) / 6.0


def semantic_codes(labels, part_names, named=None, label_names=None) -> tuple[list, np.ndarray]:
    """``(names, codes)`` of elements (points, voxels) labelled ``labels`` (part indices, -1 none):
    the distinct names and each element's 1-based name code (-1 none). With a labeller's ``named``
    (indices into ``label_names``, -1 none) its names; else each index's name
    (:func:`primkit.model.parts.label_codes`, the same codes on every shape of a model)."""
    if named is not None:
        return list(label_names), np.where(named >= 0, named + 1, -1)
    return parts.label_codes(part_names)[0], parts.named_labels(labels, part_names)


def face_labels(vertices, faces, cuboids: primitives.Cuboids) -> np.ndarray:
    """Primitive index of each face: the index holding most of its area (see the module notes).

    vertices : (n, 3) float, faces : (f, 3) int  ->  (f,) int
    """
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"`faces` must be (f, 3) int, got shape {faces.shape}")
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    corners = vertices[faces]  # (f, 3, 3)
    points = np.einsum("qc,fcd->fqd", _QUADRATURE, corners).reshape(-1, 3)
    votes = point_labels(points, cuboids).reshape(len(faces), len(_QUADRATURE))
    quarters, centroid = votes[:, :4], votes[:, 4]
    # count of each quarter's label among the four quarters; a label wins with 3 or 4 votes, or
    # with 2 votes when the other two quarters disagree with each other (2-1-1)
    same = (quarters[:, :, None] == quarters[:, None, :]).sum(axis=2)
    best = np.argmax(same, axis=1)
    top = same[np.arange(len(faces)), best]
    winner = quarters[np.arange(len(faces)), best]
    distinct_pairs = (top == 2) & ((same == 2).sum(axis=1) == 4)  # 2-2 split
    tie = (top == 1) | distinct_pairs
    return np.where(tie, centroid, winner)


@dataclass(frozen=True, eq=False)
class Segmentation:
    """The co-segmentation of one mesh by its abstraction.

    Attributes
    ----------
    name, source : str
    vertices : (n, 3) float
    faces : (f, 3) int
    face_labels : (f,) int
        Primitive index of each face.
    vertex_labels : (n,) int
        Primitive index of each vertex.
    cuboids : primitives.Cuboids
        The abstraction, in the mesh's frame.
    part_names : list of str
        The model's name of each index (``part<k>`` when unnamed).
    """

    name: str
    source: str
    vertices: np.ndarray
    faces: np.ndarray
    face_labels: np.ndarray
    vertex_labels: np.ndarray
    cuboids: primitives.Cuboids
    part_names: list = field(default_factory=list)
    #: with a labeller in the model (:mod:`primkit.segmentation.labeller`): each face's label, an
    #: index into ``label_names`` (-1: none), and the labeller's names; None without one
    named: np.ndarray | None = None
    label_names: list | None = None

    @property
    def face_areas(self) -> np.ndarray:
        """(f,) float"""
        return io.Mesh(self.vertices, self.faces).face_areas()

    def part_areas(self) -> np.ndarray:
        """Surface area assigned to each index: ``(m,) float`` (zero for parts holding no face)."""
        return np.bincount(self.face_labels, weights=self.face_areas, minlength=self.cuboids.count)

    def semantic_labels(self) -> tuple[list, np.ndarray]:
        """``(names, codes)``: the distinct part names and each face's 1-based name code
        (:func:`primkit.model.parts.label_codes`, the same codes on every shape of a model)."""
        if self.named is not None:  # the labeller's names, one per face
            return list(self.label_names), np.where(self.named >= 0, self.named + 1, -1)
        names, codes = parts.label_codes(self.part_names)
        return names, codes[self.face_labels]

    def save(self, folder, *, semantic: bool = False, overwrite: bool = False) -> dict:
        """Write ``<name>.seg`` (one label per face: the part index, or with ``semantic`` the
        1-based code of its name) and ``<name>.parts.ply`` (the mesh, faces coloured by part with
        the colour of :func:`primkit.viz.palette.part_colors`, the same on every shape).
        Returns ``{"labels": path, "mesh": path}``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = {"labels": folder / f"{self.name}.seg", "mesh": folder / f"{self.name}.parts.ply"}
        io.refuse_existing(paths.values(), overwrite)
        if semantic:
            names, labels = self.semantic_labels()
            colors = part_colors(len(names) + 1)[labels]
        else:
            labels = self.face_labels
            colors = part_colors(self.cuboids.count)[labels]
        io.write_labels(paths["labels"], labels, overwrite=overwrite)
        io.write_mesh(paths["mesh"], self.vertices, self.faces, face_colors=colors, overwrite=overwrite)
        return paths


def surface_face_labels(vertices, faces, cuboids: primitives.Cuboids, *, smoothness: float | None = None) -> np.ndarray:
    """Primitive index of each face by a graph cut over face adjacency, started from
    :func:`face_labels` (:mod:`primkit.segmentation.graphcut`; ``smoothness`` None: its default).

    vertices : (n, 3) float, faces : (f, 3) int  ->  (f,) int
    """
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    init = face_labels(vertices, faces, cuboids)
    weight = graphcut.Labelling("graphcut", smoothness).weight("mesh")  # None: the validated default
    if len(faces) == 0 or weight <= 0:
        return init
    samples = np.einsum("qc,fcd->fqd", _QUADRATURE[:4], vertices[faces])
    edges, contact, mass = graphcut.mesh_graph(vertices, faces)
    return graphcut.graphcut_labels(samples, edges, contact, mass, cuboids, init, weight)


def segment_mesh(vertices, faces, cuboids: primitives.Cuboids, *, name: str = "shape", source: str = "",
                 part_names=None, labelling=None) -> Segmentation:
    """Co-segment one mesh by its abstraction (cuboids in the mesh's frame).

    ``labelling``: ``"nearest"`` (:func:`face_labels`), ``"graphcut"`` (:func:`surface_face_labels`),
    a :class:`primkit.segmentation.graphcut.Labelling`, or None: the graph cut
    (:data:`primkit.segmentation.graphcut.DEFAULT_LABELLING`)."""
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    names = list(part_names) if part_names is not None else parts.default_part_names(cuboids.count)
    how = graphcut.as_labelling(labelling)
    labels = (surface_face_labels(vertices, faces, cuboids, smoothness=how.smoothness) if how.method_for("mesh") == "graphcut"
              else face_labels(vertices, faces, cuboids))
    return Segmentation(name, source, vertices, faces, labels, vertex_labels(vertices, cuboids), cuboids, names)


# ---------------------------------------------------------------------------------------------
# Ground truth and evaluation
# ---------------------------------------------------------------------------------------------


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
    items = [t.strip() for t in text.split(",") if t.strip()]
    if all("=" in t for t in items):
        return {int(k): v.strip() for k, v in (t.split("=", 1) for t in items)}
    if any("=" in t for t in items):
        raise ValueError(f"label names {text!r}: give either all values (1=back,2=seat) or none (back,seat)")
    return {i + 1: name for i, name in enumerate(items)}


def read_ground_truth(label_path, face_count: int, label_names=None, names=None) -> GroundTruth:
    """Read a ``.seg`` file as a :class:`GroundTruth`.

    Parameters
    ----------
    label_path : path of the ``.seg`` file (one integer per face).
    face_count : the mesh's number of faces (checked).
    label_names : str or dict or None
        What each label value means: ``"back,seat,legs"`` (values 1, 2, 3, as in COSEG),
        ``"1=back,2=seat"`` or ``{1: "back"}``. None: a ``.json`` written by
        :func:`primkit.synthetic.write_collection` beside the labels gives the part groups
        (``seat``, ``back``, ``legs``, ``arms``, ...); otherwise the values themselves are the names.
    names : list of str, optional
        A collection-wide list of names to extend (so codes agree across shapes).
    """
    label_path = Path(label_path)
    raw = io.read_labels(label_path, face_count)
    if isinstance(label_names, str):
        label_names = parse_label_names(label_names)
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


def evaluate(segmentations, truths, *, part_names=None) -> dict:
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
    dict with ``labels`` (names), and per protocol: ``description``, ``mapping`` (index -> label
    name or None), ``shapes`` ({name: {"faces": acc, "area": acc}}), ``mean_faces``, ``mean_area``,
    ``iou`` ({label: IoU}), ``mean_iou``.
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
    report = {"labels": names, "area_weighting": "face area", "protocols": {}}
    for protocol, maps in mappings.items():
        predicted = [m[a] for m, a in zip(maps, assign)]
        shapes = {}
        for s, p, t, w in zip(segmentations, predicted, truth, weights):
            shapes[s.name] = {"faces": accuracy(p, t), "area": accuracy(p, t, w)}
        iou = label_iou(predicted, truth, weights, len(names))
        entry = {
            "description": PROTOCOLS[protocol],
            "shapes": shapes,
            "mean_faces": float(np.mean([v["faces"] for v in shapes.values()])),
            "mean_area": float(np.mean([v["area"] for v in shapes.values()])),
            "iou": {n: float(x) for n, x in zip(names, iou)},
            "mean_iou": float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan"),
        }
        if protocol != "leave-one-out":
            entry["mapping"] = {str(k): (names[c] if c >= 0 else None) for k, c in enumerate(maps[0])}
        report["protocols"][protocol] = entry
    return report

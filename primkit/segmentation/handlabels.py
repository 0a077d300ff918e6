"""Labelling a shape by hand: the state behind ``primkit view abstraction --label-to`` (no GUI).

A person names the elements of one shape (a mesh's faces, or a point cloud's points) in two ways:

* **by cuboid**: every element whose part index (the abstraction's own co-segmentation, what the
  viewer colours) is ``k`` takes the name (:meth:`HandLabels.assign_part`);
* **with a brush**: every element within ``radius`` of a picked point takes the name
  (:meth:`HandLabels.paint`). On a mesh the brush spreads from the picked face through faces that
  share an edge and whose centroids stay inside the ball, so it does not jump across a thin
  seat to the faces underneath (the ball's faces not reached that way keep their label); on a
  point cloud it takes every point in the ball (Euclidean).

Each call is one step :meth:`HandLabels.undo` takes back. :meth:`HandLabels.save` writes what
``primkit name-parts`` reads:

* a mesh: ``<stem>.seg``, COSEG-style, one integer per face in face order: 1, 2, ... the names in
  the order they were first given, 0 unlabelled;
* a point cloud: ``<stem>.labels.npy`` beside the cloud, the same codes, one per point (int64);
* beside either, ``<stem>.names.json``: ``{"format": "primkit-label-names", "format_version": 1,
  "names": {"1": "seat", "2": "back"}, ...}``, which :func:`read_label_names` reads back (and
  :func:`primkit.segmentation.evaluation.read_ground_truth` and ``name-parts`` with it: the
  person's names carry through; 0 has no name, so unlabelled elements stay out of the learning).

Both files are written atomically; neither replaces an existing file unless ``overwrite`` (the
files this object wrote itself are replaced by its later saves).

Units: positions and radii in the frame of the vertices given (the viewer's: the input's own).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import io

__all__ = ["HandLabels", "NAMES_SUFFIX", "NAMES_FORMAT", "names_path", "read_label_names", "label_suffix"]

#: The names file beside a hand-written label file: ``chair.seg`` -> ``chair.names.json``.
NAMES_SUFFIX = ".names.json"
NAMES_FORMAT = "primkit-label-names"
_VERSION = 1
_POINT_LABELS = ".labels.npy"  # evaluation.POINT_LABELS (this module sits below evaluation)


def label_suffix(path) -> str:
    """``".seg"`` or ``".labels.npy"``: which kind of label file ``path`` names, whatever the case
    of its letters (ValueError else)."""
    name = Path(path).name.lower()
    if name.endswith(_POINT_LABELS):
        return _POINT_LABELS
    if name.endswith(".seg"):
        return ".seg"
    raise ValueError(f"{path}: a label file is <stem>.seg (per face) or <stem>{_POINT_LABELS} (per point)")


def names_path(label_path) -> Path:
    """The names file of a label file: ``<stem>.names.json`` beside it."""
    label_path = Path(label_path)
    stem = label_path.name[: -len(label_suffix(label_path))]
    return label_path.with_name(stem + NAMES_SUFFIX)


def read_label_names(label_path) -> dict | None:
    """``{code: name}`` from the names file beside ``label_path`` (:func:`names_path`), or None
    when there is none (or ``label_path`` is no ``.seg`` / ``.labels.npy``). A file that is not
    such a names file raises ValueError naming it."""
    try:
        path = names_path(label_path)
    except ValueError:
        return None
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        if doc.get("format") != NAMES_FORMAT:
            raise ValueError(f"format is {doc.get('format')!r}, not {NAMES_FORMAT!r}")
        if int(doc.get("format_version", 0)) > _VERSION:
            raise ValueError(f"format_version {doc.get('format_version')} is newer than this primkit reads ({_VERSION})")
        names = {int(k): str(v) for k, v in doc["names"].items()}
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"{path}: not a label names file ({exc})") from None
    return names


@dataclass
class _Step:
    index: np.ndarray  # elements changed
    before: np.ndarray  # their codes before


@dataclass(eq=False)
class HandLabels:
    """One shape's elements and the names a person gives them.

    Parameters
    ----------
    points : (n, 3) float
        The elements' positions: face centroids of a mesh (:meth:`for_mesh`), or the points.
    parts : (n,) int
        Each element's part index (the co-segmentation the viewer shows); -1 none.
    adjacency : (a, 2) int, optional
        Pairs of elements that touch (a mesh's faces sharing an edge); the brush spreads along
        them. None: the brush takes the whole ball.

    Attributes
    ----------
    codes : (n,) int
        Each element's name, ``names[code - 1]``; 0 unlabelled.
    names : list of str
        Every name given so far, in order (a name no element carries any more is left out of
        the saved files).
    """

    points: np.ndarray
    parts: np.ndarray
    adjacency: np.ndarray | None = None
    codes: np.ndarray = field(init=False)
    names: list = field(init=False, default_factory=list)
    _history: list = field(init=False, default_factory=list, repr=False)
    _written: set = field(init=False, default_factory=set, repr=False)
    _graph: object = field(init=False, default=None, repr=False)

    def __post_init__(self):
        self.points = np.asarray(self.points, float)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise ValueError(f"`points` must be (n, 3) float, got shape {self.points.shape}")
        self.parts = np.asarray(self.parts, np.int64)
        if self.parts.shape != (len(self.points),):
            raise ValueError(f"`parts` must be ({len(self.points)},) int, one per element, got shape {self.parts.shape}")
        if self.adjacency is not None:
            self.adjacency = np.asarray(self.adjacency, np.int64).reshape(-1, 2)
        self.codes = np.zeros(len(self.points), np.int64)

    @classmethod
    def for_mesh(cls, vertices, faces, parts) -> "HandLabels":
        """A mesh's faces: centroids as the points, faces sharing an edge as the adjacency
        (trimesh's ``face_adjacency``)."""
        import trimesh

        mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
        return cls(mesh.triangles_center, parts, mesh.face_adjacency)

    def load(self, path) -> "HandLabels":
        """Start from a label file (a ``.seg`` or ``.labels.npy`` with one integer per element): its
        names from the names file beside it (:func:`read_label_names`), else each value its own
        name; 0 and values the names file leaves out stay unlabelled. One undoable step; returns
        ``self``. Raises ValueError (naming the file) when it does not fit the elements."""
        path = Path(path)
        if label_suffix(path) == ".seg":
            raw = io.read_labels(path, len(self.codes))
        else:
            try:
                raw = np.load(path, allow_pickle=False)
            except (OSError, ValueError) as exc:
                raise ValueError(f"{path}: not a NumPy label array ({exc})") from None
            if raw.shape != self.codes.shape or raw.dtype.kind not in "iu":
                raise ValueError(f"{path}: expected ({len(self.codes)},) integers, got {raw.dtype} {raw.shape}")
        meaning = read_label_names(path)
        values = np.unique(raw)
        names = [meaning.get(int(v)) if meaning is not None else (str(v) if v != 0 else None) for v in values]
        return self.start_from(np.searchsorted(values, raw), names)

    def start_from(self, labels, names) -> "HandLabels":
        """Give every element a name at once (one undoable step): ``labels`` ``(n,) int`` indices
        into ``names`` (negative, or a None name: unlabelled), e.g. a labeller's guess to correct.
        Returns ``self``."""
        labels = np.asarray(labels, np.int64)
        if labels.shape != self.codes.shape:
            raise ValueError(f"`labels` must be ({len(self.codes)},) int, one per element, got shape {labels.shape}")
        table = np.array([0 if n is None else self._code(n) for n in names] + [0], np.int64)
        codes = table[np.where((labels >= 0) & (labels < len(names)), labels, len(names))]
        changed = np.flatnonzero(codes != self.codes)
        if len(changed):
            self._history.append(_Step(changed, self.codes[changed].copy()))
            self.codes[changed] = codes[changed]
        return self

    # ---- naming ---------------------------------------------------------------------------------

    def _code(self, name: str) -> int:
        name = str(name).strip()
        if not name:
            raise ValueError("a label name must not be empty")
        if name not in self.names:
            self.names.append(name)
        return self.names.index(name) + 1

    def _set(self, index, name) -> int:
        """Give ``name`` (None: unlabelled) to the elements ``index``: one undoable step; returns
        how many elements changed."""
        index = np.unique(np.asarray(index, np.int64))
        code = 0 if name is None else self._code(name)
        index = index[self.codes[index] != code]
        if len(index):
            self._history.append(_Step(index, self.codes[index].copy()))
            self.codes[index] = code
        return len(index)

    def assign_part(self, k: int, name) -> int:
        """Every element of part ``k`` takes ``name`` (None: unlabelled); returns how many changed."""
        return self._set(np.flatnonzero(self.parts == int(k)), name)

    def brush(self, centre, radius: float, start: int | None = None) -> np.ndarray:
        """The elements a brush stroke at ``centre`` (3,) of ``radius`` covers: ``(k,) int``.

        With an adjacency and a ``start`` element (the picked face), those in the ball reached
        from ``start`` through touching elements in the ball; otherwise every element in the ball.
        """
        centre = np.asarray(centre, float).reshape(3)
        inside = np.linalg.norm(self.points - centre, axis=1) <= float(radius)
        if start is not None:
            inside[int(start)] = True
        if self.adjacency is None or start is None or not len(self.adjacency):
            return np.flatnonzero(inside)
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        a, b = self.adjacency.T
        keep = inside[a] & inside[b]
        n = len(self.points)
        graph = coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(n, n))
        _, component = connected_components(graph, directed=False)
        return np.flatnonzero(inside & (component == component[int(start)]))

    def paint(self, centre, radius: float, name, start: int | None = None) -> int:
        """The elements of :meth:`brush` take ``name`` (None: unlabelled); returns how many changed."""
        return self._set(self.brush(centre, radius, start), name)

    def undo(self) -> bool:
        """Take back the last step that changed something; False when there is none."""
        if not self._history:
            return False
        step = self._history.pop()
        self.codes[step.index] = step.before
        return True

    # ---- what there is --------------------------------------------------------------------------

    def used_names(self) -> list:
        """The names some element carries, in the order they were first given."""
        present = set(np.unique(self.codes[self.codes > 0]).tolist())
        return [n for i, n in enumerate(self.names) if i + 1 in present]

    def saved_codes(self) -> tuple[np.ndarray, list]:
        """``(codes (n,) int, names)`` as :meth:`save` writes them: 1, 2, ... the used names, 0
        unlabelled."""
        used = self.used_names()
        remap = np.zeros(len(self.names) + 1, np.int64)
        for j, n in enumerate(used):
            remap[self.names.index(n) + 1] = j + 1
        return remap[self.codes], used

    def counts(self) -> dict[str, int]:
        """``{name: elements}`` of the used names."""
        codes, used = self.saved_codes()
        return {n: int((codes == j + 1).sum()) for j, n in enumerate(used)}

    @property
    def changed(self) -> bool:
        """Whether any step is left to undo."""
        return bool(self._history)

    # ---- files ----------------------------------------------------------------------------------

    def save(self, path, *, overwrite: bool = False, source=None) -> tuple[Path, Path]:
        """Write the label file ``path`` (``<stem>.seg`` for faces, ``<stem>.labels.npy`` for
        points) and its names file (:func:`names_path`), each atomically; returns both paths.

        An existing file is replaced only with ``overwrite``, or when this object wrote it.
        Raises FileExistsError (before writing anything) otherwise, and ValueError when nothing
        is labelled. ``source``: the shape's file, recorded in the names file.
        """
        path = Path(path)
        kind = label_suffix(path)
        meta = names_path(path)
        codes, used = self.saved_codes()
        if not used:
            raise ValueError(f"{path}: nothing is labelled yet")
        for p in (path, meta):
            if p.exists() and not overwrite and p.resolve() not in self._written:
                raise FileExistsError(f"{p}: exists (give --force to replace it)")
        if kind == ".seg":
            io.write_labels(path, codes, overwrite=True)
        else:
            io.write_array(path, codes.astype(np.int64), overwrite=True)
        doc = {"format": NAMES_FORMAT, "format_version": _VERSION,
               "names": {str(j + 1): n for j, n in enumerate(used)},
               "unlabelled": 0, "elements": "faces" if kind == ".seg" else "points", "count": len(codes),
               "labelled": int((codes > 0).sum())}
        if source is not None:
            doc["source"] = str(source)
        with io.atomic_output(meta, overwrite=True) as tmp:
            Path(tmp).write_text(json.dumps(doc, indent=1), encoding="utf-8")
        self._written.update({path.resolve(), meta.resolve()})
        return path, meta

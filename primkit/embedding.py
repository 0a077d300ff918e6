"""Interpretable shape similarity: per-part descriptors, distances, neighbours and maps.

One network explains a whole category, so primitive ``k`` is the same part on every shape. A
shape's cuboids are therefore a feature vector whose blocks mean something: "the back's
orientation", "the arms' presence". Choosing the blocks steers the similarity (the paper's second
application): all parts together separate chairs with and without arms; back and seat alone ignore
arms; the back's orientation alone orders chairs by how far the back leans.

The descriptor (:class:`PartDescriptor`)
----------------------------------------
For each selected part ``k`` and each selected property, a block of numbers, divided by that
property's scale (a difference of one scale counts 1 in the distance)::

    size         half extents z (3,) / scale["size"]          canonical units: longest side 1
    position     translation t (3,) / scale["position"]       canonical units
    orientation  R.ravel() (9,) / (2 sqrt 2 sin(scale/2))     scale["orientation"] in degrees
    presence     1 or 0 (1,) / scale["presence"]

The distance between two shapes is the Euclidean distance between their descriptors, so every
tool built on Euclidean vectors (scikit-learn's neighbour indices, t-SNE on vectors) applies.

* **Frame.** Cuboids are compared in the network's canonical frame (upright, front toward +X,
  bounding box centred, longest side 1): :attr:`AbstractionResult.canonical`, not the input's
  frame. So the descriptor ignores where the shape was and how large it was.
* **Rotations.** ``q`` and ``-q`` are the same rotation, so quaternion coordinates cannot be
  compared directly (and flipping to ``w >= 0`` is discontinuous at ``w = 0``). The rotation
  matrix is sign-free, and for two rotations an angle ``theta`` apart
  ``||R1 - R2||_F = 2 sqrt(2) sin(theta / 2)``, a monotone function of the angle on [0, 180°].
  Dividing by ``2 sqrt 2 sin(scale / 2)`` makes a rotation of exactly ``scale`` degrees count 1.
  (The ``|<q1, q2>|``-based distance has the same order but is not a Euclidean distance between
  vectors, which the neighbour index needs.)
* **Box symmetries.** A cuboid's orientation is ambiguous up to the box's own symmetries
  (permuting local axes together with the extents, flipping axis signs in pairs). We compare
  orientations *as predicted*: the network gives each index a consistent local frame across a
  category (a chair back's thin axis is the same local axis on every chair), so the predicted
  frames are comparable index by index. A model that swapped axes between shapes would show a
  90° rotation with permuted extents for what is the same box; the size block shows it too.
* **Absent parts.** Never silent zeros (a zero-size part at the centre is a real, wrong
  description). With ``presence`` selected, each part has a presence coordinate: a part present
  on one shape and absent on the other costs ``1 / scale["presence"]`` (the documented fixed
  penalty; the default 0.5 makes it 2, as much as moving a part by twice the position scale).
  The size, position and orientation blocks of an absent part hold ``fill_``, the collection's
  average instance of that part learned in :meth:`PartDescriptor.fit` (mean extents and
  position, chordal-mean rotation), so those blocks add only how far the present part is from an
  average one, and two shapes both lacking the part differ by nothing there. A strictly constant
  penalty in every block is not a Euclidean distance (no point is equally far from every size),
  and giving that up would cost the neighbour index and t-SNE on vectors.

Parts by label (:class:`RegionDescriptor`)
------------------------------------------
With a model labeller, ``--parts back`` means the voxels the labeller names ``back`` on each shape,
whichever cuboids hold them. Those voxels are described as a region (:func:`region_properties`, in
units of the shape's height): extent (height, width, depth), share of the shape's voxels, place
(centroid against the shape's box), thickness (voxels over the shadow along the thinnest extent),
fill (voxels over the region's box: slats and frames score low) and a signature (the histogram of
the distances between the region's voxels, a plain shape distribution). Each component is
standardised over the collection and weighted by :data:`REGION_WEIGHTS`; the distance is Euclidean,
so ``embed``'s matrix and map, ``similar`` and the explorer rank by one distance.

Measured against PartNet's labelled parts (``python scripts/similarity_partnet.py``; the truth
distance is that of the labelled part's extent and share, each standardised; Spearman over all
pairs / top-5 retrieval gain, :func:`distance_spearman`, :func:`retrieval_gain`) on PartNet
validation chairs 100-218, named by a labeller learned from validation chairs 0-99 (the bundled
labeller learned from all of them, so it would flatter)::

    part (chairs)    regions        signature only   label boxes     voxel IoU (whole shape)
    back (119)       0.737 / 0.654  0.486 / 0.382    0.565 / 0.412   0.229 / 0.429
    seat (119)       0.889 / 0.796  0.690 / 0.488    0.624 / 0.521   0.261 / 0.546
    legs (119)       0.913 / 0.743  0.373 / 0.358    0.566 / 0.491   0.368 / 0.465
    arms (54 armed)  0.581 / 0.561  0.455 / 0.469    0.283 / 0.424   0.103 / 0.458

(label boxes: each labelled region's oriented box through :class:`PartDescriptor`, the previous
meaning of ``--parts`` by label.) What holds back and arms down is the labeller on chairs it has not
seen: where the back ends above the seat, and the arms' height and depth. The test chairs' figures
are in docs/results-applications.md.

scikit-learn
------------
:class:`PartDescriptor` is a scikit-learn transformer (``clone``, ``get_params``,
``get_feature_names_out``, ``set_output``, pipelines), and :class:`AbstractionTransformer` turns a
list of shapes into a :class:`CuboidTable` (inference only), so
``make_pipeline(AbstractionTransformer("chair"), PartDescriptor(parts="back"), TSNE())`` maps shapes
by their backs. The table is numeric (``(s, 11 m)``, :data:`CUBOID_COLUMNS` per part slot, canonical
frame) and carries the model's part names, which is how ``parts="back"`` resolves in a pipeline.

Scale: for 10,000 shapes the descriptors are (10,000, d) floats (d <= 16 per part);
:func:`nearest_neighbors` uses scikit-learn's index and never builds the (s, s) matrix;
:func:`tsne_map` runs t-SNE on a precomputed matrix for small collections and on the descriptors
(Barnes-Hut) for large ones, as scikit-learn does it. :func:`descriptor_distances` builds the full
matrix only when asked.

The baseline the paper compares with is :func:`voxel_iou_distances` (1 - IoU of the prepared
occupancy grids, also in the canonical frame).

Measured with the bundled chair model (``python scripts/similarity_by_parts.py``: 400 procedural
chairs, ``synthetic.write_collection(..., "chair", 400)``, 28.5% with arms, so nearest neighbours
agree on "has arms" by chance 0.592; back tilt 0-25 degrees)::

    descriptor                     refine=0   refine=100
    all parts: arms                  0.920      0.963
    back,seat: arms                  0.733      0.615
    back orientation: Spearman       0.898      0.993

(Spearman between the back-orientation distance to the most upright chair and the true tilt.) Use
refinement for orientations: the network alone under-reads the back's lean. The chair model has
arm parts (indices 12, 13 and 15, named ``arms``); back and seat alone still carry a little of
"has arms" from the network, and next to nothing after refinement, which fits each cuboid to its
own part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
# scikit-learn at the top, against the package's habit: the two estimators subclass its BaseEstimator
# (this module is an application of scikit-learn's neighbours and t-SNE; ``import primkit`` does not load it)
from sklearn.base import BaseEstimator, TransformerMixin

from .model import parts as _parts
from . import primitives
from .viz.maps import draw_map, draw_matches, region_layers, render_thumbnails  # noqa: F401 (their old home)

__all__ = [
    "PROPERTIES",
    "DEFAULT_SCALES",
    "CUBOID_COLUMNS",
    "CuboidTable",
    "PartDescriptor",
    "region_box",
    "label_boxes",
    "REGION_PROPERTIES",
    "REGION_WEIGHTS",
    "region_properties",
    "RegionTable",
    "RegionDescriptor",
    "AbstractionTransformer",
    "Neighbors",
    "descriptor_distances",
    "nearest_neighbors",
    "voxel_iou_distances",
    "tsne_map",
    "neighbour_agreement",
    "retrieval_gain",
    "distance_spearman",
]

#: The properties a descriptor can hold, in block order.
PROPERTIES = ("size", "position", "orientation", "presence")

#: Default scales: half-extent and position differences in canonical units (longest side 1),
#: orientation in degrees of rotation, presence as the inverse of the present/absent penalty.
DEFAULT_SCALES = {"size": 0.05, "position": 0.1, "orientation": 15.0, "presence": 0.5}

_WIDTH = {"size": 3, "position": 3, "orientation": 9, "presence": 1}
_COMPONENTS = {
    "size": ("x", "y", "z"),
    "position": ("x", "y", "z"),
    "orientation": tuple(f"r{i}{j}" for i in range(3) for j in range(3)),
    "presence": ("",),
}


def _parse_what(what) -> tuple[str, ...]:
    if isinstance(what, str):
        what = [w.strip() for w in what.split(",") if w.strip()]
    what = tuple(what)
    if not what or what == ("all",):
        return PROPERTIES
    unknown = [w for w in what if w not in PROPERTIES]
    if unknown:
        raise ValueError(f"unknown propert{'y' if len(unknown) == 1 else 'ies'} {', '.join(unknown)}: choose from {', '.join(PROPERTIES)}")
    return tuple(p for p in PROPERTIES if p in what)


def _chordal_mean(rotations: np.ndarray) -> np.ndarray:
    """The rotation nearest (Frobenius) to the mean of ``(n, 3, 3)`` rotations (the chordal L2 mean)."""
    u, _, vt = np.linalg.svd(rotations.mean(axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


#: The columns of a cuboid table for each part slot, in order (slot-major: slot ``k`` holds columns
#: ``11 k`` to ``11 k + 10``): half extents, the unit quaternion local-to-canonical (real part first),
#: the centre, and presence (1.0 present, 0.0 absent; a table read back counts values >= 0.5 present).
CUBOID_COLUMNS = ("size.x", "size.y", "size.z", "quaternion.w", "quaternion.x", "quaternion.y", "quaternion.z",
                  "position.x", "position.y", "position.z", "present")
_NCOL = len(CUBOID_COLUMNS)


def _slot_labels(names) -> list[str]:
    """One label per slot for column names: the part's name, with its index appended when several
    slots share the name (the chair model's seven ``legs`` slots are ``legs3``, ``legs5``, ...)."""
    names = [str(n) for n in names]
    return [n if names.count(n) == 1 else f"{n}{k}" for k, n in enumerate(names)]


def _names_from_columns(columns) -> list[str] | None:
    """The part names behind a table's column names (:meth:`CuboidTable.feature_names`, what a
    pandas output of :class:`AbstractionTransformer` carries), or None when the columns are not
    laid out so. Inverse of :func:`_slot_labels`: a label ``<name><k>`` on slot ``k`` is ``name``
    when another slot's label is ``<name><j>`` too (a shared name), except ``part<k>``, the default
    name of an unnamed slot."""
    columns = [str(c) for c in columns]
    if not columns or len(columns) % _NCOL:
        return None
    labels = []
    for k in range(len(columns) // _NCOL):
        block = columns[k * _NCOL:(k + 1) * _NCOL]
        label = block[0][: -len(CUBOID_COLUMNS[0]) - 1]
        if block != [f"{label}.{c}" for c in CUBOID_COLUMNS]:
            return None
        labels.append(label)
    bases = [label[: -len(str(k))] if label.endswith(str(k)) and len(label) > len(str(k)) and label != f"part{k}"
             else None for k, label in enumerate(labels)]
    names = [b if b is not None and bases.count(b) > 1 else label for b, label in zip(bases, labels)]
    return names if _slot_labels(names) == labels else labels


def _is_shape_list(X) -> bool:
    """True for a list of Cuboids / AbstractionResult / Abstraction (or an Abstractions), not a numeric table."""
    if isinstance(X, (np.ndarray, CuboidTable)) or hasattr(X, "shape") or not hasattr(X, "__getitem__") or not len(X):
        return False
    first = X[0]
    return isinstance(first, primitives.Cuboids) or isinstance(getattr(first, "canonical", None), primitives.Cuboids)


def _as_cuboids(shapes) -> list[primitives.Cuboids]:
    """Cuboids of each shape: an AbstractionResult's (or Abstraction's) canonical cuboids, or Cuboids as given."""
    out = []
    for s in shapes:
        cub = getattr(s, "canonical", s)
        if not isinstance(cub, primitives.Cuboids):
            raise TypeError(f"expected Cuboids or AbstractionResult, got {type(s).__name__}")
        out.append(cub)
    if not out:
        raise ValueError("no shapes given")
    m = out[0].count
    if any(c.count != m for c in out):
        raise ValueError(f"all shapes must have the same number of part slots (one model); got {sorted({c.count for c in out})}")
    return out


@dataclass(frozen=True, eq=False)
class CuboidTable:
    """Cuboids of ``s`` shapes as one numeric table, with the part names they came with: what
    :class:`AbstractionTransformer` returns, and what :class:`PartDescriptor` reads.

    Attributes
    ----------
    values : (s, 11 m) float
        One row per shape, :data:`CUBOID_COLUMNS` for each of the ``m`` part slots (slot-major),
        in the canonical frame (upright, front +X, longest side 1). Absent slots keep the
        network's values with ``present`` 0.
    part_names : tuple of m str
        The model's name of each slot (several slots may share one).
    names : tuple of s str
        The shapes' names.

    ``np.asarray(table)`` is ``values``, so every scikit-learn estimator takes a table as it takes
    an array; :class:`PartDescriptor` also reads ``part_names``, so ``parts="back"`` resolves in a
    pipeline.
    """

    values: np.ndarray
    part_names: tuple
    names: tuple = ()

    def __post_init__(self):
        v = np.asarray(self.values, float)
        if v.ndim != 2 or v.shape[1] != _NCOL * len(self.part_names):
            raise ValueError(f"`values` must be (s, {_NCOL} m) float with m = {len(self.part_names)} part names, "
                             f"got shape {v.shape}")
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "part_names", tuple(str(n) for n in self.part_names))
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    @classmethod
    def from_cuboids(cls, shapes, part_names=None, names=None) -> "CuboidTable":
        """The table of a list of :class:`primitives.Cuboids` (taken as canonical),
        :class:`AbstractionResult` or :class:`~primkit.model.abstraction.Abstraction` (their
        ``canonical`` cuboids), or an :class:`~primkit.model.abstraction.Abstractions` (whose
        model gives the part names). ``part_names``: default the model's, else ``part0, ...``."""
        cubs = _as_cuboids(shapes)
        m = cubs[0].count
        if part_names is None:
            model = getattr(shapes, "model", None)
            part_names = model.part_names if model is not None else _parts.default_part_names(m)
        if names is None:
            names = [getattr(s, "name", f"shape{i}") for i, s in enumerate(shapes)]
        rows = [np.concatenate([c.half_extents, c.quaternions, c.translations, c.existence[:, None].astype(float)],
                               axis=1).ravel() for c in cubs]
        return cls(np.stack(rows), tuple(part_names), tuple(names))

    @property
    def shape(self) -> tuple:
        return self.values.shape

    def __len__(self) -> int:
        return len(self.values)

    def __array__(self, dtype=None, copy=None):
        return self.values.astype(dtype or self.values.dtype, copy=bool(copy))

    def __iter__(self):
        """The rows, ``(11 m,) float`` each (so ``pandas.DataFrame(table)`` is the numbers)."""
        return iter(self.values)

    def __getitem__(self, key) -> "CuboidTable | np.ndarray":
        """Rows: ``table[3]`` is row 3's numbers; ``table[rows]`` (indices, a mask or a slice, also
        ``table[rows, ...]`` as scikit-learn's cross-validation asks) is a table of those shapes, with
        the part names, so a precomputed table keeps them through ``GridSearchCV``."""
        if isinstance(key, tuple):
            if len(key) != 2 or not (key[1] is Ellipsis or key[1] == slice(None)):
                raise IndexError("a CuboidTable is indexed by rows only: table[rows] or table[rows, ...]")
            key = key[0]
        if isinstance(key, (int, np.integer)):
            return self.values[key]
        rows = np.arange(len(self.values))[key]
        names = tuple(self.names[i] for i in rows) if len(self.names) == len(self.values) else ()
        return CuboidTable(self.values[rows], self.part_names, names)

    def feature_names(self) -> list[str]:
        """One name per column: ``"<part>.<column>"`` (``"seat.size.x"``, ``"legs3.present"``)."""
        return [f"{label}.{c}" for label in _slot_labels(self.part_names) for c in CUBOID_COLUMNS]


def _signed_permutations() -> np.ndarray:
    """The 24 rotations that permute and flip the axes: ``(24, 3, 3)``."""
    import itertools

    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            P = np.zeros((3, 3))
            P[list(perm), range(3)] = signs
            if np.linalg.det(P) > 0:
                out.append(P)
    return np.array(out)


_AXIS_MOVES = _signed_permutations()


def region_box(points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The oriented box of a region's points: ``(half extents (3,), rotation (3, 3), centre (3,))``.

    The axes are the principal axes of the points (the eigenvectors of their covariance), and of
    the 24 ways to name them (which axis is local x, y, z, and their signs: the same box) the one
    whose rotation is nearest the identity (largest trace), so a box's local x is the canonical
    axis nearest it and the rotation is the region's tilt away from the canonical axes (a
    back leaning 15 degrees is a 15 degree rotation). The box spans the points' projections on
    these axes; ``centre`` is its centre (not the points' mean). ``rotation`` maps local to
    canonical coordinates (columns: the local axes). Fewer than 4 points or a flat set still give
    a box (extents may be 0).
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    mean = pts.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((pts - mean).T) if len(pts) > 1 else np.eye(3))
    if np.linalg.det(vecs) < 0:
        vecs[:, 0] = -vecs[:, 0]
    R = vecs @ _AXIS_MOVES[np.argmax(np.trace(vecs @ _AXIS_MOVES, axis1=1, axis2=2))]
    local = (pts - mean) @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    return (hi - lo) / 2.0, R, mean + R @ ((hi + lo) / 2.0)


def label_boxes(points, labels, label_names, *, min_share: float = 0.01, names=None) -> CuboidTable:
    """Each labelled region of each shape as a box: a :class:`CuboidTable` with one slot per label,
    which :class:`PartDescriptor` reads as it reads cuboids (``parts="arms"`` describes the arms
    the labeller finds on each shape, whichever cuboids hold them).

    Parameters
    ----------
    points : list of (n_i, 3) float
        Per shape, its elements (e.g. occupied voxel centres) in the canonical frame (upright,
        front +X, longest side 1).
    labels : list of (n_i,) int
        Per shape, each element's label, an index into ``label_names`` (negative: none).
    label_names : sequence of str
        The slots' names.
    min_share : float
        A label is present on a shape when it holds at least this share of the shape's elements
        and 4 of them (the labeller's own rule drops labels under 1%); an absent label's slot
        holds a unit box at the centre with ``present`` 0.
    names : the shapes' names (default ``shape0, ...``).

    Each present label's box is :func:`region_box` of its elements (centres: the box of a voxel
    region's centres is half a voxel short of the voxels' on each side, on every shape alike).
    """
    label_names = [str(n) for n in label_names]
    if len(points) != len(labels):
        raise ValueError(f"`points` and `labels` differ in length ({len(points)} and {len(labels)} shapes)")
    rows = []
    for pts, lab in zip(points, labels):
        pts, lab = np.asarray(pts, float).reshape(-1, 3), np.asarray(lab, np.int64)
        if len(pts) != len(lab):
            raise ValueError(f"a shape has {len(pts)} points but {len(lab)} labels")
        row = []
        for j in range(len(label_names)):
            mine = lab == j
            if mine.sum() >= max(4, min_share * len(lab)):
                z, R, t = region_box(pts[mine])
                q = primitives.matrix_to_quaternion(R[None])[0]
                row.append(np.concatenate([z, q, t, [1.0]]))
            else:
                row.append(np.array([1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
        rows.append(np.concatenate(row))
    if names is None:
        names = [f"shape{i}" for i in range(len(rows))]
    return CuboidTable(np.array(rows).reshape(len(rows), -1), tuple(label_names), tuple(names))


def _raw_from_table(A: np.ndarray, idx):
    """Selected slots of an ``(s, m, 11)`` table: (s, k, 3) half extents, (s, k, 3, 3) rotations,
    (s, k, 3) translations, (s, k) presence."""
    T = A[:, idx]
    q = T[..., 3:7]
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("a quaternion of the table is zero: columns quaternion.w-z must hold a rotation")
    R = primitives.quaternion_to_matrix((q / norm).reshape(-1, 4)).reshape(q.shape[:-1] + (3, 3))
    return T[..., 0:3], R, T[..., 7:10], T[..., 10] >= 0.5


class PartDescriptor(TransformerMixin, BaseEstimator):
    """Per-part descriptors of abstracted shapes: a scikit-learn transformer (``clone``, pipelines,
    ``GridSearchCV``, ``set_output``).

    Parameters
    ----------
    parts : None, str or sequence of (str or int)
        The parts to describe, by name or index (:func:`primkit.model.parts.resolve_parts`: ``"back,seat"``,
        ``"3,7"``, ``"all"``). None: all.
    what : str or sequence of str
        Properties, from :data:`PROPERTIES` (``"size,orientation"``); default all four.
    scales : dict, optional
        Overrides of :data:`DEFAULT_SCALES` (``{"orientation": 30.0}``).
    part_names : sequence of str, optional
        The model's name of each index (:attr:`primkit.model.abstractor.Abstractor.part_names`);
        default the names the input carries (a :class:`CuboidTable` or an ``Abstractions``), else
        ``part0, part1, ...``.

    Input
    -----
    ``X`` is one of: a list of :class:`primitives.Cuboids` (canonical frame) or of
    :class:`AbstractionResult` / :class:`~primkit.model.abstraction.Abstraction` (their
    ``canonical`` cuboids); an ``Abstractions``; a :class:`CuboidTable`; or any ``(s, 11 m)``
    numeric array laid out as :data:`CUBOID_COLUMNS` (checked by scikit-learn's
    ``validate_data``: finite values, ``n_features_in_``).

    Fitted attributes
    -----------------
    parts_ : (k,) int
        Selected part indices.
    what_ : tuple of str
    scales_ : dict
    fill_ : dict of property -> (k, width) float
        Values an absent part takes (the average present instance of that part; see the module).
    present_fraction_ : (k,) float
        Fraction of the fitted shapes on which each selected part is present.
    feature_names_ : list of str, one per descriptor column (``"back.orientation.r01"``; a name
        shared by several slots gets the index appended, ``"legs3.size.x"``).
    n_slots_ : int
        Part slots of the model (m).
    n_features_in_ : int
        Columns of the input table (``11 m``).
    """

    def __init__(self, parts=None, what=PROPERTIES, scales=None, part_names=None):
        self.parts = parts
        self.what = what
        self.scales = scales
        self.part_names = part_names

    # ---- input ------------------------------------------------------------------------------

    def _table(self, X, reset: bool):
        """``X`` as an ``(s, m, 11)`` float array, with the part names it carries (or None)."""
        from sklearn.utils.validation import validate_data

        names = None
        if _is_shape_list(X):
            X = CuboidTable.from_cuboids(X)
            names = X.part_names
        if isinstance(X, CuboidTable):
            names = X.part_names
            X = X.values
        elif hasattr(X, "columns"):  # a DataFrame (set_output): the names from its columns
            names = _names_from_columns(X.columns)
        A = validate_data(self, X, reset=reset, dtype=np.float64)
        if A.shape[1] % _NCOL:
            raise ValueError(f"a cuboid table has {_NCOL} columns per part slot ({', '.join(CUBOID_COLUMNS)}); "
                             f"got {A.shape[1]} columns")
        return A.reshape(len(A), -1, _NCOL), names

    # ---- fitting ----------------------------------------------------------------------------

    def fit(self, X, y=None) -> "PartDescriptor":
        """Learn the part selection and the absent-part fill values from ``X`` (see *Input*)."""
        A, carried = self._table(X, reset=True)
        m = A.shape[1]
        names = [str(n) for n in (self.part_names if self.part_names is not None else carried or _parts.default_part_names(m))]
        if len(names) != m:
            raise ValueError(f"part_names has {len(names)} names but the cuboids have {m} slots")
        self.n_slots_ = m
        self.part_names_ = names
        self.parts_ = _parts.resolve_parts(self.parts, names)
        if len(self.parts_) == 0:
            raise ValueError("no parts selected")
        self.what_ = _parse_what(self.what)
        scales = dict(DEFAULT_SCALES)
        for key, value in (self.scales or {}).items():
            if key not in PROPERTIES:
                raise ValueError(f"unknown scale {key!r}: choose from {', '.join(PROPERTIES)}")
            if not float(value) > 0:
                raise ValueError(f"scale {key!r} must be > 0, got {value}")
            scales[key] = float(value)
        if not scales["orientation"] <= 180:
            raise ValueError(f"the orientation scale is an angle in degrees in (0, 180], got {scales['orientation']}")
        self.scales_ = scales

        z, R, t, e = _raw_from_table(A, self.parts_)
        self.present_fraction_ = e.mean(axis=0)
        fill = {"size": np.zeros((len(self.parts_), 3)), "position": np.zeros((len(self.parts_), 3)),
                "orientation": np.tile(np.eye(3).ravel(), (len(self.parts_), 1))}
        for j in range(len(self.parts_)):
            on = e[:, j]
            if on.any():  # a part never seen present keeps size 0 at the centre, unrotated
                fill["size"][j] = z[on, j].mean(axis=0)
                fill["position"][j] = t[on, j].mean(axis=0)
                fill["orientation"][j] = _chordal_mean(R[on, j]).ravel()
        self.fill_ = fill
        labels = _slot_labels(names)
        self.feature_names_ = [
            f"{labels[k]}.{p}" + (f".{c}" if c else "")
            for k in self.parts_ for p in self.what_ for c in _COMPONENTS[p]
        ]
        return self

    # ---- transforming -----------------------------------------------------------------------

    def transform(self, X) -> np.ndarray:
        """Descriptors: ``(s, d) float``, columns as :attr:`feature_names_`."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self, "parts_")
        A, _ = self._table(X, reset=False)
        z, R, t, e = _raw_from_table(A, self.parts_)
        s, k = e.shape
        values = {"size": z, "position": t, "orientation": R.reshape(s, k, 9)}
        scale = dict(self.scales_)
        scale["orientation"] = 2.0 * np.sqrt(2.0) * np.sin(np.radians(self.scales_["orientation"]) / 2.0)
        blocks = []
        for p in self.what_:
            if p == "presence":
                blocks.append(e[..., None].astype(float) / scale[p])
            else:
                v = np.where(e[..., None], values[p], self.fill_[p][None])
                blocks.append(v / scale[p])
        return np.concatenate(blocks, axis=2).reshape(s, -1)

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """The descriptor's column names (:attr:`feature_names_`), as scikit-learn asks for them."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self, "parts_")
        if input_features is not None and len(input_features) != self.n_features_in_:
            raise ValueError(f"input_features has {len(input_features)} names but the descriptor was fitted on "
                             f"{self.n_features_in_} columns")
        return np.asarray(self.feature_names_, dtype=object)

    def __sklearn_tags__(self):
        # a cuboid table (11 columns per part slot, see Input), not any 2-D array: scikit-learn's
        # estimator checks then leave out those that fit on their own generic data of 1-10 columns,
        # as for its own DictVectorizer; tests/test_embedding.py checks what they check on real tables
        tags = super().__sklearn_tags__()
        tags.input_tags.two_d_array = False
        return tags


# ------------------------------------------------------------------------------------------------
# Parts by their elements: what a labeller names on each shape, described as a region
# ------------------------------------------------------------------------------------------------

#: The properties of a part's region (:class:`RegionDescriptor`), in block order.
REGION_PROPERTIES = ("extent", "share", "place", "thickness", "fill", "signature")

#: The weight of each region property in the distance (each property standardised over the
#: collection first). Chosen on PartNet validation chairs the labeller did not learn from
#: (``scripts/similarity_partnet.py --choose-weights --model CHAIR-VAL100 --start 100``: a labeller
#: learned from validation chairs 0-99 names chairs 100-218; docs/results-applications.md, "Similarity by
#: parts"): the best mean of Spearman and top-5 gain over back, seat, legs and arms among 324
#: weight sets, ties (within 0.001) going to the set that uses more properties. The best 20 sets
#: score within 0.007 of each other (the worst 0.063 below the best): near the choice, weights
#: matter little.
REGION_WEIGHTS = {"extent": 1.0, "share": 1.0, "place": 0.25, "thickness": 0.25, "fill": 0.25, "signature": 0.5}

#: Bins of the ``signature`` histogram and the distance (in shape heights) its last bin ends at.
SIGNATURE_BINS = 12
SIGNATURE_RANGE = 1.5

_AXES = ("height", "width", "depth")
_REGION_COMPONENTS = {
    "extent": _AXES, "share": ("",), "place": _AXES, "thickness": ("",), "fill": ("",),
    "signature": tuple(f"d{i}" for i in range(SIGNATURE_BINS)),
}
#: canonical grid axes (x front, y up, z side) in the order height, width, depth
_HWD = [1, 2, 0]


def region_properties(occupancy, labels, count: int, max_elements: int = 512) -> tuple[dict, np.ndarray]:
    """The properties of each labelled region of one voxel grid, in units of the shape's height.

    Parameters
    ----------
    occupancy : (R, R, R) bool
        The shape's grid in the canonical frame (index axes x front, y up, z to the side).
    labels : (R, R, R) int
        Each cell's label, an index into ``count`` part names; negative: no part.
    count : int
        The number of labels (part names).
    max_elements : int
        At most this many cells of a region enter its signature (every ``ceil(n / max_elements)``-th
        cell in index order: deterministic).

    Returns
    -------
    values : dict property -> (count, width) float, for :data:`REGION_PROPERTIES`:

        extent     (height, width, depth) of the region's cells (last minus first cell, plus one)
                   over the shape's height (its occupied cells' height)
        share      the region's cells over the shape's occupied cells
        place      the region's centroid minus the centre of the shape's box, (height, width, depth),
                   over the shape's height
        thickness  the region's cells over its shadow along its thinnest extent (the mean thickness
                   across the part: a panel's, a leg's), over the shape's height
        fill       the region's cells over its box's cells (a solid panel 1, slats or a frame less)
        signature  the histogram of the distances between the region's cells (over the shape's
                   height, :data:`SIGNATURE_BINS` bins on [0, :data:`SIGNATURE_RANGE`], the last
                   taking the rest), summing to 1: a plain shape distribution of the part

    present : (count,) bool
        Labels with at least one cell; an absent label's rows are 0.
    """
    from scipy.spatial.distance import pdist

    occ = np.asarray(occupancy, bool)
    lab = np.asarray(labels)
    if occ.ndim != 3 or lab.shape != occ.shape:
        raise ValueError(f"`occupancy` and `labels` must be (R, R, R) grids of one shape, got {occ.shape} and {lab.shape}")
    cells = np.argwhere(occ)
    if not len(cells):
        raise ValueError("an empty grid has no parts")
    lo, hi = cells.min(axis=0), cells.max(axis=0) + 1
    height = float(hi[1] - lo[1])
    centre = (lo + hi) / 2.0
    values = {p: np.zeros((count, len(_REGION_COMPONENTS[p]))) for p in REGION_PROPERTIES}
    present = np.zeros(count, bool)
    named = lab[tuple(cells.T)]
    for j in range(count):
        mine = cells[named == j]
        if not len(mine):
            continue
        present[j] = True
        a, b = mine.min(axis=0), mine.max(axis=0) + 1
        extent = b - a
        thin = int(np.argmin(extent))
        region = np.zeros(occ.shape, bool)
        region[tuple(mine.T)] = True
        shadow = int(region.any(axis=thin).sum())  # the cells of the region's projection along ``thin``
        sub = mine[:: -(-len(mine) // max_elements)]
        d = pdist(sub.astype(float)) / height if len(sub) > 1 else np.zeros(1)
        hist = np.histogram(np.minimum(d, SIGNATURE_RANGE * (1 - 1e-9)), SIGNATURE_BINS, range=(0.0, SIGNATURE_RANGE))[0]
        values["extent"][j] = extent[_HWD] / height
        values["share"][j] = len(mine) / len(cells)
        values["place"][j] = (mine.mean(axis=0) + 0.5 - centre)[_HWD] / height
        values["thickness"][j] = len(mine) / shadow / height
        values["fill"][j] = len(mine) / np.prod(extent)
        values["signature"][j] = hist / hist.sum()
    return values, present


@dataclass(frozen=True, eq=False)
class RegionTable:
    """The regions a labeller names on ``s`` shapes, as :func:`region_properties` describes them:
    what :class:`RegionDescriptor` reads.

    Attributes
    ----------
    values : dict property -> (s, m, width) float
        :data:`REGION_PROPERTIES` of each of the ``m`` labels on each shape (0 where absent).
    present : (s, m) bool
    part_names : tuple of m str, the labels' names
    names : tuple of s str, the shapes' names
    """

    values: dict
    present: np.ndarray
    part_names: tuple
    names: tuple = ()

    def __post_init__(self):
        present = np.asarray(self.present, bool)
        if present.ndim != 2 or present.shape[1] != len(self.part_names):
            raise ValueError(f"`present` must be (s, {len(self.part_names)}) bool, got shape {present.shape}")
        values = {}
        for p in REGION_PROPERTIES:
            v = np.asarray(self.values[p], float)
            if v.shape != present.shape + (len(_REGION_COMPONENTS[p]),):
                raise ValueError(f"values[{p!r}] must be {present.shape + (len(_REGION_COMPONENTS[p]),)}, got {v.shape}")
            values[p] = v
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "present", present)
        object.__setattr__(self, "part_names", tuple(str(n) for n in self.part_names))
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    @classmethod
    def from_grids(cls, occupancy, labels, part_names, names=None, max_elements: int = 512) -> "RegionTable":
        """The table of ``s`` shapes: ``occupancy`` and ``labels``, one ``(R, R, R)`` grid each per
        shape (:func:`region_properties`; :func:`primkit.segmentation.bylabel.labelled_grid` names a
        shape's cells with a model's labeller), ``part_names`` the labels' names."""
        if len(occupancy) != len(labels):
            raise ValueError(f"`occupancy` and `labels` differ in length ({len(occupancy)} and {len(labels)} shapes)")
        if not len(occupancy):
            raise ValueError("no shapes given")
        rows = [region_properties(o, lab, len(part_names), max_elements) for o, lab in zip(occupancy, labels)]
        values = {p: np.stack([r[0][p] for r in rows]) for p in REGION_PROPERTIES}
        names = [f"shape{i}" for i in range(len(rows))] if names is None else names
        return cls(values, np.stack([r[1] for r in rows]), tuple(part_names), tuple(names))

    def __len__(self) -> int:
        return len(self.present)

    def __getitem__(self, rows) -> "RegionTable":
        """The table of some shapes: a slice, or an index array or list."""
        rows = rows if isinstance(rows, slice) else np.asarray(rows, np.int64).reshape(-1)
        return RegionTable({p: v[rows] for p, v in self.values.items()}, self.present[rows], self.part_names,
                           tuple(np.asarray(self.names, object)[rows]) if self.names else ())


class RegionDescriptor(TransformerMixin, BaseEstimator):
    """Per-part descriptors from the elements each shape's labeller puts on the part: a
    scikit-learn transformer of :class:`RegionTable` s (what ``embed --parts back`` and
    ``similar --parts back`` compare when the model has a labeller).

    For each selected part and each selected property (:func:`region_properties`), a block of
    numbers standardised over the fitted collection (each component minus its mean, over its
    standard deviation; the ``signature`` block also over ``sqrt(bins)``, so the whole histogram
    weighs as much as one component), times the property's weight. The distance between two
    shapes is the Euclidean distance between their descriptors, so ``embed``'s distances, its map
    and ``similar``'s ranking are one distance.

    Parameters
    ----------
    parts : None, str or sequence of str
        The labels to describe (``"back"``, ``"back,seat"``); None: all.
    what : None, str or sequence of str
        Properties from :data:`REGION_PROPERTIES`; None: those with a weight above 0 in
        :data:`REGION_WEIGHTS` (all six by default). A property named here whose weight is 0
        counts with weight 1 unless ``weights`` says otherwise.
    weights : dict, optional
        Overrides of :data:`REGION_WEIGHTS` (``{"signature": 1.0}``).

    An absent part has extent, share, thickness and fill 0 and the collection's mean place and
    signature: a chair without arms is as far from a chair with small arms as those arms are small.

    Fitted attributes
    -----------------
    parts_ : (k,) int, the selected labels; part_names_ : list of str; what_ : tuple of str;
    weights_ : dict; mean_, scale_ : dict property -> (k, width) float; fill_ : dict of the mean
    place and signature of present parts; present_fraction_ : (k,) float; feature_names_ : list of str.
    """

    def __init__(self, parts=None, what=None, weights=None):
        self.parts = parts
        self.what = what
        self.weights = weights

    def fit(self, X, y=None) -> "RegionDescriptor":
        """Learn the selection, the absent parts' values and each component's mean and scale from a :class:`RegionTable`."""
        if not isinstance(X, RegionTable):
            raise TypeError(f"expected a RegionTable, got {type(X).__name__}")
        names = list(X.part_names)
        self.part_names_ = names
        self.parts_ = _parts.resolve_parts(self.parts, names)
        if len(self.parts_) == 0:
            raise ValueError("no parts selected")
        weights = dict(REGION_WEIGHTS)
        for key, value in (self.weights or {}).items():
            if key not in REGION_PROPERTIES:
                raise ValueError(f"unknown weight {key!r}: choose from {', '.join(REGION_PROPERTIES)}")
            if not float(value) >= 0:
                raise ValueError(f"weight {key!r} must be >= 0, got {value}")
            weights[key] = float(value)
        if self.what is None:
            what = tuple(p for p in REGION_PROPERTIES if weights[p] > 0)
        else:
            items = [w.strip() for w in self.what.split(",")] if isinstance(self.what, str) else list(self.what)
            unknown = [w for w in items if w and w not in REGION_PROPERTIES]
            if unknown:
                raise ValueError(f"unknown propert{'y' if len(unknown) == 1 else 'ies'} {', '.join(unknown)}: "
                                 f"choose from {', '.join(REGION_PROPERTIES)}")
            what = tuple(p for p in REGION_PROPERTIES if p in items)
            for p in what:
                if REGION_WEIGHTS[p] == 0 and p not in (self.weights or {}):
                    weights[p] = 1.0
        if not what or not any(weights[p] > 0 for p in what):
            raise ValueError("no property with a weight above 0 selected")
        self.what_ = what
        self.weights_ = weights
        present = X.present[:, self.parts_]
        self.present_fraction_ = present.mean(axis=0)
        self.fill_ = {}
        for p in ("place", "signature"):
            v = X.values[p][:, self.parts_]
            counts = np.maximum(present.sum(axis=0), 1)[:, None]
            self.fill_[p] = np.where(present.any(axis=0)[:, None], (v * present[..., None]).sum(axis=0) / counts, 0.0)
        self.mean_, self.scale_ = {}, {}
        for p in self.what_:
            v = self._filled(X, p)
            std = v.std(axis=0)
            self.mean_[p] = v.mean(axis=0)
            self.scale_[p] = np.where(std > 1e-12, std, 1.0)
        self.feature_names_ = [f"{names[k]}.{p}" + (f".{c}" if c else "")
                               for k in self.parts_ for p in self.what_ for c in _REGION_COMPONENTS[p]]
        return self

    def _filled(self, X, p) -> np.ndarray:
        v = X.values[p][:, self.parts_]
        if p in self.fill_:
            v = np.where(X.present[:, self.parts_, None], v, self.fill_[p][None])
        return v

    def transform(self, X) -> np.ndarray:
        """Descriptors ``(s, d) float``, columns as :attr:`feature_names_`."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self, "parts_")
        if not isinstance(X, RegionTable):
            raise TypeError(f"expected a RegionTable, got {type(X).__name__}")
        if list(X.part_names) != self.part_names_:
            raise ValueError(f"the table's labels {list(X.part_names)} are not the fitted ones {self.part_names_}")
        blocks = []
        for p in self.what_:
            v = (self._filled(X, p) - self.mean_[p][None]) / self.scale_[p][None]
            if p == "signature":
                v = v / np.sqrt(SIGNATURE_BINS)
            blocks.append(self.weights_[p] * v)
        return np.concatenate(blocks, axis=2).reshape(len(X), -1)

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """The descriptor's column names (``"back.extent.height"``, ``"arms.signature.d3"``)."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self, "parts_")
        return np.asarray(self.feature_names_, dtype=object)



class AbstractionTransformer(TransformerMixin, BaseEstimator):
    """Shapes -> their cuboids, as a scikit-learn transformer (inference only: nothing is learned).

    ``make_pipeline(AbstractionTransformer("chair"), PartDescriptor(parts="back"), TSNE())`` maps
    shapes by their backs. ``X`` is a list of shapes, each anything :func:`primkit.abstract` takes
    (a path to one shape file, ``(vertices, faces)``, ``(n, 3)`` points, an :class:`primkit.io.Mesh`,
    a trimesh, pyvista or Open3D object); ``transform`` returns a :class:`CuboidTable`, one row per
    shape (the canonical frame, :data:`CUBOID_COLUMNS` per part slot), that carries the model's part
    names down the pipeline. A shape that cannot be abstracted raises ValueError naming it (a
    transformer cannot drop rows).

    Parameters
    ----------
    model : a bundled model's name, a model file's path, or an :class:`~primkit.model.abstractor.Abstractor`.
    up, front, align, refine, existence_threshold, prune_threshold, cache, workers, progress
        As :func:`primkit.model.abstraction.abstract_shapes`.

    Fitted attributes
    -----------------
    model_ : Abstractor
        Loaded by :meth:`fit` (``X`` is not looked at).
    part_names_ : list of str
    n_slots_ : int
    """

    def __init__(self, model="chair", *, up=None, front=None, align=None, refine=0, existence_threshold=0.5,
                 prune_threshold=0.6, cache=None, workers=None, progress=False):
        self.model = model
        self.up = up
        self.front = front
        self.align = align
        self.refine = refine
        self.existence_threshold = existence_threshold
        self.prune_threshold = prune_threshold
        self.cache = cache
        self.workers = workers
        self.progress = progress

    def fit(self, X=None, y=None) -> "AbstractionTransformer":
        """Load the model (``X`` is not used: the model is trained elsewhere)."""
        from .model.abstraction import load_model

        self.model_ = load_model(self.model)
        self.part_names_ = list(self.model_.part_names)
        self.n_slots_ = int(self.model_.parts)
        return self

    def transform(self, X) -> CuboidTable:
        """Abstract every shape of ``X``: a :class:`CuboidTable`, ``(s, 11 m)``."""
        import os

        from sklearn.utils.validation import check_is_fitted

        from .model.abstraction import abstract_shapes

        check_is_fitted(self, "model_")
        if isinstance(X, (str, os.PathLike)) or not hasattr(X, "__len__"):
            raise TypeError(f"X must be a list of shapes, got {type(X).__name__}")
        items = list(X)
        if not items:
            raise ValueError("X holds no shapes")
        for item in items:
            if isinstance(item, (str, os.PathLike)) and os.path.isdir(item):
                raise ValueError(f"{item}: a folder; list its shape files (one row per shape)")
        out = abstract_shapes(items, self.model_, up=self.up, front=self.front, align=self.align, refine=self.refine,
                              existence_threshold=self.existence_threshold, prune_threshold=self.prune_threshold,
                              cache=self.cache, workers=self.workers, progress=self.progress)
        if out.errors or len(out.shapes) != len(items):
            raise ValueError(f"cannot abstract {len(items) - len(out.shapes)} of {len(items)} shapes: "
                             + "; ".join(map(str, out.errors[:3])))
        return CuboidTable.from_cuboids(out, part_names=self.part_names_)

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """The table's column names (:meth:`CuboidTable.feature_names`): ``"seat.size.x"``, ..."""
        from sklearn.utils.validation import check_is_fitted

        check_is_fitted(self, "model_")
        labels = _slot_labels(self.part_names_)
        return np.asarray([f"{label}.{c}" for label in labels for c in CUBOID_COLUMNS], dtype=object)

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.two_d_array = False  # a list of shapes, not a numeric array
        tags.transformer_tags.preserves_dtype = []
        return tags



# ------------------------------------------------------------------------------------------------
# Distances, neighbours, maps
# ------------------------------------------------------------------------------------------------


def descriptor_distances(X, Y=None) -> np.ndarray:
    """Full distance matrix between descriptors: ``(s, d)`` and ``(t, d)`` -> ``(s, t) float``
    (``Y`` None: ``X`` against itself). Quadratic in memory: for neighbours use :func:`nearest_neighbors`."""
    from scipy.spatial.distance import cdist

    X = np.asarray(X, float)
    return cdist(X, X if Y is None else np.asarray(Y, float))


@dataclass(frozen=True)
class Neighbors:
    """Nearest neighbours: ``indices (q, k) int`` into the collection, ``distances (q, k) float``, nearest first."""

    indices: np.ndarray
    distances: np.ndarray


def nearest_neighbors(X, k: int = 1, queries=None, algorithm: str = "auto", working_memory: int = 64) -> Neighbors:
    """The ``k`` nearest descriptors of each query, through scikit-learn's neighbour index.

    Parameters
    ----------
    X : (s, d) float
        The collection's descriptors.
    queries : (q, d) float, optional
        None: each shape of the collection, its own entry excluded.
    algorithm : str
        scikit-learn's ``"auto"``, ``"ball_tree"``, ``"kd_tree"`` or ``"brute"``. Brute force there
        works through bounded chunks of the distance matrix, never the whole (s, s) matrix; for
        descriptors of many parts (hundreds of columns) scikit-learn's ``"auto"`` picks it, as
        trees lose their edge in high dimension (see ``benchmarks/bench_embed.py``).
    working_memory : int
        MiB for one chunk of brute-force distances (scikit-learn's ``working_memory``, 1 GiB by default there).
    """
    import sklearn

    from sklearn.neighbors import NearestNeighbors

    X = np.asarray(X, float)
    limit = len(X) - (1 if queries is None else 0)
    if not 1 <= k <= limit:
        raise ValueError(f"k must be between 1 and {limit} for a collection of {len(X)} shapes, got {k}")
    index = NearestNeighbors(n_neighbors=k, algorithm=algorithm).fit(X)
    with sklearn.config_context(working_memory=working_memory):
        dist, idx = index.kneighbors(None if queries is None else np.asarray(queries, float), k)
    return Neighbors(idx, dist)


def voxel_iou_distances(occupancy, others=None, chunk: int = 512) -> np.ndarray:
    """``1 - IoU`` between occupancy grids: ``(s, R, R, R)`` and ``(t, R, R, R) bool`` -> ``(s, t) float``.

    Intersections are one matrix product of the flattened grids (float32 counts are exact up to
    2^24 cells), computed in chunks of rows. Two empty grids are at distance 0.
    """
    A = np.asarray(occupancy, bool).reshape(len(occupancy), -1)
    B = A if others is None else np.asarray(others, bool).reshape(len(others), -1)
    if A.shape[1] != B.shape[1]:
        raise ValueError(f"grids differ in size: {A.shape[1]} and {B.shape[1]} cells")
    Bf = B.astype(np.float32)
    nb = B.sum(axis=1)
    out = np.empty((len(A), len(B)))
    for i in range(0, len(A), chunk):
        a = A[i : i + chunk]
        inter = a.astype(np.float32) @ Bf.T
        union = a.sum(axis=1)[:, None] + nb[None, :] - inter
        with np.errstate(invalid="ignore", divide="ignore"):
            out[i : i + chunk] = np.where(union > 0, 1.0 - inter / np.maximum(union, 1), 0.0)
    return out


def tsne_map(descriptors=None, *, distances=None, n_components: int = 2, perplexity: float = 30.0,
             random_state=0, precomputed_below: int = 2000) -> np.ndarray:
    """t-SNE coordinates ``(s, n_components) float`` (scikit-learn).

    Give ``distances (s, s)`` (any metric, e.g. voxel IoU) or ``descriptors (s, d)``. Descriptors of
    fewer than ``precomputed_below`` shapes go through their exact distance matrix
    (``metric="precomputed"``); larger collections run Barnes-Hut t-SNE on the descriptors
    directly, whose neighbour search does not build the full matrix. The perplexity is lowered to
    ``(s - 1) / 3`` for small collections (t-SNE needs it below ``s``).
    """
    from sklearn.manifold import TSNE

    if (descriptors is None) == (distances is None):
        raise ValueError("give exactly one of `descriptors` and `distances`")
    s = len(descriptors if distances is None else distances)
    if s < 3:
        raise ValueError(f"a map needs at least 3 shapes, got {s}")
    perplexity = float(min(perplexity, max(1.0, (s - 1) / 3.0)))
    method = "barnes_hut" if n_components <= 3 else "exact"
    if distances is None and s >= precomputed_below:
        tsne = TSNE(n_components, perplexity=perplexity, init="pca", random_state=random_state, method=method)
        return tsne.fit_transform(np.asarray(descriptors, float))
    D = descriptor_distances(descriptors) if distances is None else np.asarray(distances, float)
    if D.shape != (s, s):
        raise ValueError(f"`distances` must be (s, s) float, got shape {D.shape}")
    tsne = TSNE(n_components, perplexity=perplexity, metric="precomputed", init="random",
                random_state=random_state, method=method)
    return tsne.fit_transform(D)


def retrieval_gain(distances, truth, k: int = 5) -> float:
    """How much closer, in ``truth``, the ``k`` nearest shapes by ``distances`` are than random ones:
    ``(random - ranked) / (random - best)``, 1 when the ranking finds the truth's own ``k`` nearest,
    0 for chance, negative when worse.

    ``distances``, ``truth``: ``(s, s) float``. For each query ``i``, ``ranked`` is the mean truth
    distance from ``i`` to its ``k`` nearest by ``distances`` (``i`` itself left out, ties in index
    order), ``best`` the same for its ``k`` nearest by ``truth``, ``random`` the mean truth distance
    from ``i`` to all the others (what ``k`` shapes drawn at random give on average); each of the three
    is averaged over the queries before the ratio is taken.
    """
    D = np.array(distances, float)
    T = np.asarray(truth, float)
    s = len(D)
    if D.shape != (s, s) or T.shape != (s, s):
        raise ValueError(f"`distances` and `truth` must be (s, s) float, got {D.shape} and {T.shape}")
    if not 1 <= k <= s - 1:
        raise ValueError(f"k must be between 1 and {s - 1} for {s} shapes, got {k}")
    off = ~np.eye(s, dtype=bool)
    D[~off] = np.inf
    Tm = np.where(off, T, np.inf)
    rows = np.arange(s)[:, None]
    ranked = T[rows, np.argsort(D, axis=1, kind="stable")[:, :k]].mean()
    best = T[rows, np.argsort(Tm, axis=1, kind="stable")[:, :k]].mean()
    random = T[off].reshape(s, s - 1).mean()
    return float((random - ranked) / (random - best))


def distance_spearman(distances, truth) -> float:
    """Spearman's rank correlation between two ``(s, s)`` distance matrices over the ``s (s - 1) / 2``
    pairs of distinct shapes (scipy's ``spearmanr``; ties get their mean rank)."""
    from scipy.stats import spearmanr

    D, T = np.asarray(distances, float), np.asarray(truth, float)
    if D.shape != T.shape or D.ndim != 2 or D.shape[0] != D.shape[1]:
        raise ValueError(f"`distances` and `truth` must be (s, s) float of one size, got {D.shape} and {T.shape}")
    upper = np.triu_indices(len(D), 1)
    return float(spearmanr(D[upper], T[upper]).statistic)


def neighbour_agreement(neighbour_index, labels) -> float:
    """Fraction of shapes whose nearest neighbour has the same label: ``(s,) int`` (or ``(s, k)``,
    first column used) and ``(s,)`` labels. Chance for two classes of frequency p is ``p^2 + (1-p)^2``."""
    nn = np.asarray(neighbour_index)
    nn = nn[:, 0] if nn.ndim == 2 else nn
    labels = np.asarray(labels)
    return float(np.mean(labels[nn] == labels))

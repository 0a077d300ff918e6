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

from .model import parts as _parts
from . import primitives
from .viz.camera import CAMERA
from .viz.render import mesh_layer, ThumbnailRenderer, Tile
from .io import atomic_output

__all__ = [
    "PROPERTIES",
    "DEFAULT_SCALES",
    "PartDescriptor",
    "Neighbors",
    "descriptor_distances",
    "nearest_neighbors",
    "voxel_iou_distances",
    "tsne_map",
    "neighbour_agreement",
    "render_thumbnails",
    "draw_map",
    "draw_matches",
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


def _as_cuboids(shapes) -> list[primitives.Cuboids]:
    """Cuboids of each shape: an AbstractionResult's canonical cuboids, or Cuboids as given."""
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


class PartDescriptor:
    """Per-part descriptors of abstracted shapes (scikit-learn style: ``fit`` then ``transform``).

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
        The model's name of each index (:attr:`primkit.model.abstractor.Abstractor.part_names`); default
        ``part0, part1, ...``.

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
    feature_names_ : list of str, one per descriptor column (``"back.orientation.r01"``).
    n_slots_ : int
        Part slots of the model (m).
    """

    def __init__(self, parts=None, what=PROPERTIES, scales=None, part_names=None):
        self.parts = parts
        self.what = what
        self.scales = scales
        self.part_names = part_names

    # ---- fitting ----------------------------------------------------------------------------

    def fit(self, shapes, y=None) -> "PartDescriptor":
        """Learn the part selection and the absent-part fill values from ``shapes``
        (a list of :class:`primitives.Cuboids` or :class:`AbstractionResult`, one model's)."""
        cubs = _as_cuboids(shapes)
        m = cubs[0].count
        names = list(self.part_names) if self.part_names is not None else _parts.default_names(m)
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

        z, R, t, e = self._raw(cubs)
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
        self.feature_names_ = [
            f"{names[k]}.{p}" + (f".{c}" if c else "")
            for k in self.parts_ for p in self.what_ for c in _COMPONENTS[p]
        ]
        return self

    def _raw(self, cubs):
        """Selected parts' (s, k, 3) half extents, (s, k, 3, 3) rotations, (s, k, 3) translations, (s, k) existence."""
        idx = self.parts_
        z = np.stack([c.half_extents[idx] for c in cubs])
        R = np.stack([c.rotations[idx] for c in cubs])
        t = np.stack([c.translations[idx] for c in cubs])
        e = np.stack([c.existence[idx] for c in cubs])
        return z, R, t, e

    # ---- transforming -----------------------------------------------------------------------

    def transform(self, shapes) -> np.ndarray:
        """Descriptors: ``(s, d) float``, columns as :attr:`feature_names_`."""
        if not hasattr(self, "parts_"):
            raise RuntimeError("PartDescriptor is not fitted: call fit(shapes) first")
        cubs = _as_cuboids(shapes)
        if cubs[0].count != self.n_slots_:
            raise ValueError(f"the cuboids have {cubs[0].count} slots but the descriptor was fitted on {self.n_slots_}")
        z, R, t, e = self._raw(cubs)
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

    def fit_transform(self, shapes, y=None) -> np.ndarray:
        return self.fit(shapes).transform(shapes)


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


def neighbour_agreement(neighbour_index, labels) -> float:
    """Fraction of shapes whose nearest neighbour has the same label: ``(s,) int`` (or ``(s, k)``,
    first column used) and ``(s,)`` labels. Chance for two classes of frequency p is ``p^2 + (1-p)^2``."""
    nn = np.asarray(neighbour_index)
    nn = nn[:, 0] if nn.ndim == 2 else nn
    labels = np.asarray(labels)
    return float(np.mean(labels[nn] == labels))


# ------------------------------------------------------------------------------------------------
# Pictures
# ------------------------------------------------------------------------------------------------


def render_thumbnails(meshes, size: int = 96, progress: bool = False) -> list[np.ndarray]:
    """Small pictures of meshes in the canonical frame: ``(size, size, 4) uint8`` RGBA each.

    ``meshes``: ``(vertices, faces)`` or ``(vertices, faces, (f, 3) uint8 face colours)``. One
    off-screen plotter is reused (:class:`primkit.viz.render.ThumbnailRenderer`); every thumbnail is
    framed on the canonical frame's origin at one scale, so sizes compare across thumbnails.
    """
    from tqdm import tqdm

    frame = np.array([[-0.5] * 3, [0.5] * 3])  # centred on the origin of the canonical frame
    radius = 0.62 / (1.0 + CAMERA.margin)  # a viewport half-height of 0.62: a unit-size shape with room
    images = []
    with ThumbnailRenderer(size=size) as renderer:
        for item in tqdm(meshes, desc="thumbnails", unit="shape", disable=not progress):
            v, f = item[0], item[1]
            colors = item[2] if len(item) > 2 else None
            layers = [mesh_layer(v, f, colors, color="#b8c4d6")] if len(f) else []
            images.append(renderer.render(Tile("", layers, frame=frame), radius=radius, transparent=True))
    return images


def draw_map(coords, images, path, *, colors=None, title: str = "", zoom: float = 0.6, spacing: float = 0.035,
             svg=None) -> None:
    """Draw thumbnails at 2D map positions (PNG; also SVG when ``svg`` is a path).

    Every shape gets a dot; thumbnails are drawn for shapes at least ``spacing`` (a fraction of the
    map's extent, per axis) from every thumbnail already drawn, so dense clusters stay readable.

    ``coords (s, 2) float``, ``images``: one RGBA thumbnail per shape (or None for a dot alone);
    ``colors``: optional ``(s,) float`` values (a known attribute) that colour the dots and the
    thumbnails' frames, with a colour bar.
    """
    from matplotlib.figure import Figure  # matplotlib: imported on first use
    from matplotlib.offsetbox import AnnotationBbox, OffsetImage

    coords = np.asarray(coords, float)
    # a Figure of its own (no pyplot): drawing here never switches the caller's backend
    fig = Figure(figsize=(14, 14), dpi=100)
    ax = fig.subplots()
    edge = None
    if colors is None:
        ax.scatter(coords[:, 0], coords[:, 1], s=12, c="0.6")
    else:
        dots = ax.scatter(coords[:, 0], coords[:, 1], s=40, c=colors, cmap="coolwarm")
        edge = dots.to_rgba(np.asarray(colors, float))
        fig.colorbar(dots, ax=ax, shrink=0.5, pad=0.01)
    # thumbnails drawn greedily in a fixed random order, skipping those that would mostly cover one
    # already drawn: the dots show every shape, the thumbnails stay readable
    unit = (coords - coords.min(axis=0)) / (np.ptp(coords, axis=0) + 1e-12)
    drawn = np.empty((0, 2))
    for i in np.random.default_rng(0).permutation(len(coords)):
        if images[i] is None or (len(drawn) and np.min(np.abs(drawn - unit[i]).max(axis=1)) < spacing):
            continue
        drawn = np.vstack([drawn, unit[i]])
        framed = edge is not None
        ax.add_artist(AnnotationBbox(OffsetImage(images[i], zoom=zoom), coords[i], frameon=framed, pad=0.05,
                                     bboxprops={"edgecolor": edge[i], "linewidth": 2.0} if framed else None))
    pad = 0.06 * (np.ptp(coords, axis=0) + 1e-9)
    ax.set_xlim(coords[:, 0].min() - pad[0], coords[:, 0].max() + pad[0])
    ax.set_ylim(coords[:, 1].min() - pad[1], coords[:, 1].max() + pad[1])
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=11)
    fig.tight_layout()
    for out, fmt in ((path, "png"), (svg, "svg")):
        if out is not None:
            with atomic_output(out, overwrite=True) as tmp:
                fig.savefig(tmp, format=fmt)


def draw_matches(query_image, images, names, distances, path, *, query_name: str = "query", title: str = "") -> None:
    """The query's thumbnail, then its matches in rank order with names and distances, in one PNG row."""
    from matplotlib.figure import Figure  # matplotlib: imported on first use

    n = len(images) + 1
    fig = Figure(figsize=(2.2 * n, 2.6), dpi=100)  # no pyplot: the caller's backend is left alone
    axes = fig.subplots(1, n)
    axes = np.atleast_1d(axes)
    panels = [(query_image, f"query\n{query_name[:18]}")]
    panels += [(img, f"#{i + 1} {nm[:16]}\nd = {d:.3g}") for i, (img, nm, d) in enumerate(zip(images, names, distances))]
    for ax, (img, label) in zip(axes, panels):
        ax.imshow(img)
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    axes[0].patch.set_edgecolor("black")
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png")

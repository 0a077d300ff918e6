"""The 24 axis-aligned orientations, and prepared shapes turned into them (``--align auto``).

A model learns one canonical frame (+Y up, +X front). A shape whose up or front axis is another
one can be tried in every proper rotation that maps axes to axes (the 24 signed permutation
matrices with determinant +1), and the orientation the model explains best is kept.

Turning a prepared shape by such a rotation ``A`` needs no new preparation: the canonical frame
centres the bounding box and scales its longest side to 1, which ``A`` preserves, and the grid's
cell centres ``-0.5 + (i + 0.5) / R`` are mapped onto cell centres by it. So the grids are
permuted and flipped, the closest points and samples rotated, and the frame composed
(``canonical' = A @ canonical``), all exactly.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass, replace

import numpy as np

from .. import geometry

__all__ = ["AXIS_ROTATIONS", "UPRIGHT", "ALIGN_MODES", "UP_MARGIN", "candidate_rotations", "choose_orientation",
           "default_front", "resolve_align", "rotate_grid", "rotate_prepared", "axis_name", "describe_rotation",
           "FrameAxes", "Alignment", "FrameVote", "vote_sample", "choose_auto", "compose_index", "MIRROR_LIMIT",
           "mirror_symmetry", "turn_symmetry"]


def _axis_rotations() -> np.ndarray:
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            r = np.zeros((3, 3))
            r[np.arange(3), perm] = signs
            if np.linalg.det(r) > 0:
                out.append(r)
    out.sort(key=lambda r: (not np.allclose(r, np.eye(3)),))  # the identity first
    return np.array(out)


#: (24, 3, 3) float: every proper rotation that maps coordinate axes to coordinate axes; [0] is the identity.
AXIS_ROTATIONS = _axis_rotations()


#: (24,) bool: the rotations of :data:`AXIS_ROTATIONS` that keep +Y up (the 4 turns about the up axis).
UPRIGHT = np.array([np.allclose(r[1], [0.0, 1.0, 0.0]) for r in AXIS_ROTATIONS])

#: How a shape's orientation is found (``align=``); see :func:`choose_orientation`.
ALIGN_MODES = {
    "none": "as given (or as declared with up/front)",
    "front": "the 4 turns about the up axis; the one the model explains best",
    "auto": "the 4 turns about the up axis (+Y, or the collection's when two thirds of it agree), and another "
    "up axis only when the shape is clearly lying down (the best orientation with another up axis explained "
    "with under `up_margin` of the best upright loss; so all 24 are scored); an axis the shape is mirror "
    "symmetric across is never taken as up",
    "any": "all 24 axis-aligned orientations; the one the model explains best",
}

#: Default ``up_margin`` of ``align="auto"``: an orientation with another up axis must cut the loss by 30% (measured on validation chairs).
UP_MARGIN = 0.7


#: Mirror symmetry (:func:`mirror_symmetry`) from which ``align="auto"`` never takes an axis as up.
#: Gravity tells up from down, so an upright shape is seldom its own mirror image across the horizontal
#: plane, while chairs, tables and airplanes are across their left-right plane, and stools and round
#: tables across two vertical planes. On the ShapeNet, Princeton and procedural shapes the frame check
#: chooses on (``scripts/frame_check.py``), the true up axis reached 0.89 and a mirror plane's axis
#: most often 0.9-1.0; 0.8 found the most upright frames there.
MIRROR_LIMIT = 0.8


def mirror_symmetry(occupancy) -> np.ndarray:
    """(3,) float: for each grid axis, the intersection over union of the occupancy and its mirror
    image across the mid-plane normal to that axis (1: mirror symmetric). The canonical frame centres
    the bounding box, so the mid-plane is the box's."""
    g = np.asarray(occupancy, bool)
    if g.ndim != 3:
        raise ValueError(f"`occupancy` must be (R, R, R) bool, got {g.shape}")
    out = np.zeros(3)
    for a in range(3):
        flipped = np.flip(g, axis=a)
        union = np.count_nonzero(g | flipped)
        out[a] = np.count_nonzero(g & flipped) / union if union else 1.0
    return out


def turn_symmetry(symmetry, rotation) -> np.ndarray:
    """The :func:`mirror_symmetry` of a shape turned by an axis rotation, from the shape's own:
    new axis ``j`` is old axis ``argmax |rotation[j]|``."""
    return np.asarray(symmetry, float)[..., np.argmax(np.abs(np.asarray(rotation, float)), axis=1)]


def _up_allowed(candidates, symmetry, mirror_limit: float) -> np.ndarray:
    """(k,) bool: the candidates whose up axis is not a mirror axis of the shape (all of them when
    every axis is, or when no symmetry is given)."""
    candidates = np.asarray(candidates)
    if symmetry is None:
        return np.ones(len(candidates), bool)
    mirror = np.asarray(symmetry, float) >= mirror_limit
    if mirror.all():
        return np.ones(len(candidates), bool)
    up_axis = np.argmax(np.abs(AXIS_ROTATIONS[candidates][:, 1]), axis=1)
    return ~mirror[up_axis]


def resolve_align(align=None, up=None, front=None) -> str:
    """The orientation search to run, from an explicit ``align`` or from what the user declared.

    ``align`` given: that mode (``None``/``"none"`` is no search only when given explicitly as
    ``"none"``). Otherwise: both ``up`` and ``front`` declared -> ``"none"``; only ``up`` ->
    ``"front"``; neither -> ``"auto"``. ``"auto"`` given as an axis means undeclared.
    """
    if align is not None:
        if align not in ALIGN_MODES:
            raise ValueError(f"align must be one of {', '.join(ALIGN_MODES)}, got {align!r}")
        return align
    declared_up = up not in (None, "auto")
    declared_front = front not in (None, "auto")
    if declared_up and declared_front:
        return "none"
    return "front" if declared_up else "auto"


def default_front(up: str) -> str:
    """A front axis to go with a declared ``up`` when none is declared (``+x``, or ``+z`` when the
    up axis is X): the front is then searched by ``align="front"``."""
    return "+z" if up.strip().lower().lstrip("+-") == "x" else "+x"


def candidate_rotations(mode: str) -> np.ndarray:
    """Indices into :data:`AXIS_ROTATIONS` that ``mode`` tries (identity first)."""
    if mode == "none":
        return np.array([0])
    if mode == "front":
        return np.flatnonzero(UPRIGHT)
    if mode in ("auto", "any"):
        return np.arange(len(AXIS_ROTATIONS))
    raise ValueError(f"align must be one of {', '.join(ALIGN_MODES)}, got {mode!r}")


def choose_orientation(losses, candidates, mode: str, up_margin: float = UP_MARGIN, up=(0.0, 1.0, 0.0), *,
                       symmetry=None, mirror_limit: float = MIRROR_LIMIT) -> int:
    """The chosen index into :data:`AXIS_ROTATIONS`, from the fit loss of each candidate.

    ``losses`` (k,) float for ``candidates`` (k,) int. ``"auto"`` keeps the best turn that leaves
    ``up`` ((3,) float, an input axis in the shape's prepared frame; +Y by default, or the
    collection's up axis) as the up axis, unless the best of the others has a loss below
    ``up_margin`` times it: a chair model explains a lying-down chair far better once it is stood
    up, while a symmetric stool on its side is at best a little better explained, and is kept
    upright. With ``symmetry`` ((3,) float, :func:`mirror_symmetry` of the shape as scored), ``"auto"``
    first sets aside every candidate whose up axis the shape is mirror symmetric across (at least
    ``mirror_limit``), ``up`` included: a pedestal stool on its side has its column across a mirror
    plane, and the model may explain it better so. When ``up`` is set aside, the best candidate left wins.
    """
    losses = np.asarray(losses, float)
    candidates = np.asarray(candidates)
    if mode != "auto":
        return int(candidates[int(np.argmin(losses))])
    upright = np.all(np.isclose(AXIS_ROTATIONS[candidates][:, 1], np.asarray(up, float)), axis=1)
    if not upright.any():
        raise ValueError(f"no candidate keeps {axis_name(up)} up")
    allowed = _up_allowed(candidates, symmetry, mirror_limit)
    if not (upright & allowed).any():
        kept = np.flatnonzero(allowed)
        return int(candidates[kept[np.argmin(losses[kept])]])
    keep_up = upright & allowed
    best_up = int(np.flatnonzero(keep_up)[np.argmin(losses[keep_up])])
    others = np.flatnonzero(~upright & allowed)
    if not len(others):
        return int(candidates[best_up])
    best_other = int(others[np.argmin(losses[others])])
    if losses[best_other] < up_margin * losses[best_up]:
        return int(candidates[best_other])
    return int(candidates[best_up])


def vote_sample(count: int, vote_shapes: int = 24) -> np.ndarray:
    """Indices of the (at most ``vote_shapes``) shapes, spread over a collection of ``count``, whose
    own up axes are put to the vote by ``align="auto"``."""
    return np.unique(np.linspace(0, count - 1, min(vote_shapes, count)).round().astype(int))


@dataclass(frozen=True, eq=False)
class FrameVote:
    """What ``align="auto"`` chose for ``s`` shapes (:func:`choose_auto`).

    Attributes
    ----------
    choice : (s,) int
        Each shape's orientation, an index into :data:`AXIS_ROTATIONS`.
    expected : (3,) float
        The up axis expected of every shape: +Y, or the collection's when the vote carried.
    agree, voters : int
        How many of the sampled shapes picked ``expected``, of how many.
    voted : bool
        Whether the collection's up axis was expected (two thirds agree, more than one shape).
    """

    choice: np.ndarray
    expected: np.ndarray
    agree: int
    voters: int
    voted: bool


def choose_auto(losses, up_margin: float = UP_MARGIN, vote_shapes: int = 24, *, symmetry=None,
                mirror_limit: float = MIRROR_LIMIT) -> FrameVote:
    """``align="auto"`` on a collection, from every shape's fit loss in the 24 orientations.

    ``losses`` (s, 24) float, columns in the order of :data:`AXIS_ROTATIONS`; ``symmetry`` (s, 3)
    float or None, each shape's :func:`mirror_symmetry`. Up to ``vote_shapes`` shapes
    (:func:`vote_sample`) each pick an up axis from +Y (:func:`choose_orientation`); when two thirds
    agree and there is more than one shape, that axis is expected of every shape, else +Y; then
    every shape keeps the best turn about the expected axis unless another up axis cuts its loss by
    the margin, mirror axes set aside.
    """
    losses = np.asarray(losses, float)
    if losses.ndim != 2 or losses.shape[1] != len(AXIS_ROTATIONS):
        raise ValueError(f"`losses` must be (s, {len(AXIS_ROTATIONS)}) float, got {losses.shape}")
    sym = [None] * len(losses) if symmetry is None else np.asarray(symmetry, float).reshape(len(losses), 3)
    everything = np.arange(len(AXIS_ROTATIONS))
    sample = vote_sample(len(losses), vote_shapes)

    def pick(i, up=(0.0, 1.0, 0.0)):
        return choose_orientation(losses[i], everything, "auto", up_margin, up, symmetry=sym[i],
                                  mirror_limit=mirror_limit)

    ups = [tuple(AXIS_ROTATIONS[pick(i)][1]) for i in sample]
    common = max(set(ups), key=ups.count)
    agree = ups.count(common)
    voted = agree * 3 >= 2 * len(ups) and len(losses) > 1
    expected = np.asarray(common if voted else (0.0, 1.0, 0.0))
    choice = np.array([pick(i, expected) for i in range(len(losses))], int)
    return FrameVote(choice, expected, agree, len(ups), bool(voted))


@functools.lru_cache(maxsize=1)
def _compose_table() -> np.ndarray:
    r = AXIS_ROTATIONS
    out = np.empty((len(r), len(r)), int)
    for i, a in enumerate(r):
        for j, b in enumerate(r):
            out[i, j] = int(np.flatnonzero(np.all(np.isclose(r, a @ b), axis=(1, 2)))[0])
    out.flags.writeable = False
    return out


def compose_index(i, j):
    """Index into :data:`AXIS_ROTATIONS` of ``AXIS_ROTATIONS[i] @ AXIS_ROTATIONS[j]`` (arrays broadcast).

    A shape turned by rotation ``j`` and then tried in candidate ``i`` is the shape tried in
    ``compose_index(i, j)``: so the 24 losses of a turned shape are the shape's own, permuted."""
    return _compose_table()[np.asarray(i), np.asarray(j)]


def axis_name(vector) -> str:
    """``(3,)`` unit axis vector -> ``"+x"``, ``"-z"``, ..."""
    v = np.asarray(vector, float)
    i = int(np.argmax(np.abs(v)))
    return ("+" if v[i] > 0 else "-") + "xyz"[i]


@dataclass(frozen=True)
class FrameAxes:
    """The input axes a frame takes as up (canonical +Y) and front (canonical +X): ``"+x"``, ``"-z"``, ..."""

    up: str
    front: str


@dataclass(frozen=True, eq=False)
class Alignment:
    """How ``align`` turned one shape (:meth:`primkit.model.abstractor.Abstractor.orient`).

    Attributes
    ----------
    mode : str
        The mode asked for (:data:`ALIGN_MODES`).
    rotation : (3, 3) float
        The chosen axis rotation of the canonical frame (acts on column vectors).
    up, front : str
        The input axes then taken as up and front (:class:`FrameAxes`).
    up_decided_by : str
        ``"given"``, ``"shape"``, or how the collection's vote decided it.
    loss, loss_as_given : float
        Fit loss (:func:`primkit.model.fitting.fit_losses`) of the chosen orientation and of the
        shape as given.
    """

    mode: str
    rotation: np.ndarray
    up: str
    front: str
    up_decided_by: str
    loss: float
    loss_as_given: float

    def to_dict(self) -> dict:
        """JSON-ready (the ``alignment`` entry of ``<name>.cuboids.json``)."""
        return {"mode": self.mode, "rotation": np.asarray(self.rotation, float).tolist(), "up": self.up,
                "front": self.front, "up_decided_by": self.up_decided_by, "loss": self.loss,
                "loss_as_given": self.loss_as_given}


def describe_rotation(rotation) -> FrameAxes:
    """The input axes that a frame rotation (``canonical = rotation @ x``) makes up (+Y) and front (+X)."""
    r = np.asarray(rotation, float)
    return FrameAxes(up=axis_name(r[1]), front=axis_name(r[0]))


def _source_cells(res: int, rotation: np.ndarray) -> tuple:
    """Flat index arrays of the old cell whose value lands in each new cell: the value at cell centre
    ``c`` ends at cell centre ``rotation @ c``. Cached per resolution and rotation (24 of them): the
    frame search turns every shape by each, and computing the indices took 3.2 s of a 24.4 s
    profile of ``Abstractor.orient`` on 64 ShapeNet chairs."""
    a = np.asarray(rotation, float)
    if not np.array_equal(a, np.rint(a)):  # not an axis rotation: computed as it is
        return _cells(int(res), a)
    return _source_cells_cached(int(res), tuple(a.astype(int).ravel()))


def _cells(res: int, a: np.ndarray) -> tuple:
    idx = np.indices((res,) * 3).reshape(3, -1).T  # new cells
    old = np.rint((idx - (res - 1) / 2.0) @ a + (res - 1) / 2.0).astype(np.int64)  # rotation.T @ c per row
    return old[:, 0], old[:, 1], old[:, 2]


@functools.lru_cache(maxsize=64)
def _source_cells_cached(res: int, rotation: tuple) -> tuple:
    out = _cells(res, np.array(rotation, float).reshape(3, 3))
    for o in out:
        o.flags.writeable = False  # shared by every caller
    return out


def source_index(res: int, rotation) -> np.ndarray:
    """(R^3,) int: the flat (C-order) index of the old cell whose value lands in each new cell
    under an axis rotation (:func:`_source_cells` flattened; cached, read-only): ``grids.reshape(s,
    -1)[:, source_index(R, a)]`` turns ``s`` grids at once, as :func:`rotate_grid` turns one."""
    a = np.asarray(rotation, float)
    if not np.array_equal(a, np.rint(a)):
        i, j, k = _cells(int(res), a)
        return (i * res + j) * res + k
    return _source_index_cached(int(res), tuple(a.astype(int).ravel()))


@functools.lru_cache(maxsize=64)
def _source_index_cached(res: int, rotation: tuple) -> np.ndarray:
    i, j, k = _source_cells_cached(res, rotation)
    out = (i * res + j) * res + k
    out.flags.writeable = False
    return out


def rotate_grid(grid: np.ndarray, rotation) -> np.ndarray:
    """A cubic ``(R, R, R, ...)`` grid turned by an axis rotation of the canonical frame (cell values
    move with their cell centres, exactly): what :func:`rotate_prepared` does to the occupancy."""
    a = np.asarray(rotation, float)
    grid = np.asarray(grid)
    return grid[_source_cells(grid.shape[0], a)].reshape(grid.shape)


def rotate_prepared(shape, rotation):
    """A :class:`primkit.data.PreparedShape` turned by an axis rotation of its canonical frame.

    Parameters
    ----------
    shape : primkit.data.PreparedShape
    rotation : (3, 3) float
        One of :data:`AXIS_ROTATIONS`.

    Returns
    -------
    PreparedShape whose ``frame`` maps the input to the rotated canonical frame, so results computed
    on it still come back in the input's frame through ``frame``.
    """
    a = np.asarray(rotation, float)
    if a.shape != (3, 3) or not np.any(np.all(np.isclose(AXIS_ROTATIONS, a), axis=(1, 2))):
        raise ValueError("`rotation` must be a proper axis rotation (a signed permutation matrix, det +1)")
    if np.allclose(a, np.eye(3)):
        return shape
    res = shape.resolution
    src = _source_cells(res, a)
    closest = shape.closest[src].reshape(shape.closest.shape) @ a.T
    f = shape.frame
    frame = geometry.CanonicalFrame(a @ f.rotation, a @ f.centre, f.scale)
    return replace(
        shape,
        occupancy=shape.occupancy[src].reshape(shape.occupancy.shape),
        solid=shape.solid[src].reshape(shape.solid.shape),
        closest=closest.astype(shape.closest.dtype),
        points=(np.asarray(shape.points) @ a.T).astype(shape.points.dtype),
        frame=frame,
    )

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
           "FrameAxes", "Alignment"]


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
    "with under `up_margin` of the best upright loss; so all 24 are scored)",
    "any": "all 24 axis-aligned orientations; the one the model explains best",
}

#: Default ``up_margin`` of ``align="auto"``: an orientation with another up axis must cut the loss by 30% (measured on validation chairs).
UP_MARGIN = 0.7


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


def choose_orientation(losses, candidates, mode: str, up_margin: float = UP_MARGIN, up=(0.0, 1.0, 0.0)) -> int:
    """The chosen index into :data:`AXIS_ROTATIONS`, from the fit loss of each candidate.

    ``losses`` (k,) float for ``candidates`` (k,) int. ``"auto"`` keeps the best turn that leaves
    ``up`` ((3,) float, an input axis in the shape's prepared frame; +Y by default, or the
    collection's up axis) as the up axis, unless the best of the others has a loss below
    ``up_margin`` times it: a chair model explains a lying-down chair far better once it is stood
    up, while a symmetric stool on its side is at best a little better explained, and is kept
    upright.
    """
    losses = np.asarray(losses, float)
    candidates = np.asarray(candidates)
    if mode != "auto":
        return int(candidates[int(np.argmin(losses))])
    upright = np.all(np.isclose(AXIS_ROTATIONS[candidates][:, 1], np.asarray(up, float)), axis=1)
    if not upright.any():
        raise ValueError(f"no candidate keeps {axis_name(up)} up")
    best_up = int(np.flatnonzero(upright)[np.argmin(losses[upright])])
    if upright.all():
        return int(candidates[best_up])
    others = np.flatnonzero(~upright)
    best_other = int(others[np.argmin(losses[others])])
    if losses[best_other] < up_margin * losses[best_up]:
        return int(candidates[best_other])
    return int(candidates[best_up])


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

"""Part edits: scale, turn and move parts in their own frames, lengthen parts below a cut plane,
and carry the parts resting on them along (``primkit edit``)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..primitives import Cuboids, matrix_to_quaternion, world_to_local
from .binding import as_vertices
from .transfer import cuboid_gap

__all__ = ["Edit", "Lengthening", "edit_cuboids"]


_UP = np.array([0.0, 1.0, 0.0])


_FRONT = np.array([1.0, 0.0, 0.0])


@dataclass(frozen=True)
class Edit:
    """The result of :func:`edit_cuboids`.

    Attributes
    ----------
    cuboids : Cuboids
        The edited abstraction.
    transforms : (m, 4, 4) float
        Per-slot maps from the old cuboids to the new (identity for untouched parts).
    edited : list of int
        Slots edited directly.
    carried : dict of int -> list of int
        Slots moved because they rest on moved parts, with the parts they rest on.
    lengthening : Lengthening or None
        The cut-plane stretch of the parts edited with ``lengthen`` (their mesh follows
        :meth:`Lengthening.displacement`, not their row of ``transforms``).
    """

    cuboids: Cuboids
    transforms: np.ndarray
    edited: list
    carried: dict = field(default_factory=dict)
    lengthening: "Lengthening | None" = None


@dataclass(frozen=True)
class Lengthening:
    """Parts lengthened below a cut plane (``lengthen`` of :func:`edit_cuboids`).

    What "lengthen the legs by 30%" means here: the legs' length **below the seat's underside**
    grows by 30%. Heights are measured along ``up``; the map of a lengthened part is

        h -> h + (factor - 1) (clip(h, floor, cut) - floor)

    (a stretch along ``up`` about the floor, for the points between the floor and the cut plane;
    the points above the plane rise by the full ``rise = (factor - 1) (cut - floor)``). The feet
    stay where they are, and whatever the legs hold up (the seat, the back and arms on it) is
    translated by the rise, so the chair grows by exactly ``rise``. Why not scale the leg cuboids
    about their feet: on real chairs the rear legs continue into the back posts and the model's
    rear-leg cuboids reach up to or above the seat; stretching them whole pushes into the back
    and stretches it, and the seat no longer "rests" on them (COSEG chairs: 2-33% short of the
    expected rise, back edges stretched 12-64%).

    Attributes
    ----------
    factors : dict of int -> float
        Slot -> length factor.
    floor : float
        Height where the stretch starts (the feet; stays put).
    cut : float
        Height of the cut plane (the underside of ``support``, or given).
    support : int or None
        The slot the lengthened parts hold up (it rises by the full rise; its underside gives
        ``cut`` unless that was given). None when no part rests on them; then ``cut`` defaults
        to the top of the lengthened parts.
    up : (3,) float
        Unit up direction.
    """

    factors: dict
    floor: float
    cut: float
    support: int | None
    up: np.ndarray

    def height_map(self, heights, k: int) -> np.ndarray:
        """(n,) float: heights ``(n,) float`` after part ``k``'s stretch."""
        h = np.asarray(heights, float)
        return h + (self.factors[k] - 1.0) * (np.clip(h, self.floor, self.cut) - self.floor)

    def rise(self, k: int) -> float:
        """How far part ``k`` lifts what it holds up: ``(factor - 1) (cut - floor)``."""
        return float((self.factors[k] - 1.0) * (self.cut - self.floor))

    def displacement(self, points, k: int) -> np.ndarray:
        """(n, 3) float: displacement of points ``(n, 3) float`` under part ``k``'s stretch."""
        h = as_vertices(points) @ self.up
        return np.outer(self.height_map(h, k) - h, self.up)

    def linear(self, points, k: int) -> np.ndarray:
        """(n, 3, 3) float: the map's linear part at the points (a stretch along ``up`` strictly
        between the floor and the cut, identity elsewhere)."""
        h = as_vertices(points) @ self.up
        inside = (h > self.floor) & (h < self.cut)
        out = np.tile(np.eye(3), (len(h), 1, 1))
        out[inside] += (self.factors[k] - 1.0) * np.outer(self.up, self.up)
        return out


def _apply_to_cuboids(cuboids: Cuboids, transforms: np.ndarray) -> Cuboids:
    """The cuboids moved by per-slot affine maps whose linear parts map the cuboid's axes to
    orthogonal directions (true for every map made here): new frame, extents and centre."""
    z, q, t = cuboids.half_extents.copy(), cuboids.quaternions.copy(), cuboids.translations.copy()
    rot = cuboids.rotations
    for k in cuboids.present:
        cols = transforms[k, :3, :3] @ rot[k]  # images of the scaled axes
        lengths = np.linalg.norm(cols, axis=0)
        r = cols / lengths
        if np.linalg.det(r) < 0:
            r[:, 0] = -r[:, 0]
        z[k] = z[k] * lengths
        q[k] = matrix_to_quaternion(r)
        t[k] = transforms[k, :3, :3] @ t[k] + transforms[k, :3, 3]
    return Cuboids(z, q, t, cuboids.existence, cuboids.probabilities)


def _axis_order(rot: np.ndarray, front: np.ndarray, up: np.ndarray, side: np.ndarray):
    """Local axis index and sign matched to (front, up, side): the assignment of the three local
    axes with the largest total alignment."""
    dirs = np.stack([front, up, side])  # (3 world directions, 3)
    dots = dirs @ rot  # dots[d, i] = dir_d . axis_i
    best = max(itertools.permutations(range(3)), key=lambda p: sum(abs(dots[d, p[d]]) for d in range(3)))
    axes = np.array(best)
    signs = np.sign(dots[np.arange(3), axes])
    signs[signs == 0] = 1.0
    return axes, signs


def _rotation_about(axis: np.ndarray, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


def _bottom_height(cuboids: Cuboids, k: int, up: np.ndarray) -> float:
    return float(cuboids.translations[k] @ up - np.abs(cuboids.rotations[k].T @ up) @ cuboids.half_extents[k])


def _top_height(cuboids: Cuboids, k: int, up: np.ndarray) -> float:
    return float(cuboids.translations[k] @ up + np.abs(cuboids.rotations[k].T @ up) @ cuboids.half_extents[k])


#: the largest factor by which an edit may scale or lengthen a part (and the smallest, its inverse), and the
#: largest move in canonical units (the shape is 1 long): beyond, a part's matrices overflow
EDIT_LIMIT = 1e6


def edit_cuboids(cuboids: Cuboids, *, scale=None, rotate=None, move=None, lengthen=None, up=_UP, front=_FRONT,
                 carry: bool = True, contact: float = 0.05, floor: float | None = None,
                 cut: float | None = None) -> Edit:
    """Scale, turn and move parts in their own frames; parts resting on moved parts move along.

    Each part's local axes are matched to the shape's (front, up, side) directions (``side =
    front x up``; with the defaults +X, +Y and +Z, the canonical frame) and every edit is read in
    that matched frame, about the part's **pivot**: the centre of its bottom face (the face whose
    axis is matched to up, on the down side) — the end of a leg on the ground, the edge where a
    back meets the seat.

    Parameters
    ----------
    cuboids : Cuboids
    scale : dict of int -> float or (3,) float
        A number scales the part uniformly; three numbers scale it along its (front, up, side)
        axes (``(1, 1.3, 1)`` lengthens a leg by 30% and keeps its thickness).
    rotate : dict of int -> float
        Degrees about the part's axis matched to ``side`` (right-handed about +side: with the
        defaults a positive angle tips the top of the part backwards, toward -front).
    move : dict of int -> (3,) float
        Displacement along the part's (front, up, side) axes, in the cuboids' units.
    lengthen : dict of int -> float
        Lengthen parts (legs) **below a cut plane** by a factor: see :class:`Lengthening` for
        the rule and why (``scale`` with ``(1, 1.3, 1)`` stretches the whole cuboid instead,
        which on real chairs also stretches the back). The cut plane is ``cut`` when given,
        otherwise the underside of the part they hold up: of the other present parts that touch
        a lengthened part (gap under ``contact``) with their centre above the lowest
        lengthened part's centre, the one with the largest footprint seen from above (a chair's
        seat, a table's top; :func:`edit` then refines the height from the mesh). ``floor`` (default: the lowest bottom of the lengthened cuboids; pass the
        mesh's, as :func:`edit` does, since cuboids fitted loosely reach below the floor) is
        where the stretch starts. A part cannot be both lengthened and scaled, turned or moved.
        In ``transforms`` a lengthened part's row is the affine map of its whole cuboid onto the
        stretched one (for ``Edit.cuboids``); the mesh follows :class:`Lengthening`.
    carry : bool
        Carry resting parts along (default). Part ``j`` rests on part ``k`` when the two touch
        (gap under ``contact``) and ``j``'s centre lies above ``k``'s top (along ``up``). Parts
        are visited from the lowest centre up; a part resting on moved parts is translated by the
        mean displacement of the points of those parts nearest its centre, after its own edit.
        So legs lengthened about their feet raise the seat, and the back and arms on the seat.
        A part touching a lengthened part is carried whatever its height: translated by the
        stretch's displacement at its centre (the full rise above the cut: the seat, and a back
        touching rear legs that continue into its posts; a part of the rise for a stretcher
        between the legs).

    Returns
    -------
    Edit
    """
    up = np.asarray(up, float) / np.linalg.norm(up)
    front = np.asarray(front, float) / np.linalg.norm(front)
    side = np.cross(front, up)
    scale, rotate, move = dict(scale or {}), dict(rotate or {}), dict(move or {})
    lengthen = {int(k): float(v) for k, v in dict(lengthen or {}).items()}
    m = cuboids.count
    own = np.tile(np.eye(4), (m, 1, 1))
    edited = sorted({int(k) for k in (*scale, *rotate, *move, *lengthen)})
    for k in edited:
        if not 0 <= k < m:
            raise ValueError(f"part index {k} is out of range (0-{m - 1})")
        if not cuboids.existence[k]:
            raise ValueError(f"part {k} is not present in this abstraction")
        if k in lengthen:
            if k in scale or k in rotate or k in move:
                raise ValueError(f"part {k} is lengthened; it cannot also be scaled, turned or moved")
            if not (1 / EDIT_LIMIT <= lengthen[k] <= EDIT_LIMIT):
                raise ValueError(f"length factors must be > 0, between {1 / EDIT_LIMIT:g} and {EDIT_LIMIT:g}, got "
                                 f"{lengthen[k]} for part {k}")
            continue
        if k in rotate and not np.isfinite(float(rotate[k])):
            raise ValueError(f"turns must be finite, got {rotate[k]} for part {k}")
        rot = cuboids.rotations[k]
        axes, signs = _axis_order(rot, front, up, side)
        frame = rot[:, axes] * signs  # columns: the part's front, up, side directions
        pivot = cuboids.translations[k] - frame[:, 1] * cuboids.half_extents[k][axes[1]]
        lin = np.eye(3)
        if k in scale:
            s = np.broadcast_to(np.asarray(scale[k], float), (3,))
            if not np.all((s >= 1 / EDIT_LIMIT) & (s <= EDIT_LIMIT)):  # 1e308 overflowed the part's matrices
                raise ValueError(f"scale factors must be > 0, between {1 / EDIT_LIMIT:g} and {EDIT_LIMIT:g}, got "
                                 f"{s.tolist()} for part {k}")
            lin = frame @ np.diag(s) @ frame.T
        if k in rotate:
            lin = _rotation_about(frame[:, 2], float(rotate[k])) @ lin
        shift = np.broadcast_to(np.asarray(move.get(k, 0.0), float), (3,))
        if not np.all(np.abs(shift) <= EDIT_LIMIT):
            raise ValueError(f"moves must be within +-{EDIT_LIMIT:g} (canonical units), got {shift.tolist()} for part {k}")
        offset = frame @ shift
        own[k, :3, :3] = lin
        own[k, :3, 3] = pivot - lin @ pivot + offset
    stretch = _lengthening(cuboids, lengthen, up, contact, floor, cut) if lengthen else None
    for k in lengthen:  # the whole cuboid's affine equivalent, for Edit.cuboids
        b, t = _bottom_height(cuboids, k, up), _top_height(cuboids, k, up)
        nb, nt = stretch.height_map([b, t], k)
        a = (nt - nb) / (t - b) if t > b else 1.0
        own[k, :3, :3] = np.eye(3) + (a - 1.0) * np.outer(up, up)
        own[k, :3, 3] = up * (nb - a * b)
    total = own.copy()
    carried: dict = {}
    if carry:
        present = [int(k) for k in cuboids.present]
        centre_h = {k: float(cuboids.translations[k] @ up) for k in present}
        order = sorted(present, key=lambda k: centre_h[k])
        for j in order:
            if j in lengthen:
                continue
            below = [k for k in order if k != j and (k in lengthen or centre_h[j] > _top_height(cuboids, k, up))
                     and not np.allclose(total[k], np.eye(4)) and cuboid_gap(cuboids, j, k) < contact]
            if not below:
                continue
            shifts = []
            for k in below:  # the point of k nearest j's centre, moved by k's total transform
                if k in lengthen:  # the full rise for the support, else the stretch at j's centre
                    shifts.append(stretch.rise(k) * up if j == stretch.support
                                  else stretch.displacement(cuboids.translations[j][None], k)[0])
                    continue
                c = cuboids.subset([k])
                local = np.clip(world_to_local(cuboids.translations[j][None], c)[0, 0], -c.half_extents[0], c.half_extents[0])
                p = c.rotations[0] @ local + c.translations[0]
                shifts.append(total[k, :3, :3] @ p + total[k, :3, 3] - p)
            total[j, :3, 3] += np.mean(shifts, axis=0)
            carried[j] = below
    return Edit(_apply_to_cuboids(cuboids, total), total, edited, carried, stretch)


def _lengthening(cuboids: Cuboids, factors: dict, up, contact: float, floor, cut) -> Lengthening:
    """The :class:`Lengthening` of ``factors`` (see :func:`edit_cuboids` for the cut plane)."""
    parts = sorted(factors)
    if floor is None:
        floor = min(_bottom_height(cuboids, k, up) for k in parts)
    lowest = min(float(cuboids.translations[k] @ up) for k in parts)
    held = [int(j) for j in cuboids.present if int(j) not in factors
            and float(cuboids.translations[j] @ up) > lowest
            and min(cuboid_gap(cuboids, int(j), k) for k in parts) < contact]
    support = max(held, key=lambda j: _footprint(cuboids, j, up)) if held else None
    if cut is None:
        cut = _bottom_height(cuboids, support, up) if held else max(_top_height(cuboids, k, up) for k in parts)
    if not cut > floor:
        raise ValueError(f"the cut plane (height {cut:.4f}) must lie above the floor (height {floor:.4f})")
    return Lengthening({k: float(factors[k]) for k in parts}, float(floor), float(cut), support, np.asarray(up, float))


def _footprint(cuboids: Cuboids, k: int, up) -> float:
    """Area of cuboid ``k``'s shadow on the plane normal to ``up`` (seen from above)."""
    r, z = cuboids.rotations[k], cuboids.half_extents[k]
    axes = r * (2.0 * z)  # columns: the full edges
    flat = axes - np.outer(up, up @ axes)
    # the shadow of a box is the zonotope of its three projected edges: area = sum of the
    # parallelograms spanned by pairs of them
    return float(sum(abs(np.cross(flat[:, a], flat[:, b]) @ up) for a, b in ((0, 1), (0, 2), (1, 2))))

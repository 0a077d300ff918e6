"""Procedural, seeded, part-labelled shapes: chairs, tables, airplanes and four-legged animals.

They stand in for real data sets (ShapeNet and friends) that cannot be shipped, so tests, examples
and demos of the cuboid abstraction have something realistic to chew on. Every shape is

* one watertight triangle mesh: the parts are built as closed solids that overlap slightly and are
  joined by a boolean union (manifold3d), so the result is a single connected component;
* labelled per face: each face carries the index of the part it came from, recovered from
  manifold3d's provenance (every part enters the union as its own *original* mesh, and the output
  mesh says which original each run of triangles came from);
* not a union of boxes: legs are cylinders or tapered, seats and backs have rounded edges, backs
  tilt, wings are swept, fuselages and torsos are smooth, heads are spheres; cuboids can only
  approximate them, as with real data;
* in the canonical frame of :mod:`primkit`: +Y up, +X front (chair seat faces +X, airplane nose
  and animal head point to +X), bounding box centred at the origin, longest side 1.

Left and right are the shape's own: looking along +X with +Y up, the right-hand side is +Z, so
``*_left`` parts lie at negative Z and ``*_right`` parts at positive Z.

Each category has a fixed tuple of instance-level part names (:data:`PART_NAMES`), so a label is a
stable index; parts a shape does not have (the arms of an armless chair) simply have no faces.
:data:`PART_GROUPS` maps every part to a coarse semantic group (``"legs"``, ``"seat"``, ...).

Randomness comes only from the ``seed`` argument. Every attribute is drawn from the generator in
a fixed order whatever the overrides, so ``chair(3, has_arms=True)`` is ``chair(3)`` with arms.
Absolute sizes are in metre-like units before the final normalisation; the attributes keep
those units.
"""

from __future__ import annotations

import functools
import json
import math
import operator
from dataclasses import dataclass
from pathlib import Path

import manifold3d
import numpy as np
import trimesh

from ..io import atomic_output

__all__ = [
    "CATEGORIES",
    "PART_GROUPS",
    "PART_NAMES",
    "LabelledShape",
    "airplane",
    "animal",
    "chair",
    "generate",
    "read_collection_labels",
    "table",
    "write_collection",
]

CATEGORIES = ("chair", "table", "airplane", "animal")

_LEGS = ("leg_front_left", "leg_front_right", "leg_back_left", "leg_back_right")

PART_NAMES: dict[str, tuple[str, ...]] = {
    "chair": ("seat", "back", *_LEGS, "arm_left", "arm_right", "column", "star_base"),
    "table": ("top", *_LEGS, "pedestal", "foot"),
    "airplane": (
        "fuselage",
        "wing_left",
        "wing_right",
        "tail_left",
        "tail_right",
        "fin",
        "engine_left_inner",
        "engine_right_inner",
        "engine_left_outer",
        "engine_right_outer",
    ),
    "animal": ("torso", "head", "neck", *_LEGS, "tail"),
}

PART_GROUPS: dict[str, dict[str, str]] = {
    "chair": {
        "seat": "seat",
        "back": "back",
        **{leg: "legs" for leg in _LEGS},
        "arm_left": "arms",
        "arm_right": "arms",
        "column": "base",
        "star_base": "base",
    },
    "table": {"top": "top", **{leg: "legs" for leg in _LEGS}, "pedestal": "base", "foot": "base"},
    "airplane": {
        "fuselage": "fuselage",
        "wing_left": "wings",
        "wing_right": "wings",
        "tail_left": "tail",
        "tail_right": "tail",
        "fin": "tail",
        "engine_left_inner": "engines",
        "engine_right_inner": "engines",
        "engine_left_outer": "engines",
        "engine_right_outer": "engines",
    },
    "animal": {
        "torso": "torso",
        "head": "head",
        "neck": "neck",
        **{leg: "legs" for leg in _LEGS},
        "tail": "tail",
    },
}


@dataclass(frozen=True, eq=False)
class LabelledShape:
    """One generated shape: a watertight mesh whose faces are labelled with part indices.

    Attributes
    ----------
    category : str
      One of :data:`CATEGORIES`.
    vertices : (n, 3) float64
      In the canonical frame (+Y up, +X front, bbox centred, longest side 1).
    faces : (f, 3) int64
      Triangles, counter-clockwise seen from outside.
    face_labels : (f,) int64
      ``face_labels[i]`` indexes ``part_names``: the part face ``i`` belongs to.
    part_names : tuple of str
      The category's fixed part names (:data:`PART_NAMES`); absent parts have no faces.
    part_groups : dict of str to str
      Part name to coarse group (:data:`PART_GROUPS`).
    attributes : dict
      The generating attributes, JSON-serialisable plain values, in the units used before
      normalisation.
    seed : int or None
      The seed the shape was generated from.
    """

    category: str
    vertices: np.ndarray
    faces: np.ndarray
    face_labels: np.ndarray
    part_names: tuple[str, ...]
    part_groups: dict[str, str]
    attributes: dict
    seed: int | None

    def __post_init__(self):
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError("`vertices` must be (n, 3) float")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ValueError("`faces` must be (f, 3) int")
        if self.face_labels.shape != (len(self.faces),):
            raise ValueError("`face_labels` must be (f,) int, one label per face")

    @property
    def present_parts(self) -> tuple[str, ...]:
        """Names of the parts that own at least one face, in ``part_names`` order."""
        present = np.unique(self.face_labels)
        return tuple(self.part_names[i] for i in present)

    def part_faces(self, name: str) -> np.ndarray:
        """Indices of the faces of part ``name``: (k,) int64, empty if the part is absent."""
        return np.flatnonzero(self.face_labels == self.part_names.index(name))

    def to_trimesh(self) -> trimesh.Trimesh:
        """The mesh as a :class:`trimesh.Trimesh`, unprocessed (face order kept)."""
        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False)


# ---------------------------------------------------------------------------------------------
# Solid building blocks. Every helper returns a closed manifold3d.Manifold.
# ---------------------------------------------------------------------------------------------


def _affine(rotation: np.ndarray, translation) -> np.ndarray:
    """(3, 4) affine matrix [R | t] acting on column vectors, as Manifold.transform wants."""
    return np.hstack([np.asarray(rotation, float), np.asarray(translation, float).reshape(3, 1)])


def _rot_z(degrees: float) -> np.ndarray:
    """Rotation about +Z; a positive angle turns +Y towards -X (a chair back tilting back)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(degrees: float) -> np.ndarray:
    """Rotation about +Y; a positive angle turns +X towards -Z."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _frame_along(direction) -> np.ndarray:
    """A rotation whose third column is the unit vector along ``direction`` (det +1)."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    return np.column_stack([e1, e2, d])


def _check(solid: manifold3d.Manifold, what: str) -> manifold3d.Manifold:
    if solid.is_empty() or solid.status() != manifold3d.Error.NoError:
        raise RuntimeError(f"building {what} gave an empty or invalid solid")
    return solid


def _hull(points) -> manifold3d.Manifold:
    """Convex hull of (k, 3) points."""
    return _check(manifold3d.Manifold.hull_points(np.asarray(points, float)), "a convex hull")


def _rod(p0, p1, r0: float, r1: float | None = None, segments: int = 32) -> manifold3d.Manifold:
    """Cylinder (or cone frustum) from ``p0`` (radius ``r0``) to ``p1`` (radius ``r1``)."""
    p0 = np.asarray(p0, float)
    axis = np.asarray(p1, float) - p0
    r1 = r0 if r1 is None else r1
    solid = manifold3d.Manifold.cylinder(float(np.linalg.norm(axis)), r0, r1, segments)
    return _check(solid.transform(_affine(_frame_along(axis), p0)), "a rod")


def _ellipsoid(center, radii, segments: int = 32) -> manifold3d.Manifold:
    solid = manifold3d.Manifold.sphere(1.0, segments).scale(tuple(float(r) for r in radii))
    return _check(solid.translate(tuple(float(c) for c in center)), "an ellipsoid")


def _disk(center, rx: float, rz: float, thickness: float, segments: int = 64):
    """Elliptic slab with a vertical axis: radii ``rx`` along X and ``rz`` along Z."""
    solid = manifold3d.Manifold.cylinder(1.0, 1.0, 1.0, segments, True)
    # local z (the axis) -> world Y, local y -> world -Z: a proper rotation times a scale.
    m = np.array([[rx, 0.0, 0.0], [0.0, 0.0, thickness], [0.0, -rz, 0.0]])
    return _check(solid.transform(_affine(m, center)), "a disk")


@functools.cache
def _unit_sphere_points() -> np.ndarray:
    """(k, 3) points on the unit sphere, used to round the corners of hulls."""
    mesh = manifold3d.Manifold.sphere(1.0, 20).to_mesh64()
    return np.asarray(mesh.vert_properties, float)[:, :3]


def _rounded_box(size, radius: float) -> manifold3d.Manifold:
    """Box of full extents ``size`` centred at the origin, every edge rounded by ``radius``."""
    half = np.asarray(size, float) / 2.0
    radius = float(min(radius, 0.999 * half.min()))
    inner = half - radius
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    points = (corners * inner)[:, None, :] + radius * _unit_sphere_points()[None, :, :]
    return _hull(points.reshape(-1, 3))


def _rounded_slab(
    length: float, width: float, thickness: float, corner: float, bevel: float, center
) -> manifold3d.Manifold:
    """Horizontal slab (X length, Z width, Y thickness), corners rounded in plan by ``corner``.

    The upper 40% of the rim is vertical; below it the underside is bevelled: the bottom face
    is the top outline offset inwards by ``bevel``, as on many table tops.
    """
    corner = float(min(corner, 0.999 * min(length, width) / 2.0))
    bevel = float(min(bevel, 0.45 * min(length, width)))
    angles = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    # (height as a fraction of the thickness, corner radius, how far the corner centres move in)
    levels = ((0.5, corner, 0.0), (0.1, corner, 0.0))
    levels += ((-0.5, max(corner - bevel, 0.0), max(bevel - corner, 0.0)),)
    points = []
    for sx in (-1.0, 1.0):
        for sz in (-1.0, 1.0):
            for level, radius, shrink in levels:
                cx = sx * (length / 2 - corner - shrink)
                cz = sz * (width / 2 - corner - shrink)
                ys = np.full(len(ring), level * thickness)
                xs, zs = cx + radius * ring[:, 0], cz + radius * ring[:, 1]
                points.append(np.column_stack([xs, ys, zs]))
    return _hull(np.vstack(points) + np.asarray(center, float))


def _tapered_square(p_bottom, p_top, half_bottom: float, half_top: float) -> manifold3d.Manifold:
    """Square-section leg: hull of horizontal squares around the bottom and top points."""
    square = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float)
    bottom = np.asarray(p_bottom, float) + half_bottom * square
    return _hull(np.vstack([bottom, np.asarray(p_top, float) + half_top * square]))


def _airfoil(
    le_x: float, chord: float, thickness: float, at: float, span_coord: float, vertical=False
) -> np.ndarray:
    """(23, 3) points of a symmetric airfoil section (NACA four-digit thickness law, convex).

    The section lies in the x-y plane at z = ``span_coord`` with its chord line at y = ``at``
    (a wing or tail), or, when ``vertical``, in the x-z plane at y = ``span_coord`` with its
    chord line at z = ``at`` (a fin). The leading edge is at ``le_x``, the trailing edge at
    ``le_x - chord``; ``thickness`` is the largest thickness.
    """
    u = 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, 12)))  # chord fractions, dense at the ends
    poly = 0.2969 * np.sqrt(u) - 0.1260 * u - 0.3516 * u**2 + 0.2843 * u**3 - 0.1015 * u**4
    half = 5.0 * thickness * poly
    xs = le_x - chord * np.concatenate([u, u[1:]])
    ts = np.concatenate([half, -half[1:]])
    if vertical:
        return np.column_stack([xs, np.full(len(xs), span_coord), at + ts])
    return np.column_stack([xs, at + ts, np.full(len(xs), span_coord)])


def _ray_exit(point, direction, center, radii) -> np.ndarray:
    """Where the ray from ``point`` (inside the ellipsoid) along ``direction`` leaves it."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    p = (np.asarray(point, float) - center) / radii
    q = d / radii
    a, b, c = q @ q, 2.0 * (p @ q), p @ p - 1.0
    t = (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return np.asarray(point, float) + t * d


def _union(solids) -> manifold3d.Manifold:
    solids = list(solids)
    if len(solids) == 1:
        return solids[0]
    return manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)


# ---------------------------------------------------------------------------------------------
# Assembly: union with provenance, then normalise into the canonical frame.
# ---------------------------------------------------------------------------------------------


_EDGES_PER_EXTENT = 15  # longest edge after refinement: the bbox's longest side over this
_SLIVER_VOLUME = 1e-5  # loose union pieces below this fraction of the main one are dropped


def _assemble(category: str, parts: dict[str, list], attributes: dict, seed) -> LabelledShape:
    """Union the parts, label faces by provenance and normalise into the canonical frame.

    ``parts`` maps a part name to the solids that make it up (unioned into one original first).
    """
    names = PART_NAMES[category]
    id_to_label = {}
    originals = []
    for name, solids in parts.items():
        original = _check(_union(solids), name).as_original()
        id_to_label[original.original_id()] = names.index(name)
        originals.append(original)
    solid = _check(_union(originals), f"the {category}")
    pieces = solid.decompose()
    if len(pieces) > 1:
        # Where two surfaces nearly touch, the union can leave a loose sliver of almost no
        # volume; drop those. Anything bigger means the parts do not overlap: a bug.
        volumes = np.array([piece.volume() for piece in pieces])
        kept = [piece for piece, v in zip(pieces, volumes) if v > _SLIVER_VOLUME * volumes.max()]
        if len(kept) != 1:
            raise RuntimeError(f"the parts of the {category} do not form one connected solid")
        solid = kept[0]

    # Split long edges (big flat faces come out of the hulls as a few slivers) so triangles
    # have comparable sizes; provenance survives refinement.
    bbox = np.asarray(solid.bounding_box(), dtype=float)
    solid = solid.refine_to_length(float((bbox[3:] - bbox[:3]).max()) / _EDGES_PER_EXTENT)
    mesh = solid.to_mesh64()
    vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    merge_from = np.asarray(mesh.merge_from_vert, dtype=np.int64)
    if len(merge_from):  # vertices split by properties; we only keep positions, so merge them
        remap = np.arange(len(vertices))
        remap[merge_from] = np.asarray(mesh.merge_to_vert, dtype=np.int64)
        faces = remap[faces]
        used, faces = np.unique(faces, return_inverse=True)
        faces = faces.reshape(-1, 3)
        vertices = vertices[used]
    # run_index counts triangle-vertex indices (3 per triangle), with a final end marker.
    run_index = np.asarray(mesh.run_index, dtype=np.int64) // 3
    run_labels = np.array([id_to_label[int(i)] for i in mesh.run_original_id], dtype=np.int64)
    face_labels = np.repeat(run_labels, np.diff(run_index))
    if len(face_labels) != len(faces):
        raise RuntimeError("manifold3d provenance does not cover every face")

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    vertices = (vertices - (lo + hi) / 2.0) / (hi - lo).max()
    return LabelledShape(
        category=category,
        vertices=np.ascontiguousarray(vertices),
        faces=np.ascontiguousarray(faces),
        face_labels=face_labels,
        part_names=names,
        part_groups=dict(PART_GROUPS[category]),
        attributes=attributes,
        seed=None if seed is None else operator.index(seed),
    )


def _finish_attributes(name: str, sampled: dict, overrides: dict, choices: dict) -> dict:
    """Apply user overrides to sampled attributes, keeping the sampled value types."""
    unknown = set(overrides) - set(sampled)
    if unknown:
        raise TypeError(
            f"{name}() got unknown attributes {sorted(unknown)}; known: {sorted(sampled)}"
        )
    attributes = dict(sampled)
    for key, value in overrides.items():
        kind = type(sampled[key])
        if kind is bool:
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"attribute {key!r} must be a bool, got {value!r}")
            value = bool(value)
        elif kind is int:
            value = int(value)
        elif kind is float:
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"attribute {key!r} must be finite, got {value!r}")
        else:
            value = str(value)
        if key in choices and value not in choices[key]:
            raise ValueError(f"attribute {key!r} must be one of {choices[key]}, got {value!r}")
        attributes[key] = value
    return attributes


def _uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


def _pick(rng: np.random.Generator, options, p=None):
    return options[int(rng.choice(len(options), p=p))]


def _legs_at(corners: dict, y_top: float, length: float, attributes: dict) -> dict:
    """Four legs from (x, z) corner positions down to the floor, splayed outwards.

    ``corners`` maps a leg name to its (x, z) under the top; the top end sits at ``y_top``
    (inside the part it carries), the bottom end on the floor y = 0, pushed outwards by
    ``length * tan(leg_splay_deg)`` along both X and Z. Reads ``leg_splay_deg``,
    ``leg_radius`` and ``leg_style`` from ``attributes``.
    """
    radius, style = attributes["leg_radius"], attributes["leg_style"]
    out = length * math.tan(math.radians(attributes["leg_splay_deg"]))
    legs = {}
    for name, (x, z) in corners.items():
        top = np.array([x, y_top, z])
        bottom = np.array([x + math.copysign(out, x), 0.0, z + math.copysign(out, z)])
        if style == "round":
            solid = _rod(bottom, top, radius, radius)
        elif style == "tapered":
            solid = _rod(bottom, top, 0.6 * radius, radius)
        else:  # "square"
            solid = _tapered_square(bottom, top, 0.6 * radius, radius)
        legs[name] = [solid]
    return legs


def _corner_positions(half_x: float, half_z: float) -> dict:
    """Leg names to (x, z): front is +X, left is -Z."""
    return {
        "leg_front_left": (half_x, -half_z),
        "leg_front_right": (half_x, half_z),
        "leg_back_left": (-half_x, -half_z),
        "leg_back_right": (-half_x, half_z),
    }


# ---------------------------------------------------------------------------------------------
# Categories
# ---------------------------------------------------------------------------------------------

_CHAIR_CHOICES = {"leg_style": ("round", "tapered", "square")}


def chair(seed: int | None = None, **overrides) -> LabelledShape:
    """A chair: seat, tilted back, four legs or a swivel base, optional arms.

    Attributes (override any by keyword): ``swivel`` (bool, ~20%; a column on a five-spoke star
    base replaces the legs and the seat is an elliptic cushion), ``has_arms`` (bool, ~30%),
    ``seat_width`` (Z), ``seat_depth`` (X), ``seat_thickness``, ``leg_length`` (floor to seat
    underside), ``leg_radius``, ``leg_style`` ("round", "tapered", "square"), ``leg_splay_deg``,
    ``back_height`` (above the seat), ``back_thickness``, ``back_tilt_deg`` (0-25, leaning
    towards -X), ``arm_height`` (above the seat), ``arm_width``, ``column_radius``,
    ``base_radius``. Derived and recorded: ``seat_height`` (floor to seat top).
    """
    rng = np.random.default_rng(seed)
    sampled = {
        "swivel": bool(rng.random() < 0.2),
        "has_arms": bool(rng.random() < 0.3),
        "seat_width": _uniform(rng, 0.42, 0.58),
        "seat_depth": _uniform(rng, 0.40, 0.54),
        "seat_thickness": _uniform(rng, 0.04, 0.09),
        "leg_length": _uniform(rng, 0.36, 0.50),
        "leg_radius": _uniform(rng, 0.016, 0.032),
        "leg_style": _pick(rng, _CHAIR_CHOICES["leg_style"]),
        "leg_splay_deg": _uniform(rng, 0.0, 10.0),
        "back_height": _uniform(rng, 0.30, 0.60),
        "back_thickness": _uniform(rng, 0.025, 0.06),
        "back_tilt_deg": _uniform(rng, 0.0, 25.0),
        "arm_height": _uniform(rng, 0.16, 0.26),
        "arm_width": _uniform(rng, 0.04, 0.07),
        "column_radius": _uniform(rng, 0.022, 0.035),
        "base_radius": _uniform(rng, 0.26, 0.34),
    }
    a = _finish_attributes("chair", sampled, overrides, _CHAIR_CHOICES)
    w, d, t = a["seat_width"], a["seat_depth"], a["seat_thickness"]
    seat_bottom = a["leg_length"]
    seat_top = seat_bottom + t
    a["seat_height"] = seat_top
    parts: dict[str, list] = {}

    # Seat: a cushion with rounded edges, or an elliptic disk on swivel chairs.
    edge = min(0.4 * t, 0.03)
    if a["swivel"]:
        parts["seat"] = [_disk((0.0, seat_bottom + t / 2, 0.0), d / 2, w / 2, t)]
    else:
        parts["seat"] = [_rounded_box((d, t, w), edge).translate((0.0, seat_bottom + t / 2, 0.0))]

    # Back: a rounded slab hinged at the rear of the seat top, tilted towards -X.
    bt, tilt = a["back_thickness"], a["back_tilt_deg"]
    overlap = 0.5 * t
    back_width = 0.9 * w if a["swivel"] else w
    pivot = np.array([-d / 2 + bt / 2, seat_top, 0.0])
    slab = _rounded_box((bt, a["back_height"] + overlap, back_width), min(0.45 * bt, 0.02))
    offset = np.array([0.0, (a["back_height"] + overlap) / 2 - overlap, 0.0])
    rot = _rot_z(tilt)
    parts["back"] = [slab.transform(_affine(rot, pivot + rot @ offset))]

    if a["swivel"]:
        cr = a["column_radius"]
        hub_r = max(1.8 * cr, 0.045)
        parts["column"] = [_rod((0.0, 0.06, 0.0), (0.0, seat_bottom + t / 2, 0.0), cr, 0.8 * cr)]
        star = [_rod((0.0, 0.035, 0.0), (0.0, 0.10, 0.0), hub_r, hub_r, 24)]
        reach = a["base_radius"]
        spoke = _hull(
            [
                *([0.0, y, z] for y in (0.04, 0.09) for z in (-0.025, 0.025)),
                *([reach, y, z] for y in (0.02, 0.045) for z in (-0.016, 0.016)),
            ]
        )
        caster = _rod((reach - 0.015, 0.0, 0.0), (reach - 0.015, 0.03, 0.0), 0.016, 0.016, 16)
        arm_of_star = _union([spoke, caster])
        for k in range(5):
            star.append(arm_of_star.transform(_affine(_rot_y(72.0 * k), (0.0, 0.0, 0.0))))
        parts["star_base"] = star
    else:
        inset = a["leg_radius"] + 0.6 * edge + 0.005
        corners = _corner_positions(d / 2 - inset, w / 2 - inset)
        parts.update(_legs_at(corners, seat_bottom + t / 2, seat_bottom, a))

    if a["has_arms"]:
        aw, ah = a["arm_width"], a["arm_height"]
        x_rear = pivot[0] - ah * math.tan(math.radians(tilt))
        x_front = 0.25 * d if a["swivel"] else d / 2
        x_post = x_front - 0.6 * aw
        if a["swivel"]:
            half_z = (w / 2) * math.sqrt(max(0.0, 1.0 - (2.0 * x_post / d) ** 2))
            z_arm = half_z - 0.7 * aw
        else:
            z_arm = w / 2 - aw / 2
        y_rest = seat_top + ah
        for name, side in (("arm_left", -1.0), ("arm_right", 1.0)):
            rest = _rounded_box((x_front - x_rear, 0.035, aw), 0.012)
            rest = rest.translate(((x_front + x_rear) / 2, y_rest, side * z_arm))
            z = side * z_arm
            post = _rod((x_post, seat_top - t / 2, z), (x_post, y_rest, z), min(0.4 * aw, 0.02))
            parts[name] = [rest, post]

    return _assemble("chair", parts, a, seed)


_TABLE_CHOICES = {"top_shape": ("rect", "round"), "leg_style": ("round", "tapered", "square")}


def table(seed: int | None = None, **overrides) -> LabelledShape:
    """A table: a rectangular or round top on four legs or on a central pedestal and foot.

    Attributes: ``top_shape`` ("rect" or "round", ~35% round; round tops may be oval),
    ``pedestal`` (bool; ~60% of round tables, ~15% of rectangular ones), ``top_length`` (X),
    ``top_width`` (Z), ``top_thickness``, ``corner_radius`` (plan rounding of rectangular tops,
    whose underside is also bevelled by 0.6 ``top_thickness``),
    ``height`` (floor to top surface), ``leg_style``, ``leg_radius``, ``leg_inset``,
    ``leg_splay_deg``, ``pedestal_radius``, ``foot_radius``, ``foot_height``.
    """
    rng = np.random.default_rng(seed)
    top_shape = _pick(rng, _TABLE_CHOICES["top_shape"], p=[0.65, 0.35])
    pedestal = bool(rng.random() < (0.6 if top_shape == "round" else 0.15))
    width = _uniform(rng, 0.5, 1.0)
    length_ratio = _uniform(rng, 1.0, 1.3) if top_shape == "round" else _uniform(rng, 1.2, 2.2)
    sampled = {
        "top_shape": top_shape,
        "pedestal": pedestal,
        "top_length": width * length_ratio,
        "top_width": width,
        "top_thickness": _uniform(rng, 0.025, 0.06),
        "corner_radius": _uniform(rng, 0.01, 0.1),
        "height": _uniform(rng, 0.55, 0.8),
        "leg_style": _pick(rng, _TABLE_CHOICES["leg_style"]),
        "leg_radius": _uniform(rng, 0.02, 0.045),
        "leg_inset": _uniform(rng, 0.03, 0.12),
        "leg_splay_deg": _uniform(rng, 0.0, 6.0),
        "pedestal_radius": _uniform(rng, 0.04, 0.08),
        "foot_radius": _uniform(rng, 0.18, 0.35),
        "foot_height": _uniform(rng, 0.03, 0.07),
    }
    a = _finish_attributes("table", sampled, overrides, _TABLE_CHOICES)
    length, width, t, h = a["top_length"], a["top_width"], a["top_thickness"], a["height"]
    parts: dict[str, list] = {}
    top_center = (0.0, h - t / 2, 0.0)
    if a["top_shape"] == "round":
        parts["top"] = [_disk(top_center, length / 2, width / 2, t, 128)]
    else:
        bevel = 0.6 * t
        parts["top"] = [_rounded_slab(length, width, t, a["corner_radius"], bevel, top_center)]

    if a["pedestal"]:
        foot_r = min(a["foot_radius"], 0.45 * min(length, width))
        foot_r = max(foot_r, 1.5 * a["pedestal_radius"])
        fh = a["foot_height"]
        parts["foot"] = [_rod((0.0, 0.0, 0.0), (0.0, fh, 0.0), foot_r, 0.55 * foot_r, 48)]
        pr = a["pedestal_radius"]
        column = _rod((0.0, fh / 2, 0.0), (0.0, h - t / 2, 0.0), 1.15 * pr, 0.85 * pr, 32)
        parts["pedestal"] = [column]
    else:
        inset = a["leg_inset"]
        if a["top_shape"] == "round":
            half_x = (length / 2 - inset) * math.sqrt(0.5)
            half_z = (width / 2 - inset) * math.sqrt(0.5)
        else:
            inset = max(inset, a["leg_radius"] + 0.01 + 0.3 * a["corner_radius"], bevel)
            half_x, half_z = length / 2 - inset, width / 2 - inset
        corners = _corner_positions(half_x, half_z)
        parts.update(_legs_at(corners, h - t / 2, h - t, a))
    return _assemble("table", parts, a, seed)


def airplane(seed: int | None = None, **overrides) -> LabelledShape:
    """An airplane: fuselage, swept wings, horizontal tail halves, fin, 0/2/4 engines.

    The fuselage has length 1 along X (nose at +X) before normalisation. Attributes:
    ``fuselage_radius``, ``wing_span`` (tip to tip), ``wing_root_chord``, ``wing_taper``
    (tip chord / root chord), ``wing_sweep_deg``, ``wing_dihedral_deg``, ``wing_x`` (root
    mid-chord position), ``wing_y_frac`` (root height as a fraction of the fuselage radius,
    -0.6 low wing to 0.6 high wing), ``wing_thickness_ratio``, ``tail_span``,
    ``tail_root_chord``, ``tail_sweep_deg``, ``fin_height``, ``fin_root_chord``,
    ``fin_sweep_deg``, ``engine_count`` (0, 2 or 4), ``engine_radius``, ``engine_length``.
    """
    rng = np.random.default_rng(seed)
    sampled = {
        "fuselage_radius": _uniform(rng, 0.04, 0.075),
        "wing_span": _uniform(rng, 0.7, 1.2),
        "wing_root_chord": _uniform(rng, 0.14, 0.26),
        "wing_taper": _uniform(rng, 0.25, 0.6),
        "wing_sweep_deg": _uniform(rng, 0.0, 38.0),
        "wing_dihedral_deg": _uniform(rng, 0.0, 7.0),
        "wing_x": _uniform(rng, -0.05, 0.12),
        "wing_y_frac": _uniform(rng, -0.6, 0.6),
        "wing_thickness_ratio": _uniform(rng, 0.08, 0.14),
        "tail_span": _uniform(rng, 0.25, 0.45),
        "tail_root_chord": _uniform(rng, 0.08, 0.14),
        "tail_sweep_deg": _uniform(rng, 10.0, 40.0),
        "fin_height": _uniform(rng, 0.10, 0.20),
        "fin_root_chord": _uniform(rng, 0.10, 0.18),
        "fin_sweep_deg": _uniform(rng, 20.0, 50.0),
        "engine_count": int(_pick(rng, (0, 2, 4), p=[0.3, 0.45, 0.25])),
        "engine_radius": _uniform(rng, 0.025, 0.045),
        "engine_length": _uniform(rng, 0.12, 0.2),
    }
    a = _finish_attributes("airplane", sampled, overrides, {"engine_count": (0, 2, 4)})
    r = a["fuselage_radius"]
    parts: dict[str, list] = {}

    # Fuselage: hull of a pointed nose ellipsoid, a full-radius body sphere and a raised tail cone.
    tail_r, tail_y = 0.35 * r, 0.4 * r
    nose = _ellipsoid((0.5 - 1.6 * r, 0.0, 0.0), (1.6 * r, r, r), 48)
    body = manifold3d.Manifold.sphere(r, 48).translate((-0.15, 0.0, 0.0))
    cone = manifold3d.Manifold.sphere(tail_r, 32).translate((-0.5 + tail_r, tail_y, 0.0))
    parts["fuselage"] = [_check(manifold3d.Manifold.batch_hull([nose, body, cone]), "the fuselage")]

    def axis_y(x: float) -> float:
        """Height of the fuselage axis at x (it rises along the tail cone)."""
        x0, x1 = -0.15, -0.5 + tail_r
        return 0.0 if x >= x0 else tail_y * (x - x0) / (x1 - x0)

    # Wings: lofted convex airfoil sections, swept back (towards -X) with dihedral.
    c_root = a["wing_root_chord"]
    c_tip = c_root * a["wing_taper"]
    half_span = a["wing_span"] / 2
    le_root = a["wing_x"] + c_root / 2
    y_root = a["wing_y_frac"] * r
    sweep = math.tan(math.radians(a["wing_sweep_deg"]))
    dihedral = math.tan(math.radians(a["wing_dihedral_deg"]))
    tr = a["wing_thickness_ratio"]

    def wing_at(frac: float):
        """Leading-edge x, chord, chord-line y of the wing at a span fraction."""
        chord = c_root + (c_tip - c_root) * frac
        return le_root - frac * half_span * sweep, chord, y_root + frac * half_span * dihedral

    le_tip, _, y_tip = wing_at(1.0)
    for name, side in (("wing_left", -1.0), ("wing_right", 1.0)):
        root = _airfoil(le_root, c_root, tr * c_root, y_root, 0.0)
        tip = _airfoil(le_tip, c_tip, tr * c_tip, y_tip, side * half_span)
        parts[name] = [_hull(np.vstack([root, tip]))]

    # Horizontal tail halves and the fin, rooted on the fuselage axis near the tail.
    ct = a["tail_root_chord"]
    x_tail = -0.5 + 0.6 * ct + 0.05
    tail_half = a["tail_span"] / 2
    tail_le = x_tail + ct / 2
    ty = axis_y(x_tail)
    tail_tip_le = tail_le - tail_half * math.tan(math.radians(a["tail_sweep_deg"]))
    for name, side in (("tail_left", -1.0), ("tail_right", 1.0)):
        root = _airfoil(tail_le, ct, 0.1 * ct, ty, 0.0)
        tip = _airfoil(tail_tip_le, 0.5 * ct, 0.05 * ct, ty, side * tail_half)
        parts[name] = [_hull(np.vstack([root, tip]))]
    cf = a["fin_root_chord"]
    x_fin = -0.5 + 0.6 * cf + 0.05
    fin_le = x_fin + cf / 2
    fy = axis_y(x_fin)
    fin_tip_le = fin_le - a["fin_height"] * math.tan(math.radians(a["fin_sweep_deg"]))
    root = _airfoil(fin_le, cf, 0.12 * cf, 0.0, fy, vertical=True)
    fin_top = fy + tail_r + a["fin_height"]
    tip = _airfoil(fin_tip_le, 0.55 * cf, 0.06 * cf, 0.0, fin_top, vertical=True)
    parts["fin"] = [_hull(np.vstack([root, tip]))]

    # Engines: tapered nacelles hanging under the wings on a pylon that reaches the chord plane.
    slots = {0: (), 2: (("inner", 0.32),), 4: (("inner", 0.28), ("outer", 0.6))}[a["engine_count"]]
    re, le_len = a["engine_radius"], a["engine_length"]
    for which, frac in slots:
        le_x, chord, y_mid = wing_at(frac)
        yc = y_mid - 0.5 * tr * chord - 1.1 * re
        x0, x1 = le_x - min(0.55 * le_len, 0.6 * chord), le_x - 0.1 * chord
        for side_name, side in (("left", -1.0), ("right", 1.0)):
            z = side * frac * half_span
            front = (le_x + 0.45 * le_len, yc, z)
            back = (le_x - 0.55 * le_len, yc, z)
            dzs = (-0.2 * re, 0.2 * re)
            pylon = _hull([[x, y, z + dz] for x in (x0, x1) for y in (yc, y_mid) for dz in dzs])
            parts[f"engine_{side_name}_{which}"] = [_rod(back, front, 0.75 * re, re, 32), pylon]
    return _assemble("airplane", parts, a, seed)


def animal(seed: int | None = None, **overrides) -> LabelledShape:
    """A four-legged animal: ellipsoid torso, neck, spherical head (with a snout), legs, tail.

    Attributes: ``torso_length`` (X), ``torso_height`` (Y), ``torso_width`` (Z), ``leg_length``
    (floor to torso underside), ``leg_radius``, ``leg_splay_deg``, ``neck_length`` (the visible
    part), ``neck_angle_deg`` (above horizontal), ``neck_radius``, ``head_radius``,
    ``snout_length``, ``tail_length`` (visible part), ``tail_angle_deg`` (above horizontal,
    negative hangs down), ``tail_radius``.
    """
    rng = np.random.default_rng(seed)
    torso_width = _uniform(rng, 0.14, 0.24)
    torso_height = _uniform(rng, 0.16, 0.28)
    sampled = {
        "torso_length": _uniform(rng, 0.45, 0.8),
        "torso_height": torso_height,
        "torso_width": torso_width,
        "leg_length": _uniform(rng, 0.25, 0.6),
        "leg_radius": torso_width * _uniform(rng, 0.12, 0.2),
        "leg_splay_deg": _uniform(rng, 0.0, 8.0),
        "neck_length": _uniform(rng, 0.05, 0.4),
        "neck_angle_deg": _uniform(rng, 20.0, 75.0),
        "neck_radius": torso_height * _uniform(rng, 0.18, 0.3),
        "head_radius": _uniform(rng, 0.06, 0.11),
        "snout_length": _uniform(rng, 0.0, 0.12),
        "tail_length": _uniform(rng, 0.1, 0.45),
        "tail_angle_deg": _uniform(rng, -60.0, 30.0),
        "tail_radius": _uniform(rng, 0.012, 0.03),
    }
    a = _finish_attributes("animal", sampled, overrides, {})
    tl, th, tw = a["torso_length"], a["torso_height"], a["torso_width"]
    center = np.array([0.0, a["leg_length"] + th / 2, 0.0])
    radii = np.array([tl / 2, th / 2, tw / 2])
    parts: dict[str, list] = {"torso": [_ellipsoid(center, radii, 48)]}

    # Legs: tapered, from inside the lower torso to the floor.
    y_top = center[1] - 0.2 * th
    corners = _corner_positions(0.3 * tl, 0.35 * tw / 2 + 0.5 * a["leg_radius"])
    for name, (x, z) in corners.items():
        out = a["leg_length"] * math.tan(math.radians(a["leg_splay_deg"]))
        top = (x, y_top, z)
        bottom = (x, 0.0, z + math.copysign(out, z))
        parts[name] = [_rod(bottom, top, 0.7 * a["leg_radius"], a["leg_radius"], 20)]

    # Neck and head: the neck leaves the front-top of the torso; the head caps its end.
    angle = math.radians(a["neck_angle_deg"])
    direction = np.array([math.cos(angle), math.sin(angle), 0.0])
    base = center + np.array([0.35 * tl, 0.15 * th, 0.0])
    exit_point = _ray_exit(base, direction, center, radii)
    hr, nr = a["head_radius"], a["neck_radius"]
    head_center = exit_point + direction * (a["neck_length"] + hr)
    neck_end = exit_point + direction * (a["neck_length"] + 0.5 * hr)
    parts["neck"] = [_rod(base, neck_end, nr, min(0.75 * nr, 0.8 * hr), 20)]
    head = [manifold3d.Manifold.sphere(hr, 32).translate(tuple(head_center))]
    if a["snout_length"] > 1e-3:
        sl = a["snout_length"]
        snout_center = head_center + np.array([0.6 * hr + sl / 2, -0.3 * hr, 0.0])
        head.append(_ellipsoid(snout_center, (sl / 2 + 0.3 * hr, 0.5 * hr, 0.5 * hr), 24))
    parts["head"] = head

    # Tail: a thin tapered rod from inside the rump, backwards and up or down.
    tangle = math.radians(a["tail_angle_deg"])
    tdir = np.array([-math.cos(tangle), math.sin(tangle), 0.0])
    tbase = center + np.array([-0.4 * tl, 0.15 * th, 0.0])
    texit = _ray_exit(tbase, tdir, center, radii)
    tip = texit + tdir * a["tail_length"]
    parts["tail"] = [_rod(tbase, tip, a["tail_radius"], 0.4 * a["tail_radius"], 12)]
    return _assemble("animal", parts, a, seed)


_GENERATORS = {"chair": chair, "table": table, "airplane": airplane, "animal": animal}


def _check_category(category: str):
    if category not in _GENERATORS:
        raise ValueError(f"unknown category {category!r}; expected one of {CATEGORIES}")
    return _GENERATORS[category]


def _derived_seed(seed: int, index: int) -> int:
    """The seed of shape ``index`` of a collection seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1, dtype=np.uint32)[0])


def generate(category: str, count: int, seed: int = 0, *, rates: dict | None = None) -> list[LabelledShape]:
    """``count`` shapes of ``category``; shape ``i`` comes from a seed derived from (seed, i).

    The shape's own ``seed`` field holds that derived seed, so ``chair(shapes[i].seed)``
    regenerates shape ``i`` alone (with ``rates``, pass its drawn values too:
    ``chair(s.seed, has_arms=s.attributes["has_arms"])``).

    Parameters
    ----------
    rates : dict of str to float, optional
        The fraction of shapes that have a yes/no attribute, replacing the generator's own rate:
        ``{"has_arms": 0.5}`` gives a collection in which about half the chairs have arms (the
        generator's default is about 30%). Each shape draws these from its own stream, seeded by
        ``(seed, i)`` and separate from the one its other attributes come from, so a shape keeps
        every other attribute whatever the rates.
    """
    make = _check_category(category)
    if count < 0:
        raise ValueError(f"`count` must be non-negative, got {count}")
    if seed < 0:
        raise ValueError(f"`seed` must be non-negative, got {seed}")
    rates = dict(rates or {})
    if rates:
        defaults = make(0).attributes
        for key, rate in rates.items():
            if not isinstance(defaults.get(key), bool):
                yes_no = sorted(k for k, v in defaults.items() if isinstance(v, bool))
                raise ValueError(f"`rates` takes yes/no attributes of {category} ({', '.join(yes_no)}), got {key!r}")
            if not 0.0 <= float(rate) <= 1.0:
                raise ValueError(f"rate of {key!r} must lie in [0, 1], got {rate!r}")
    shapes = []
    for i in range(count):
        overrides = {}
        if rates:
            draws = np.random.default_rng([seed, i, _RATES_STREAM]).random(len(rates))
            overrides = {key: bool(u < float(rate)) for (key, rate), u in zip(sorted(rates.items()), draws)}
        shapes.append(make(_derived_seed(seed, i), **overrides))
    return shapes


_RATES_STREAM = 0x72617465  # tells the ``rates`` draws' seed apart from the shapes' own


# ---------------------------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------------------------


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` through :func:`primkit.io.atomic_output` (existence was checked by the caller)."""
    with atomic_output(path, overwrite=True) as tmp:
        Path(tmp).write_bytes(data)


def write_collection(
    folder, category: str, count: int, seed: int = 0, *, rates: dict | None = None, overwrite: bool = False
) -> list[Path]:
    """Generate ``count`` shapes and write them to ``folder``; returns the mesh paths.

    For shape ``i`` three files are written: ``<category>_<i:04d>.ply`` (the mesh, binary PLY,
    vertex and face order as generated), ``<category>_<i:04d>.seg`` (one part index per line,
    in face order) and ``<category>_<i:04d>.json`` (``category``, ``part_names``,
    ``part_groups``, ``attributes``, ``seed``). ``rates`` is :func:`generate`'s. Existing files are refused with
    :class:`FileExistsError` (before anything is written) unless ``overwrite`` is set. Every
    file is written atomically.
    """
    _check_category(category)
    folder = Path(folder)
    stems = [folder / f"{category}_{i:04d}" for i in range(count)]
    if not overwrite:
        for stem in stems:
            for suffix in (".ply", ".seg", ".json"):
                path = stem.with_suffix(suffix)
                if path.exists():
                    raise FileExistsError(
                        f"{path} already exists; pass overwrite=True to replace it"
                    )
    shapes = generate(category, count, seed, rates=rates)  # bad rates fail before anything is written
    folder.mkdir(parents=True, exist_ok=True)
    mesh_paths = []
    for stem, shape in zip(stems, shapes):
        mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
        _write_atomic(stem.with_suffix(".ply"), mesh.export(file_type="ply"))
        labels = "".join(f"{label}\n" for label in shape.face_labels.tolist())
        _write_atomic(stem.with_suffix(".seg"), labels.encode("ascii"))
        meta = {
            "category": shape.category,
            "part_names": list(shape.part_names),
            "part_groups": shape.part_groups,
            "attributes": shape.attributes,
            "seed": shape.seed,
        }
        text = json.dumps(meta, indent=2) + "\n"
        _write_atomic(stem.with_suffix(".json"), text.encode("utf-8"))
        mesh_paths.append(stem.with_suffix(".ply"))
    return mesh_paths


def read_collection_labels(mesh_path) -> tuple[np.ndarray, dict]:
    """Read the ``.seg`` and ``.json`` written by :func:`write_collection` beside ``mesh_path``.

    Returns
    -------
    face_labels : (f,) int64
      Part index per face, in the mesh's face order.
    meta : dict
      ``category``, ``part_names`` (a tuple), ``part_groups``, ``attributes``, ``seed``.
    """
    mesh_path = Path(mesh_path)
    text = mesh_path.with_suffix(".seg").read_text(encoding="ascii")
    labels = np.array([int(line) for line in text.split()], dtype=np.int64)
    meta = json.loads(mesh_path.with_suffix(".json").read_text(encoding="utf-8"))
    meta["part_names"] = tuple(meta["part_names"])
    return labels, meta

"""The four procedural categories: chairs, tables, airplanes and four-legged animals, each a
function of a seed and attribute overrides (see :mod:`primkit.synthetic`)."""

from __future__ import annotations

import math

import manifold3d
import numpy as np

from .labelled import LabelledShape, assemble
from .solids import airfoil, affine, checked, disk, ellipsoid, hull, ray_exit, rod, rot_y, rot_z, rounded_box, rounded_slab, tapered_square, union

__all__ = ["chair", "stool", "table", "airplane", "animal", "GENERATORS"]


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
            solid = rod(bottom, top, radius, radius)
        elif style == "tapered":
            solid = rod(bottom, top, 0.6 * radius, radius)
        else:  # "square"
            solid = tapered_square(bottom, top, 0.6 * radius, radius)
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
        parts["seat"] = [disk((0.0, seat_bottom + t / 2, 0.0), d / 2, w / 2, t)]
    else:
        parts["seat"] = [rounded_box((d, t, w), edge).translate((0.0, seat_bottom + t / 2, 0.0))]

    # Back: a rounded slab hinged at the rear of the seat top, tilted towards -X.
    bt, tilt = a["back_thickness"], a["back_tilt_deg"]
    overlap = 0.5 * t
    back_width = 0.9 * w if a["swivel"] else w
    pivot = np.array([-d / 2 + bt / 2, seat_top, 0.0])
    slab = rounded_box((bt, a["back_height"] + overlap, back_width), min(0.45 * bt, 0.02))
    offset = np.array([0.0, (a["back_height"] + overlap) / 2 - overlap, 0.0])
    rot = rot_z(tilt)
    parts["back"] = [slab.transform(affine(rot, pivot + rot @ offset))]

    if a["swivel"]:
        cr = a["column_radius"]
        hub_r = max(1.8 * cr, 0.045)
        parts["column"] = [rod((0.0, 0.06, 0.0), (0.0, seat_bottom + t / 2, 0.0), cr, 0.8 * cr)]
        star = [rod((0.0, 0.035, 0.0), (0.0, 0.10, 0.0), hub_r, hub_r, 24)]
        reach = a["base_radius"]
        spoke = hull(
            [
                *([0.0, y, z] for y in (0.04, 0.09) for z in (-0.025, 0.025)),
                *([reach, y, z] for y in (0.02, 0.045) for z in (-0.016, 0.016)),
            ]
        )
        caster = rod((reach - 0.015, 0.0, 0.0), (reach - 0.015, 0.03, 0.0), 0.016, 0.016, 16)
        arm_of_star = union([spoke, caster])
        for k in range(5):
            star.append(arm_of_star.transform(affine(rot_y(72.0 * k), (0.0, 0.0, 0.0))))
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
            rest = rounded_box((x_front - x_rear, 0.035, aw), 0.012)
            rest = rest.translate(((x_front + x_rear) / 2, y_rest, side * z_arm))
            z = side * z_arm
            post = rod((x_post, seat_top - t / 2, z), (x_post, y_rest, z), min(0.4 * aw, 0.02))
            parts[name] = [rest, post]

    return assemble("chair", parts, a, seed)


_STOOL_CHOICES = {"base": ("legs4", "legs3", "column"), "seat_shape": ("round", "square"),
                  "leg_style": ("round", "tapered", "square")}


def stool(seed: int | None = None, **overrides) -> LabelledShape:
    """A stool: a seat on three or four legs or on a column with a round foot, and no back.

    Labelled with the chair's part names (:data:`PART_NAMES` ``["chair"]``: ``seat``, the legs,
    ``column``, ``star_base`` for the foot; never ``back`` nor arms), so that a chair model's part
    indices can be checked on it. Attributes (override any by keyword): ``base`` ("legs4",
    "legs3", "column"), ``seat_shape`` ("round", "square"), ``seat_width`` (diameter or side),
    ``seat_thickness``, ``leg_length`` (floor to seat underside: 0.40-0.75, low to bar stools),
    ``leg_radius``, ``leg_style``, ``leg_splay_deg``, ``column_radius``, ``foot_radius``. Derived
    and recorded: ``seat_height``.
    """
    rng = np.random.default_rng(seed)
    sampled = {
        "base": _pick(rng, _STOOL_CHOICES["base"], p=[0.45, 0.3, 0.25]),
        "seat_shape": _pick(rng, _STOOL_CHOICES["seat_shape"]),
        "seat_width": _uniform(rng, 0.32, 0.46),
        "seat_thickness": _uniform(rng, 0.04, 0.08),
        "leg_length": _uniform(rng, 0.40, 0.75),
        "leg_radius": _uniform(rng, 0.018, 0.032),
        "leg_style": _pick(rng, _STOOL_CHOICES["leg_style"]),
        "leg_splay_deg": _uniform(rng, 0.0, 10.0),
        "column_radius": _uniform(rng, 0.025, 0.04),
        "foot_radius": _uniform(rng, 0.16, 0.24),
    }
    a = _finish_attributes("stool", sampled, overrides, _STOOL_CHOICES)
    w, t = a["seat_width"], a["seat_thickness"]
    seat_bottom = a["leg_length"]
    a["seat_height"] = seat_bottom + t
    parts: dict[str, list] = {}
    edge = min(0.4 * t, 0.03)
    if a["seat_shape"] == "round":
        parts["seat"] = [disk((0.0, seat_bottom + t / 2, 0.0), w / 2, w / 2, t)]
    else:
        parts["seat"] = [rounded_box((w, t, w), edge).translate((0.0, seat_bottom + t / 2, 0.0))]
    if a["base"] == "column":
        cr = a["column_radius"]
        parts["column"] = [rod((0.0, 0.03, 0.0), (0.0, seat_bottom + t / 2, 0.0), cr, cr)]
        parts["star_base"] = [disk((0.0, 0.015, 0.0), a["foot_radius"], a["foot_radius"], 0.03)]
    elif a["base"] == "legs4":
        inset = a["leg_radius"] + 0.6 * edge + 0.005
        half = w / 2 - inset if a["seat_shape"] == "square" else (w / 2 - inset) / math.sqrt(2.0)
        parts.update(_legs_at(_corner_positions(half, half), seat_bottom + t / 2, seat_bottom, a))
    else:  # three legs at 120 degrees, splayed outwards along their own direction
        r_top = w / 2 - a["leg_radius"] - 0.01
        out = seat_bottom * math.tan(math.radians(a["leg_splay_deg"]))
        radius = a["leg_radius"]
        for name, angle in (("leg_front_left", 60.0), ("leg_front_right", -60.0), ("leg_back_left", 180.0)):
            u = np.array([math.cos(math.radians(angle)), 0.0, math.sin(math.radians(angle))])
            top = r_top * u + np.array([0.0, seat_bottom + t / 2, 0.0])
            bottom = (r_top + out) * u
            if a["leg_style"] == "round":
                parts[name] = [rod(bottom, top, radius, radius)]
            elif a["leg_style"] == "tapered":
                parts[name] = [rod(bottom, top, 0.6 * radius, radius)]
            else:
                parts[name] = [tapered_square(bottom, top, 0.6 * radius, radius)]
    return assemble("chair", parts, a, seed)


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
        parts["top"] = [disk(top_center, length / 2, width / 2, t, 128)]
    else:
        bevel = 0.6 * t
        parts["top"] = [rounded_slab(length, width, t, a["corner_radius"], bevel, top_center)]

    if a["pedestal"]:
        foot_r = min(a["foot_radius"], 0.45 * min(length, width))
        foot_r = max(foot_r, 1.5 * a["pedestal_radius"])
        fh = a["foot_height"]
        parts["foot"] = [rod((0.0, 0.0, 0.0), (0.0, fh, 0.0), foot_r, 0.55 * foot_r, 48)]
        pr = a["pedestal_radius"]
        column = rod((0.0, fh / 2, 0.0), (0.0, h - t / 2, 0.0), 1.15 * pr, 0.85 * pr, 32)
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
    return assemble("table", parts, a, seed)


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
    nose = ellipsoid((0.5 - 1.6 * r, 0.0, 0.0), (1.6 * r, r, r), 48)
    body = manifold3d.Manifold.sphere(r, 48).translate((-0.15, 0.0, 0.0))
    cone = manifold3d.Manifold.sphere(tail_r, 32).translate((-0.5 + tail_r, tail_y, 0.0))
    parts["fuselage"] = [checked(manifold3d.Manifold.batch_hull([nose, body, cone]), "the fuselage")]

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
        root = airfoil(le_root, c_root, tr * c_root, y_root, 0.0)
        tip = airfoil(le_tip, c_tip, tr * c_tip, y_tip, side * half_span)
        parts[name] = [hull(np.vstack([root, tip]))]

    # Horizontal tail halves and the fin, rooted on the fuselage axis near the tail.
    ct = a["tail_root_chord"]
    x_tail = -0.5 + 0.6 * ct + 0.05
    tail_half = a["tail_span"] / 2
    tail_le = x_tail + ct / 2
    ty = axis_y(x_tail)
    tail_tip_le = tail_le - tail_half * math.tan(math.radians(a["tail_sweep_deg"]))
    for name, side in (("tail_left", -1.0), ("tail_right", 1.0)):
        root = airfoil(tail_le, ct, 0.1 * ct, ty, 0.0)
        tip = airfoil(tail_tip_le, 0.5 * ct, 0.05 * ct, ty, side * tail_half)
        parts[name] = [hull(np.vstack([root, tip]))]
    cf = a["fin_root_chord"]
    x_fin = -0.5 + 0.6 * cf + 0.05
    fin_le = x_fin + cf / 2
    fy = axis_y(x_fin)
    fin_tip_le = fin_le - a["fin_height"] * math.tan(math.radians(a["fin_sweep_deg"]))
    root = airfoil(fin_le, cf, 0.12 * cf, 0.0, fy, vertical=True)
    fin_top = fy + tail_r + a["fin_height"]
    tip = airfoil(fin_tip_le, 0.55 * cf, 0.06 * cf, 0.0, fin_top, vertical=True)
    parts["fin"] = [hull(np.vstack([root, tip]))]

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
            pylon = hull([[x, y, z + dz] for x in (x0, x1) for y in (yc, y_mid) for dz in dzs])
            parts[f"engine_{side_name}_{which}"] = [rod(back, front, 0.75 * re, re, 32), pylon]
    return assemble("airplane", parts, a, seed)


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
    parts: dict[str, list] = {"torso": [ellipsoid(center, radii, 48)]}

    # Legs: tapered, from inside the lower torso to the floor.
    y_top = center[1] - 0.2 * th
    corners = _corner_positions(0.3 * tl, 0.35 * tw / 2 + 0.5 * a["leg_radius"])
    for name, (x, z) in corners.items():
        out = a["leg_length"] * math.tan(math.radians(a["leg_splay_deg"]))
        top = (x, y_top, z)
        bottom = (x, 0.0, z + math.copysign(out, z))
        parts[name] = [rod(bottom, top, 0.7 * a["leg_radius"], a["leg_radius"], 20)]

    # Neck and head: the neck leaves the front-top of the torso; the head caps its end.
    angle = math.radians(a["neck_angle_deg"])
    direction = np.array([math.cos(angle), math.sin(angle), 0.0])
    base = center + np.array([0.35 * tl, 0.15 * th, 0.0])
    exit_point = ray_exit(base, direction, center, radii)
    hr, nr = a["head_radius"], a["neck_radius"]
    head_center = exit_point + direction * (a["neck_length"] + hr)
    neck_end = exit_point + direction * (a["neck_length"] + 0.5 * hr)
    parts["neck"] = [rod(base, neck_end, nr, min(0.75 * nr, 0.8 * hr), 20)]
    head = [manifold3d.Manifold.sphere(hr, 32).translate(tuple(head_center))]
    if a["snout_length"] > 1e-3:
        sl = a["snout_length"]
        snout_center = head_center + np.array([0.6 * hr + sl / 2, -0.3 * hr, 0.0])
        head.append(ellipsoid(snout_center, (sl / 2 + 0.3 * hr, 0.5 * hr, 0.5 * hr), 24))
    parts["head"] = head

    # Tail: a thin tapered rod from inside the rump, backwards and up or down.
    tangle = math.radians(a["tail_angle_deg"])
    tdir = np.array([-math.cos(tangle), math.sin(tangle), 0.0])
    tbase = center + np.array([-0.4 * tl, 0.15 * th, 0.0])
    texit = ray_exit(tbase, tdir, center, radii)
    tip = texit + tdir * a["tail_length"]
    parts["tail"] = [rod(tbase, tip, a["tail_radius"], 0.4 * a["tail_radius"], 12)]
    return assemble("animal", parts, a, seed)


GENERATORS = {"chair": chair, "table": table, "airplane": airplane, "animal": animal,
              "stool": stool}  # stools are chairs without a back: labelled with the chair's part names

"""Closed solids for the procedural shapes (manifold3d): rods, ellipsoids, disks, rounded boxes
and slabs, tapered legs, airfoil sections, convex hulls and unions. Every function returns a
closed ``manifold3d.Manifold``; rotations are (3, 3) float acting on column vectors."""

from __future__ import annotations

import functools
import math

import manifold3d
import numpy as np

__all__ = ["affine", "rot_z", "rot_y", "frame_along", "checked", "hull", "rod", "ellipsoid", "disk", "rounded_box",
           "rounded_slab", "tapered_square", "airfoil", "ray_exit", "union"]


def affine(rotation: np.ndarray, translation) -> np.ndarray:
    """(3, 4) affine matrix [R | t] acting on column vectors, as Manifold.transform wants."""
    return np.hstack([np.asarray(rotation, float), np.asarray(translation, float).reshape(3, 1)])


def rot_z(degrees: float) -> np.ndarray:
    """Rotation about +Z; a positive angle turns +Y towards -X (a chair back tilting back)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(degrees: float) -> np.ndarray:
    """Rotation about +Y; a positive angle turns +X towards -Z."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def frame_along(direction) -> np.ndarray:
    """A rotation whose third column is the unit vector along ``direction`` (det +1)."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    return np.column_stack([e1, e2, d])


def checked(solid: manifold3d.Manifold, what: str) -> manifold3d.Manifold:
    if solid.is_empty() or solid.status() != manifold3d.Error.NoError:
        raise RuntimeError(f"building {what} gave an empty or invalid solid")
    return solid


def hull(points) -> manifold3d.Manifold:
    """Convex hull of (k, 3) points."""
    return checked(manifold3d.Manifold.hull_points(np.asarray(points, float)), "a convex hull")


def rod(p0, p1, r0: float, r1: float | None = None, segments: int = 32) -> manifold3d.Manifold:
    """Cylinder (or cone frustum) from ``p0`` (radius ``r0``) to ``p1`` (radius ``r1``)."""
    p0 = np.asarray(p0, float)
    axis = np.asarray(p1, float) - p0
    r1 = r0 if r1 is None else r1
    solid = manifold3d.Manifold.cylinder(float(np.linalg.norm(axis)), r0, r1, segments)
    return checked(solid.transform(affine(frame_along(axis), p0)), "a rod")


def ellipsoid(center, radii, segments: int = 32) -> manifold3d.Manifold:
    solid = manifold3d.Manifold.sphere(1.0, segments).scale(tuple(float(r) for r in radii))
    return checked(solid.translate(tuple(float(c) for c in center)), "an ellipsoid")


def disk(center, rx: float, rz: float, thickness: float, segments: int = 64):
    """Elliptic slab with a vertical axis: radii ``rx`` along X and ``rz`` along Z."""
    solid = manifold3d.Manifold.cylinder(1.0, 1.0, 1.0, segments, True)
    # local z (the axis) -> world Y, local y -> world -Z: a proper rotation times a scale.
    m = np.array([[rx, 0.0, 0.0], [0.0, 0.0, thickness], [0.0, -rz, 0.0]])
    return checked(solid.transform(affine(m, center)), "a disk")


@functools.cache
def _unit_sphere_points() -> np.ndarray:
    """(k, 3) points on the unit sphere, used to round the corners of hulls."""
    mesh = manifold3d.Manifold.sphere(1.0, 20).to_mesh64()
    return np.asarray(mesh.vert_properties, float)[:, :3]


def rounded_box(size, radius: float) -> manifold3d.Manifold:
    """Box of full extents ``size`` centred at the origin, every edge rounded by ``radius``."""
    half = np.asarray(size, float) / 2.0
    radius = float(min(radius, 0.999 * half.min()))
    inner = half - radius
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    points = (corners * inner)[:, None, :] + radius * _unit_sphere_points()[None, :, :]
    return hull(points.reshape(-1, 3))


def rounded_slab(
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
    return hull(np.vstack(points) + np.asarray(center, float))


def tapered_square(p_bottom, p_top, half_bottom: float, half_top: float) -> manifold3d.Manifold:
    """Square-section leg: hull of horizontal squares around the bottom and top points."""
    square = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float)
    bottom = np.asarray(p_bottom, float) + half_bottom * square
    return hull(np.vstack([bottom, np.asarray(p_top, float) + half_top * square]))


def airfoil(
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


def ray_exit(point, direction, center, radii) -> np.ndarray:
    """Where the ray from ``point`` (inside the ellipsoid) along ``direction`` leaves it."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    p = (np.asarray(point, float) - center) / radii
    q = d / radii
    a, b, c = q @ q, 2.0 * (p @ q), p @ p - 1.0
    t = (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return np.asarray(point, float) + t * d


def union(solids) -> manifold3d.Manifold:
    solids = list(solids)
    if len(solids) == 1:
        return solids[0]
    return manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)

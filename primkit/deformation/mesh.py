"""One call per task: bind a mesh, move its cuboids (:func:`deform` onto a target, :func:`edit` by
part edits), repair folds and measure the result (:class:`Deformed`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import sample_surface
from ..metrics import chamfer_distance
from ..primitives import Cuboids, assign_points
from .binding import DEFAULT_FALLOFF, Binding, as_vertices, bind, signed_distances
from .edits import Edit, Lengthening, edit_cuboids
from .transfer import MIN_HALF_EXTENT, Transfer, transfer_transforms
from .folds import edge_distortion, face_normals, flipped_fraction, unfold

__all__ = ["SEAM_GAIN", "DeformationQuality", "Deformed", "deform", "edit", "seam_falloff"]


@dataclass(frozen=True)
class DeformationQuality:
    """What :meth:`Deformed.quality` measures.

    Attributes
    ----------
    flipped : float
        Fraction of triangles whose normal turned against its normal before (plain test).
    flipped_vs_parts : float
        The same against the normal carried by the parts' own transforms (:func:`flipped_fraction`).
    distortion : dict part slot or "all" -> EdgeStats
        :func:`edge_distortion` relative to each part's own map (how far blending bent the parts).
    stretch : dict part slot or "all" -> EdgeStats
        Plain edge-length change inside parts.
    chamfer_result_target, chamfer_source_target : float or None
        Chamfer-L1 to the target points of the result and of the source (None when not asked).
    """

    flipped: float
    flipped_vs_parts: float
    distortion: dict
    stretch: dict
    chamfer_result_target: float | None = None
    chamfer_source_target: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready, the Chamfer entries only when measured: ``{"flipped", "flipped_vs_parts",
        "distortion": {slot: {"edges", "median", "p99", "max"}}, "stretch": {...}[, "chamfer_*"]}``."""
        out = {"flipped": self.flipped, "flipped_vs_parts": self.flipped_vs_parts,
               "distortion": {k: v.to_dict() for k, v in self.distortion.items()},
               "stretch": {k: v.to_dict() for k, v in self.stretch.items()}}
        for key in ("chamfer_result_target", "chamfer_source_target"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        return out


#: blending distance per unit of seam discrepancy (see :func:`seam_falloff`)
SEAM_GAIN = 3.0


@dataclass(frozen=True, eq=False)
class Deformed:
    """A deformed mesh and how it came about.

    Attributes
    ----------
    vertices : (n, 3) float
        The deformed vertices (same order as the input; faces unchanged).
    binding : Binding
    transforms : (m, 4, 4) float
        The per-part maps that were applied.
    transfer : Transfer or None
        Set by :func:`deform`.
    edit : Edit or None
        Set by :func:`edit`.
    resolved : (n,) bool or None
        Vertices :func:`unfold` re-solved (None when it did not run: no faces, or ``unfold=False``).
    linear : (n, 3, 3) float or None
        The blended linear map at each vertex when it is not ``binding.blended(transforms)``
        (parts lengthened below a cut plane: their map is piecewise).
    """

    vertices: np.ndarray
    binding: Binding
    transforms: np.ndarray
    transfer: Transfer | None = None
    edit: Edit | None = None
    resolved: np.ndarray | None = None
    linear: np.ndarray | None = None

    def quality(self, faces, *, target_points=None, source_points=None, samples: int = 10000,
                seed: int = 0) -> DeformationQuality:
        """Quality measures of the deformation (:class:`DeformationQuality`).

        * ``flipped``: fraction of triangles whose normal turned against its normal before
          (plain test); ``flipped_vs_parts``: against the normal carried by the parts'
          own transforms (see :func:`flipped_fraction`).
        * ``distortion``: :func:`edge_distortion` relative to each part's own map (how far
          blending bent the parts); ``stretch``: plain edge-length change inside parts.
        * with ``target_points`` ((k, 3) float, in the vertices' frame): ``chamfer_result_target``
          (Chamfer-L1 of :func:`primkit.metrics.chamfer_distance` between ``samples`` area-uniform
          points of the result and the target points), and with ``source_points`` also
          ``chamfer_source_target``.
        """
        f = np.asarray(faces, dtype=np.int64)
        b = self.binding
        lin = self.transforms[:, :3, :3]
        out = {
            "flipped": flipped_fraction(b.vertices, self.vertices, f),
            "flipped_vs_parts": flipped_fraction(b.vertices, self.vertices, f,
                                                 b.blended(self.transforms) if self.linear is None else self.linear),
            "distortion": edge_distortion(b.vertices, self.vertices, f, b.labels, lin),
            "stretch": edge_distortion(b.vertices, self.vertices, f, b.labels),
        }
        if target_points is not None:
            pts = sample_surface(self.vertices, f, samples, seed=seed).points
            out["chamfer_result_target"] = chamfer_distance(pts, target_points)
            if source_points is not None:
                out["chamfer_source_target"] = chamfer_distance(source_points, target_points)
        return DeformationQuality(**out)


def _finish(binding: Binding, transforms, faces, do_unfold: bool, stretch: Lengthening | None = None,
            **extra) -> Deformed:
    if stretch is None:
        out, linear, own = binding.apply(transforms), binding.blended(transforms), None
    else:  # lengthened parts follow their piecewise stretch instead of their affine row
        affine = np.array(transforms, dtype=float)
        affine[list(stretch.factors)] = np.eye(4)
        out, linear = binding.apply(affine), binding.blended(affine)
        cols = {int(k): i for i, k in enumerate(binding.parts)}
        for k in stretch.factors:
            w = binding.weights[:, cols[k]]
            sel = np.flatnonzero(w)
            out[sel] += w[sel, None] * stretch.displacement(binding.vertices[sel], k)
            linear[sel] += w[sel, None, None] * (stretch.linear(binding.vertices[sel], k) - np.eye(3))
        own = linear
    resolved = None
    if faces is not None and do_unfold:
        out, resolved = unfold(binding.vertices, out, faces, linear)
    return Deformed(out, binding, transforms, resolved=resolved, linear=own, **extra)


def deform(vertices, source: Cuboids, target: Cuboids, *, falloff: float | None = None, faces=None,
           method: str = "distance", min_extent: float = MIN_HALF_EXTENT, unfold: bool = False) -> Deformed:
    """Move a mesh bound to ``source`` so its parts take the configuration of ``target``.

    vertices : (n, 3) float, in the frame of both cuboid sets (use the canonical frames of two
    :class:`~primkit.model.abstractor.AbstractionResult`: the shapes are then normalised alike). See
    :func:`bind` and :func:`transfer_transforms`. With ``faces`` (and ``unfold``, the default),
    flipped triangles are re-solved by :func:`unfold`; without faces the result is the plain
    blend :meth:`Binding.apply`.
    """
    transfer = transfer_transforms(source, target, min_extent=min_extent)
    if falloff is None:
        falloff = seam_falloff(vertices, source, transfer.transforms)
    binding = bind(vertices, source, falloff=falloff, faces=faces, method=method)
    return _finish(binding, transfer.transforms, faces, unfold, transfer=transfer)


def seam_falloff(vertices, cuboids: Cuboids, transforms, *, base: float | None = None, gain: float | None = None,
                 quantile: float = 95.0, limit: float = 0.25) -> float:
    """A blending distance wide enough for the given transforms.

    Where two parts meet, their maps send a seam vertex to points ``delta`` apart; blending them
    over a distance ``w`` adds a shear of about ``delta / w`` to the deformation gradient, which
    folds triangles (flips them) once it passes 1. So the falloff is ``gain`` (default :data:`SEAM_GAIN`) times the
    ``quantile`` of ``delta`` over the seam vertices (those within ``base`` of two parts), at least
    ``base`` (default :data:`DEFAULT_FALLOFF` of the bounding box) and at most ``limit`` of it.
    """
    v = as_vertices(vertices)
    gain = SEAM_GAIN if gain is None else float(gain)
    size = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    base = DEFAULT_FALLOFF * size if base is None else float(base)
    parts = cuboids.present
    if len(parts) < 2 or len(v) == 0:
        return base
    sd = signed_distances(v, cuboids)
    order = np.argsort(sd, axis=1)[:, :2]
    first, second = order[:, 0], order[:, 1]
    rows = np.arange(len(v))
    seam = sd[rows, second] - sd[rows, first] < base
    if not seam.any():
        return base
    t = np.asarray(transforms, float)[parts]
    x = v[seam]
    d1 = np.einsum("nij,nj->ni", t[first[seam], :3, :3], x) + t[first[seam], :3, 3]
    d2 = np.einsum("nij,nj->ni", t[second[seam], :3, :3], x) + t[second[seam], :3, 3]
    delta = np.percentile(np.linalg.norm(d1 - d2, axis=1), quantile)
    return float(np.clip(gain * delta, base, limit * size))


def edit(vertices, cuboids: Cuboids, *, scale=None, rotate=None, move=None, lengthen=None,
         falloff: float | None = None, faces=None, method: str = "distance", unfold: bool = False,
         **kwargs) -> Deformed:
    """Edit parts of a mesh bound to ``cuboids`` (see :func:`edit_cuboids` for the edits and
    their frames; ``kwargs`` go there). An empty edit gives the vertices back to round-off. The
    default falloff is :func:`seam_falloff` of the edit's transforms; ``faces`` and ``unfold``
    as in :func:`deform`.

    ``lengthen={slot: factor}`` lengthens parts below a cut plane (:class:`Lengthening`): the
    vertices bound to a lengthened part follow its piecewise stretch (blended with the
    neighbours' maps at seams like any part), the floor defaults to the lowest vertex bound to a
    lengthened part, and the chair's height grows by ``(factor - 1) (cut - floor)``: "legs=1.3"
    makes the legs' length below the seat 30% longer and lifts everything above by that much.
    """
    v = as_vertices(vertices)
    e = edit_cuboids(cuboids, scale=scale, rotate=rotate, move=move, lengthen=lengthen, **kwargs)
    if e.lengthening is not None and len(v):
        e = _lengthen_on_mesh(v, faces, cuboids, e, scale=scale, rotate=rotate, move=move, lengthen=lengthen, **kwargs)
    if falloff is None:
        falloff = seam_falloff(v, cuboids, _seam_transforms(v, cuboids, e))
    offsets = None
    if e.lengthening is not None:  # seams blend on the legs' side: what they hold up stays rigid
        offsets = np.where(np.isin(cuboids.present, list(e.lengthening.factors)), falloff, 0.0)
    binding = bind(v, cuboids, falloff=falloff, faces=faces, method=method, offsets=offsets)
    return _finish(binding, e.transforms, faces, unfold, e.lengthening, edit=e)


def _lengthen_on_mesh(v, faces, cuboids: Cuboids, e: Edit, **edits) -> Edit:
    """Redo a lengthening edit with the floor and cut plane measured on the mesh: the floor at
    the lowest vertex bound to a lengthened part, the cut at the support's underside, the
    area-weighted median height of the support's downward-facing triangles (normal within 45
    degrees of down). The network's cuboids are loose: on the 10 COSEG chairs the seat cuboid's
    bottom is 0.01-0.1 (canonical units) off the ground-truth seat underside, the mesh's 0-0.03."""
    L = e.lengthening
    up = L.up
    labels = assign_points(v, cuboids)
    kwargs = {k: val for k, val in edits.items() if k not in ("floor", "cut")}
    floor, cut = edits.get("floor"), edits.get("cut")
    mine = np.isin(labels, list(L.factors))
    if floor is None and mine.any():
        floor = float((v[mine] @ up).min())
    if cut is None and faces is not None and L.support is not None:
        f = np.asarray(faces, dtype=np.int64)
        n = face_normals(v, f)
        area = np.linalg.norm(n, axis=1)
        down = (n @ up) < -np.sqrt(0.5) * area
        sel = down & (labels[f] == L.support).all(axis=1) & (area > 0)
        if sel.any():
            h = v[f[sel]].mean(axis=1) @ up
            o = np.argsort(h)
            cum = np.cumsum(area[sel][o])
            cut = float(h[o][np.searchsorted(cum, 0.5 * cum[-1])])
    if floor is None and cut is None:
        return e
    if cut is None:
        cut = L.cut
    if not cut > (floor if floor is not None else L.floor):
        return e  # the mesh disagrees with the cuboids; keep the cuboids' planes
    return edit_cuboids(cuboids, floor=floor, cut=cut, **kwargs)


def _seam_transforms(vertices, cuboids: Cuboids, e: Edit) -> np.ndarray:
    """The edit's transforms with each lengthened part's row replaced by the translation by its
    rise (its map above the cut, where it meets what it holds up), for :func:`seam_falloff`."""
    t = e.transforms
    if e.lengthening is None:
        return t
    t = t.copy()
    for k in e.lengthening.factors:
        t[k] = np.eye(4)
        t[k, :3, 3] = e.lengthening.rise(k) * e.lengthening.up
    return t

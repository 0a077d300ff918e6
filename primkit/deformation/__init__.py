"""Deformation transfer and part editing: the cuboids as a skeleton for the real mesh.

The paper's third application. A mesh is *bound* to its abstraction; moving, turning or
stretching the cuboids then moves the mesh. Two ways to move the cuboids:

* :func:`transfer_transforms` pairs a source's cuboids with a target's **by index** (one network
  explains a whole category, so slot ``k`` is the same part on both) and maps each source cuboid
  onto its target cuboid (``primkit deform``);
* :func:`edit_cuboids` scales, turns or moves named parts in their own frames and carries the
  parts resting on them along (``primkit edit``).

Binding
-------
Each vertex ``x`` is bound to the nearest present cuboid (the co-segmentation rule of
:func:`primkit.primitives.assign_points`: nearest solid, ties to the larger) and, for every part
``k``, has local coordinates scaled by the half-extents, ``u_k = R_k^T (x - t_k) / z_k``. Moving
cuboid ``k`` to ``(z'_k, R'_k, t'_k)`` sends the vertex to ``R'_k (z'_k * u_k) + t'_k``: an affine
map ``A_k x + b_k`` with ``A_k = R'_k diag(z'_k / z_k) R_k^T``, so stretching a cuboid stretches
its part. The deformed vertex is the blend ``x + sum_k w_k(x) ((A_k - I) x + b_k)`` (written as a
displacement so that identity transforms give the source back to round-off).

Why distance-based blending weights (and not a libigl solve)
------------------------------------------------------------
With hard assignment a triangle whose corners are bound to different parts is torn apart at the
seam. The weights here come from the *signed* distance ``d_k(x)`` to each present solid cuboid
(negative inside, so a vertex deep in the seat is not shared with a leg whose cuboid merely
overlaps it): with the margin ``a_k = (d_k - min_j d_j) / falloff``, ``w_k ∝ 1 - smoothstep(a_k)``.
``min_j d_j`` is continuous, so the weights and the deformation are continuous in space: vertices
of a seam (and coincident vertices of separate components) move together, and only vertices within
``falloff`` of a second part are blended, so parts away from seams move exactly with their cuboids.

Alternatives measured on the 90 ordered COSEG chair pairs (bundled chair model; scripts in the
issue's scratch): harmonic weights on the mesh (the COSEG chairs are closed single-component
meshes) with part-interior vertices as handles did worse than the distance weights: uniform
graph Laplacian, 97.8% of pairs closer but mean flipped fraction 4.6%; inverse-edge-length
Laplacian, 0.12% mean and 17% of pairs over 0.1%, or 0.47% with a 0.05 band (distance weights:
0.28% mean, 21% of pairs over 0.1%). Smoother weights alone do not remove the folds, because a
fold comes from the *translation* mismatch of two parts' maps squeezed into the blending band.
``method="harmonic"`` (``igl.harmonic``) is kept for comparison.

Unfolding (``unfold=True``, used by ``primkit deform`` and ``primkit edit``)
---------------------------------------------------------------------------
So the blend stays the distance blend, and :func:`unfold` repairs it where it folded: the
vertices within ``r`` edges of flipped triangles are re-solved so that every edge follows the
blended *linear* maps (a Poisson / gradient-domain solve, ``sum w_e |x_i - x_j - G_e (v_i -
v_j)|^2`` with the rest held), which drops the fold-making translation term and spreads the
mismatch over the region; ``r`` doubles from 1 up to 16 until nothing is flipped. Vertices away
from folds keep the blend exactly (rigid parts stay rigid; an identity edit is untouched). On
the 90 pairs: closer to the target 84/90 (93%; the blend alone 89/90), Chamfer-L1 median 0.0186
(quartiles 0.0158, 0.0399; source 0.0502), every pair under 0.1% flipped (mean 0.003%, worst
0.093%; the blend alone 21% of pairs over, mean 0.28%, worst 2.2%). Four rounds (up to 8 edges)
left 3% of pairs over 0.1%. Edge weights 1 / rest length: uniform weights ruin the coarse,
irregular COSEG meshes (74% closer, flips left). Harmonic displacement instead of the gradient
solve (it does not reproduce affine maps) flattened the deformation (82% closer). The pairs not
closer are five of chair 23 (a swivel chair whose base the model explains with a near-degenerate
cuboid) and 19->15 (already close). ``deform`` and ``edit`` default to ``unfold=False`` so that
the result is the plain blend :meth:`Binding.apply` that :mod:`primkit.viewers.deformation_viewer` shows.

Thin cuboids: the network often predicts a thin part (a leg) a few thousandths thick, fitting it
loosely. A ratio of half-extents with such a denominator blows the part up, and transferring the
thickness of parts thinner than the grid resolves is noise that folds the seams, so ratios use
half-extents floored at ``min_extent`` (default 1/32 of the canonical cube: one cell of the 32^3
grid the network reads). On the 90 COSEG chair pairs the floor 1/64 left 29% of pairs with 0.1%
or more flipped triangles, 1/32 left 21% (for a Chamfer median 0.0189 instead of 0.0187).

Blending width: where two parts meet, their maps disagree by some distance; blending over less
than that folds the surface. :func:`deform` therefore widens the falloff to :data:`SEAM_GAIN`
times the seam discrepancy (:func:`seam_falloff`); on the COSEG pairs a fixed falloff of 0.03
left 72% of pairs with 0.1% or more flipped triangles (0.1: 46%), the adaptive one 21%.

Conventions: all functions work in whatever frame the vertices and cuboids share; the editing
directions (up, front, side) default to the canonical frame of :mod:`primkit` (+Y up, +X front,
side = front x up = +Z), where :class:`~primkit.model.abstractor.AbstractionResult`'s
``canonical`` cuboids live. Transforms are ``(m, 4, 4)`` homogeneous matrices acting on column
vectors, one per part slot (identity for absent parts).

Modules: :mod:`~primkit.deformation.binding`, :mod:`~primkit.deformation.transfer`,
:mod:`~primkit.deformation.edits`, :mod:`~primkit.deformation.folds` (flipped triangles: measured and
repaired) and :mod:`~primkit.deformation.mesh` (the one-call :func:`deform` and :func:`edit`).
``primkit.deformation`` imports :mod:`primkit.primitives`, :mod:`primkit.geometry` and
:mod:`primkit.metrics`; nothing of the model.
"""

from .binding import DEFAULT_FALLOFF, Binding, apply_transforms, bind, blend_weights, signed_distances
from .edits import Edit, Lengthening, edit_cuboids
from .mesh import SEAM_GAIN, DeformationQuality, Deformed, deform, edit, seam_falloff
from .transfer import MAX_RATIO, MIN_HALF_EXTENT, Transfer, cuboid_map, transfer_transforms
from .folds import UNFOLD_ROUNDS, EdgeStats, edge_distortion, flipped_fraction, unfold

__all__ = [
    "Binding",
    "bind",
    "blend_weights",
    "signed_distances",
    "cuboid_map",
    "Transfer",
    "transfer_transforms",
    "Edit",
    "Lengthening",
    "edit_cuboids",
    "apply_transforms",
    "Deformed",
    "deform",
    "edit",
    "flipped_fraction",
    "edge_distortion",
    "EdgeStats",
    "DeformationQuality",
    "DEFAULT_FALLOFF",
    "MIN_HALF_EXTENT",
    "MAX_RATIO",
    "SEAM_GAIN",
    "seam_falloff",
    "unfold",
    "UNFOLD_ROUNDS",
]

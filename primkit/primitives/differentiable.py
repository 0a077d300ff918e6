"""The torch twins of the cuboid math, for training: batch first (``B``), differentiable, on the
device and dtype of their inputs. torch is imported inside each function (it is heavy), so that
importing :mod:`primkit.primitives` stays cheap."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .sampling import face_area_pairs, surface_layout

if TYPE_CHECKING:  # pragma: no cover
    import torch

__all__ = ["quaternion_to_matrix_torch", "world_to_local_torch", "cuboid_distance_sq_torch", "sample_cuboid_surfaces_torch",
           "surface_coefficients_torch", "surface_samples_from_coefficients_torch"]


def quaternion_to_matrix_torch(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices from quaternions ``(w, x, y, z)``; ``q`` is normalised here.

    q : (..., 4)  ->  (..., 3, 3), acting on column vectors; differentiable.
    """
    import torch

    if q.shape[-1:] != (4,):
        raise ValueError("`q` must be (..., 4)")
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def _check_points_and_poses(points, quaternions, translations) -> None:
    """Shapes of the torch functions' batched inputs: (B, n, 3), (B, m, 4), (B, m, 3)."""
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError("`points` must be (B, n, 3)")
    if quaternions.ndim != 3 or quaternions.shape[-1] != 4:
        raise ValueError("`quaternions` must be (B, m, 4)")
    if translations.shape != quaternions.shape[:2] + (3,):
        raise ValueError("`translations` must be (B, m, 3), matching `quaternions`")


def world_to_local_torch(
    points: torch.Tensor, quaternions: torch.Tensor, translations: torch.Tensor
) -> torch.Tensor:
    """Points in every cuboid's local frame, ``R.T @ (x - t)``.

    points (B, n, 3), quaternions (B, m, 4), translations (B, m, 3)  ->  (B, m, n, 3)
    """
    import torch

    _check_points_and_poses(points, quaternions, translations)
    rot = quaternion_to_matrix_torch(quaternions)  # (B, m, 3, 3)
    d = points[:, None, :, :] - translations[:, :, None, :]
    return torch.einsum("bmji,bmnj->bmni", rot, d)


def cuboid_distance_sq_torch(
    points: torch.Tensor,
    half_extents: torch.Tensor,
    quaternions: torch.Tensor,
    translations: torch.Tensor,
    *,
    parts_first: bool = False,
) -> torch.Tensor:
    """Squared distance from each point to each solid cuboid (0 inside).

    points (B, n, 3), half_extents (B, m, 3), quaternions (B, m, 4), translations (B, m, 3)
    ->  (B, n, m), or (B, m, n) with ``parts_first``. No square root, so the gradient is finite
    everywhere (and continuous: the kink of ``max(., 0)`` is squared away and ``|x|`` only kinks
    at 0, inside the cuboid).

    Computed coordinate-planar, as ``(B, m, 3, n)`` local coordinates ``R^T x - R^T t`` from one
    batched matrix product of ``(B, 3m, 3)`` by ``(B, 3, n)`` (broadcasting the points over the
    parts instead copies them ``m`` times): the per-point sums then run over a middle axis with
    ``n`` contiguous values, which vectorises (a trailing axis of length 3, as in
    :func:`world_to_local_torch`'s layout, made this 4x slower on CPU). Without gradients the
    element-wise steps run in place (``benchmarks/bench_abstractor.py``: 3.5 ms instead of 13 ms
    for 32 shapes, 20 parts, 1,000 points on one CPU thread).
    """
    import torch

    if half_extents.shape != translations.shape:
        raise ValueError("`half_extents` must be (B, m, 3), matching `translations`")
    _check_points_and_poses(points, quaternions, translations)
    b, m = half_extents.shape[:2]
    rot_t = quaternion_to_matrix_torch(quaternions).transpose(-1, -2)  # (B, m, 3, 3), R^T
    offset = (rot_t @ translations[..., None]).reshape(b, 3 * m, 1)  # R^T t
    local = torch.baddbmm(offset, rot_t.reshape(b, 3 * m, 3), points.transpose(1, 2), beta=-1.0)
    local = local.view(b, m, 3, -1)  # (B, m, 3, n)
    if torch.is_grad_enabled() and any(x.requires_grad for x in (points, half_extents, quaternions, translations)):
        excess = (local.abs() - half_extents[..., None]).clamp_min(0.0)
        d2 = excess.square().sum(dim=2)
    else:
        d2 = local.abs_().sub_(half_extents[..., None]).clamp_min_(0.0).square_().sum(dim=2)
    return d2 if parts_first else d2.transpose(1, 2)


def surface_samples_from_coefficients_torch(
    half_extents: torch.Tensor, quaternions: torch.Tensor, translations: torch.Tensor, uv: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Surface points (B, m, k, 3) and weights (B, m, k) of :func:`sample_cuboid_surfaces_torch` from given
    face coefficients ``uv`` (B, m, k, 2) in [-1, 1] (:func:`surface_coefficients_torch`)."""
    import torch

    k = uv.shape[2]
    face, fixed, spread = surface_layout(k)
    opts = {"dtype": half_extents.dtype, "device": half_extents.device}
    fixed_t = torch.as_tensor(fixed, **opts)
    spread_t = torch.as_tensor(spread, **opts)
    u, v = uv.to(**opts).unbind(-1)  # (B, m, k) each
    # Element-wise products and sums, not einsum: a (k, 2, 3) or (3, 3) contraction per cuboid
    # became a batched matrix product of tiny matrices, slower on CPU than these few passes over
    # (B, m, k) rows (bench_abstractor.py). The one-hot `spread` makes `unit` the same values.
    unit = fixed_t + u[..., None] * spread_t[:, 0] + v[..., None] * spread_t[:, 1]  # (B, m, k, 3)
    lx, ly, lz = (unit * half_extents[:, :, None, :]).unbind(-1)
    rot = quaternion_to_matrix_torch(quaternions)  # (B, m, 3, 3)
    r = rot[..., None].unbind(-3)  # r[i]: (B, m, 3, 1), row i of R
    t = translations[..., None].unbind(-2)  # (B, m, 1) each
    points = torch.stack([r[i][:, :, 0] * lx + r[i][:, :, 1] * ly + r[i][:, :, 2] * lz + t[i] for i in range(3)], dim=-1)
    pairs = face_area_pairs()
    areas = 4.0 * half_extents[..., pairs[:, 0]] * half_extents[..., pairs[:, 1]]  # (B, m, 3)
    # faces come k / 6 samples at a time in the order 0..5, so axis face // 2 covers k / 3 samples
    # each, in order: an expansion, whose backward is a sum (indexing's backward is a scatter)
    b, m = areas.shape[:2]
    weights = areas[..., None].expand(b, m, 3, k // 3).reshape(b, m, k) / (k // 6)
    return points, weights


def sample_cuboid_surfaces_torch(
    half_extents: torch.Tensor,
    quaternions: torch.Tensor,
    translations: torch.Tensor,
    samples_per_cuboid: int = 150,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reparametrised surface samples, differentiable in ``z``, ``q`` and ``t``.

    Parameters
    ----------
    half_extents : (B, m, 3)
    quaternions : (B, m, 4)
    translations : (B, m, 3)
    samples_per_cuboid : int
        ``k``, a positive multiple of 6; ``k / 6`` samples per face, in the face order of the
        module notes (as :func:`sample_cuboid_surfaces`).
    generator : torch.Generator, optional
        Source of the coefficients ``u``; they are drawn on the generator's device and moved.

    Returns
    -------
    points : (B, m, k, 3)
        World coordinates.
    weights : (B, m, k)
        ``area(face) / (k / 6)``, differentiable in ``z``; they sum to each surface area.
    """
    uv = surface_coefficients_torch(half_extents, quaternions, translations, samples_per_cuboid, generator)
    return surface_samples_from_coefficients_torch(half_extents, quaternions, translations, uv)


def surface_coefficients_torch(
    half_extents: torch.Tensor,
    quaternions: torch.Tensor,
    translations: torch.Tensor,
    samples_per_cuboid: int = 150,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """The random face coefficients :func:`sample_cuboid_surfaces_torch` places its samples by: (B, m, k, 2)
    uniform in [-1, 1], drawn on the generator's device (from the same stream, so that a caller
    forming the samples its own way gets the same points), on ``half_extents``' device and dtype."""
    import torch

    k = int(samples_per_cuboid)
    surface_layout(k)  # validates k
    if half_extents.ndim != 3 or half_extents.shape[-1] != 3:
        raise ValueError("`half_extents` must be (B, m, 3)")
    if quaternions.shape != half_extents.shape[:2] + (4,):
        raise ValueError("`quaternions` must be (B, m, 4), matching `half_extents`")
    if translations.shape != half_extents.shape:
        raise ValueError("`translations` must be (B, m, 3), matching `half_extents`")
    B, m = half_extents.shape[:2]
    device = half_extents.device if generator is None else generator.device
    uv = torch.rand((B, m, k, 2), generator=generator, device=device, dtype=half_extents.dtype)
    return (2.0 * uv - 1.0).to(half_extents.device)

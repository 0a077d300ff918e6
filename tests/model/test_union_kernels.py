"""The compiled coverage distances (distance to the union of present cuboids, presence effects)
against the torch form they replace on the CPU."""

import pytest
import torch

from primkit.model import losses
from primkit.model._compiled import kernels

from primkit.model import _union_kernels  # noqa: E402,F401 - Numba is a dependency: a kernel that fails to load fails here


def _case(dtype, m=20, seed=0):
    g = torch.Generator().manual_seed(seed)
    b, n = 4, 500
    points = (torch.rand(b, n, 3, generator=g) - 0.5).to(dtype)
    z = (0.03 + 0.2 * torch.rand(b, m, 3, generator=g)).to(dtype)
    q = torch.randn(b, m, 4, generator=g).to(dtype)
    t = (0.6 * torch.rand(b, m, 3, generator=g) - 0.3).to(dtype)
    present = (torch.rand(b, m, generator=g) < 0.6).to(dtype)
    present[1] = 0.0  # a shape with no part present: every point to its nearest absent part
    present[2] = 1.0
    return points, z, q, t, present


def _run(fn, points, z, q, t, present, weights):
    leaves = [x.clone().requires_grad_(True) for x in (z, q, t)]
    union, deltas = fn(points, *leaves, present, toggles=True)
    (union * weights).sum().backward()
    return [union.detach(), deltas] + [x.grad for x in leaves]


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
@pytest.mark.parametrize("m", [20, 1])
def test_compiled_union_equals_the_torch_form(dtype, tol, m):
    """Distances, presence effects and the gradients with respect to extents, quaternions and
    translations, under uneven weights of the points; a shape with no part present; one part."""
    points, z, q, t, present = _case(dtype, m)
    weights = torch.linspace(0.2, 2.0, points.shape[1], dtype=dtype)
    assert kernels("_union_kernels", points, z, q, t, present, data=(points,))  # the compiled path applies
    compiled = _run(losses._union_distance_sq, points, z, q, t, present, weights)
    reference = _run(losses._union_distance_sq_torch, points, z, q, t, present, weights)
    for name, a, b in zip(("distances", "effects", "extents", "quaternions", "translations"), compiled, reference):
        err = ((a - b).abs().max() / b.abs().max().clamp_min(1e-30)).item()
        assert err < tol, f"{name}: {err:.1e}"


def test_points_with_a_gradient_take_the_torch_form():
    """The symmetry term's mirrored samples carry a gradient: the torch form serves them."""
    points, z, q, t, present = _case(torch.float32)
    assert not kernels("_union_kernels", points.requires_grad_(True), z, q, t, present, data=(points,))
    union = losses._union_distance_sq(points, z, q, t, present)
    union.sum().backward()
    assert points.grad is not None and torch.isfinite(points.grad).all()


def test_the_compiled_kernels_serve_every_cpu_float_call():
    """``kernels`` falls back to the torch forms only for what the kernels do not take (other
    dtypes, CUDA): on the CPU with float32 or float64 it returns the compiled module, so a kernel
    module that fails to load fails this test instead of training silently on the slower path."""
    x = torch.zeros(2, 3)
    for name in ("_union_kernels", "_field_kernels"):
        for dtype in (torch.float32, torch.float64):
            module = kernels(name, x.to(dtype))
            assert module is not None and module.__name__ == f"primkit.model.{name}", (name, dtype)
    assert kernels("_union_kernels", x.half()) is None
    assert kernels("_union_kernels", x, data=(x.clone().requires_grad_(),)) is None

"""The compiled winner search of the distance-field lookup against the torch search it replaces on the CPU."""

import numpy as np
import pytest
import torch

from primkit import geometry, synthetic
from primkit.model import distance_field

from primkit.model import _field_kernels as kernel  # Numba is a dependency: a kernel that fails to load fails here


@pytest.fixture(scope="module")
def grids():
    out = []
    for s in synthetic.generate("chair", 3, seed=2):
        v = geometry.canonical_frame(s.vertices).to_canonical(s.vertices)
        out.append(geometry.distance_grid(v, s.faces, 16).closest)
    return np.stack(out)  # (3, 16, 16, 16, 3) float32


def _planar(closest):
    b, r = closest.shape[0], closest.shape[1]
    return closest.reshape(b, r ** 3, 3).transpose(1, 2).contiguous()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_same_cells_as_the_torch_search(grids, dtype):
    """Points inside, outside and on the grid's cells, NaN and infinite ones, a NaN stored in a
    grid (it poisons the running minimum, as torch.minimum does), and ties (every cell of the third
    grid holds the same point, so all 8 corners tie and the first must win)."""
    closest = torch.as_tensor(grids, dtype=dtype).clone()
    closest[2] = torch.tensor([0.1, -0.2, 0.05], dtype=dtype)
    closest[0, 8, 8, 8] = float("nan")
    rng = np.random.default_rng(0)
    pts = torch.as_tensor(rng.uniform(-0.8, 0.8, (3, 4000, 3)), dtype=dtype)
    pts[0, 1000:1100] = torch.as_tensor(rng.uniform(0.0, 0.1, (100, 3)), dtype=dtype)  # around cell (8, 8, 8)
    pts[:, :500] = torch.as_tensor(geometry.grid_centres(16).reshape(-1, 3)[rng.choice(4096, 500)], dtype=dtype)
    pts[0, 600] = float("nan")
    pts[0, 601, 1] = float("nan")
    pts[1, 602] = float("inf")
    pts[1, 603, 2] = -float("inf")
    planar = _planar(closest)
    ref = distance_field._winners(planar, pts, 16)
    cells, got = kernel.nearest_cells(planar.numpy(), pts.transpose(1, 2).contiguous().numpy(), 16)
    np.testing.assert_array_equal(got, ref.numpy())  # NaN where NaN, every other value bit for bit
    # the cells hold the points returned, and ties went to the first corner (x, y, z lowest)
    flat = planar.numpy()
    np.testing.assert_array_equal(np.take_along_axis(flat, np.broadcast_to(cells[:, None, :], got.shape), 2), got)
    base = np.clip(np.floor((pts[2].numpy() + 0.5) * 16 - 0.5), 0, 15).astype(int)
    finite = np.isfinite(pts[2].numpy()).all(1)
    assert np.array_equal(cells[2][finite], (base[:, 0] * 256 + base[:, 1] * 16 + base[:, 2])[finite])


def test_lookup_values_and_gradients_equal_the_torch_search(grids, monkeypatch):
    """lookup_distance_sq_torch through the compiled search against the same function with the compiled
    search turned off: the same values and gradients, bit for bit."""
    closest = torch.as_tensor(grids)
    pts = torch.as_tensor(np.random.default_rng(2).uniform(-0.7, 0.7, (3, 3000, 3)), dtype=torch.float32)

    def run():
        p = pts.clone().requires_grad_(True)
        d = distance_field.lookup_distance_sq_torch(closest, p)
        d.sum().backward()
        return d.detach(), p.grad

    d1, g1 = run()
    monkeypatch.setattr(distance_field, "_winners_compiled", lambda *a: None)
    d2, g2 = run()
    assert torch.equal(d1, d2) and torch.equal(g1, g2)


def _cuboids(dtype, seed=3):
    """20 random cuboids for each of 3 shapes, some of them degenerate (a zero extent: no area on
    two faces; all zero: no area at all, the mean's denominator clamped)."""
    g = torch.Generator().manual_seed(seed)
    z = (0.02 + 0.2 * torch.rand(3, 20, 3, generator=g)).to(dtype)
    z[0, 3, 1] = 0.0
    z[1, 4] = 0.0
    q = torch.randn(3, 20, 4, generator=g).to(dtype)
    t = (0.6 * torch.rand(3, 20, 3, generator=g) - 0.3).to(dtype)
    return z, q, t


@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-12), (torch.float32, 2e-5)])
def test_compiled_consistency_equals_the_torch_form_and_its_gradient(grids, dtype, tol):
    """surface_consistency (compiled on the CPU) against the torch form, sample_cuboid_surfaces_torch +
    consistency_per_part under autograd, from the same random coefficients: values and gradients
    with respect to extents, quaternions and translations, under an uneven weighting of the parts."""
    from primkit.model import losses

    closest = torch.as_tensor(grids, dtype=dtype)
    scale = torch.linspace(0.5, 1.5, 20, dtype=dtype)

    def run(compiled: bool):
        leaves = [x.clone().requires_grad_(True) for x in _cuboids(dtype)]
        generator = torch.Generator().manual_seed(9)
        if compiled:
            out = losses.surface_consistency(closest, *leaves, 150, generator)
            assert type(out.grad_fn).__name__ == "_SurfaceConsistencyBackward"  # the compiled path was taken
        else:
            out = losses.consistency_per_part(closest, *losses.sample_cuboid_surfaces_torch(*leaves, 150, generator=generator))
        (out * scale).sum().backward()
        return [out.detach()] + [x.grad for x in leaves]

    for name, a, b in zip(("values", "extents", "quaternions", "translations"), run(True), run(False)):
        assert torch.isfinite(a).all(), name
        err = ((a - b).abs().max() / b.abs().max()).item()
        assert err < tol, f"{name}: {err:.1e}"


def test_the_compiled_path_draws_the_same_random_stream(grids):
    """surface_consistency draws its coefficients as sample_cuboid_surfaces_torch does: the generator ends
    in the same state either way."""
    from primkit.model import losses

    z, q, t = _cuboids(torch.float32)
    g1, g2 = torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
    losses.surface_consistency(torch.as_tensor(grids), z, q, t, 150, g1)
    losses.sample_cuboid_surfaces_torch(z, q, t, 150, generator=g2)
    assert torch.equal(torch.rand(4, generator=g1), torch.rand(4, generator=g2))

"""The local-expectation existence gradient: each part's presence effect against recomputing the
losses with that part switched, and the surrogate's gradient against the exact derivative of the
expected cost (which REINFORCE estimates with far more variance)."""

import itertools

import pytest
import torch

from primkit.model import losses
from primkit.model.network import PrimitivePrediction


def _batch(seed=0, b=3, m=5, n=300, r=8):
    g = torch.Generator().manual_seed(seed)
    z = 0.02 + 0.2 * torch.rand(b, m, 3, generator=g, dtype=torch.float64)
    q = torch.nn.functional.normalize(torch.randn(b, m, 4, generator=g, dtype=torch.float64), dim=-1)
    t = torch.rand(b, m, 3, generator=g, dtype=torch.float64) - 0.5
    points = torch.rand(b, n, 3, generator=g, dtype=torch.float64) - 0.5
    closest = torch.rand(b, r, r, r, 3, generator=g, dtype=torch.float64) - 0.5
    present = (torch.rand(b, m, generator=g) < 0.6).double()
    present[0] = 0.0
    present[0, 2] = 1.0  # shape 0 has one present part: removing it leaves nothing
    return PrimitivePrediction(z, q, t, torch.rand(b, m, dtype=torch.float64)), present, points, closest


def _total(pred, present, points, closest, weights):
    return losses.shape_losses(pred, present, points, closest, weights, 42,
                               generator=torch.Generator().manual_seed(7)).total


@pytest.mark.parametrize("weights", [losses.LossWeights(), losses.LossWeights(coverage=2.0, consistency=0.5)])
def test_presence_effect_is_the_loss_with_the_part_minus_without_it(weights):
    pred, present, points, closest = _batch()
    out = losses.shape_losses(pred, present, points, closest, weights, 42, generator=torch.Generator().manual_seed(7),
                              presence_effects=True)
    assert torch.allclose(out.total, _total(pred, present, points, closest, weights))
    for j in range(present.shape[1]):
        on, off = present.clone(), present.clone()
        on[:, j], off[:, j] = 1.0, 0.0
        expected = _total(pred, on, points, closest, weights) - _total(pred, off, points, closest, weights)
        others = (off.sum(1) > 0)  # with no other part present the empty union is only a large stand-in
        assert torch.allclose(out.presence_effect[others, j], expected[others], rtol=1e-9, atol=1e-12)
        assert torch.all(out.presence_effect[~others, j] < -10)  # the last part is always worth keeping


def test_local_surrogate_gradient_is_the_exact_derivative_of_the_expected_cost():
    # two parts with fixed costs per configuration: E[cost] is a polynomial in p1, p2
    cost = {(0, 0): 3.0, (1, 0): 1.0, (0, 1): 2.0, (1, 1): 0.5}
    parsimony = 0.1
    logits = torch.tensor([[0.4, -0.3]], dtype=torch.float64, requires_grad=True)
    p = torch.sigmoid(logits)[0].detach()

    def expected(p):
        return sum(c * (p[0] if a else 1 - p[0]) * (p[1] if b else 1 - p[1]) - parsimony * (2 - a - b)
                   * (p[0] if a else 1 - p[0]) * (p[1] if b else 1 - p[1]) for (a, b), c in cost.items())

    exact = torch.autograd.grad(expected(torch.sigmoid(logits)[0]), logits)[0]
    # average the surrogate's gradient over the other part's choice, exactly (weights p_other)
    grad = torch.zeros_like(logits)
    for z in itertools.product((0, 1), repeat=2):
        weight = float((p[0] if z[0] else 1 - p[0]) * (p[1] if z[1] else 1 - p[1]))
        effect = torch.tensor([[cost[(1, z[1])] - cost[(0, z[1])], cost[(z[0], 1)] - cost[(z[0], 0)]]],
                              dtype=torch.float64)
        g, = torch.autograd.grad(losses.local_existence_surrogate(logits, effect, parsimony), logits)
        grad += weight * g
    assert torch.allclose(grad, exact, atol=1e-12)
    # a part that costs more than it saves (effect + parsimony > 0) is pushed towards absent
    g, = torch.autograd.grad(losses.local_existence_surrogate(logits, torch.tensor([[0.0, -1.0]], dtype=torch.float64),
                                                              parsimony), logits)
    assert g[0, 0] > 0 > g[0, 1]

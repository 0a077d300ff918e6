"""Tests for primkit.model.network: shapes, output ranges, initialisation, head scaling, gradients."""

import math

import pytest
import torch

from primkit.model.network import INITIAL_EXISTENCE, INITIAL_HALF_EXTENT, AbstractionNet, NetworkConfig, PrimitivePrediction


def random_grids(batch, r, seed=0, fill=0.2):
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(batch, 1, r, r, r, generator=generator) < fill


def rotation_angle(q):
    """Angle (radians) of the rotations of unit quaternions q (..., 4), real part first."""
    return 2 * torch.acos(q[..., 0].abs().clamp(max=1.0))


def check_ranges(out: PrimitivePrediction, batch, m, max_half_extent=0.5):
    assert out.half_extents.shape == (batch, m, 3)
    assert out.quaternions.shape == (batch, m, 4)
    assert out.translations.shape == (batch, m, 3)
    assert out.existence.shape == (batch, m)
    assert out.existence_logits.shape == (batch, m)
    assert torch.all(out.half_extents > 0) and torch.all(out.half_extents <= max_half_extent)
    assert torch.all(out.translations.abs() <= 0.5)
    assert torch.allclose(out.quaternions.norm(dim=-1), torch.ones(batch, m), atol=1e-5)
    assert torch.all(out.existence > 0) and torch.all(out.existence < 1)
    assert torch.allclose(out.existence, torch.sigmoid(out.existence_logits))
    for t in (out.half_extents, out.quaternions, out.translations, out.existence):
        assert torch.isfinite(t).all()


@pytest.mark.parametrize(
    "config",
    [
        NetworkConfig(parts=7, grid=32),
        NetworkConfig(parts=5, grid=64),
        NetworkConfig.paper(parts=6, grid=32),
        NetworkConfig(parts=3, grid=64, encoder="paper", fc_width=16),
    ],
    ids=["released-32", "released-64", "paper-32", "paper-64"],
)
def test_shapes_and_ranges(config):
    torch.manual_seed(0)
    net = AbstractionNet(config)
    grids = random_grids(3, config.grid)
    out = net.train()(grids)
    check_ranges(out, 3, config.parts)
    with torch.no_grad():
        out = net.eval()(grids.float().squeeze(1))  # (B, R, R, R) float is accepted too
    check_ranges(out, 3, config.parts)


def test_extreme_pre_activations_stay_in_range():
    torch.manual_seed(0)
    net = AbstractionNet(NetworkConfig(parts=4)).eval()
    with torch.no_grad():
        for head in (net.half_extent_head, net.translation_head, net.quaternion_head):
            head.bias.mul_(1e3)
        net.translation_head.bias.normal_(0, 1e3)
        net.half_extent_head.bias.fill_(30.0)
        out = net(random_grids(2, 32))
    assert torch.all(out.half_extents <= 0.5) and torch.all(out.translations.abs() <= 0.5)
    assert torch.allclose(out.quaternions.norm(dim=-1), torch.ones(2, 4), atol=1e-5)


def test_encoder_depth_follows_grid():
    for grid in (16, 32, 64):
        net = AbstractionNet(NetworkConfig(grid=grid))
        convs = [m for m in net.encoder if isinstance(m, torch.nn.Conv3d)]
        assert len(convs) == int(math.log2(grid))
        assert convs[-1].out_channels == 4 * 2 ** (len(convs) - 1)


def test_initialisation_eval_mode():
    """Untrained net in eval mode: small cubes near the centre, near identity, p near 0.92."""
    torch.manual_seed(1)
    net = AbstractionNet().eval()
    with torch.no_grad():
        out = net(random_grids(4, 32, seed=3))
    assert torch.allclose(out.half_extents, torch.full_like(out.half_extents, INITIAL_HALF_EXTENT), atol=2e-3)
    assert rotation_angle(out.quaternions).max() < math.radians(5)
    assert out.translations.abs().max() < 0.05
    assert torch.allclose(out.existence, torch.full_like(out.existence, INITIAL_EXISTENCE), atol=0.01)


def test_initialisation_train_mode():
    """With batch statistics the features are O(1): parts differ a little, still near the start."""
    torch.manual_seed(2)
    net = AbstractionNet().train()
    with torch.no_grad():
        out = net(random_grids(8, 32, seed=4))
    assert out.half_extents.min() > 0.01 and out.half_extents.max() < 0.05
    assert rotation_angle(out.quaternions).max() < math.radians(15)
    assert out.translations.abs().max() < 0.4
    assert out.translations.std() > 0.01  # parts are spread, not all at the origin
    assert 0.85 < out.existence.min() and out.existence.max() < 0.97
    assert abs(out.existence.mean().item() - INITIAL_EXISTENCE) < 0.02


@pytest.mark.parametrize("encoder", ["released", "paper"])
def test_set_head_scales_preserves_function(encoder):
    torch.manual_seed(3)
    net = AbstractionNet(NetworkConfig(parts=6, encoder=encoder))
    grids = random_grids(4, 32, seed=5)
    # train a few steps of batch-norm statistics so eval-mode features are not trivial
    with torch.no_grad():
        net.train()(grids)
    net.eval()
    with torch.no_grad():
        before = net(grids)
        for shape_scale, existence_scale in [(0.01, 1e-4), (0.5, 0.2), (1.0, 1.0)]:
            net.set_head_scales(shape_scale, existence_scale)
            assert net.shape_scale == pytest.approx(shape_scale)
            assert net.existence_scale == pytest.approx(existence_scale)
            after = net(grids)
            for name in ("half_extents", "quaternions", "translations", "existence"):
                assert torch.allclose(getattr(before, name), getattr(after, name), atol=1e-5, rtol=1e-4), name


def test_head_scales_change_function_without_rescaling_and_are_saved():
    torch.manual_seed(4)
    net = AbstractionNet(NetworkConfig(parts=3)).eval()
    grids = random_grids(2, 32)
    with torch.no_grad():
        before = net(grids)
        net.set_head_scales(0.01, 1e-4, preserve_function=False)
        after = net(grids)
    # existence pre-activation shrunk 1e4 times: p -> 0.5
    assert torch.allclose(after.existence, torch.full_like(after.existence, 0.5), atol=1e-3)
    assert not torch.allclose(before.half_extents, after.half_extents)
    state = net.state_dict()
    assert "head_scales" in state
    other = AbstractionNet(NetworkConfig(parts=3))
    other.load_state_dict(state)
    assert other.shape_scale == pytest.approx(0.01) and other.existence_scale == pytest.approx(1e-4)
    with pytest.raises(ValueError):
        net.set_head_scales(0.0, 1.0)


@pytest.mark.parametrize(
    "config", [NetworkConfig(parts=4), NetworkConfig.paper(parts=4)], ids=["released", "paper"]
)
def test_gradient_reaches_every_parameter(config):
    torch.manual_seed(5)
    net = AbstractionNet(config).train()
    out = net(random_grids(4, 32))
    target = torch.randn(4, 4, 3)
    loss = (
        ((out.half_extents - 0.1) ** 2).sum()
        + ((out.translations - 0.3 * target) ** 2).sum()
        + (out.quaternions * torch.randn(4, 4, 4)).sum()
        + (out.existence * torch.randn(4, 4)).sum()
    )
    loss.backward()
    for name, param in net.named_parameters():
        assert param.grad is not None, name
        assert torch.isfinite(param.grad).all(), name
        assert param.grad.abs().max() > 0, name


def test_parameter_count():
    # released, 20 parts, 32^3: conv 108 + 864 + 3456 + 13824 + 55296, batch norm 2 * 124 (3d) + 2 * 128 (1d),
    # fc 64*64 * 2, heads (64 + 1) * 20 * (3 + 4 + 3 + 1)
    net = AbstractionNet()
    convs = 27 * (1 * 4 + 4 * 8 + 8 * 16 + 16 * 32 + 32 * 64)
    norms = 2 * (4 + 8 + 16 + 32 + 64) + 2 * (64 + 64)
    fcs = 64 * 64 * 2
    heads = 65 * 20 * 11
    assert sum(p.numel() for p in net.parameters()) == convs + norms + fcs + heads == 96544


def test_bad_inputs():
    net = AbstractionNet(NetworkConfig(parts=2))
    with pytest.raises(ValueError, match=r"\(B, 1, 32, 32, 32\)"):
        net(torch.zeros(2, 1, 16, 16, 16))
    with pytest.raises(ValueError):
        NetworkConfig(grid=48)
    with pytest.raises(ValueError):
        NetworkConfig(encoder="resnet")
    with pytest.raises(ValueError):
        NetworkConfig(parts=0)


def test_config_round_trip():
    config = NetworkConfig(parts=12, grid=64, encoder="paper", fc_width=100, max_half_extent=0.4)
    assert NetworkConfig.from_dict(config.to_dict()) == config
    assert NetworkConfig.from_dict({}) == NetworkConfig()
    with pytest.raises(ValueError, match="unknown"):
        NetworkConfig.from_dict({"parts": 3, "layers": 7})


def test_max_half_extent_respected():
    torch.manual_seed(6)
    net = AbstractionNet(NetworkConfig(parts=3, max_half_extent=0.25)).eval()
    with torch.no_grad():
        out = net(random_grids(2, 32))
        start = torch.full_like(out.half_extents, INITIAL_HALF_EXTENT)
        assert torch.allclose(out.half_extents, start, atol=2e-3)
        net.half_extent_head.bias.fill_(50.0)
        out = net(random_grids(2, 32))
    assert out.half_extents.max() <= 0.25

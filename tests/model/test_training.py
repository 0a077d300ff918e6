"""Losses against brute force and finite differences, REINFORCE, and real (small) training runs."""

import logging
import signal
import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import pytest
import torch

from primkit.model import losses, network, training
from primkit import data, geometry, primitives, synthetic


def random_cuboids(batch, m, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    z = 0.05 + 0.2 * torch.rand(batch, m, 3, generator=g, dtype=dtype)
    q = torch.nn.functional.normalize(torch.randn(batch, m, 4, generator=g, dtype=dtype), dim=-1)
    t = 0.3 * (torch.rand(batch, m, 3, generator=g, dtype=dtype) - 0.5)
    return z, q, t


def test_coverage_loss_matches_numpy_union_distance():
    z, q, t = random_cuboids(2, 5)
    present = torch.tensor([[1, 0, 1, 1, 0], [1, 1, 1, 1, 1]], dtype=torch.float64)
    pts = torch.rand(2, 300, 3, dtype=torch.float64) - 0.5
    got = losses.coverage_loss(pts, z, q, t, present)
    for b in range(2):
        cub = primitives.Cuboids(z[b].numpy(), q[b].numpy(), t[b].numpy(), present[b].numpy().astype(bool))
        ref = primitives.union_distance(pts[b].numpy(), cub, squared=True).mean()
        assert np.isclose(got[b].item(), ref, rtol=1e-10)


def test_nearest_cuboid_recomputation_is_the_plain_minimum_with_its_gradient():
    """The coverage loss finds each point's nearest cuboid without a graph and differentiates that
    cuboid only: values and gradients must equal autograd through the plain minimum over cuboids."""
    z, q, t = (x.requires_grad_() for x in random_cuboids(3, 6, seed=4))
    present = torch.tensor([[1, 1, 0, 1, 1, 1], [1] * 6, [0, 1, 1, 1, 1, 0]], dtype=torch.float64)
    pts = (torch.rand(3, 400, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(5)) - 0.5).requires_grad_()
    ours = losses.coverage_loss(pts, z, q, t, present)
    plain = (primitives.cuboid_distance_sq_torch(pts, z, q, t) + (1 - present)[:, None, :] * losses.ABSENT_PENALTY).min(-1).values.mean(1)
    assert torch.allclose(ours, plain, rtol=1e-12, atol=1e-15)
    weights = torch.tensor([1.0, 2.0, 0.5], dtype=torch.float64)
    g_ours = torch.autograd.grad((ours * weights).sum(), (pts, z, q, t))
    g_plain = torch.autograd.grad((plain * weights).sum(), (pts, z, q, t))
    for a, b in zip(g_ours, g_plain):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-14)


def test_consistency_loss_matches_weighted_brute_force(prepared_chairs):
    closest = torch.from_numpy(np.stack([p.closest for p in prepared_chairs[:2]])).double()
    z, q, t = random_cuboids(2, 4, seed=1)
    present = torch.tensor([[1, 1, 0, 1], [0, 1, 1, 1]], dtype=torch.float64)
    samples, w = primitives.sample_cuboid_surfaces_torch(z, q, t, 60, generator=torch.Generator().manual_seed(0))
    got = losses.consistency_loss(closest, samples, w, present)
    # brute force: every sample's distance by looping over the 8 neighbouring cells
    from primkit.geometry import grid_centres

    c = grid_centres(32)
    for b in range(2):
        total = 0.0
        for j in range(4):
            if not present[b, j]:
                continue
            d2 = []
            for x in samples[b, j].numpy():
                u = (x + 0.5) * 32 - 0.5
                base = np.floor(u).astype(int)
                best = np.inf
                for off in np.ndindex(2, 2, 2):
                    i = np.clip(base + off, 0, 31)
                    best = min(best, ((x - closest[b][tuple(i)].numpy()) ** 2).sum())
                d2.append(best)
            ww = w[b, j].numpy()
            total += (np.array(d2) * ww).sum() / ww.sum()
        assert np.isclose(got[b].item(), total, rtol=1e-8)
    del c


def test_loss_gradients_match_finite_differences(prepared_chairs):
    closest = torch.from_numpy(prepared_chairs[0].closest).double()[None]
    pts = torch.from_numpy(prepared_chairs[0].points[:200]).double()[None]
    z, q, t = random_cuboids(1, 3, seed=2)
    present = torch.ones(1, 3, dtype=torch.float64)

    def total(z, q, t):
        samples, w = primitives.sample_cuboid_surfaces_torch(z, q, t, 30, generator=torch.Generator().manual_seed(5))
        return (losses.coverage_loss(pts, z, q, t, present) + losses.consistency_loss(closest, samples, w, present)
                + losses.symmetry_loss(samples, w, z, q, t, present))

    args = tuple(a.clone().requires_grad_(True) for a in (z, q, t))
    # the losses are piecewise smooth (min over parts and cells): compare at this generic point
    assert torch.autograd.gradcheck(total, args, eps=1e-7, atol=1e-5, rtol=1e-3)


def test_reinforce_sign_and_parsimony():
    logits = torch.zeros(1, 2, requires_grad=True)
    present = torch.tensor([[1.0, 0.0]])
    # the shape did better than the baseline: the choices made become more likely
    losses.reinforce_surrogate(logits, present, torch.tensor([0.5]), baseline=1.0, parsimony=0.0).backward()
    assert logits.grad[0, 0] < 0 < logits.grad[0, 1]  # descent raises p for the present part, lowers it for the absent
    logits.grad = None
    losses.reinforce_surrogate(logits, present, torch.tensor([1.5]), baseline=1.0, parsimony=0.0).backward()
    assert logits.grad[0, 0] > 0 > logits.grad[0, 1]
    # at the baseline, only the parsimony reward acts, and it favours "absent"
    logits.grad = None
    losses.reinforce_surrogate(logits, torch.tensor([[0.0, 0.0]]), torch.tensor([1.0]), baseline=1.0, parsimony=1e-2).backward()
    assert (logits.grad > 0).all()


@pytest.mark.parametrize("baseline", [0.0, 0.7])
def test_reinforce_is_unbiased_for_any_baseline(baseline):
    # one Bernoulli part with p = sigmoid(l); cost 1.0 when present, 0.2 when absent
    l0 = 0.3
    p = torch.sigmoid(torch.tensor(l0))
    exact = (1.0 - 0.2) * p * (1 - p)  # d/dl E[cost]
    g = torch.Generator().manual_seed(0)
    n = 200000
    logits = torch.full((n, 1), l0, requires_grad=True)
    present = (torch.rand(n, 1, generator=g) < p).float()
    cost = torch.where(present[:, 0] > 0, 1.0, 0.2)
    losses.reinforce_surrogate(logits, present, cost, baseline=baseline, parsimony=0.0).backward()
    estimate = logits.grad.sum() * 1.0  # the surrogate averages over shapes: sum of per-sample grads / n * n
    assert abs(estimate.item() - exact.item()) < 0.01


def test_moving_baseline():
    b = losses.MovingBaseline(0.9)
    assert b.update(2.0) == 2.0
    assert np.isclose(b.update(1.0), 0.9 * 2.0 + 0.1 * 1.0)


def small_config(**kw):
    cfg = training.TrainConfig(stage1_iterations=120, stage2_iterations=60, batch_size=8, points_per_shape=500,
                               samples_per_cuboid=60, parts=8, log_every=10, checkpoint_every=10_000)
    return replace(cfg, **kw)


def test_end_to_end_training_reduces_the_loss(prepared_chairs, tmp_path):
    shapes = training.ShapeTensors(prepared_chairs)
    out = tmp_path / "m.safetensors"
    result = training.train(shapes, out, small_config(), progress=False)
    first, last = result.history[0]["total"], result.history[-1]["total"]
    assert last < 0.5 * first
    assert out.exists() and (tmp_path / "m.training.png").exists() and (tmp_path / "m.history.json").exists()
    from pictures import read_picture

    # the plot: total, coverage and consistency drawn in matplotlib's first three colours in the
    # upper panel (losses; measured 700-800 pixels each), nothing coloured in the lower one (the
    # parts in use, in black)
    plot = read_picture(tmp_path / "m.training.png")
    upper = type(plot)(plot.rgb[:300], plot.background, plot.foreground[:300])
    lower = type(plot)(plot.rgb[300:], plot.background, plot.foreground[300:])
    for colour in ((31, 119, 180), (255, 127, 14), (44, 160, 44)):
        assert upper.colour_pixels(colour) > 200 and lower.colour_pixels(colour) < 20, colour
    net, meta = network.load_network(out)
    assert meta["training"]["iterations"] == 180 and meta["network"]["parts"] == 8
    x = torch.from_numpy(prepared_chairs[0].occupancy[None].astype(np.float32))
    with torch.no_grad():
        a, b = net(x), result.network.eval()(x)
    assert torch.equal(a.translations, b.translations)
    # stage 2 sampled existence: parts in use were logged
    assert all(h["parts"] == 8 for h in result.history if h["stage"] == 1)


def test_same_seed_same_model_and_resume_after_interrupt(prepared_chairs, tmp_path, monkeypatch, caplog):
    # bit-identical for the same thread count: pinned, as the load of a shared machine would change it
    monkeypatch.setenv("PRIMKIT_THREADS", "1")
    shapes = training.ShapeTensors(prepared_chairs[:4])
    cfg = small_config(stage1_iterations=12, stage2_iterations=12, checkpoint_every=6, log_every=6)
    a = training.train(shapes, tmp_path / "a.safetensors", cfg, progress=False)
    b = training.train(shapes, tmp_path / "b.safetensors", cfg, progress=False)
    for (k, va), vb in zip(a.network.state_dict().items(), b.network.state_dict().values()):
        assert torch.equal(va, vb), k
    # interrupt in stage 2 (Ctrl-C): a checkpoint is saved; resuming gives the same model
    calls = {"n": 0}
    original = training.ShapeTensors.batch

    def flaky(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 17:
            signal.raise_signal(signal.SIGINT)  # Ctrl-C in stage 2: the iteration finishes, then it stops
        return original(self, *args, **kwargs)

    monkeypatch.setattr(training.ShapeTensors, "batch", flaky)
    with caplog.at_level(logging.WARNING, logger="primkit.model.training"):
        c = training.train(shapes, tmp_path / "c.safetensors", cfg, progress=False)
    assert c.interrupted and not (tmp_path / "c.safetensors").exists()
    ckpt = tmp_path / "c.safetensors.checkpoint.safetensors"
    assert ckpt.exists()
    # said as a log record (the CLI shows it), naming the checkpoint to resume from
    (said,) = [r for r in caplog.records if r.name == "primkit.model.training"]
    assert said.levelno == logging.WARNING and "interrupted after iteration 17" in said.getMessage()
    assert str(ckpt) in said.getMessage()
    monkeypatch.setattr(training.ShapeTensors, "batch", original)
    d = training.train(shapes, tmp_path / "c.safetensors", cfg, progress=False, resume=ckpt)
    for (k, va), vd in zip(a.network.state_dict().items(), d.network.state_dict().values()):
        assert torch.equal(va, vd), k
    assert not ckpt.exists()


@pytest.mark.integration  # two processes under torchrun
def test_two_process_ddp_on_gloo(prepared_chairs, tmp_path):
    for i, p in enumerate(prepared_chairs[:4]):
        p.save(tmp_path / f"s{i}.npz")
    script = tmp_path / "run.py"
    script.write_text(textwrap.dedent(f"""
        import hashlib, os, sys
        import torch
        from pathlib import Path
        from primkit import data
        from primkit.model import training
        shapes = training.ShapeTensors([data.PreparedShape.load(p) for p in sorted(Path({str(tmp_path)!r}).glob("s*.npz"))])
        cfg = training.TrainConfig(stage1_iterations=4, stage2_iterations=4, batch_size=4, points_per_shape=200,
                                   samples_per_cuboid=30, parts=6, log_every=2)
        res = training.train(shapes, Path({str(tmp_path)!r}) / "ddp.safetensors", cfg, progress=False)
        h = hashlib.sha256(b"".join(v.numpy().tobytes() for v in res.network.state_dict().values())).hexdigest()
        Path({str(tmp_path)!r}, "rank%s.txt" % os.environ["RANK"]).write_text(h)
    """))
    proc = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", str(script)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "ddp.safetensors").exists()
    h0, h1 = (tmp_path / "rank0.txt").read_text(), (tmp_path / "rank1.txt").read_text()
    assert h0 == h1  # DDP kept the two replicas identical
    _, meta = network.load_network(tmp_path / "ddp.safetensors")
    assert meta["training"]["processes"] == 2


def test_schedule_scaling():
    cfg = training.TrainConfig()
    assert cfg.iterations == 50000
    small = cfg.scaled_for(64)
    assert small.iterations == 2000 and small.stage1_iterations == 800
    assert cfg.scaled_for(6000).iterations == 50000


def test_training_leaves_the_global_torch_state_alone(prepared_chairs, tmp_path):
    """train() seeds and draws from torch's global generator and flushes denormals for speed; the
    caller's generator state and torch's default (no flushing) are back when it returns."""
    torch.manual_seed(1234)
    before = torch.get_rng_state()
    threads = torch.get_num_threads()
    result = training.train(training.ShapeTensors(prepared_chairs[:2]), None, small_config(stage1_iterations=2, stage2_iterations=2),
                            progress=False, threads=1)
    assert torch.equal(torch.get_rng_state(), before)
    assert torch.get_num_threads() == threads  # the thread count the caller had
    tiny = torch.tensor([1e-40], dtype=torch.float32)
    assert (tiny * 1.0).item() != 0.0  # denormals are kept again


@pytest.mark.parametrize("compact", [False, True])
def test_batches_streamed_from_the_cache_are_the_stacked_ones(tmp_path, compact):
    folder = tmp_path / "shapes"
    synthetic.write_collection(folder, "chair", 3, seed=8)
    coll = data.prepare_collection(folder, data.PrepareSettings(samples=700), cache_dir=tmp_path / "cache", workers=1,
                                   progress=False, compact=compact)
    streamed, stacked = training.ShapeTensors(coll, stack_limit=0), training.ShapeTensors(list(coll))
    decoded = training.ShapeTensors(coll)  # small: decoded once into tensors
    assert streamed.streamed and not decoded.streamed and not stacked.streamed
    assert streamed.names == stacked.names == decoded.names and len(streamed) == 3
    for name in ("occupancy", "closest", "points", "point_labels"):
        assert torch.equal(getattr(decoded, name), getattr(stacked, name)), name
    index = torch.tensor([2, 0, 2, 1])
    a = streamed.batch(index, 50, torch.Generator().manual_seed(1), "cpu")
    b = stacked.batch(index, 50, torch.Generator().manual_seed(1), "cpu")
    for x, y in zip(a, b):
        assert x.shape == y.shape and x.dtype == y.dtype and torch.equal(x, y)
    assert a[1].permute(0, 4, 1, 2, 3).is_contiguous()  # planar, as the distance lookup reads it
    config = small_config(stage1_iterations=2, stage2_iterations=2, batch_size=2, log_every=1)
    runs = [training.train(s, None, config, device="cpu", progress=False, threads=1).history
            for s in (streamed, stacked, decoded)]
    assert runs[0] == runs[1] == runs[2]


def test_torch_decoding_of_closest_points_is_numpys_bit_for_bit():
    rng = np.random.default_rng(2)
    res = 16
    codes = rng.integers(0, 256, (3, 3, res**3), dtype=np.uint8)
    near = rng.integers(0, 256, (3, res**3 // 8), dtype=np.uint8)
    want = geometry.decode_closest(codes, near, res, planar=True)
    assert torch.equal(training.decode_closest_torch(codes, near, res), torch.from_numpy(want))


def test_stack_limit_follows_the_environment_and_memory(monkeypatch):
    monkeypatch.setenv("PRIMKIT_STACK_LIMIT_MIB", "3")
    assert training.stack_limit_bytes() == 3 * 2**20
    monkeypatch.delenv("PRIMKIT_STACK_LIMIT_MIB")
    limit = training.stack_limit_bytes()
    with open("/proc/meminfo") as f:  # Linux: MemAvailable, in kB
        available = next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    assert limit >= 2**30
    assert abs(limit - max(2**30, available // 3)) <= max(available // 30, 2**26)  # memory moves between the reads

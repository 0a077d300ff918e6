"""Benchmark: training iterations per second and inference shapes per second of the abstractor.

    python benchmarks/bench_abstractor.py [--quick] [--iterations N] [--device cpu|cuda|all] [--before REV]

What it measures, all in one run:

1. One training iteration as :func:`primkit.model.training.train` runs it (batch 32, 20 parts, 1,000
   surface points per shape, 150 samples per cuboid): network forward, ``primkit.model.losses.shape_losses``,
   backward, Adam step; stage 1 (every part present) and stage 2 (existence sampled, REINFORCE
   term), for the paper's encoder (stride-2 convs, fc 100) and the released one (conv + batch norm
   + max-pool). Projected time for the paper's 20k + 30k iterations.
1c. ``primkit.model.training.train`` itself, end to end, in fresh processes: iterations per second of
   today's code and, with ``--before REV``, of primkit as it was at REV (``git archive``), runs
   alternating; and whether the losses of the first iterations are the same.
2. The straightforward alternative, in the same run and on the same batches: the same losses
   computed one cuboid at a time in a Python loop (running minimum for coverage, one consistency
   term per cuboid); checked to give the same values, then timed alone and inside a whole step.
2b. The loss terms compiled on the CPU (the consistency term's lookup, the consistency term, the coverage
    term) against their torch forms.
3. Peak memory of training (a fresh spawned process per variant; RSS, and CUDA allocations).
4. Inference with :class:`primkit.model.abstractor.Abstractor` around a randomly initialised network:
   shapes per second from prepared grids (batched, with and without pruning, against one shape at
   a time) and from mesh files (prepare + predict).

Data: procedural chairs from :mod:`primkit.synthetic` prepared with :func:`primkit.data.prepare`
(16 shapes; batches of 32 drawn with replacement), so no data set or trained model is needed.
Times are wall-clock per iteration (CUDA synchronised), reported as median and 90th percentile
after warm-up iterations. Nothing here asserts a time: it prints and exits 0.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import load_line, maxrss_kib, run_at_revision, run_fresh, run_isolated, table  # noqa: E402

BATCH = 32
PARTS = 20
POINTS = 1000
SAMPLES_PER_CUBOID = 150
STAGE1, STAGE2 = 20000, 30000  # the paper's schedule (TrainConfig defaults)


# --------------------------------------------------------------------------------------------
# small helpers: tables, statistics, fresh processes
# --------------------------------------------------------------------------------------------


def med(values) -> float:
    return float(np.median(values))


def p90(values) -> float:
    return float(np.percentile(values, 90))


def sync(device) -> None:
    import torch

    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


# --------------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------------


def prepared_chairs(count: int, seed: int = 0) -> list:
    """``count`` procedural chairs, prepared at 32^3 (PreparedShape list)."""
    from primkit import data, io, synthetic

    return [
        data.prepare(io.Mesh(s.vertices, s.faces), name=f"chair_{i:02d}")
        for i, s in enumerate(synthetic.generate("chair", count, seed=seed))
    ]


# --------------------------------------------------------------------------------------------
# losses: ours (shape_losses) and the per-cuboid loop
# --------------------------------------------------------------------------------------------


def loop_losses(prediction, present, points, closest, samples_per_cuboid: int = SAMPLES_PER_CUBOID, generator=None):
    """The loss terms of :func:`primkit.model.losses.shape_losses`, one cuboid at a time.

    Coverage keeps a running minimum over cuboids of each point's squared distance; consistency
    adds one area-weighted mean per cuboid. The surface coefficients are drawn in one call with
    the same shape as ``sample_cuboid_surfaces_torch`` draws them, so with equally seeded generators the
    two give the same numbers.
    """
    import torch

    from primkit.model.distance_field import lookup_distance_sq_torch
    from primkit.model.losses import _ABSENT, ShapeLosses
    from primkit.primitives.differentiable import surface_samples_from_coefficients_torch, cuboid_distance_sq_torch

    z, q, t = prediction.half_extents, prediction.quaternions, prediction.translations
    batch, m = present.shape
    k = samples_per_cuboid
    device = z.device if generator is None else generator.device
    uv = (2.0 * torch.rand((batch, m, k, 2), generator=generator, device=device, dtype=z.dtype) - 1.0).to(z.device)
    best = None
    consistency = torch.zeros(batch, dtype=z.dtype, device=z.device)
    for j in range(m):
        zj, qj, tj = z[:, j : j + 1], q[:, j : j + 1], t[:, j : j + 1]
        d2 = cuboid_distance_sq_torch(points, zj, qj, tj)[..., 0] + (1.0 - present[:, j, None]) * _ABSENT  # (B, n)
        best = d2 if best is None else torch.minimum(best, d2)
        samples, w = surface_samples_from_coefficients_torch(zj, qj, tj, uv[:, j : j + 1])  # (B, 1, k, 3), (B, 1, k)
        ds = lookup_distance_sq_torch(closest, samples[:, 0])  # (B, k)
        part = (ds * w[:, 0]).sum(-1) / w[:, 0].sum(-1).clamp_min(1e-12)
        consistency = consistency + part * present[:, j]
    coverage = best.mean(dim=1)
    return ShapeLosses(coverage, consistency, torch.zeros_like(coverage), coverage + consistency)


def ours_losses(prediction, present, points, closest, generator=None):
    from primkit.model.losses import shape_losses

    return shape_losses(prediction, present, points, closest, samples_per_cuboid=SAMPLES_PER_CUBOID, generator=generator)


LOSSES = {"vectorised": ours_losses, "loop": loop_losses}


# --------------------------------------------------------------------------------------------
# 1-2. training iterations
# --------------------------------------------------------------------------------------------


class Trainer:
    """One training iteration as primkit.model.training.train runs it (without logging/checkpoints)."""

    def __init__(self, shapes, encoder: str, device: str, loss: str = "vectorised", seed: int = 0,
                 existence_gradient: str = "reinforce", placement_weight: float = 0.0):
        import torch

        from primkit.model.losses import MovingBaseline, SlotPlacement
        from primkit.model.network import AbstractionNet, NetworkConfig
        from primkit.model.training import ShapeTensors, training_layout

        torch.set_flush_denormal(True)  # as training does
        torch.manual_seed(seed)
        self.device = device
        self.tensors = shapes if isinstance(shapes, ShapeTensors) else ShapeTensors(shapes)
        width = 100 if encoder == "paper" else 64
        self.net = AbstractionNet(NetworkConfig(parts=PARTS, grid=self.tensors.resolution, encoder=encoder, fc_width=width)).to(device)
        training_layout(self.net, device)  # as train()
        self.optimizer = torch.optim.Adam(self.net.parameters(), lr=1e-3, fused=torch.device(device).type in ("cpu", "cuda"))  # as train()
        self.generator = torch.Generator().manual_seed(seed)
        self.baseline = MovingBaseline(0.9)
        self.placement = SlotPlacement(0.99)
        self.local = existence_gradient == "local"
        self.placement_weight = placement_weight
        self.loss_fn = LOSSES[loss]

    def step(self, stage2: bool) -> dict:
        """One iteration; returns the seconds spent in each phase."""
        import torch

        from primkit.model.losses import local_existence_surrogate, reinforce_surrogate, shape_losses

        dev = self.device
        t0 = time.perf_counter()
        index = torch.randint(0, len(self.tensors), (BATCH,), generator=self.generator)
        occ, closest, pts = self.tensors.batch(index, POINTS, self.generator, dev)
        sync(dev)
        t1 = time.perf_counter()
        self.net.train()
        pred = self.net(occ)
        if stage2:
            u = torch.rand(pred.existence.shape, generator=self.generator).to(dev)
            present = (u < pred.existence.detach()).to(pred.existence.dtype)
        else:
            present = torch.ones_like(pred.existence)
        sync(dev)
        t2 = time.perf_counter()
        local = stage2 and self.local
        if local:  # as train() with existence_gradient="local"
            losses = shape_losses(pred, present, pts, closest, samples_per_cuboid=SAMPLES_PER_CUBOID, presence_effects=True)
        else:
            losses = self.loss_fn(pred, present, pts, closest)
        if self.placement_weight:
            place = self.placement.costs(pred.translations)
            self.placement.update(pred.translations, present)
            losses.total = losses.total + self.placement_weight * (place * present).sum(1)
            if losses.presence_effect is not None:
                losses.presence_effect = losses.presence_effect + self.placement_weight * place.detach()
        loss = losses.total.mean()
        if local:
            loss = loss + local_existence_surrogate(pred.existence_logits, losses.presence_effect, 8e-5)
            self.baseline.update(float(loss.detach()))
        elif stage2:
            mean_loss = float(loss.detach())
            b = self.baseline.value if self.baseline.value is not None else mean_loss
            loss = loss + reinforce_surrogate(pred.existence_logits, present, losses.total, b, 8e-5)
            self.baseline.update(mean_loss)
        else:
            loss = loss + 0.0 * pred.existence_logits.sum()
        sync(dev)
        t3 = time.perf_counter()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        sync(dev)
        t4 = time.perf_counter()
        self.optimizer.step()
        sync(dev)
        t5 = time.perf_counter()
        return {"batch": t1 - t0, "forward": t2 - t1, "loss": t3 - t2, "backward": t4 - t3, "adam": t5 - t4, "step": t5 - t0}


def time_steps(trainer: Trainer, stage2: bool, iterations: int, warmup: int) -> dict:
    for _ in range(warmup):
        trainer.step(stage2)
    records = [trainer.step(stage2) for _ in range(iterations)]
    return {k: [r[k] for r in records] for k in records[0]}


def check_loop_agrees(shapes, device: str) -> tuple[float, float]:
    """Largest relative difference between the loop and shape_losses (coverage, consistency)."""
    import torch

    tr = Trainer(shapes, "paper", device)
    index = torch.arange(min(BATCH, len(tr.tensors)))
    occ, closest, pts = tr.tensors.batch(index, POINTS, tr.generator, device)
    with torch.no_grad():
        pred = tr.net(occ)
    present = (torch.rand(pred.existence.shape, generator=torch.Generator().manual_seed(1)) < 0.7).to(pred.existence.dtype).to(device)
    gen_kind = torch.device(device).type
    a = ours_losses(pred, present, pts, closest, generator=torch.Generator(device=gen_kind).manual_seed(5))
    b = loop_losses(pred, present, pts, closest, generator=torch.Generator(device=gen_kind).manual_seed(5))

    def rel(x, y):
        return float(((x - y).abs() / y.abs().clamp_min(1e-12)).max())

    return rel(b.coverage, a.coverage), rel(b.consistency, a.consistency)


def time_loss_alone(shapes, device: str, loss: str, iterations: int, warmup: int) -> dict:
    """Loss forward, and forward + backward to the cuboid parameters, on one fixed batch."""
    import torch

    tr = Trainer(shapes, "paper", device)
    index = torch.randint(0, len(tr.tensors), (BATCH,), generator=tr.generator)
    occ, closest, pts = tr.tensors.batch(index, POINTS, tr.generator, device)
    with torch.no_grad():
        pred = tr.net(occ)
    leaves = [pred.half_extents, pred.quaternions, pred.translations]
    pred.half_extents, pred.quaternions, pred.translations = (x.clone().requires_grad_(True) for x in leaves)
    present = torch.ones_like(pred.existence)
    fn = LOSSES[loss]
    fwd, both = [], []
    for i in range(warmup + iterations):
        sync(device)
        t0 = time.perf_counter()
        total = fn(pred, present, pts, closest).total.mean()
        sync(device)
        t1 = time.perf_counter()
        total.backward()
        sync(device)
        t2 = time.perf_counter()
        if i >= warmup:
            fwd.append(t1 - t0)
            both.append(t2 - t0)
    return {"forward": fwd, "both": both}


def bench_training(shapes, device: str, iterations: int, warmup: int) -> None:
    ms = lambda s: f"{1000.0 * s:.1f}"  # noqa: E731
    import torch

    threads = torch.get_num_threads()
    local = {"existence_gradient": "local", "placement_weight": 0.01}
    variants = [
        ("paper encoder, shape_losses", "paper", "vectorised", threads, {}),
        ("paper encoder, local existence gradient + placement", "paper", "vectorised", threads, local),
        ("released encoder, shape_losses", "released", "vectorised", threads, {}),
        ("paper encoder, per-cuboid loop", "paper", "loop", threads, {}),
    ]
    if device == "cpu" and threads > 1:
        # on a small shared machine, OpenMP threads competing with other processes can cost more than they give
        variants.append(("paper encoder, shape_losses, 1 thread", "paper", "vectorised", 1, {}))
        variants.append(("paper encoder, local + placement, 1 thread", "paper", "vectorised", 1, local))
    rows, projections = [], []
    for label, encoder, loss, n_threads, options in variants:
        trainer = Trainer(shapes, encoder, device, loss, **options)
        per_stage = {}
        for stage2 in (False, True):
            torch.set_num_threads(n_threads)
            try:
                r = time_steps(trainer, stage2, iterations, warmup)
            finally:
                torch.set_num_threads(threads)
            per_stage[stage2] = med(r["step"])
            rows.append([
                f"{label}, stage {2 if stage2 else 1}", ms(med(r["step"])), ms(p90(r["step"])), f"{1.0 / med(r['step']):.1f}",
                ms(med(r["batch"])), ms(med(r["forward"])), ms(med(r["loss"])), ms(med(r["backward"])), ms(med(r["adam"])),
            ])
        hours = (STAGE1 * per_stage[False] + STAGE2 * per_stage[True]) / 3600.0
        projections.append([label, f"{hours * 60:.0f} min ({hours:.2f} h)", "yes" if hours < 1 else "no"])
    table(
        f"1. training iteration on {device} (batch {BATCH}, {PARTS} parts, {POINTS} points, {SAMPLES_PER_CUBOID} samples/cuboid; ms)",
        ["variant", "median", "p90", "it/s", "batch", "forward", "loss", "backward", "adam"],
        rows,
        f"{iterations} timed iterations per row after {warmup} warm-up; torch threads {threads} unless the row says otherwise;\n"
        "phase columns are medians of each phase "
        "(backward includes the loss's backward, which is where the loop alternative pays most).",
    )
    table(
        f"1b. projected time for the paper's {STAGE1:,} + {STAGE2:,} iterations on {device}",
        ["variant", "projected", "under an hour"],
        projections,
    )

    cov, cons = check_loop_agrees(shapes, device)
    rows = []
    for n_threads in [threads] + ([1] if device == "cpu" and threads > 1 else []):
        for loss in ("vectorised", "loop"):
            torch.set_num_threads(n_threads)
            try:
                r = time_loss_alone(shapes, device, loss, iterations, warmup)
            finally:
                torch.set_num_threads(threads)
            label = "primkit.model.losses.shape_losses" if loss == "vectorised" else "per-cuboid Python loop"
            if device == "cpu":
                label += f", {n_threads} thread{'s' if n_threads > 1 else ''}"
            rows.append([label, ms(med(r["forward"])), ms(p90(r["forward"])), ms(med(r["both"])), ms(p90(r["both"]))])
    table(
        f"2. losses alone on {device} (one batch of {BATCH}, all {PARTS} parts present; ms)",
        ["losses", "forward median", "forward p90", "fwd+bwd median", "fwd+bwd p90"],
        rows,
        f"agreement, same random surface coefficients: max relative difference coverage {cov:.1e}, consistency {cons:.1e}",
    )


def _alternate(ways: dict, fn, iterations: int, warmup: int, rounds: int = 3) -> tuple:
    """Times ``fn(way)`` for each way, ``rounds`` rounds alternating; (seconds per way, last result per way)."""
    times, results = {label: [] for label in ways}, {}
    for _ in range(rounds):
        for label, way in ways.items():
            for i in range(warmup + iterations):
                t0 = time.perf_counter()
                results[label] = fn(way)
                if i >= warmup:
                    times[label].append(time.perf_counter() - t0)
    return times, results


def bench_loss_terms(shapes, device: str, iterations: int, warmup: int) -> None:
    """2b. The loss terms on the training batch (32 shapes x 20 parts, 150 samples a part, 1,000
    surface points a shape), each with its gradient, compiled on the CPU against the torch form,
    in the same process, alternating, at torch's thread count and on one thread: the consistency
    term's distance-field lookup alone (the winner search), the whole consistency term
    (``losses.surface_consistency``: samples, lookup and weighted means in one pass, gradient in
    closed form) and the coverage term with the presence effects (``losses._union_distance_sq``)."""
    import torch

    from primkit.model import distance_field, losses
    from primkit.primitives import sample_cuboid_surfaces_torch

    if device != "cpu":
        return
    tr = Trainer(shapes, "paper", device)
    index = torch.randint(0, len(tr.tensors), (BATCH,), generator=tr.generator)
    occ, closest, _ = tr.tensors.batch(index, POINTS, tr.generator, device)
    with torch.no_grad():
        pred = tr.net(occ)
        samples, _ = sample_cuboid_surfaces_torch(pred.half_extents, pred.quaternions, pred.translations, SAMPLES_PER_CUBOID,
                                          generator=tr.generator)
    leaves = [x.detach() for x in (pred.half_extents, pred.quaternions, pred.translations)]
    compiled_lookup = distance_field._winners_compiled

    def lookup(way):
        distance_field._winners_compiled = way
        try:
            points = samples.reshape(BATCH, -1, 3).clone().requires_grad_(True)
            d2 = distance_field.lookup_distance_sq_torch(closest, points)
            d2.sum().backward()
            return d2.detach(), points.grad
        finally:
            distance_field._winners_compiled = compiled_lookup

    def consistency(way):
        z, q, t = (x.clone().requires_grad_(True) for x in leaves)
        generator = torch.Generator().manual_seed(0)
        if way == "compiled":
            out = losses.surface_consistency(closest, z, q, t, SAMPLES_PER_CUBOID, generator)
        else:
            out = losses.consistency_per_part(closest, *sample_cuboid_surfaces_torch(z, q, t, SAMPLES_PER_CUBOID, generator=generator))
        out.sum().backward()
        return out.detach(), z.grad, q.grad, t.grad

    present = (torch.rand(BATCH, PARTS, generator=tr.generator) < 0.7).to(torch.float32)

    def coverage(way):
        z, q, t = (x.clone().requires_grad_(True) for x in leaves)
        union, effect = way(points_batch, z, q, t, present, toggles=True)
        union.mean(1).sum().backward()
        return union.detach(), effect, z.grad, q.grad, t.grad

    _, _, points_batch = tr.tensors.batch(index, POINTS, tr.generator, device)
    threads = torch.get_num_threads()
    rows, notes = [], []
    for n_threads in [threads] + ([1] if threads > 1 else []):
        torch.set_num_threads(n_threads)
        try:
            lk, lk_out = _alternate({"compiled": compiled_lookup, "torch": lambda *a: None}, lookup, iterations, warmup)
            cs, cs_out = _alternate({"compiled": "compiled", "torch": "torch"}, consistency, iterations, warmup)
            cv, cv_out = _alternate({"compiled": losses._union_distance_sq, "torch": losses._union_distance_sq_torch},
                                    coverage, iterations, warmup)
        finally:
            torch.set_num_threads(threads)
        on = f"torch on {n_threads} thread{'s' if n_threads > 1 else ''}"
        pieces = [(lk, "lookup, compiled winner search (model._field_kernels)", "lookup, torch winner search (8 gathers of (B, 3, n) rows)"),
                  (cs, "consistency term, one compiled pass + closed-form gradient", "consistency term, torch form (samples, lookup, means; autograd)"),
                  (cv, "coverage term + presence effects, compiled (model._union_kernels)", "coverage term + presence effects, torch form (batched product; autograd)")]
        for times, *labels in pieces:
            for way, label in zip(("compiled", "torch"), labels):
                rows.append([f"{label}; {on}", *(f"{1000.0 * f(times[way]):.2f}" for f in (med, p90))])
        same = all(torch.equal(a, b) for a, b in zip(lk_out["compiled"], lk_out["torch"]))
        rel = [max(((a - b).abs().max() / b.abs().max()).item() for a, b in zip(out["compiled"], out["torch"]))
               for out in (cs_out, cv_out)]
        notes.append(f"{on}: lookup values and gradients {'bit-identical' if same else 'DIFFERENT'}; consistency values and "
                     f"gradients within {rel[0]:.1e} relative, coverage within {rel[1]:.1e}")
    table(
        f"2b. loss terms with their gradients, {BATCH} shapes x {PARTS} parts ({SAMPLES_PER_CUBOID} samples each), {POINTS} points a shape, on {device} (ms)",
        ["way", "median", "p90"],
        rows,
        "; ".join(notes) + f". {iterations} timed calls a way a round, three rounds alternating. The compiled kernels run on\n"
        "the calling thread alone: split over two Python threads beside torch's OpenMP pool (whose threads spin after each\n"
        "parallel region) the lookup took 1 ms off a training step's loss phase on 2 cores, against 3-5 ms alone.",
    )


#: one run of primkit.model.training.train in a fresh process: argv stage-1 and stage-2 iterations and
#: the recipe ("paper": the defaults, REINFORCE; "shapenet": the bundled ShapeNet models' local
#: existence gradient). Written against the API that train() has had since before issue 20, so that
#: the same script times an older revision (run_at_revision) and today's code (run_fresh).
_TRAIN_RUN = """
import json, sys
from dataclasses import replace
import torch
from primkit import data, io, synthetic
from primkit.model.training import ShapeTensors, TrainConfig, train
s1, s2, recipe = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
shapes = [data.prepare(io.Mesh(s.vertices, s.faces), name=f"chair_{i:02d}")
          for i, s in enumerate(synthetic.generate("chair", 16, seed=0))]
config = TrainConfig(stage1_iterations=s1, stage2_iterations=s2, checkpoint_every=10**9, log_every=1)
if recipe == "shapenet":
    config = replace(config, existence_gradient="local", parsimony=4e-5)
r = train(ShapeTensors(shapes), None, config, device="cpu", progress=False)
print(json.dumps({"seconds": r.seconds, "threads": torch.get_num_threads(),
                  "losses": [e["total"] for e in r.history]}))
"""


def _loss_agreement(a: list, b: list) -> str:
    """How alike two runs' per-iteration losses are: identical for how many, then how far apart."""
    same = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), len(a))
    rel = max(abs(x - y) / abs(y) for x, y in zip(a[:10], b[:10]))
    return f"losses identical for the first {same} iterations; largest relative difference in the first 10: {rel:.1e}"


def bench_train_function(before: str | None, rounds: int, s1: int, s2: int) -> None:
    """``train()`` itself, end to end, today's and (``--before REV``) as it was at REV.

    Each run is a fresh process on the same 16 procedural chairs and seed; today's and REV's runs
    alternate, ``rounds`` times, so that a change in the machine's load touches both. The losses of
    the first iterations are compared too: the same losses per step, within floating-point noise.
    """
    variants = [("today's", None)] + ([(f"primkit at {before}", before)] if before else [])
    rows, rates, losses = [], {}, {}
    for recipe in ("paper", "shapenet"):
        for r in range(rounds):
            for label, rev in variants:
                out, why = run_fresh(_TRAIN_RUN, str(s1), str(s2), recipe) if rev is None else \
                    run_at_revision(rev, _TRAIN_RUN, str(s1), str(s2), recipe)
                if out is None:
                    print(f"  ({label}, {recipe}: {why})")
                    continue
                rates.setdefault((recipe, label), []).append((s1 + s2) / out["seconds"])
                losses.setdefault((recipe, label), out["losses"])
                print(f"  {recipe}, {label}, round {r + 1}: {(s1 + s2) / out['seconds']:.1f} it/s, "
                      f"{out['threads']} threads; {load_line()}", flush=True)
        for label, _ in variants:
            got = rates.get((recipe, label))
            if got:
                rows.append([f"{recipe}: {label}", f"{med(got):.1f}", " ".join(f"{x:.1f}" for x in got)])
        if before and (recipe, "today's") in rates and (recipe, variants[1][0]) in rates:
            today = losses[(recipe, "today's")]
            ratio = med(rates[(recipe, "today's")]) / med(rates[(recipe, variants[1][0])])
            rows.append([f"{recipe}: today's / {before}", f"{ratio:.2f}x", _loss_agreement(today, losses[(recipe, variants[1][0])])])
            # the noise floor: today's code with one thread, whose sums round differently
            one, why = run_fresh(_TRAIN_RUN, str(s1), str(s2), recipe, env={"PRIMKIT_THREADS": "1"})
            if one is not None:
                rows.append([f"{recipe}: today's, 1 thread / 2", "", "(float noise alone) " + _loss_agreement(today, one["losses"])])
    table(
        f"1c. train() end to end on cpu (batch 32, 20 parts; {s1} + {s2} iterations; fresh process per run)",
        ["run", "median it/s", "each round"],
        rows,
        "it/s = iterations / TrainResult.seconds (the loop alone: data and network built before it starts);\n"
        "torch threads as train() chooses them (today: the cores free; before issue 20: torch's default).",
    )


def _memory_job(shapes, encoder: str, loss: str, device: str, iterations: int) -> dict:
    """Runs in a fresh process: build everything, then train ``iterations`` steps (stage 2)."""
    import torch

    trainer = Trainer(shapes, encoder, device, loss)
    base = maxrss_kib()
    if device.startswith("cuda"):
        torch.cuda.reset_peak_memory_stats()
    for i in range(iterations):
        trainer.step(stage2=i % 2 == 1)
    out = {"base": base, "peak": maxrss_kib(), "threads": torch.get_num_threads()}
    if device.startswith("cuda"):
        out["cuda_peak"] = torch.cuda.max_memory_allocated()
    return out


def bench_training_memory(shapes, device: str, iterations: int) -> None:
    rows = []
    for label, encoder, loss in (("paper encoder, shape_losses", "paper", "vectorised"),
                                 ("released encoder, shape_losses", "released", "vectorised"),
                                 ("paper encoder, per-cuboid loop", "paper", "loop")):
        r = run_isolated(_memory_job, shapes, encoder, loss, device, iterations)
        row = [label, f"{r['base'] / 1024:.0f}", f"{r['peak'] / 1024:.0f}", f"{(r['peak'] - r['base']) / 1024:.0f}"]
        if "cuda_peak" in r:
            row.append(f"{r['cuda_peak'] / 2**20:.0f}")
        rows.append(row)
    headers = ["variant", "RSS before training MiB", "peak RSS MiB", "increase MiB"]
    if device.startswith("cuda"):
        headers.append("CUDA peak allocated MiB")
    table(
        f"3. peak memory of training on {device} ({iterations} iterations, stages 1 and 2 alternating), fresh spawned process per variant",
        headers,
        rows,
        "'before training': after imports, data ({} prepared shapes as tensors), network and optimizer.".format(len(shapes)),
    )


def bench_shared_machine(shapes, iterations: int, warmup: int, rounds: int = 3) -> None:
    """Training steps with one core kept busy by another process (a Python busy loop): torch's
    default thread count against primkit's thread policy (:class:`primkit.parallel.ThreadGovernor`),
    each against the same count on the machine as it is without that process.

    The first steps of a fresh network are slower than later ones (measured 83 ms against 60 ms
    on one thread), and this machine's speed drifts from minute to minute, so the trainer first
    runs 20 untimed steps, and quiet and busy measurements then alternate for ``rounds`` rounds;
    the table gives the medians over rounds and each round's ratio."""
    import subprocess

    import torch

    from primkit import parallel

    default = torch.get_num_threads()
    trainer = Trainer(shapes, "paper", "cpu", existence_gradient="local", placement_weight=0.01)
    time_steps(trainer, True, 1, max(warmup, 20))

    def steps(n_threads):
        torch.set_num_threads(n_threads)
        try:
            return med(time_steps(trainer, True, iterations, warmup)["step"])
        finally:
            torch.set_num_threads(default)

    def policy():
        governor = parallel.ThreadGovernor(interval=1.0)
        governor.close()
        return governor.threads

    quiet, busy, chosen, loads = {}, {}, {"quiet": [], "busy": []}, {}
    for _ in range(rounds):
        chosen["quiet"].append(policy())
        for n in sorted({default, 1, chosen["quiet"][-1]}):
            quiet.setdefault(n, []).append(steps(n))
        loads["quiet"] = load_line()
        spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        try:
            time.sleep(1.0)
            chosen["busy"].append(policy())
            for n in sorted({default, 1, chosen["busy"][-1]}):
                busy.setdefault(n, []).append(steps(n))
            loads["busy"] = load_line()
        finally:
            spinner.kill()
            spinner.wait()
    ms = lambda t: f"{1000.0 * t:.1f}"  # noqa: E731

    def row(label, q, b):
        """medians over rounds; the ratio of the medians, then each round's own ratio"""
        each = ", ".join(f"{y / x:.2f}" for x, y in zip(q, b))
        return [label, ms(med(q)), ms(med(b)), f"{med(b) / med(q):.2f}x ({each})"]

    # each thread count is measured once a round, so round r's measurement of n is [n][r]
    policy_quiet = [quiet[n][r] for r, n in enumerate(chosen["quiet"])]
    policy_busy = [busy[n][r] for r, n in enumerate(chosen["busy"])]
    rows = [row(f"torch's default ({default})", quiet[default], busy[default]),
            row(f"primkit's policy (chose {'/'.join(map(str, sorted(set(chosen['quiet']))))}, "
                f"then {'/'.join(map(str, sorted(set(chosen['busy']))))})", policy_quiet, policy_busy),
            row("1 thread", quiet[1], busy[1])]
    table(
        f"5. training step (paper encoder, local existence gradient + placement, stage 2) with one core kept busy "
        f"by another process ({parallel.available_cores()} cores available), {rounds} round{'s' if rounds != 1 else ''} alternating",
        ["threads", "without the busy process ms", "with it ms", "slowdown (each round)"],
        rows,
        f"median over rounds of each round's median of {iterations} steps, after 20 untimed steps; the slowdown is "
        f"the ratio of those two medians, then each round's own ratio in brackets. "
        f"With one core left a step cannot beat the one-thread step of the quiet machine: that floor is "
        f"{med(quiet[1]) / med(quiet[default]):.2f}x the quiet {default}-thread step "
        f"({', '.join(f'{b / a:.2f}' for a, b in zip(quiet[default], quiet[1]))}). "
        f"Load without the busy process: {loads['quiet']}; with it: {loads['busy']} (last round).",
    )


# --------------------------------------------------------------------------------------------
# 4. inference
# --------------------------------------------------------------------------------------------


def make_abstractor(device: str):
    from primkit.model.abstractor import Abstractor
    from primkit.model.network import AbstractionNet, NetworkConfig

    import torch

    torch.manual_seed(0)
    config = NetworkConfig(parts=PARTS, grid=32, encoder="paper", fc_width=100)
    return Abstractor(AbstractionNet(config), {"network": config.to_dict()}, device=device)


def best_time(repeats: int, fn) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _prune_loop(cuboids, threshold=0.6, k=1000, seed=0):
    """The straightforward pruning: recompute every part's fraction inside the others (all samples
    against all present parts) after each removal, one shape at a time."""
    from primkit import primitives

    existence = cuboids.existence.copy()
    while existence.sum() > 1:
        frac = primitives.fraction_inside_others(cuboids.with_existence(existence), k, seed)
        worst = int(np.nanargmax(frac))
        if not frac[worst] > threshold:
            break
        existence[worst] = False
    return cuboids.with_existence(existence)


def bench_trained_pruning(count: int, repeats: int) -> None:
    """4c: the bundled chair model on held-out ShapeNetVox32 chairs: network, then pruning batched
    (``primitives.prune_covered_many``) against the loop above, checked to agree."""
    from primkit import data, io, load_model, primitives

    folder = Path(__file__).resolve().parents[2] / "shared" / "data" / "shapenetvox32" / "03001627"
    paths = sorted(folder.glob("*/model.binvox"))[9::10][:count]
    if not paths:
        print("\n(no ShapeNetVox32 chairs: section 4c skipped)")
        return
    ab = load_model("chair")
    shapes = [data.prepare(io.read_shape(p), ab.settings) for p in paths]
    occupancy = np.stack([s.occupancy for s in shapes])
    raw = ab.predict_canonical(occupancy)
    cubs = [ab._cuboids(raw, i, 0.5) for i in range(len(shapes))]
    batched = primitives.prune_covered_many(cubs, 0.6)
    loop = [_prune_loop(c) for c in cubs]
    agree = sum(np.array_equal(a.existence, b.existence) for a, b in zip(batched, loop))
    t_net = best_time(repeats, lambda: ab.predict_canonical(occupancy))
    t_many = best_time(repeats, lambda: primitives.prune_covered_many(cubs, 0.6))
    t_loop = best_time(repeats, lambda: [_prune_loop(c) for c in cubs])
    n = len(shapes)
    rows = [
        ["network (predict_canonical)", f"{1000 * t_net / n:.2f}", ""],
        ["pruning, primkit (all shapes at once, pair culling)", f"{1000 * t_many / n:.2f}", ""],
        ["pruning, recomputed after each removal, one shape at a time", f"{1000 * t_loop / n:.2f}", ""],
        ["network + pruning, primkit", f"{1000 * (t_net + t_many) / n:.2f}", f"{(t_net + t_loop) / (t_net + t_many):.1f}x"],
        ["network + pruning, the loop", f"{1000 * (t_net + t_loop) / n:.2f}", ""],
    ]
    present = np.mean([c.existence.sum() for c in cubs])
    kept = np.mean([c.existence.sum() for c in batched])
    table(
        f"4c. network + pruning, bundled chair model, {n} held-out ShapeNetVox32 chairs (ms per shape)",
        ["step", "ms/shape", "speed-up"],
        rows,
        f"fastest of {repeats} passes; {present:.1f} parts present before pruning, {kept:.1f} after; the two prunings agree on\n"
        f"{agree}/{n} shapes (the same volume samples, 1,000 a part).",
    )


def bench_inference(shapes, device: str, count: int, files: int, repeats: int) -> None:
    from primkit import data, synthetic
    from primkit.model.abstraction import abstract_shapes

    ab = make_abstractor(device)
    many = [shapes[i % len(shapes)] for i in range(count)]
    occupancy = np.stack([s.occupancy for s in many])
    ab.predict(many[:2])  # warm-up

    def one_by_one(**kw):
        for s in many:
            ab.predict([s], **kw)

    cases = [
        ("network only (predict_canonical; on the CPU one shape at a time)", lambda: ab.predict_canonical(occupancy)),
        ("predict, batched, no pruning", lambda: ab.predict(many, prune_threshold=None)),
        ("predict, batched, with pruning (default)", lambda: ab.predict(many)),
        ("predict, one shape at a time, no pruning", lambda: one_by_one(prune_threshold=None)),
        ("predict, one shape at a time, with pruning", lambda: one_by_one()),
    ]
    rows = []
    for label, fn in cases:
        t = best_time(repeats, fn)
        rows.append([label, f"{count / t:.0f}", f"{1000.0 * t / count:.2f}"])
    kept = np.mean([r.canonical.existence.sum() for r in ab.predict(many)])
    table(
        f"4. inference from prepared 32^3 grids on {device} ({count} shapes, random network)",
        ["method", "shapes/s", "ms/shape"],
        rows,
        f"fastest of {repeats} passes. A random network predicts {PARTS} small overlapping parts, all present;\n"
        f"pruning keeps {kept:.1f} of them on average. Near-identical parts are the worst case for pruning: every pair\n"
        "overlaps without one holding the other, so every sample is tested; section 4c is a trained model.",
    )

    bench_trained_pruning(count, repeats)

    with tempfile.TemporaryDirectory(prefix="primkit-bench-files-") as tmp:
        paths = synthetic.write_collection(Path(tmp) / "meshes", "chair", files, seed=3)
        rows = []
        for label, workers in (("abstract_shapes, workers=1 (prepare + predict)", 1), ("abstract_shapes, workers=2", 2)):
            times = []
            for r in range(repeats):
                cache = Path(tmp) / f"cache-{workers}-{r}"  # empty cache every time
                t0 = time.perf_counter()
                out = abstract_shapes(paths, ab, cache=cache, workers=workers, progress=False)
                times.append(time.perf_counter() - t0)
                assert len(out) == files and not out.errors
            rows.append([label, f"{files / min(times):.1f}", f"{1000.0 * min(times) / files:.0f}"])
        t = best_time(repeats, lambda: [ab.predict([data.prepare_file(p, ab.settings)]) for p in paths])
        rows.append(["prepare_file + predict, one file at a time (no cache)", f"{files / t:.1f}", f"{1000.0 * t / files:.0f}"])
    table(
        f"4b. inference from mesh files on {device} ({files} procedural chairs, PLY, empty cache)",
        ["method", "shapes/s", "ms/shape"],
        rows,
        "abstract_shapes prepares through the on-disk cache (hashing + writing .npz) and spawns its worker pool per call.",
    )


# --------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="few iterations and shapes (smoke test)")
    parser.add_argument("--iterations", type=int, default=None, help="timed iterations per variant (default 30; quick 5)")
    parser.add_argument("--device", choices=("auto", "cpu", "cuda", "all"), default="auto",
                        help="auto: cpu, and cuda too when available")
    parser.add_argument("--shapes", type=int, default=16, help="prepared procedural chairs to draw batches from")
    parser.add_argument("--shared", action=argparse.BooleanOptionalAction, default=True,
                        help="also time training with one core kept busy by another process (default on)")
    parser.add_argument("--only", choices=("training", "train", "shared", "inference"), default=None,
                        help="run one section (train: section 1c alone)")
    parser.add_argument("--before", default=None, metavar="REV",
                        help="section 1c also runs train() as it was at this git revision (e.g. 7f3df5b, before issue 20)")
    parser.add_argument("--rounds", type=int, default=None, help="section 1c: alternating runs per side (default 3; quick 1)")
    args = parser.parse_args(argv)
    quick = args.quick
    iterations = args.iterations or (5 if quick else 30)
    warmup = 1 if quick else 3
    repeats = 1 if quick else 3

    import torch

    import primkit

    cuda = torch.cuda.is_available()
    if args.device == "cpu":
        devices = ["cpu"]
    elif args.device == "cuda":
        if not cuda:
            print("CUDA is not available", file=sys.stderr)
            return 2
        devices = ["cuda"]
    else:
        devices = ["cpu"] + (["cuda"] if cuda else [])

    print(f"# bench_abstractor: primkit {primkit.__version__}, torch {torch.__version__}, Python {platform.python_version()}, "
          f"{'quick' if quick else 'full'} run")
    print(f"# CPU: {platform.machine()}, {os.cpu_count()} cores, torch threads {torch.get_num_threads()}; {load_line()} at start")
    if cuda:
        print(f"# CUDA: {torch.cuda.get_device_name(0)}")
    t_start = time.perf_counter()
    shapes, t_prep = (lambda t0: (prepared_chairs(args.shapes), time.perf_counter() - t0))(time.perf_counter())
    print(f"# data: {len(shapes)} procedural chairs prepared in {t_prep:.1f} s")

    for device in devices:
        if args.only in (None, "training"):
            bench_training(shapes, device, iterations, warmup)
            bench_loss_terms(shapes, device, iterations, warmup)
            bench_training_memory(shapes, device, max(4, iterations // 3))
        if device == "cpu" and args.only in (None, "train"):
            rounds = args.rounds or (1 if quick else 3)
            bench_train_function(args.before, rounds, *((20, 20) if quick else (150, 250)))
        if device == "cpu" and args.shared and args.only in (None, "shared"):
            bench_shared_machine(shapes, iterations, warmup, rounds=1 if quick else 3)
        if args.only in (None, "inference"):
            bench_inference(shapes, device, count=16 if quick else 64, files=4 if quick else 8, repeats=repeats)
    print(f"\n# {load_line()} at end; benchmark took {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

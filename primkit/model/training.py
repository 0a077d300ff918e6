"""Training the cuboid abstractor on a collection of prepared shapes (torch).

Schedule (the published one, see ``TrainConfig``): Adam 1e-3, batch 32, 20 parts, 1,000 surface
points per shape and 150 samples per cuboid each iteration; stage 1 with every part present
(existence not learned), stage 2 with existence sampled from the network's probabilities and
learned by REINFORCE with a moving-average baseline and a parsimony reward. Between the stages the
heads are rescaled without changing the network's function (:meth:`AbstractionNet.set_head_scales`).

For small collections :meth:`TrainConfig.scaled_for` shortens the schedule to a number of epochs
comparable to the paper's (50,000 iterations of 32 shapes is about 270 passes over ShapeNet's
5,900 chairs), never below 2,000 iterations.

Multi-GPU / multi-node: launch with ``torchrun`` (``python -m torch.distributed.run``); each
process trains on its own batches (seeded by rank), gradients are averaged by DDP, the REINFORCE
baseline uses the mean loss over all processes, and only rank 0 writes files.
"""

from __future__ import annotations

import json
import math
import contextlib
import os
import signal
import sys
import functools
import threading
import time
import logging
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .. import geometry, io, parallel
from . import modelfile
from .modelfile import claim_output
from .losses import (LossWeights, MovingBaseline, SlotPlacement, local_existence_surrogate, reinforce_surrogate,
                     shape_losses)
from .network import AbstractionNet, NetworkConfig

_logger = logging.getLogger(__name__)

__all__ = ["TrainConfig", "ShapeTensors", "PreparedDataset", "TrainResult", "train", "isolated_torch_state",
           "TrainingOutputs", "training_outputs", "check_training_outputs", "check_checkpoint", "claim_output"]


@dataclass(frozen=True)
class TrainConfig:
    """Every setting of a training run (saved in the model file)."""

    parts: int = 20
    encoder: str = "paper"
    fc_width: int = 100
    batch_size: int = 32
    learning_rate: float = 1e-3
    points_per_shape: int = 1000
    samples_per_cuboid: int = 150
    stage1_iterations: int = 20000
    stage2_iterations: int = 30000
    parsimony: float = 8e-5
    existence_gradient: str = "reinforce"
    placement_weight: float = 0.0
    placement_momentum: float = 0.99
    baseline_momentum: float = 0.9
    coverage_weight: float = 1.0
    consistency_weight: float = 1.0
    symmetry_weight: float = 0.0
    stage1_shape_scale: float = 1.0
    stage2_shape_scale: float = 0.5
    stage2_existence_scale: float = 0.2
    seed: int = 0
    log_every: int = 25
    checkpoint_every: int = 500

    @property
    def iterations(self) -> int:
        return self.stage1_iterations + self.stage2_iterations

    def scaled_for(self, shapes: int, min_iterations: int = 2000, epochs: float = 270.0) -> "TrainConfig":
        """The same schedule shortened for a collection of ``shapes`` shapes (stage split kept)."""
        total = self.iterations
        want = int(min(total, max(min_iterations, math.ceil(epochs * shapes / self.batch_size))))
        s1 = int(round(want * self.stage1_iterations / total))
        return replace(self, stage1_iterations=s1, stage2_iterations=want - s1)

    def to_dict(self) -> dict:
        return asdict(self)


def stack_limit_bytes() -> int:
    """Decoded bytes a collection may take in memory before :class:`ShapeTensors` streams it instead:
    ``PRIMKIT_STACK_LIMIT_MIB`` when set, else a third of the memory available now (at least 1 GiB).

    Stacked batches cost about 4 ms of CPU against 25 for streamed ones, whose closest points are
    decoded again in every batch: a sixth of a training step at batch 32 (chair model, one thread).
    ShapeNet's chairs take 3.1 GB decoded."""
    text = os.environ.get("PRIMKIT_STACK_LIMIT_MIB")
    if text is not None:
        return int(float(text) * 2**20)
    available = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if available is None:
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            available = 0
    return max(2**30, available // 3)


class ShapeTensors:
    """Random training batches of prepared shapes.

    A :class:`primkit.data.PreparedCollection` whose decoded arrays fit :func:`stack_limit_bytes`
    (a third of the memory available, at least 1 GiB; a shape of 10,000 samples at 32^3 takes
    0.59 MB; ``PRIMKIT_STACK_LIMIT_MIB``, or ``stack_limit``) is decoded once into the tensors below,
    the fastest batches. A larger one
    is *streamed*: nothing is loaded, each batch is gathered from the cache's memory-mapped rows
    and decoded (:meth:`primkit.data.PreparedCollection.gather`, :func:`decode_closest_torch`; a few
    ms a batch), so that training starts at once and holds only its batch whatever the
    collection's size. A list of :class:`primkit.data.PreparedShape` is stacked. Every way gives
    the same batches, bit for bit, for the same shapes and generator.

    Attributes
    ----------
    occupancy : (S, R, R, R) uint8
    closest : (S, R, R, R, 3) float32
        Stored coordinate-planar (a ``(S, 3, R, R, R)`` tensor seen through a permutation), the
        layout :func:`primkit.model.distance_field.lookup_distance_sq_torch` reads without a copy.
    points : (S, n, 3) float32
    point_labels : (S, n) int32
        These four when stacked (``streamed`` False).
    names : list of str
    streamed : bool
    """

    def __init__(self, shapes, *, stack_limit: int | None = None):
        self._collection = None
        self.streamed = False
        if hasattr(shapes, "gather") and hasattr(shapes, "settings"):  # a PreparedCollection
            if not len(shapes):
                raise ValueError("no shapes to train on")
            self.names = [shapes.name(i) for i in range(len(shapes))]
            res, n = shapes.settings.resolution, shapes.settings.samples
            self._resolution, self._samples = res, n
            per_shape = res**3 * 13 + n * 16  # occupancy, closest points, samples, labels
            if len(shapes) * per_shape > (stack_limit_bytes() if stack_limit is None else stack_limit):
                self._collection, self.streamed = shapes, True
                return
            self._stack_collection(shapes)
            return
        shapes = list(shapes)
        if not shapes:
            raise ValueError("no shapes to train on")
        n = min(len(s.points) for s in shapes)
        res = shapes[0].resolution
        self.names = [s.name for s in shapes]
        self.occupancy = torch.from_numpy(np.stack([s.occupancy for s in shapes]).astype(np.uint8))
        planar = torch.empty((len(shapes), 3, res, res, res), dtype=torch.float32)
        for i, s in enumerate(shapes):
            planar[i] = torch.from_numpy(np.moveaxis(np.asarray(s.closest, np.float32), -1, 0))
        self.closest = planar.permute(0, 2, 3, 4, 1)
        self.points = torch.from_numpy(np.stack([s.points[:n] for s in shapes]).astype(np.float32))
        self.point_labels = torch.from_numpy(np.stack([s.point_labels[:n] for s in shapes]).astype(np.int32))
        self._resolution, self._samples = res, n

    def _stack_collection(self, coll, chunk: int = 64) -> None:
        """Decode a collection into the stacked tensors, ``chunk`` shapes at a time."""
        res, n, count = self._resolution, self._samples, len(coll)
        self.occupancy = torch.empty((count, res, res, res), dtype=torch.uint8)
        planar = torch.empty((count, 3, res, res, res), dtype=torch.float32)
        self.points = torch.empty((count, n, 3), dtype=torch.float32)
        every = np.arange(n)
        for lo in range(0, count, chunk):
            idx = np.arange(lo, min(count, lo + chunk))
            occ, codes, near, pts = coll.gather(idx, np.broadcast_to(every, (len(idx), n)))
            self.occupancy[lo:lo + len(idx)] = torch.from_numpy(occ.view(np.uint8))
            closest = torch.from_numpy(codes) if near is None else decode_closest_torch(codes, near, res)
            planar[lo:lo + len(idx)] = closest.reshape(len(idx), 3, res, res, res)
            self.points[lo:lo + len(idx)] = torch.from_numpy(pts)
        self.closest = planar.permute(0, 2, 3, 4, 1)
        self.point_labels = torch.from_numpy(np.stack([coll.point_labels(i) for i in range(count)]))

    def __len__(self) -> int:
        return len(self.names)

    @property
    def resolution(self) -> int:
        return self._resolution

    def batch(self, index, points_per_shape: int, generator: torch.Generator, device):
        """Occupancy (B, 1, R, R, R), closest (B, R, R, R, 3) and ``points_per_shape`` random surface points (B, n, 3).

        The closest points come out planar in memory like :attr:`closest`; the points are picked
        straight from the stored rows (no copy of each shape's whole sample set).
        """
        index = torch.as_tensor(index, dtype=torch.int64)
        if self._collection is not None:
            pick = torch.randint(0, self._samples, (len(index), points_per_shape), generator=generator)
            occ, codes, near, pts = self._collection.gather(index.numpy(), pick.numpy())
            occ = torch.from_numpy(occ).unsqueeze(1).to(device=device, dtype=torch.float32)
            res = self._resolution
            closest = torch.from_numpy(codes) if near is None else decode_closest_torch(codes, near, res)
            closest = closest.reshape(len(index), 3, res, res, res).to(device)
            return occ, closest.permute(0, 2, 3, 4, 1), torch.from_numpy(pts).to(device)
        occ = self.occupancy.index_select(0, index).unsqueeze(1).to(device=device, dtype=torch.float32)
        closest = self.closest.permute(0, 4, 1, 2, 3).index_select(0, index).to(device).permute(0, 2, 3, 4, 1)
        total = self.points.shape[1]
        pick = torch.randint(0, total, (len(index), points_per_shape), generator=generator)
        rows = (index[:, None] * total + pick).reshape(-1)
        pts = self.points.reshape(-1, 3).index_select(0, rows).reshape(len(index), points_per_shape, 3).to(device)
        return occ, closest, pts


def decode_closest_torch(codes, near, resolution: int) -> torch.Tensor:
    """The torch twin of :func:`primkit.geometry.decode_closest` (planar), the same float32
    values bit for bit (the same operations in the same order; ``tests/model/test_training.py``):
    (b, 3, R^3) closest points from (b, 3, R^3) uint8 codes and (b, R^3 / 8) near bits. Measured
    3x faster than NumPy on a batch of 32 shapes (one thread): a few ms a batch."""
    s_near, s_far = geometry.closest_scales(resolution)
    nearf = torch.from_numpy(np.unpackbits(near, axis=-1)[:, None, : resolution**3]).to(torch.float32)
    scale = nearf.mul(float(np.float32(s_near - s_far))).add_(float(np.float32(s_far)))
    out = torch.from_numpy(np.ascontiguousarray(codes)).to(torch.float32).mul_(scale).sub_(0.5)
    return out.add_(nearf.mul(_near_shift(resolution)))


@functools.lru_cache(maxsize=4)
def _near_shift(resolution: int) -> torch.Tensor:
    return torch.from_numpy(np.array(geometry.near_shift(resolution)))


class PreparedDataset(torch.utils.data.Dataset):
    """A torch ``Dataset`` over a :class:`primkit.data.PreparedCollection` (loaded lazily).

    Items are dicts of tensors: ``occupancy`` (1, R, R, R) float, ``closest`` (R, R, R, 3),
    ``points`` (n, 3), ``point_labels`` (n,).
    """

    def __init__(self, collection):
        self.collection = collection

    def __len__(self) -> int:
        return len(self.collection)

    def __getitem__(self, i: int) -> dict:
        s = self.collection[i]
        return {
            "occupancy": torch.from_numpy(s.occupancy.astype(np.float32))[None],
            "closest": torch.from_numpy(np.ascontiguousarray(s.closest)),
            "points": torch.from_numpy(np.ascontiguousarray(s.points)),
            "point_labels": torch.from_numpy(np.ascontiguousarray(s.point_labels)),
        }


@dataclass
class TrainResult:
    """What :func:`train` returns."""

    model_path: Path | None
    network: AbstractionNet
    history: list = field(default_factory=list)
    interrupted: bool = False
    seconds: float = 0.0


@dataclass(frozen=True)
class TrainingOutputs:
    """The files :func:`train` writes for one model file.

    Attributes
    ----------
    model : Path
        The model file (``.safetensors``).
    checkpoint : Path
        ``<model>.checkpoint.safetensors``, while the run is unfinished.
    history : Path
        ``<stem>.history.json``, the losses.
    plot : Path
        ``<stem>.training.png``, the losses and the parts in use.
    """

    model: Path
    checkpoint: Path
    history: Path
    plot: Path

    def paths(self) -> list[Path]:
        """The four paths, in the order above."""
        return [self.model, self.checkpoint, self.history, self.plot]


def training_outputs(output) -> TrainingOutputs:
    """The files :func:`train` writes for the model file ``output`` (:class:`TrainingOutputs`)."""
    output = Path(output)
    stem = str(output.with_suffix(""))
    return TrainingOutputs(model=output, checkpoint=output.with_name(output.name + ".checkpoint.safetensors"),
                           history=Path(stem + ".history.json"), plot=Path(stem + ".training.png"))


def check_training_outputs(output, *, overwrite: bool = False, resume=None, inputs=()) -> TrainingOutputs:
    """Check before any work that a training run can write all it will write
    (:func:`training_outputs`, :func:`primkit.io.check_outputs`): the model's suffix is
    ``.safetensors``, the folder can be written, nothing is an input (``resume`` and ``inputs``), and
    nothing exists without ``overwrite``, except the checkpoint being resumed. Returns the outputs."""
    paths = training_outputs(io.check_suffix(output, ".safetensors", "a model file"))
    ckpt = paths.checkpoint
    resumed = resume is not None and os.path.realpath(resume) == os.path.realpath(ckpt)
    if os.path.lexists(ckpt) and not (overwrite or resumed):
        raise FileExistsError(f"{ckpt}: exists, the checkpoint of an unfinished run (go on with --resume {ckpt}, "
                              "or use --force to start afresh)")
    read = list(inputs) + ([resume] if resume is not None and not resumed else [])
    io.check_outputs(paths.paths(), inputs=read, overwrite=overwrite, resumed=[ckpt] if resumed else [])
    return paths


def _dist():
    import torch.distributed as dist

    return dist if dist.is_available() and dist.is_initialized() else None


def _setup_distributed(device_kind: str):
    """Initialise torch.distributed when launched by torchrun (WORLD_SIZE > 1)."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return 0, 1
    import torch.distributed as dist

    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device_kind == "cuda" else "gloo")
    return dist.get_rank(), dist.get_world_size()


def training_layout(net: AbstractionNet, device) -> AbstractionNet:
    """The encoder's memory layout for training, in place: channels-last (NDHWC) on CUDA, the default
    layout on the CPU, where oneDNN's channels-last 3D convolutions measured slower for this encoder:
    a training step of the chair preset took 84 ms of CPU channels-last against 75 ms (one thread,
    batch 32, three alternating runs), and no faster with two threads. The values are the same to
    float rounding; saved files and inference use the default layout."""
    if torch.device(device).type == "cuda":
        net.encoder.to(memory_format=torch.channels_last_3d)
    return net


def _adam(net, learning_rate: float, device) -> "torch.optim.Adam":
    """Adam over the network's parameters; fused (one kernel for all of them) on CPU and CUDA: the
    same update up to rounding, 3x faster than the per-parameter loop on CPU (0.28 against 0.92 ms
    for the paper's network)."""
    fused = torch.device(device).type in ("cpu", "cuda")
    return torch.optim.Adam(net.parameters(), lr=learning_rate, fused=fused or None)


def _optimizer_tensors(optimizer) -> tuple[dict, dict]:
    """Adam's state as flat tensors plus JSON-ready scalars (for safetensors checkpoints)."""
    state = optimizer.state_dict()
    tensors, scalars = {}, {"param_groups": state["param_groups"], "state": {}}
    for pid, s in state["state"].items():
        scalars["state"][str(pid)] = {}
        for key, value in s.items():
            if torch.is_tensor(value):
                tensors[f"optimizer.{pid}.{key}"] = value
            else:
                scalars["state"][str(pid)][key] = value
    return tensors, scalars


def _restore_optimizer(optimizer, tensors: dict, scalars: dict) -> None:
    state = {"param_groups": scalars["param_groups"], "state": {}}
    for pid, extra in scalars["state"].items():
        entry = dict(extra)
        for name, value in tensors.items():
            prefix = f"optimizer.{pid}."
            if name.startswith(prefix):
                entry[name[len(prefix):]] = value
        state["state"][int(pid)] = entry
    optimizer.load_state_dict(state)
    # moments are saved contiguous; a fused step reads them with its parameter's strides, so they
    # take the parameter's memory layout back (the conv weights are channels-last)
    for group in optimizer.param_groups:
        for p in group["params"]:
            for key, value in optimizer.state.get(p, {}).items():
                if torch.is_tensor(value) and value.shape == p.shape and value.stride() != p.stride():
                    optimizer.state[p][key] = torch.empty_like(p).copy_(value)


def _save_checkpoint(path, net, optimizer, generator, baseline, iteration, history, config, extra) -> bool:
    """Write the checkpoint; on any failure of the writer (a full disk raises OSError or safetensors'
    SafetensorError, the folder gone or read-only) say so (a :class:`RuntimeWarning`) and return False:
    the run goes on, and the previous checkpoint, if any, stands (writes are atomic)."""
    try:
        _write_checkpoint(path, net, optimizer, generator, baseline, iteration, history, config, extra)
    except Exception as exc:  # noqa: BLE001 - whatever the writer raises, training must not be lost
        reason = getattr(exc, "strerror", None) or str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        kept = f"the checkpoint {path} of an earlier iteration stands" if os.path.exists(path) else "no checkpoint yet"
        warnings.warn(f"could not write the checkpoint {path} at iteration {iteration} "
                      f"({type(exc).__name__}: {reason}); {kept}; training goes on", RuntimeWarning, stacklevel=2)
        return False
    return True


def _write_checkpoint(path, net, optimizer, generator, baseline, iteration, history, config, extra) -> None:
    weights = {f"model.{k}": v for k, v in net.state_dict().items()}
    opt_tensors, opt_scalars = _optimizer_tensors(optimizer)
    weights.update(opt_tensors)
    weights["rng.batches"] = generator.get_state()
    weights["rng.torch"] = torch.get_rng_state()
    meta = {
        "network": net.config.to_dict(),
        "checkpoint": {
            "iteration": iteration,
            "baseline": baseline.state_dict(),
            "optimizer": opt_scalars,
            "config": config.to_dict(),
            "history": history,
            **extra,
        },
    }
    modelfile.save_model(path, weights, meta, overwrite=True)


def check_checkpoint(path, network: NetworkConfig) -> dict:
    """The ``checkpoint`` metadata of the training checkpoint ``path``, after checking from its
    header alone (nothing allocated) that it is a valid checkpoint of ``network``: a run cannot go on
    with other ``--parts`` or ``--encoder``, which is refused in one line
    (:class:`~primkit.model.modelfile.ModelFileError`)."""
    from .network import read_network

    saved, meta = read_network(path)
    ck = meta.get("checkpoint")
    if not isinstance(ck, dict) or not {"iteration", "optimizer", "baseline", "history"} <= set(ck):
        raise modelfile.ModelFileError(path, "not a training checkpoint (a model file? --resume takes "
                                             "<model>.checkpoint.safetensors)")
    if saved != network:
        flags = {"parts": "--parts", "encoder": "--encoder"}
        theirs, mine = saved.to_dict(), network.to_dict()
        differ = [f"{k} {v}" + (f" ({flags[k]} {v})" if k in flags else "") for k, v in theirs.items() if v != mine[k]]
        asked = ", ".join(f"{k} {v}" for k, v in mine.items() if v != theirs[k])
        raise modelfile.ModelFileError(path, f"the checkpoint's network has {', '.join(differ)}; this run asks for "
                                             f"{asked}: resume with the settings it was trained with, or start "
                                             "afresh without --resume")
    return ck


def _read_checkpoint(path, network: NetworkConfig, config: TrainConfig) -> tuple[dict, dict]:
    """The weights and ``checkpoint`` metadata of a checkpoint of ``network`` (:func:`check_checkpoint`);
    training settings that differ from the checkpoint's are named in a warning (this run's are used)."""
    ck = check_checkpoint(path, network)
    before = ck.get("config") if isinstance(ck.get("config"), dict) else {}
    changed = [f"{k} {before[k]} -> {v}" for k, v in config.to_dict().items() if k in before and before[k] != v]
    if changed:
        warnings.warn(f"resuming {path} with settings that differ from its own: {', '.join(changed)}", UserWarning,
                      stacklevel=3)
    weights, _ = modelfile.load_model_file(path, map_location="cpu")
    return weights, ck


def _save_trained(output: Path, state: dict, meta: dict) -> None:
    """Save the trained model through :func:`~primkit.model.modelfile.write_model`: if that fails
    (its folder removed, full or made read-only during the run), the model goes to the system's
    temporary folder and an OSError says where (:func:`train` adds where its checkpoint is)."""
    modelfile.write_model(output, state, meta, overwrite=True)  # claimed before the first iteration


def _plot_history(history, path, stage1: int) -> None:
    from matplotlib.figure import Figure  # matplotlib: imported on first use

    if not history:
        return
    it = [h["iteration"] for h in history]
    fig = Figure(figsize=(7, 6))  # no pyplot: training never switches the caller's backend
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for key, label in (("total", "total"), ("coverage", "coverage"), ("consistency", "consistency"), ("symmetry", "symmetry")):
        vals = [h[key] for h in history]
        if any(v > 0 for v in vals):
            ax1.semilogy(it, vals, label=label)
    ax1.set_ylabel("loss (squared distance)")
    ax1.legend()
    ax2.plot(it, [h["parts"] for h in history], color="k")
    ax2.set_ylabel("parts in use")
    ax2.set_xlabel("iteration")
    for ax in (ax1, ax2):
        ax.axvline(stage1, color="grey", ls="--", lw=0.8)
    ax1.set_title("training: losses and parts in use (dashed: start of stage 2)")
    fig.tight_layout()
    with io.atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png", dpi=100)


def isolated_torch_state(fn):
    """Decorate a training function so that torch's global state is the caller's again afterwards.

    The function may seed and draw from torch's global generators (initialisation and the surface
    samples of a training run draw from them, so that a seed gives bit-identical weights, as
    before) and turn on flushing of denormal floats: it runs inside ``torch.random.fork_rng`` (the
    CPU generator and every CUDA device's), and flushing is turned off again, torch's default,
    when it returns or raises (torch has no getter for the flag).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        devices = list(range(torch.cuda.device_count())) if torch.cuda.is_available() else []
        with torch.random.fork_rng(devices=devices):
            try:
                return fn(*args, **kwargs)
            finally:
                torch.set_flush_denormal(False)

    return wrapper


@isolated_torch_state
def train(
    shapes: ShapeTensors,
    output=None,
    config: TrainConfig = TrainConfig(),
    *,
    device: str | None = None,
    resume=None,
    progress: bool = False,
    description: dict | None = None,
    overwrite: bool = False,
    threads: int | None = None,
) -> TrainResult:
    """Train an abstractor on ``shapes``; write the model to ``output`` (``.safetensors``).

    torch's global random state and its denormal flag are the caller's again afterwards
    (:func:`isolated_torch_state`). Beside the model: ``<output>.checkpoint.safetensors`` (every ``checkpoint_every`` iterations
    and on Ctrl-C; pass it as ``resume`` to go on), ``<stem>.history.json`` and
    ``<stem>.training.png`` (losses and parts in use over iterations).

    Parameters
    ----------
    shapes : ShapeTensors
    output : path, optional
        Model file to write; nothing is written when None.
    device : str, optional
        ``"cuda"`` when available, else ``"cpu"``.
    progress : bool
        A tqdm bar over the iterations, on stderr (off by default: a library call is silent).
    description : dict, optional
        What the data is and its terms, stored in the model file (``training.data``).
    threads : int, optional
        torch threads on CPU. By default they follow the cores free (:class:`primkit.parallel.ThreadGovernor`:
        chosen at the start and again every few seconds, so that another process taking a core does
        not stall every step); ``PRIMKIT_THREADS``, ``OMP_NUM_THREADS`` or a torch thread count set
        by the caller count as explicit and are kept. The caller's count comes back afterwards.
        Runs are bit-identical for the same thread counts: pin them (``threads=1``) to reproduce a run
        on a shared machine.
    """
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    rank, world = _setup_distributed(torch.device(device).type)
    if world > 1 and torch.device(device).type == "cuda":
        device = f"cuda:{int(os.environ.get('LOCAL_RANK', rank))}"
    output = Path(output) if output is not None else None
    claim = contextlib.nullcontext()
    if output is not None and rank == 0:  # before the first iteration: hours of training must not end in "cannot write"
        check_training_outputs(output, overwrite=overwrite, resume=resume)
        claim = claim_output(output, overwrite)
    with claim:
        return _train(shapes, output, config, device, resume, progress, description, threads, rank, world)


def _train(shapes, output, config, device, resume, progress, description, threads, rank, world) -> TrainResult:
    outputs = training_outputs(output) if output is not None else None
    ckpt_path = outputs.checkpoint if output is not None else None

    # tiny N(0, 0.02) activations turn into denormal floats, which made CPU steps up to 5x slower
    torch.set_flush_denormal(True)
    torch.manual_seed(config.seed)
    net = AbstractionNet(NetworkConfig(parts=config.parts, grid=shapes.resolution, encoder=config.encoder, fc_width=config.fc_width))
    net.set_head_scales(config.stage1_shape_scale, 1.0)
    training_layout(net.to(device), device)
    optimizer = _adam(net, config.learning_rate, device)
    generator = torch.Generator().manual_seed(config.seed * 1000 + rank)
    baseline = MovingBaseline(config.baseline_momentum)
    placement = SlotPlacement(config.placement_momentum)
    history: list = []
    start = 0
    if resume is not None:
        weights, ck = _read_checkpoint(resume, net.config, config)
        try:
            state = {k[len("model."):]: v for k, v in weights.items() if k.startswith("model.")}
            net.load_state_dict(state)  # carries the head scales of the stage it stopped in
            net.to(device)
            optimizer = _adam(net, config.learning_rate, device)
            _restore_optimizer(optimizer, {k: v.to(device) for k, v in weights.items() if k.startswith("optimizer.")},
                               ck["optimizer"])
            generator.set_state(weights["rng.batches"])
            torch.set_rng_state(weights["rng.torch"])
            baseline.load_state_dict(ck["baseline"])
            if ck.get("placement"):
                placement.load_state_dict(ck["placement"])
            history = list(ck["history"])
            start = int(ck["iteration"])
        except (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError) as exc:
            raise modelfile.ModelFileError(resume, f"not a usable training checkpoint ({type(exc).__name__}: {exc})") from None
        if not 0 <= start <= config.iterations:
            raise modelfile.ModelFileError(resume, f"stopped at iteration {start}, outside this run's {config.iterations}")
    model = net
    if world > 1:
        from torch.nn.parallel import DistributedDataParallel

        model = DistributedDataParallel(net, device_ids=[torch.device(device).index] if torch.device(device).type == "cuda" else None)

    weights = LossWeights(config.coverage_weight, config.consistency_weight, config.symmetry_weight)
    stage1 = config.stage1_iterations
    total = config.iterations
    from tqdm.auto import tqdm

    bar = tqdm(total=total, initial=start, desc="training", unit="it", disable=not progress or rank != 0, file=sys.stderr)
    governor = parallel.ThreadGovernor(threads, enabled=torch.device(device).type == "cpu")
    t0 = time.perf_counter()
    interrupted = False
    running: dict = {}
    # Ctrl-C finishes the current iteration, then saves a checkpoint and stops, so that resuming
    # continues exactly where it stopped; a second Ctrl-C stops at once.
    stop = {"requested": False}
    previous_handler = None
    if threading.current_thread() is threading.main_thread():
        def _request_stop(signum, frame):
            if stop["requested"]:
                raise KeyboardInterrupt
            stop["requested"] = True

        previous_handler = signal.signal(signal.SIGINT, _request_stop)
        # SIGTERM (SLURM, Kubernetes, timeout) as Ctrl-C: finish the iteration, checkpoint, stop
        previous_term = signal.signal(signal.SIGTERM, _request_stop)
    if rank == 0:  # from here on Ctrl-C and SIGTERM stop after a checkpoint
        _logger.info("training: iterations %d to %d on %d shapes (%s)", start + 1, total, len(shapes), device)
    try:
        for it in range(start, total):
            governor.update()
            stage2 = it >= stage1
            if stage2 and (net.shape_scale, net.existence_scale) != (config.stage2_shape_scale, config.stage2_existence_scale):
                # the switch keeps the network's function (a resumed stage-2 run already has these scales)
                net.set_head_scales(config.stage2_shape_scale, config.stage2_existence_scale)
            index = torch.randint(0, len(shapes), (config.batch_size,), generator=generator)
            occ, closest, pts = shapes.batch(index, config.points_per_shape, generator, device)
            model.train()
            pred = model(occ)
            if stage2:
                u = torch.rand(pred.existence.shape, generator=generator).to(device)
                present = (u < pred.existence.detach()).to(pred.existence.dtype)
            else:
                present = torch.ones_like(pred.existence)
            local = stage2 and config.existence_gradient == "local"
            losses = shape_losses(pred, present, pts, closest, weights, config.samples_per_cuboid, generator=None,
                                  presence_effects=local)
            if config.placement_weight:
                place = placement.costs(pred.translations)  # (B, m), from the means before this batch
                placement.update(pred.translations, present)
                losses.total = losses.total + config.placement_weight * (place * present).sum(1)
                if losses.presence_effect is not None:
                    losses.presence_effect = losses.presence_effect + config.placement_weight * place.detach()
            loss = losses.total.mean()
            mean_loss = loss.detach()
            if world > 1:
                dist = _dist()
                dist.all_reduce(mean_loss)
                mean_loss = mean_loss / world
            if stage2:
                if local:
                    loss = loss + local_existence_surrogate(pred.existence_logits, losses.presence_effect, config.parsimony)
                else:
                    b = baseline.value if baseline.value is not None else float(mean_loss)
                    loss = loss + reinforce_surrogate(pred.existence_logits, present, losses.total, b, config.parsimony)
                baseline.update(float(mean_loss))
            else:
                # existence is not learned in stage 1; the zero term keeps its head in the graph (DDP)
                loss = loss + 0.0 * pred.existence_logits.sum()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()

            for key, value in (
                ("total", losses.total.mean()),
                ("coverage", losses.coverage.mean()),
                ("consistency", losses.consistency.mean()),
                ("symmetry", losses.symmetry.mean()),
                ("parts", present.sum(1).mean()),
            ):
                running[key] = running.get(key, 0.0) + float(value.detach())
            running["count"] = running.get("count", 0) + 1
            if (it + 1) % config.log_every == 0 or it + 1 == total:
                c = running.pop("count")
                entry = {"iteration": it + 1, "stage": 2 if stage2 else 1, **{k: v / c for k, v in running.items()}}
                running = {}
                history.append(entry)
                bar.set_postfix(stage=entry["stage"], cov=f"{entry['coverage']:.2e}", cons=f"{entry['consistency']:.2e}", parts=f"{entry['parts']:.1f}")
            bar.update()
            if stop["requested"] and it + 1 < total:
                interrupted = True
                if ckpt_path is not None and rank == 0 and _save_checkpoint(
                        ckpt_path, net, optimizer, generator, baseline, it + 1, history, config,
                        {"placement": placement.state_dict()}):
                    _logger.warning("interrupted after iteration %d: checkpoint saved to %s (resume with --resume)", it + 1, ckpt_path)
                break
            if ckpt_path is not None and rank == 0 and (it + 1) % config.checkpoint_every == 0 and it + 1 < total:
                _save_checkpoint(ckpt_path, net, optimizer, generator, baseline, it + 1, history, config,
                                     {"placement": placement.state_dict()})
    except KeyboardInterrupt:
        interrupted = True
        _logger.warning("interrupted twice: stopped without saving this iteration (the last checkpoint stands)")
    finally:
        bar.close()
        governor.close()
        if previous_handler is not None:
            signal.signal(signal.SIGINT, previous_handler)
            signal.signal(signal.SIGTERM, previous_term)
    seconds = time.perf_counter() - t0
    net.eval()
    net.encoder.to(memory_format=torch.contiguous_format)  # inference layout (see training_layout)
    if output is not None and rank == 0 and not interrupted:
        meta = {
            "network": net.config.to_dict(),
            "grid": shapes.resolution,
            "canonical_frame": {"up": "+y", "front": "+x", "normalisation": "bounding box centred at the origin, longest side 1"},
            "training": {
                "data": description or {},
                "shapes": len(shapes),
                "config": config.to_dict(),
                "iterations": total,
                "seconds": round(seconds, 1),
                "device": str(device),
                "processes": world,
                "threads": governor.changes,
                "torch": torch.__version__,
                "final": history[-1] if history else None,
            },
            "metrics": {},
            "part_names": None,
        }
        try:
            _save_trained(output, net.state_dict(), meta)
        except OSError as exc:
            # a checkpoint of the finished run, so that no iteration is lost (resuming it writes the model)
            if _save_checkpoint(ckpt_path, net, optimizer, generator, baseline, total, history, config,
                                {"placement": placement.state_dict()}):
                kept = f"a checkpoint of the finished run is in {ckpt_path} (--resume {ckpt_path} writes the model)"
            elif ckpt_path.exists():
                kept = f"the last checkpoint {ckpt_path} stands (--resume {ckpt_path})"
            else:
                kept = "no checkpoint could be written"
            raise OSError(exc.errno, f"{exc.strerror}; {kept}") from None
        with io.atomic_output(outputs.history, overwrite=True) as tmp:  # checked before the first iteration
            tmp.write_text(json.dumps(history))
        _plot_history(history, outputs.plot, stage1)
        if ckpt_path.exists():
            ckpt_path.unlink()
    return TrainResult(output if output is not None and not interrupted else None, net, history, interrupted, seconds)

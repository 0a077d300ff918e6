"""Adapting a trained model to the user's own collection, without labels (issue 32, a first version).

The training is unsupervised, so a category model can go on learning on the shapes it is asked
about. :func:`adapt` continues the second training stage (:mod:`primkit.model.training`: the
coverage and consistency losses, existence sampled from the network's probabilities and learned by
REINFORCE with the parsimony reward of the model's own training) on the given shapes, from the
parent's weights, and returns a new :class:`~primkit.model.abstractor.Abstractor` whose part ``k``
is still the parent's part ``k`` (nothing renumbers the slots; how far the answer moves is measured
by :func:`index_agreement`).

Status: experimental, off by default (``primkit adapt``, ``--adapt [STEPS]`` on the commands that
abstract, ``abstract_shapes(..., adapt=)``, ``Segmenter(..., adapt=)``). On the 10 COSEG chairs in ``../shared``, paper protocol, face accuracy: the
parent 0.908; 600 steps without the pull 0.876 (every setting without it lowered it); with the
pull toward the parent's answer (``pull=1``, the default) 0.918, no chair lower than the parent's
by more than 0.001, 97.6% of surface samples keeping their part index (``docs/frames-and-parts.md``,
section "Adaptation"; chosen on those same 10 chairs).

Design:

* the shapes are first turned into the frame the parent finds (``align="auto"``), so that they are
  adapted in the model's canonical frame;
* every weight moves (``weights="all"``; or only the four part heads, or only the three shape
  heads), with Adam at ``learning_rate`` (1e-4: a tenth of the training's), and an optional pull
  toward the parent's answer on the same batch: ``pull`` times the mean over shapes of
  ``sum_k p0_k (||t_k - t0_k||^2 + ||z_k - z0_k||^2) + BCE(p_k, p0_k)`` (``t`` translations,
  ``z`` half extents, ``p`` existence probabilities; ``0`` the parent's);
* batch normalisation keeps the parent's statistics (its layers stay in evaluation mode), so a
  small collection does not re-normalise the features every other shape was explained with
  (``batch_norm="train"`` gave the same figures on the COSEG chairs, to 4 decimals);
* deterministic under ``seed`` with a fixed thread count (batches and existence draws come from
  one seeded generator).
"""

from __future__ import annotations

import copy
import hashlib
from dataclasses import asdict, dataclass

import numpy as np
import torch

from .abstractor import Abstractor
from .losses import LossWeights, MovingBaseline, reinforce_surrogate, shape_losses

__all__ = ["AdaptConfig", "adapt", "collection_digest", "index_agreement"]


@dataclass(frozen=True)
class AdaptConfig:
    """Settings of :func:`adapt` (recorded in the adapted model's metadata)."""

    steps: int = 600
    batch_size: int = 16
    learning_rate: float = 1e-4
    points_per_shape: int = 1000
    samples_per_cuboid: int = 150
    pull: float = 1.0
    weights: str = "all"  # "all", "heads" (the four part heads) or "shape-heads" (not the existence head)
    batch_norm: str = "frozen"
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


def collection_digest(shapes) -> str:
    """SHA-256 (hex, 16 characters) of the shapes' occupancy grids, in order: names the collection
    an adapted model was fitted to."""
    h = hashlib.sha256()
    for s in shapes:
        h.update(np.packbits(np.asarray(s.occupancy, bool)).tobytes())
    return h.hexdigest()[:16]


class _Batches:
    """Random batches of prepared shapes held in memory, as :meth:`primkit.model.training.ShapeTensors.batch`
    draws them (the same layout: closest points planar in memory). Written here rather than
    imported so that inference (``abstract_shapes(..., adapt=N)``) never imports the training module."""

    def __init__(self, shapes):
        n = min(len(s.points) for s in shapes)
        self.occupancy = torch.from_numpy(np.stack([s.occupancy for s in shapes]).astype(np.float32))
        planar = np.stack([np.moveaxis(np.asarray(s.closest, np.float32), -1, 0) for s in shapes])
        self.closest = torch.from_numpy(planar).permute(0, 2, 3, 4, 1)
        self.points = torch.from_numpy(np.stack([s.points[:n] for s in shapes]).astype(np.float32))

    def __len__(self) -> int:
        return len(self.occupancy)

    def batch(self, index, points_per_shape: int, generator: torch.Generator):
        occ = self.occupancy.index_select(0, index).unsqueeze(1)
        closest = self.closest.permute(0, 4, 1, 2, 3).index_select(0, index).permute(0, 2, 3, 4, 1)
        pick = torch.randint(0, self.points.shape[1], (len(index), points_per_shape), generator=generator)
        return occ, closest, torch.gather(self.points[index], 1, pick[..., None].expand(-1, -1, 3))


def _freeze_batch_norm(net) -> None:
    for m in net.modules():
        if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
            m.eval()


def _steps(net, data, optimizer, generator, baseline, weights, parsimony, parent, config, progress) -> None:
    """The stage-2 steps of :func:`adapt` (as :func:`primkit.model.training.train`'s stage 2)."""
    from tqdm.auto import tqdm

    net.train()
    if config.batch_norm == "frozen":
        _freeze_batch_norm(net)
    for _ in tqdm(range(config.steps), desc="adapting", unit="step", disable=not progress):
        index = torch.randint(0, len(data), (config.batch_size,), generator=generator)
        occ, closest, pts = data.batch(index, config.points_per_shape, generator)
        pred = net(occ)
        u = torch.rand(pred.existence.shape, generator=generator)
        present = (u < pred.existence.detach()).to(pred.existence.dtype)
        losses = shape_losses(pred, present, pts, closest, weights, config.samples_per_cuboid)
        mean = losses.total.mean()
        b = baseline.value if baseline.value is not None else float(mean.detach())
        loss = mean + reinforce_surrogate(pred.existence_logits, present, losses.total, b, parsimony)
        baseline.update(float(mean.detach()))
        if config.pull:
            with torch.no_grad():
                ref = parent(occ)
            w = ref.existence
            move = ((pred.translations - ref.translations) ** 2).sum(-1) + ((pred.half_extents - ref.half_extents) ** 2).sum(-1)
            keep = torch.nn.functional.binary_cross_entropy(pred.existence, w, reduction="none")
            loss = loss + config.pull * ((w * move).sum(1) + keep.sum(1)).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    net.eval()


def adapt(model, shapes, config: AdaptConfig = AdaptConfig(), *, align: str | None = "auto",
          parent_name: str | None = None, progress: bool = False) -> Abstractor:
    """A copy of ``model`` whose network continued stage-2 training on ``shapes``, without labels.

    Parameters
    ----------
    model : Abstractor
        The parent (unchanged).
    shapes : list of primkit.data.PreparedShape
        The collection, as prepared (meshes, point clouds and voxel grids alike); turned here into
        the frame the parent finds for it (:meth:`Abstractor.orient` with ``align``).
    config : AdaptConfig
    align : str or None
        How the frames are found (:data:`primkit.model.orientation.ALIGN_MODES`); None or
        ``"none"``: as prepared.
    parent_name : str, optional
        How the parent is named in the new model's metadata (a bundled model's name, a file).
    progress : bool
        A tqdm bar over the steps.

    Returns
    -------
    Abstractor
        On the CPU, with the parent's metadata and an ``adaptation`` entry: the parent's name, the
        collection's size and :func:`collection_digest`, the settings and the seconds taken.
    """
    import time

    shapes = list(shapes)
    if not shapes:
        raise ValueError("no shapes to adapt to")
    t0 = time.perf_counter()
    turned = shapes if align in (None, "none") else model.orient(shapes, align)[0]
    data = _Batches(turned)
    training = (model.metadata.get("training") or {}).get("config") or {}
    weights = LossWeights(float(training.get("coverage_weight", 1.0)), float(training.get("consistency_weight", 1.0)),
                          float(training.get("symmetry_weight", 0.0)))
    parsimony = float(training.get("parsimony", 8e-5))
    net = copy.deepcopy(model.network).to("cpu")
    if config.weights not in ("all", "heads", "shape-heads"):
        raise ValueError(f"AdaptConfig.weights must be 'all', 'heads' or 'shape-heads', got {config.weights!r}")
    if config.batch_norm not in ("frozen", "train"):
        raise ValueError(f"AdaptConfig.batch_norm must be 'frozen' or 'train', got {config.batch_norm!r}")
    if config.weights != "all":  # the encoder keeps the parent's features; only the part heads move
        heads = ("half_extent_head", "quaternion_head", "translation_head")
        heads += ("existence_head",) if config.weights == "heads" else ()  # "shape-heads": existence kept
        for name, p in net.named_parameters():
            p.requires_grad_(name.split(".")[0] in heads)
    parent = copy.deepcopy(net).eval() if config.pull else None  # the parent's answers, for the pull
    optimizer = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=config.learning_rate)
    generator = torch.Generator().manual_seed(config.seed)
    baseline = MovingBaseline(float(training.get("baseline_momentum", 0.9)))
    with torch.random.fork_rng(devices=[]):  # the caller's random state comes back afterwards
        torch.manual_seed(config.seed)  # the cuboid surface samples of the losses
        _steps(net, data, optimizer, generator, baseline, weights, parsimony, parent, config, progress)
    meta = copy.deepcopy(model.metadata)
    meta["adaptation"] = {
        "parent": parent_name or meta.get("name") or "unnamed",
        "parent_adaptation": model.metadata.get("adaptation"),
        "shapes": len(shapes),
        "digest": collection_digest(shapes),
        "config": config.to_dict(),
        "seconds": round(time.perf_counter() - t0, 1),
        "labels_used": False,
    }
    return Abstractor(net, meta, device="cpu")


def index_agreement(parent_results, adapted_results, shapes) -> float:
    """Fraction of the shapes' surface samples whose nearest present part has the same index under
    the parent's and the adapted model's cuboids (canonical frames; results of ``predict`` on the
    same ``shapes``, in order): 1 when adaptation renumbered nothing and moved no boundary."""
    from .. import primitives

    same = total = 0
    for a, b, s in zip(parent_results, adapted_results, shapes):
        pts = a.canonical_shape(s).points
        la = primitives.assign_points(pts, a.canonical)
        lb = primitives.assign_points(b.canonical_shape(s).points, b.canonical)
        same += int((la == lb).sum())
        total += len(pts)
    return same / max(total, 1)


def save_adapted(abstractor: Abstractor, path, *, overwrite: bool = False):
    """Write an adapted model (safetensors + JSON metadata, loadable by :meth:`Abstractor.load`)."""
    from . import modelfile

    return modelfile.save_model(path, abstractor.network.state_dict(), abstractor.metadata, overwrite=overwrite)

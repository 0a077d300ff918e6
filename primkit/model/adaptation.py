"""Adapting a trained model to the user's own collection, without labels (issue 32, a first version).

The training is unsupervised, so a category model can go on learning on the shapes it is asked
about. :func:`adapt` continues the second training stage (:mod:`primkit.model.training`: the
coverage and consistency losses, existence sampled from the network's probabilities and learned by
REINFORCE with the parsimony reward of the model's own training) on the given shapes, from the
parent's weights, and returns a new :class:`~primkit.model.abstractor.Abstractor` whose part ``k``
is still the parent's part ``k`` (nothing renumbers the slots; how far the answer moves is measured
by :func:`index_agreement`).

Status: experimental, not run unless asked (``primkit adapt``, ``--adapt [STEPS]`` on the commands that
abstract, ``abstract_shapes(..., adapt=)``, ``Segmenter(..., adapt=)``). On the 10 COSEG chairs in
``../shared``, paper protocol, face accuracy with the nearest labelling: the parent 0.908; 600 steps
without the pull 0.876 (every setting without it lowered it); with the pull toward the parent's
answer (``pull=1``, the default) 0.918, no chair lower than the parent's by more than 0.001, 97.6%
of surface samples keeping their part index (chosen on those same 10 chairs, by the first version,
which ran the parent every step). With today's defaults (the graph-cut labelling, 200 steps for 10
shapes): 0.944 without, 0.945 with adaptation (``docs/adaptation.md``).

Design:

* the shapes are first turned into the frame the parent finds (``align="auto"``), so that they are
  adapted in the model's canonical frame; in the same pass (``chunk`` shapes decoded at a time) the
  parent's answer for each turned shape is computed once, in evaluation mode: the pull's target,
  fixed because the inputs are never augmented;
* batches are read from the cache at each step and turned by each shape's rotation (only the
  rotations and the parent's answers are kept), so memory is flat in the collection's size;
* the number of steps follows the collection (:func:`default_steps`: each shape drawn about 40
  times, 200 to 600 steps) unless given;
* every weight moves (``weights="all"``; or only the four part heads, or only the three shape
  heads), with Adam at ``learning_rate`` (1e-4: a tenth of the training's), and an optional pull
  toward the parent's answer for the batch's shapes: ``pull`` times the mean over shapes of
  ``sum_k p0_k (||t_k - t0_k||^2 + ||z_k - z0_k||^2) + BCE(p_k, p0_k)`` (``t`` translations,
  ``z`` half extents, ``p`` existence probabilities; ``0`` the parent's);
* batch normalisation keeps the parent's statistics (its layers stay in evaluation mode), so a
  small collection does not re-normalise the features every other shape was explained with
  (``batch_norm="train"`` gave the same figures on the COSEG chairs, to 4 decimals);
* deterministic under ``seed`` with a fixed thread count (batches and existence draws come from
  one seeded generator);
* by default (``removal="outliers"``, :func:`_outlier_targets`), before the steps, a part leaves
  the pull's targets (existence target 0; every other cuboid stays the parent's) when the parent
  fits its shape more than ``removal_fit`` (4) times worse than the collection's first quartile,
  the part is unlike what its index is on the other shapes, those the parent explains well
  counting most (:func:`index_outliers`), and handing its samples to the other parts does not
  raise the shape's fit loss. Part indices keep their meaning: a real chair's duplicate leg box
  sits where that index sits on other chairs and stays; the chair model's back on a stool (a slab
  at the seat's height) and the boxes it puts on a stool's seat top (an index no chair uses) go.
  The existence pull moves the existence head only (``existence_pull_on="head"``, at 5e-2). About
  30 ms a shape; on the first 80 PartNet validation chairs mean back/seat/legs IoU 0.735 -> 0.736
  and arm F1 0.873 -> 0.873, and the chair model adapted to procedural stools and chairs drops its
  back on the stools (docs/adaptation.md);
* opt-in, :data:`LEAVE_ONE_OUT_RECIPE`: the parts each shape does without, judged by the fit loss
  once the other parts have taken over their samples and been re-fitted (:func:`_leave_one_out`),
  whatever their index means elsewhere. It also drops the back on the stools, but removes real
  chairs' duplicate legs, arms and seats too (PartNet validation 0.735 -> 0.634) and costs about a
  second a shape.
"""

from __future__ import annotations

import copy
import hashlib
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch

from .. import geometry
from . import orientation
from .abstractor import Abstractor
from .losses import LossWeights, MovingBaseline, reinforce_surrogate, shape_losses

__all__ = ["AdaptConfig", "LEAVE_ONE_OUT_RECIPE", "ShapeSequence", "adapt", "collection_digest", "default_steps",
           "index_agreement", "index_outliers"]

#: Bounds and rate of :func:`default_steps`.
MIN_STEPS, MAX_STEPS, VISITS_PER_SHAPE = 200, 600, 40


def default_steps(count: int, batch_size: int = 16) -> int:
    """Steps of an adaptation to ``count`` shapes when none are given: each shape drawn about
    ``VISITS_PER_SHAPE`` (40) times, within [200, 600]. 20 meshes get 200 steps, the 219 PartNet
    validation chairs 548, 1,000 grids 600 (the first version's fixed count). Chosen for time (a
    step is 50-150 ms on one thread of the shared 2-core machine) and checked on accuracy: the 10
    COSEG chairs adapted with 200 steps (docs/adaptation.md)."""
    return int(min(MAX_STEPS, max(MIN_STEPS, -(-VISITS_PER_SHAPE * int(count) // int(batch_size)))))


@dataclass(frozen=True)
class AdaptConfig:
    """Settings of :func:`adapt` (recorded in the adapted model's metadata)."""

    steps: int | None = None  # None: scaled to the collection (:func:`default_steps`)
    batch_size: int = 16
    learning_rate: float = 1e-4
    points_per_shape: int = 1000
    samples_per_cuboid: int = 150
    pull: float = 1.0
    existence_pull: float = 1.0  # weight of the existence term within the pull (0: existence moves freely)
    existence: str = "reinforce"  # how existence learns: "reinforce" (the training's) or "effect" (see adapt)
    existence_learning_rate: float | None = 5e-2  # the existence head's own rate; None: ``learning_rate``
    parsimony: float | None = None  # the REINFORCE reward per part dropped; None: the parent's training's
    parent_pass: str = "once"  # the parent's answers computed "once" per shape, or on "every-step"'s batch
    # leave-one-out on the parent's answers (_leave_one_out): a present part whose removal (its samples
    # handed to the other parts, re-fitted) raises the shape's fit loss by less than this share of
    # that loss is dropped from the pull's target; None or 0: off
    leave_one_out: float | None = None
    leave_one_out_rounds: int = 8  # parts dropped one at a time, at most this many a shape
    leave_one_out_refit: int = 30  # Adam steps re-fitting the kept parts of each variant before it is judged
    existence_pull_on: str = "head"  # the existence pull's gradient: "network" (all weights) or "head"
    # the pull's targets without the parts that are unlike their index and that the shape does without
    # (_outlier_targets): "outliers" (the default) or "none"; with pull=0 or parent_pass="every-step"
    # there are no targets to edit and nothing is removed
    removal: str = "outliers"
    removal_cost: float = 0.0  # cheap: handing the part's samples over raises the fit by at most this share
    removal_fit: float = 4.0  # only on shapes the parent fits this many times worse than the first quartile
    outlier_reach: float = 0.15  # index_outliers' thresholds (canonical frame, the longest side 1)
    outlier_support: float = 0.1
    weights: str = "all"  # "all", "heads" (the four part heads) or "shape-heads" (not the existence head)
    batch_norm: str = "frozen"
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


#: The settings with which the chair model, adapted to a few procedural stools and chairs, drops its
#: back on the stools and gives them the chairs' seat index (``AdaptConfig(**LEAVE_ONE_OUT_RECIPE)``;
#: ``tests/model/test_adaptation.py``). Not the default: on real chairs it removes duplicate legs
#: and other parts too, and costs about a second a shape (docs/adaptation.md).
LEAVE_ONE_OUT_RECIPE = {"leave_one_out": 0.2, "existence_pull_on": "head", "existence_learning_rate": 5e-2}


def collection_digest(shapes) -> str:
    """SHA-256 (hex, 16 characters) of the shapes' occupancy grids, in order: names the collection
    an adapted model was fitted to."""
    h = hashlib.sha256()
    for s in shapes:
        h.update(np.packbits(np.asarray(s.occupancy, bool)).tobytes())
    return h.hexdigest()[:16]


class ShapeSequence:
    """Prepared shapes read when asked for: ``get(i)`` for ``i`` in ``range(count)``. What
    :func:`adapt` streams from when the inputs of a run mix cached files and shapes in memory."""

    def __init__(self, count: int, get):
        self._count, self._get = int(count), get

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, i: int):
        return self._get(int(i))


class _Stream:
    """Random batches of the collection, turned into the frames found for it, read on demand.

    Nothing but each shape's rotation is kept: a :class:`primkit.data.PreparedCollection` is read
    from its cache's memory-mapped rows at each batch (:meth:`~primkit.data.PreparedCollection.gather`,
    closest points decoded by :func:`primkit.geometry.decode_closest`), a list of prepared shapes is
    read where it lies, and each batch is turned by its shapes' axis rotations (cells move with
    their centres, exactly as :func:`primkit.model.orientation.rotate_prepared` turns a shape). So
    memory is flat in the collection's size. Written here rather than importing
    :class:`primkit.model.training.ShapeTensors` so that inference (``abstract_shapes(..., adapt=N)``)
    never imports the training module, and because the batches are turned."""

    def __init__(self, shapes, rotations: np.ndarray):
        self.shapes = shapes
        self.rotations = np.asarray(rotations, float)  # (s, 3, 3)
        self.collection = hasattr(shapes, "gather") and hasattr(shapes, "settings")
        if self.collection:
            self.resolution, self.samples = shapes.settings.resolution, shapes.settings.samples
        else:
            self.resolution = shapes[0].resolution
            self.samples = min(len(s.points) for s in shapes)
        self._cells: dict = {}

    def __len__(self) -> int:
        return len(self.rotations)

    def _source(self, a: np.ndarray):
        """Flat index (R^3,) of the old cell whose value lands in each new cell; None for no turn."""
        key = tuple(np.rint(a).astype(int).ravel())
        if key not in self._cells:
            if np.allclose(a, np.eye(3)):
                self._cells[key] = None
            else:
                i, j, k = orientation._source_cells(self.resolution, a)
                self._cells[key] = (i * self.resolution + j) * self.resolution + k
        return self._cells[key]

    def batch(self, index, points_per_shape: int, generator: torch.Generator):
        """Occupancy (B, 1, R, R, R), closest points (B, R, R, R, 3) and (B, k, 3) random surface samples.

        The closest points are built coordinate-planar ((B, 3, R^3), as the cache stores them and
        :func:`primkit.geometry.decode_closest` returns them with ``planar=True``) and handed over as
        a channels-last view of that memory: what the losses read, with no transposing copy. A turned
        shape's cells are gathered by one flat index (an axis rotation moves whole cells)."""
        res = self.resolution
        cells = res**3
        index = np.asarray(index)
        pick = torch.randint(0, self.samples, (len(index), points_per_shape), generator=generator).numpy()
        if self.collection:
            occ, codes, near, pts = self.shapes.gather(index, pick)
            planar = (np.asarray(codes, np.float32) if near is None
                      else geometry.decode_closest(codes, near, res, planar=True))  # (B, 3, R^3)
        else:
            block = [self.shapes[i] for i in index]
            occ = np.stack([s.occupancy for s in block])
            planar = np.stack([np.asarray(s.closest, np.float32).reshape(cells, 3).T for s in block])
            pts = np.stack([np.asarray(s.points, np.float32)[p] for s, p in zip(block, pick)])
        occ_out = np.asarray(occ, np.float32).reshape(len(index), 1, cells)
        planar = np.ascontiguousarray(planar, np.float32).reshape(len(index), 3, cells)
        pts = np.ascontiguousarray(pts, np.float32)
        for b, i in enumerate(index):
            src = self._source(self.rotations[i])
            if src is not None:
                a = self.rotations[i].astype(np.float32)
                occ_out[b, 0] = occ_out[b, 0][src]
                planar[b] = a @ planar[b][:, src]
                pts[b] = pts[b] @ a.T
        occ_t = torch.from_numpy(occ_out.reshape(len(index), 1, res, res, res))
        closest_t = torch.from_numpy(planar.reshape(len(index), 3, res, res, res)).permute(0, 2, 3, 4, 1)
        return occ_t, closest_t, torch.from_numpy(pts)


def _freeze_batch_norm(net) -> None:
    for m in net.modules():
        if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
            m.eval()


@dataclass
class _ParentAnswers:
    """The parent's answer for every shape of the collection (its own frame), fixed: (s, m, 3)
    translations and half extents, (s, m) existence probabilities."""

    translations: torch.Tensor
    half_extents: torch.Tensor
    existence: torch.Tensor
    quaternions: torch.Tensor | None = None


def _steps(net, data, optimizer, generator, baseline, weights, parsimony, parent, answers, config, progress) -> None:
    """The stage-2 steps of :func:`adapt` (as :func:`primkit.model.training.train`'s stage 2)."""
    from tqdm.auto import tqdm

    net.train()
    if config.batch_norm == "frozen":
        _freeze_batch_norm(net)
    features = {}
    hook = None
    if config.existence_pull_on == "head":  # the encoder's output, for the existence head alone
        hook = net.encoder.register_forward_hook(lambda module, args, out: features.__setitem__("h", out))
    for _ in tqdm(range(config.steps), desc="adapting", unit="step", disable=not progress):
        index = torch.randint(0, len(data), (config.batch_size,), generator=generator)
        occ, closest, pts = data.batch(index.numpy(), config.points_per_shape, generator)
        pred = net(occ)
        u = torch.rand(pred.existence.shape, generator=generator)
        present = (u < pred.existence.detach()).to(pred.existence.dtype)
        effect = config.existence == "effect"
        losses = shape_losses(pred, present, pts, closest, weights, config.samples_per_cuboid, presence_effects=effect)
        mean = losses.total.mean()
        if effect:
            # each part's own effect on the fit, loss(present) - loss(absent) with the other parts as
            # drawn, plus the parsimony reward, taken on the logit itself: a sure part (p = 1.000, as
            # the parent's back is on every stool) is never drawn absent, so neither REINFORCE nor
            # the training's local gradient (through the sigmoid, times p (1 - p)) can lower it
            # (bounded: a part stops being pushed once its probability has gone past 0.02 or 0.98)
            adv = (losses.presence_effect + parsimony).detach()
            p = pred.existence.detach()
            gate = torch.where(adv > 0, p > 0.02, p < 0.98).to(adv.dtype)
            loss = mean + (gate * adv * pred.existence_logits).sum(1).mean()
        else:
            b = baseline.value if baseline.value is not None else float(mean.detach())
            loss = mean + reinforce_surrogate(pred.existence_logits, present, losses.total, b, parsimony)
            baseline.update(float(mean.detach()))
        if config.pull:
            if answers is not None:  # the parent's answers, computed once (the input is never augmented)
                ref_t, ref_z, w = (answers.translations[index], answers.half_extents[index], answers.existence[index])
            else:  # the straightforward way: the parent's network run again on the batch
                with torch.no_grad():
                    ref = parent(occ)
                ref_t, ref_z, w = ref.translations, ref.half_extents, ref.existence
            move = ((pred.translations - ref_t) ** 2).sum(-1) + ((pred.half_extents - ref_z) ** 2).sum(-1)
            if config.existence_pull_on == "head":
                # the existence target moves the existence head only: its cross-entropy, through the
                # encoder, outweighs the fit's gradients wherever the target differs from the
                # network's answer, and Adam's normalised steps then move every part's cuboid
                logits = net.head_scales[1].to(w.dtype) * net.existence_head(features["h"].detach())
                keep = torch.nn.functional.binary_cross_entropy_with_logits(logits, w, reduction="none")
            else:
                keep = torch.nn.functional.binary_cross_entropy(pred.existence, w, reduction="none")
            loss = loss + config.pull * ((w * move).sum(1) + config.existence_pull * keep.sum(1)).mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
    if hook is not None:
        hook.remove()
    net.eval()


def _handed_over(local, z, t, rot, present, k1, k2, k):
    """Shape geometry with part ``k`` removed and its samples handed to their next-nearest present
    part, each heir grown (one-sidedly, in its own frame) to the smallest box holding its old box
    and the samples it takes over: (B, m, 3) half extents and translations, (B, m) presence.

    ``local`` (B, m, n, 3) the samples in every cuboid's frame, ``k1``/``k2`` (B, n) each sample's
    nearest and next-nearest present part."""
    m = z.shape[1]
    taken = (k1 == k)[:, None, :] & (k2[:, None, :] == torch.arange(m)[None, :, None])  # (B, m, n)
    lo = torch.where(taken[..., None], local, torch.inf).amin(2).minimum(-z)
    hi = torch.where(taken[..., None], local, -torch.inf).amax(2).maximum(z)
    centre = (hi + lo) / 2  # the heir's new centre, in its own frame (0 where it took nothing)
    out = present.clone()
    out[:, k] = False
    return (hi - lo) / 2, t + (rot @ centre[..., None])[..., 0], out


def _refit(z, q, t, present, pts, closest, weights, config):
    """(C,) fit loss (coverage + consistency) of each variant after ``leave_one_out_refit`` Adam
    steps on its present cuboids' translations and half extents (rotations held), and those cuboids."""
    from .network import PrimitivePrediction

    pres = present.to(z.dtype)
    steps = config.leave_one_out_refit
    with torch.enable_grad():
        z, t = z.clone().requires_grad_(steps > 0), t.clone().requires_grad_(steps > 0)
        opt = torch.optim.Adam([t, z], lr=LEAVE_ONE_OUT_RATE) if steps else None
        for i in range(steps + 1):
            g = torch.Generator().manual_seed(config.seed)  # the same cuboid samples at every step
            pred = PrimitivePrediction(z.clamp_min(1e-4), q, t, pres)
            total = shape_losses(pred, pres, pts, closest, weights, config.samples_per_cuboid, generator=g).total
            if i == steps:
                break
            opt.zero_grad()
            total.sum().backward()
            opt.step()
    return total.detach(), z.detach().clamp_min(1e-4), t.detach()


#: Adam's rate for the re-fits of :func:`_leave_one_out` (units: the shape's longest side is 1).
LEAVE_ONE_OUT_RATE = 0.01
#: A part is re-fitted without it only when the hand-over alone costs less than this many times the
#: shape's fit loss; above, it is kept (a chair's legs cost 2.6-4.2 times, its back 7-15 times,
#: a stool's back-slab 0.06-1.05 times, on the procedural shapes of the test).
LEAVE_ONE_OUT_DOUBT = 2.0


def _leave_one_out(answers, data, weights, config) -> tuple[_ParentAnswers, np.ndarray]:
    """The parent's answers without the parts each shape does without: the pull's targets.

    For each shape, from the parent's present parts (existence over 0.5) and its cuboids:

    1. parts nearest to no surface sample (they cover nothing) are removed;
    2. each present part ``k`` is judged by its *worth*: the rise of the shape's fit loss (coverage +
       consistency with the training's weights, on ``points_per_shape`` samples) from the answer
       with it to the answer without it, the other parts allowed to take over its samples (each
       sample goes to its next-nearest present part, grown to hold it, :func:`_handed_over`; then
       ``leave_one_out_refit`` Adam steps re-fit every kept cuboid's translation and half extents,
       as they do the answer with it). Only parts whose worth after the hand-over alone is below
       :data:`LEAVE_ONE_OUT_DOUBT` times the shape's fit loss are re-fitted (the others are kept: a
       chair's back or legs cost several times the shape's loss to hand over);
    3. of the parts worth less than ``config.leave_one_out`` times the shape's re-fitted loss, the
       one nearest to the fewest samples is removed (with its heirs' re-fitted cuboids), and the
       others are judged again, at most ``leave_one_out_rounds`` times.

    In the returned targets a removed part has existence 0 and the shape's cuboids are the re-fitted
    ones; shapes without a removal are untouched. Also returns (s,) the parts removed a shape.

    Why: the parent gives parts a sure probability on shapes that do not have them (the chair model's
    back on a stool: a slab at the seat's rear edge, p = 1.000). The training's own existence signals
    (REINFORCE, or each part's effect with the others held) never see it absent, or see the samples
    it covers left to nothing; judged with the others allowed to take them over, it is worth
    nothing on a stool and a great deal on a chair (the seat would have to grow up to the back's top).
    """
    from .. import primitives

    count, m = answers.existence.shape
    t_all, z_all, p_all = answers.translations.clone(), answers.half_extents.clone(), answers.existence.clone()
    removed = np.zeros(count, int)
    generator = torch.Generator().manual_seed(config.seed)
    share_of_loss = float(config.leave_one_out)
    for lo in range(0, count, 32):
        index = np.arange(lo, min(count, lo + 32))
        _, closest, pts = data.batch(index, config.points_per_shape, generator)
        z, t, q = z_all[index].clone(), t_all[index].clone(), answers.quaternions[index]
        present = p_all[index] > 0.5
        rot = primitives.quaternion_to_matrix_torch(q)  # (B, m, 3, 3)
        with torch.no_grad():
            for round_ in range(config.leave_one_out_rounds):
                local = (pts[:, None, :, :] - t[:, :, None, :]) @ rot  # R^T (x - t), (B, m, n, 3)
                d2 = ((local.abs() - z[:, :, None, :]).clamp_min(0) ** 2).sum(-1)
                masked = d2.masked_fill(~present[:, :, None], torch.inf)
                k1 = masked.argmin(1)
                share = torch.nn.functional.one_hot(k1, m).sum(1)  # (B, m) samples nearest to each part
                if round_ == 0:  # parts that cover nothing go at once (what predict's pruning does)
                    idle = present & (share == 0) & (present.sum(1, keepdim=True) > 1)
                    removed[index] += idle.sum(1).numpy()
                    present &= ~idle
                    masked = masked.masked_fill(idle[:, :, None], torch.inf)
                k2 = masked.scatter(1, k1[:, None, :], torch.inf).argmin(1)
                base, _, _ = _refit(z, q, t, present, pts, closest, weights, replace(config, leave_one_out_refit=0))
                variants = {k: _handed_over(local, z, t, rot, present, k1, k2, k) for k in range(m)
                            if present[:, k].any()}
                worth = torch.full(present.shape, torch.inf)
                for k, (zk, tk, pk) in variants.items():
                    lk, _, _ = _refit(zk, q, tk, pk, pts, closest, weights, replace(config, leave_one_out_refit=0))
                    worth[:, k] = torch.where(present[:, k], lk - base, torch.inf)
                # re-fitted, batched over the (shape, part) pairs the hand-over alone leaves in doubt
                doubt = torch.isfinite(worth) & (worth < LEAVE_ONE_OUT_DOUBT * base[:, None])
                worth = torch.full(present.shape, torch.inf)
                lam = torch.zeros(len(index), 1)
                shapes_, parts_ = torch.nonzero(doubt, as_tuple=True)
                if len(shapes_):
                    who = torch.unique(shapes_)
                    zs = torch.cat([z[who]] + [variants[int(k)][0][b:b + 1] for b, k in zip(shapes_, parts_)])
                    ts = torch.cat([t[who]] + [variants[int(k)][1][b:b + 1] for b, k in zip(shapes_, parts_)])
                    ps = torch.cat([present[who]] + [variants[int(k)][2][b:b + 1] for b, k in zip(shapes_, parts_)])
                    rows = torch.cat([who, shapes_])
                    fit, zf, tf = _refit(zs, q[rows], ts, ps, pts[rows], closest[rows], weights, config)
                    lam[who, 0] = share_of_loss * fit[:len(who)]  # a share of the re-fitted fit loss
                    ref = dict(zip(who.tolist(), fit[:len(who)]))
                    for i, (b, k) in enumerate(zip(shapes_.tolist(), parts_.tolist())):
                        worth[b, k] = fit[len(who) + i] - ref[b]
                        variants[k][0][b], variants[k][1][b] = zf[len(who) + i], tf[len(who) + i]
                worth[present.sum(1) < 2] = torch.inf
                # of the parts worth less than the threshold, the one nearest to the fewest samples
                fewest, k = torch.where(worth < lam, share.to(worth.dtype), torch.inf).min(1)
                drop = torch.isfinite(fewest)
                if not drop.any():
                    break
                for b in torch.nonzero(drop).flatten().tolist():
                    zk, tk, pk = variants[int(k[b])]
                    z[b], t[b], present[b] = zk[b], tk[b], pk[b]
                    removed[index[b]] += 1
        for b, s in enumerate(index):
            if removed[s]:
                p_all[s, (p_all[s] > 0.5) & ~present[b]] = 0.0
                z_all[s], t_all[s] = z[b], t[b]
    return _ParentAnswers(t_all, z_all, p_all, answers.quaternions), removed


def _part_boxes(z, q, t) -> torch.Tensor:
    """(B, m, 2, 3) the lower and upper corners of each cuboid's axis-aligned bounding box, in the
    shape's (canonical) frame: where a part sits and how far it reaches, whatever its rotation."""
    from .. import primitives

    corners = torch.tensor([[x, y, w] for x in (-1, 1) for y in (-1, 1) for w in (-1, 1)], dtype=z.dtype)
    rot = primitives.quaternion_to_matrix_torch(q)  # (B, m, 3, 3), columns the part's axes
    world = t[:, :, None] + (rot[:, :, None] @ (corners[None, None] * z[:, :, None])[..., None])[..., 0]
    return torch.stack([world.amin(2), world.amax(2)], 2)


#: At most this many shapes (evenly spaced) speak for what an index means in :func:`index_outliers`.
REFERENCE_SHAPES = 2000


def index_outliers(boxes: np.ndarray, present: np.ndarray, fit: np.ndarray, *, reach: float = 0.15,
                   support: float = 0.1) -> np.ndarray:
    """(s, m) bool: where part ``k`` of shape ``s`` is unlike what index ``k`` is on the other shapes,
    those the parent explains well counting most.

    Parameters
    ----------
    boxes : (s, m, 2, 3) float
        Each part's axis-aligned bounding box (lower and upper corner) in the canonical frame
        (units: the shape's longest side is 1).
    present : (s, m) bool
        The parent's present parts.
    fit : (s,) float
        The parent's fit loss on each shape (coverage + consistency; > 0).
    reach, support
        The thresholds below.

    Each shape ``s'`` speaks for what its indices mean with weight ``w = min(1, q / fit)``, ``q``
    the collection's first quartile of the fit: a shape the parent explains as well as a quarter of
    the collection counts fully, one fitted ``c`` times worse counts ``1 / c`` (on the procedural
    stools of the tests the parent's fit is 5-25 times the chairs'). The *support* of part ``k``
    on shape ``s`` is the weight of the other shapes on which index ``k`` is present with each of
    its box's six coordinates within ``reach`` of this one's, over the weight of all the other
    shapes (in a collection of more than :data:`REFERENCE_SHAPES`, of that many evenly spaced).
    The part is an outlier when its support is under ``support``: index ``k`` is seldom there, or seldom anything like this, where the parent explains shapes well. Several modes are
    fine (legs at different places on different chairs each find their like); a chair model's back
    on a stool, a slab at the seat's height, finds none among the chairs' tall backs.
    """
    boxes = np.asarray(boxes, float)
    present = np.asarray(present, bool)
    count, m = present.shape
    if boxes.shape != (count, m, 2, 3):
        raise ValueError(f"`boxes` must be (s, m, 2, 3) float to go with `present` {present.shape}, got {boxes.shape}")
    fit = np.maximum(np.asarray(fit, float).reshape(count), 1e-12)
    w = np.minimum(1.0, np.quantile(fit, 0.25) / fit)
    # the shapes that speak: all of them, or REFERENCE_SHAPES evenly spaced in a larger collection
    # (the pairs are what this costs: O(s * reference * m))
    ref = np.unique(np.linspace(0, count - 1, min(count, REFERENCE_SHAPES)).round().astype(int))
    in_ref = np.zeros(count, bool)
    in_ref[ref] = True
    others = w[ref].sum() - np.where(in_ref, w, 0.0)  # (s,) the weight of the other shapes that speak
    flat = boxes.reshape(count, m, 6)
    out = np.zeros((count, m), bool)
    for k in range(m):
        on = np.flatnonzero(present[:, k])
        peers = ref[present[ref, k]]
        for lo in range(0, len(on), 1024):  # (1024, reference) booleans at a time
            rows = on[lo:lo + 1024]
            near = np.ones((len(rows), len(peers)), bool)
            for c in range(6):  # one coordinate at a time, not a (rows, peers, 6) stack
                near &= np.abs(flat[rows, k, c][:, None] - flat[peers, k, c][None, :]) <= reach
            near &= rows[:, None] != peers[None, :]  # not itself
            mass = near.astype(float) @ w[peers]
            out[rows, k] = mass < support * np.maximum(others[rows], 1e-12)
    return out


def _outlier_targets(answers, data, weights, config) -> tuple[_ParentAnswers, np.ndarray]:
    """The parent's answers without the parts that are unlike their index and that the shape does
    without: the pull's targets (``AdaptConfig.removal="outliers"``, the default).

    1. On each shape, from the parent's answer (existence over 0.5) and ``points_per_shape`` samples
       (32 shapes at a time, read again for step 3 where needed, the samples seeded by ``seed`` and
       the block: nothing else is kept): the fit loss (coverage + consistency, the training's weights) and each
       part's bounding box (:func:`_part_boxes`);
    2. the parts :func:`index_outliers` finds unlike what their index is on the other shapes (those
       the parent explains well counting most), kept only on the shapes the parent fits more than
       ``removal_fit`` times worse than the collection's first quartile: where it extrapolates;
    3. per shape, of those parts, the ones whose removal (their samples handed to their next-nearest
       present part, grown to hold them, :func:`_handed_over`; no re-fit) raises the fit loss by less
       than ``removal_cost`` times the shape's fit loss (0: does not raise it at all) are *cheap*;
       the cheap one nearest to the fewest samples goes and the rest are judged again, at most
       ``leave_one_out_rounds`` times, never below one part.

    A removed part gets existence target 0; every other part keeps the parent's cuboid as its
    target (the hand-over only judges the removal: taken as the target, the grown heirs, a seat
    stretched down over a leg's samples, cost 0.05 of mean IoU on PartNet chairs, docs/adaptation.md).
    Also returns (s,) the number of parts removed a shape. Cost: one loss evaluation per shape, and
    one per round and outlier part on the shapes that have outliers; no re-fit.
    """
    from .. import primitives

    count, m = answers.existence.shape
    t_all, z_all, q_all = answers.translations, answers.half_extents, answers.quaternions
    p_all = answers.existence.clone()
    removed = np.zeros(count, int)
    plain = replace(config, leave_one_out_refit=0)

    def block(lo):  # shapes lo.. lo + 31 and their samples, the same each time they are read
        index = np.arange(lo, min(count, lo + 32))
        _, closest, pts = data.batch(index, config.points_per_shape, torch.Generator().manual_seed(config.seed + lo))
        return index, closest, pts

    fit = np.empty(count)
    for lo in range(0, count, 32):  # nothing kept but the losses: memory flat in the collection's size
        index, closest, pts = block(lo)
        base, _, _ = _refit(z_all[index], q_all[index], t_all[index], p_all[index] > 0.5, pts, closest, weights, plain)
        fit[index] = base.numpy()
    boxes = _part_boxes(z_all, q_all, t_all).numpy()
    odd = index_outliers(boxes, p_all.numpy() > 0.5, fit, reach=config.outlier_reach, support=config.outlier_support)
    odd &= (fit > config.removal_fit * np.quantile(fit, 0.25))[:, None]  # only where the parent extrapolates
    for lo in range(0, count, 32):
        if not odd[lo:lo + 32].any():
            continue
        index, closest, pts = block(lo)  # read again, for the shapes with outliers
        rows = odd[index].any(1)
        index, closest, pts = index[rows], closest[torch.from_numpy(rows)], pts[torch.from_numpy(rows)]
        doubt = torch.from_numpy(odd[index])
        z, t, q = z_all[index], t_all[index], q_all[index]
        present = p_all[index] > 0.5
        rot = primitives.quaternion_to_matrix_torch(q)
        local = (pts[:, None, :, :] - t[:, :, None, :]) @ rot  # R^T (x - t), (B, m, n, 3)
        d2 = ((local.abs() - z[:, :, None, :]).clamp_min(0) ** 2).sum(-1)
        with torch.no_grad():
            for _round in range(config.leave_one_out_rounds):
                masked = d2.masked_fill(~present[:, :, None], torch.inf)
                k1 = masked.argmin(1)
                k2 = masked.scatter(1, k1[:, None, :], torch.inf).argmin(1)
                share = torch.nn.functional.one_hot(k1, m).sum(1)  # (B, m) samples nearest to each part
                base, _, _ = _refit(z, q, t, present, pts, closest, weights, plain)
                cost = torch.full(present.shape, torch.inf)
                for k in torch.nonzero((doubt & present).any(0)).flatten().tolist():
                    zk, tk, pk = _handed_over(local, z, t, rot, present, k1, k2, k)
                    lk, _, _ = _refit(zk, q, tk, pk, pts, closest, weights, plain)
                    cost[:, k] = torch.where(doubt[:, k] & present[:, k], lk - base, torch.inf)
                cost[present.sum(1) < 2] = torch.inf
                cheap = cost < config.removal_cost * base[:, None]
                fewest, k = torch.where(cheap, share.to(cost.dtype), torch.inf).min(1)
                drop = torch.nonzero(torch.isfinite(fewest)).flatten()
                if not len(drop):
                    break
                present[drop, k[drop]] = False
                doubt[drop, k[drop]] = False
                removed[index[drop.numpy()]] += 1
        for b, s in enumerate(index):
            p_all[s, (p_all[s] > 0.5) & ~present[b]] = 0.0
    return _ParentAnswers(t_all, z_all, p_all, q_all), removed


def _frames_and_answers(model, shapes, align, chunk: int, want_answers: bool):
    """The rotation :meth:`Abstractor.orient` chooses for each shape (``chunk`` shapes decoded at a
    time; ``"auto"`` votes its expected up axis within each chunk), the parent's answers on the
    turned shapes and the collection's digest. The answers are the search's own forward pass of
    each chosen turn (:meth:`Abstractor.search_orientations` with ``answers``: the turned grid is
    the network's input, so running it again gave the same answer); with no search, one forward
    pass per shape, in evaluation mode."""
    count = len(shapes)
    rotations = np.empty((count, 3, 3))
    digest = hashlib.sha256()
    t, z, p, q = [], [], [], []
    net = model.network
    was_training = net.training
    net.eval()
    try:
        for lo in range(0, count, chunk):
            block = [shapes[i] for i in range(lo, min(count, lo + chunk))]
            for s in block:
                digest.update(np.packbits(np.asarray(s.occupancy, bool)).tobytes())
            if align in (None, "none"):
                rotations[lo:lo + len(block)] = np.eye(3)
                if want_answers:
                    occ = torch.from_numpy(np.stack([s.occupancy for s in block]).astype(np.float32)).unsqueeze(1)
                    with torch.no_grad():
                        ref = net(occ.to(next(net.parameters()).device))
                    t.append(ref.translations.cpu())
                    z.append(ref.half_extents.cpu())
                    p.append(ref.existence.cpu())
                    q.append(ref.quaternions.cpu())
            else:
                found = model.search_orientations(block, align, answers=want_answers)
                rotations[lo:lo + len(block)] = orientation.AXIS_ROTATIONS[found.choice]
                if want_answers:  # float32 network outputs held as float64: exact both ways
                    t.append(torch.from_numpy(found.answers.translations.astype(np.float32)))
                    z.append(torch.from_numpy(found.answers.half_extents.astype(np.float32)))
                    p.append(torch.from_numpy(found.answers.existence.astype(np.float32)))
                    q.append(torch.from_numpy(found.answers.quaternions.astype(np.float32)))
            del block
    finally:
        net.train(was_training)
    answers = _ParentAnswers(torch.cat(t), torch.cat(z), torch.cat(p), torch.cat(q)) if want_answers else None
    return rotations, answers, digest.hexdigest()[:16]


#: Shapes (evenly spaced over the collection) on which :func:`adapt` measures the index agreement.
AGREEMENT_SHAPES = 200


def _nearest_parts(pred, i: int, points: np.ndarray) -> np.ndarray:
    """Nearest present part (existence > 0.5, no pruning) of each point under shape ``i``'s raw answer."""
    from .. import primitives

    exist = pred.existence[i].cpu().numpy() > 0.5
    if not exist.any():
        return np.full(len(points), -1)
    cuboids = primitives.Cuboids(np.maximum(pred.half_extents[i].cpu().numpy().astype(float), 1e-12),
                                 pred.quaternions[i].cpu().numpy().astype(float),
                                 pred.translations[i].cpu().numpy().astype(float), exist)
    return primitives.assign_points(points, cuboids)


def _stream_agreement(parent_net, child_net, data, count: int = AGREEMENT_SHAPES, points: int = 1000,
                      chunk: int = 32) -> tuple[float, int]:
    """``(agreement, shapes)``: the fraction of surface samples whose nearest present part has the
    same index under the parent's and the child's raw answers (each shape in the frame found for
    it; existence over 0.5, no pruning), on up to ``count`` shapes evenly spaced over ``data``.
    What :func:`index_agreement` measures on full results, taken here in one forward pass per
    shape and network so that every adaptation can record it."""
    n = len(data)
    which = np.unique(np.linspace(0, n - 1, min(n, count)).round().astype(int))
    generator = torch.Generator().manual_seed(0)
    same = total = 0
    for lo in range(0, len(which), chunk):
        index = which[lo:lo + chunk]
        occ, _, pts = data.batch(index, points, generator)
        with torch.no_grad():
            a = parent_net(occ.to(next(parent_net.parameters()).device))
            b = child_net(occ.to(next(child_net.parameters()).device))
        for i in range(len(index)):
            p = pts[i].numpy().astype(float)
            same += int((_nearest_parts(a, i, p) == _nearest_parts(b, i, p)).sum())
            total += len(p)
    return same / max(total, 1), len(which)


def adapt(model, shapes, config: AdaptConfig = AdaptConfig(), *, align: str | None = "auto",
          parent_name: str | None = None, progress: bool = False, chunk: int = 64) -> Abstractor:
    """A copy of ``model`` whose network continued stage-2 training on ``shapes``, without labels.

    Parameters
    ----------
    model : Abstractor
        The parent (unchanged).
    shapes : primkit.data.PreparedCollection or list of primkit.data.PreparedShape
        The collection, as prepared (meshes, point clouds and voxel grids alike); turned here into
        the frame the parent finds for it (:meth:`Abstractor.orient` with ``align``, ``chunk``
        shapes at a time). A collection is read from its cache at each batch, so memory does not
        grow with its size; a list is read where it lies.
    config : AdaptConfig
    align : str or None
        How the frames are found (:data:`primkit.model.orientation.ALIGN_MODES`); None or
        ``"none"``: as prepared.
    parent_name : str, optional
        How the parent is named in the new model's metadata (a bundled model's name, a file).
    progress : bool
        A tqdm bar over the steps.
    chunk : int
        Shapes decoded at once while the frames and the parent's answers are found.

    Returns
    -------
    Abstractor
        On the CPU, with the parent's metadata and an ``adaptation`` entry: the parent's name, the
        collection's size and :func:`collection_digest`, the settings, the seconds taken, and
        ``index_agreement``: the fraction of surface samples whose nearest present part keeps its
        index (parent against child, raw answers in the frames found, on up to
        :data:`AGREEMENT_SHAPES` shapes evenly spaced, ``agreement_shapes``).
    """
    import time

    if not len(shapes):
        raise ValueError("no shapes to adapt to")
    if config.weights not in ("all", "heads", "shape-heads"):
        raise ValueError(f"AdaptConfig.weights must be 'all', 'heads' or 'shape-heads', got {config.weights!r}")
    if config.batch_norm not in ("frozen", "train"):
        raise ValueError(f"AdaptConfig.batch_norm must be 'frozen' or 'train', got {config.batch_norm!r}")
    if config.existence not in ("reinforce", "effect"):
        raise ValueError(f"AdaptConfig.existence must be 'reinforce' or 'effect', got {config.existence!r}")
    if config.existence_pull_on not in ("network", "head"):
        raise ValueError(f"AdaptConfig.existence_pull_on must be 'network' or 'head', got {config.existence_pull_on!r}")
    if config.removal not in ("outliers", "none"):
        raise ValueError(f"AdaptConfig.removal must be 'outliers' or 'none', got {config.removal!r}")
    if config.leave_one_out and (not config.pull or config.parent_pass != "once"):
        raise ValueError("AdaptConfig.leave_one_out edits the pull's targets: it needs pull > 0 and parent_pass='once'")
    if config.parent_pass not in ("once", "every-step"):
        raise ValueError(f"AdaptConfig.parent_pass must be 'once' or 'every-step', got {config.parent_pass!r}")
    t0 = time.perf_counter()
    if config.steps is None:
        config = replace(config, steps=default_steps(len(shapes), config.batch_size))
    elif config.steps < 1:
        raise ValueError(f"AdaptConfig.steps must be at least 1, got {config.steps}")
    once = bool(config.pull) and config.parent_pass == "once"
    rotations, answers, digest = _frames_and_answers(model, shapes, align, chunk, once)
    data = _Stream(shapes, rotations)
    training = (model.metadata.get("training") or {}).get("config") or {}
    weights = LossWeights(float(training.get("coverage_weight", 1.0)), float(training.get("consistency_weight", 1.0)),
                          float(training.get("symmetry_weight", 0.0)))
    removed = None
    if config.leave_one_out and answers is not None:
        answers, removed = _leave_one_out(answers, data, weights, config)
    elif config.removal == "outliers" and answers is not None:
        answers, removed = _outlier_targets(answers, data, weights, config)
    parsimony = float(training.get("parsimony", 8e-5)) if config.parsimony is None else float(config.parsimony)
    net = copy.deepcopy(model.network).to("cpu")
    if config.weights != "all":  # the encoder keeps the parent's features; only the part heads move
        heads = ("half_extent_head", "quaternion_head", "translation_head")
        heads += ("existence_head",) if config.weights == "heads" else ()  # "shape-heads": existence kept
        for name, p in net.named_parameters():
            p.requires_grad_(name.split(".")[0] in heads)
    parent = copy.deepcopy(net).eval() if config.pull and not once else None
    moving = [(n, p) for n, p in net.named_parameters() if p.requires_grad]
    head = [p for n, p in moving if n.startswith("existence_head.")]
    rest = [p for n, p in moving if not n.startswith("existence_head.")]
    groups = [{"params": rest}]
    if head:
        groups.append({"params": head, "lr": config.existence_learning_rate or config.learning_rate})
    optimizer = torch.optim.Adam(groups, lr=config.learning_rate)
    generator = torch.Generator().manual_seed(config.seed)
    baseline = MovingBaseline(float(training.get("baseline_momentum", 0.9)))
    with torch.random.fork_rng(devices=[]):  # the caller's random state comes back afterwards
        torch.manual_seed(config.seed)  # the cuboid surface samples of the losses
        _steps(net, data, optimizer, generator, baseline, weights, parsimony, parent, answers, config, progress)
    was_training = model.network.training
    model.network.eval()
    try:
        agreement, agreement_shapes = _stream_agreement(model.network, net, data)
    finally:
        model.network.train(was_training)
    meta = copy.deepcopy(model.metadata)
    # the parent's semantic labeller (its tensors live in the parent's file, fitted on the parent's
    # features) does not come along: without this, a saved child named a labeller it lacked and
    # Segmenter(path) refused the file
    meta.pop("labeller", None)
    meta["adaptation"] = {
        "parent": parent_name or meta.get("name") or "unnamed",
        "parent_adaptation": model.metadata.get("adaptation"),
        "shapes": len(shapes),
        "digest": digest,
        "config": config.to_dict(),
        "seconds": round(time.perf_counter() - t0, 1),
        "index_agreement": round(agreement, 4),
        "parts_removed": None if removed is None else int(removed.sum()),  # from the pull's targets
        "agreement_shapes": agreement_shapes,
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

    return modelfile.write_model(path, abstractor.network.state_dict(), abstractor.metadata, overwrite=overwrite)

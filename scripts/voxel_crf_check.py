"""Labels that follow the voxel grid: a Potts energy over a grid's voxels after the labeller's
smoothing, tried on the PartNet validation chairs and **not adopted** (issue 33; docs/labeller.md,
"Voxels: a cut over the grid, tried").

Run from the repository root as a module, on the chairs that ``scripts.labeller_curve prepare``
cached (``chairs.npz``, ``chairs.json`` and ``features/`` in the scratch folder)::

    python -m scripts.voxel_crf_check --scratch /tmp/vcut-scratch --sizes 10,40 --draws 3

The protocol is ``labeller_curve curve --part validation``'s: labellers learn from validation
chairs 0-99 of the seed-0 shuffle (the first N of draw ``d``'s shuffle of them) and label
validation chairs 100-218; the test part is never read. Every chair's probabilities are computed
once per labeller (:func:`scripts.labeller_curve.grid_proba`: the trees, the index prior, the grid
fill), then labelled by each way below; the first is the library's (``Labeller.predict``), the
others minimise, over the voxels' labels ``l``,

    E(l) = sum_v -log max(p_v(l_v), 1e-3)  +  lam * sum_(v,w) weight_vw * mu_d(l_v, l_w)

with ``(v, w)`` the pairs of face-adjacent occupied voxels (6-neighbours; 26 with ``conn 26``,
edge and corner pairs weighing 1/sqrt 2 and 1/sqrt 3), ``p`` the probabilities after the
labeller's smoothing (two rounds over the 19 nearest voxels, or one), ``mu`` the Potts cost
``[l_v != l_w]`` or a cost learned per direction ``d`` (below), and the 1% rule applied as
:func:`primkit.segmentation.meshlabels.cut_faces` applies it (a label under 1% of the voxels is
dropped and the labelling run again without it). The minimisers:

* ``icm``: iterated conditional modes from the most probable labels (:func:`icm`);
* ``mean-field``: a few rounds of mean-field updates of the marginals, then the most probable
  label of each (:func:`mean_field`);
* ``cut``: alpha-expansion (:func:`primkit.segmentation.graphcut.alpha_expansion`, the mesh path's
  solver), the reference for how low the energy can go.

and the weights: ``normals s``: ``exp(-|n_v - n_w|^2 / s)`` (cheaper across a crease of the
voxels' normals); ``cuboids b``: ``b`` between voxels whose nearest cuboids differ;
``directional``: ``mu_d(a, b) = -log(P_d(a, b) / sqrt(P_d(a, a) P_d(b, b)))`` (clipped to [0, 10])
from how often label ``b`` lies next to label ``a`` in direction ``d`` (one of the six canonical
directions) on the labelled chairs, each chair weighing the same, so that legs above a seat cost
more than a seat above legs.

What it prints: per way the curve's figures (mean back/seat/legs IoU, arm IoU, arm detection F1)
per draw and their mean, the per-chair change of the mean IoU against the library's way (mean,
standard error, chairs better / worse) and the CPU time per chair of the step after the
probabilities (the ways timed in turn on each chair, one thread).

Why hand-written kernels: the Potts solvers with wheels here are PyMaxflow (GPL) and gco-wrapper
(research-only licence; see :mod:`primkit.segmentation.graphcut`); pydensecrf's mean field is a
fully connected CRF with Gaussian kernels over pixels or features, not a sparse neighbour list of
voxels, and has no maintained wheel; scipy's max-flow (graphcut) takes 35-60 ms a chair here.
ICM and mean field over the grid's neighbour table are a few loops in Numba.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from primkit.segmentation import graphcut
from primkit.segmentation.labeller import Labeller, LabellerSettings, decide, grid_neighbours

from scripts import labeller_curve as lc

#: weight of each column of :func:`grid_neighbours` (the voxel itself, 6 face, 12 edge, 8 corner
#: neighbours): one over the distance between the centres
COLUMN_WEIGHT = np.array([0.0] + [1.0] * 6 + [2**-0.5] * 12 + [3**-0.5] * 8)
FLOOR = 1e-3

_KERNELS = {}


def _kernels():
    """The Numba loops, compiled on first use."""
    if not _KERNELS:
        import numba

        @numba.njit(cache=True, nogil=True)
        def softmax_row(logits, out):  # out = exp(logits - max) / sum: the normalised row
            top = logits.max()
            total = 0.0
            for c in range(logits.shape[0]):
                out[c] = np.exp(logits[c] - top)
                total += out[c]
            for c in range(logits.shape[0]):
                out[c] /= total

        def rounds_with(term):
            """The mean-field rounds, a neighbour's part of each message given by ``term(msg, q,
            other, w, args)`` (``w``: the pair's weight); compiled once per term, not cached on
            disk (two loops from one factory would share a cache entry)."""
            @numba.njit(nogil=True)
            def run(logp, near, weight, args, rounds, out):
                n, k = logp.shape
                q = np.empty((n, k))
                for i in range(n):  # start: the softmax of the unary, the probabilities themselves
                    softmax_row(logp[i], q[i])
                msg = np.empty(k)
                for _ in range(rounds):
                    new = np.empty((n, k))
                    for i in range(n):
                        for c in range(k):
                            msg[c] = logp[i, c]
                        for j in range(1, near.shape[1]):
                            if near[i, j] != i:
                                term(msg, q, near[i, j], j, weight[i, j], args)
                        softmax_row(msg, new[i])
                    q = new
                out[:] = q

            return run

        @numba.njit(nogil=True, inline="always")
        def general(msg, q, other, j, w, args):  # args: (lam, mu, direction)
            lam, mu, direction = args
            if w == 0.0:
                return
            d = direction[j]
            for c in range(msg.shape[0]):
                cost = 0.0
                for b in range(msg.shape[0]):
                    cost += mu[d, c, b] * q[other, b]
                msg[c] -= lam * w * cost

        @numba.njit(nogil=True, inline="always")
        def potts_term(msg, q, other, j, w, args):  # args: (lam,)
            # the Potts case of ``general``: sum_b [c != b] q_w(b) = 1 - q_w(c), and the constant 1
            # is the same for every c, so each neighbour adds lam * weight * q_w(c)
            w = args[0] * w
            if w == 0.0:
                return
            for c in range(msg.shape[0]):
                msg[c] += w * q[other, c]

        field, field_potts = rounds_with(general), rounds_with(potts_term)

        @numba.njit(cache=True, nogil=True)
        def modes(unary, near, weight, lam, labels, sweeps):
            n, k = unary.shape
            cost = np.empty(k)
            for _ in range(sweeps):
                changed = 0
                for i in range(n):
                    for c in range(k):
                        cost[c] = unary[i, c]
                    for j in range(1, near.shape[1]):
                        other = near[i, j]
                        if other == i:
                            continue
                        for c in range(k):
                            if labels[other] != c:
                                cost[c] += lam * weight[i, j]
                    best = labels[i]
                    for c in range(k):
                        if cost[c] < cost[best]:
                            best = c
                    if best != labels[i]:
                        labels[i] = best
                        changed += 1
                if changed == 0:
                    break
            return labels

        _KERNELS.update(field=field, field_potts=field_potts, modes=modes)
    return _KERNELS


def neighbour_weights(near, conn: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """``(near (n, c) int, weight (n, c) float)``: the first ``c`` columns (7 or 27) of a grid's
    :func:`grid_neighbours` and each pair's weight (:data:`COLUMN_WEIGHT`; 0 where the neighbour
    is empty: the table holds the voxel itself there)."""
    c = 7 if conn == 6 else 27
    near = np.ascontiguousarray(np.asarray(near, np.int64)[:, :c])
    weight = np.tile(COLUMN_WEIGHT[:c], (len(near), 1))
    weight[near == np.arange(len(near))[:, None]] = 0.0
    return near, weight


def potts(k: int, directions: int = 1) -> np.ndarray:
    """``(directions, k, k)``: the Potts cost ``[a != b]`` in every direction."""
    return np.broadcast_to(1.0 - np.eye(k), (directions, k, k)).copy()


def mean_field(logp, near, weight, lam: float, rounds: int = 5, mu=None, direction=None) -> np.ndarray:
    """``(n, k)`` marginals after ``rounds`` mean-field updates of the energy of the module notes:
    ``q_v(c) ~ exp(logp_v(c) - lam sum_w weight_vw sum_b mu_d(c, b) q_w(b))``, all voxels updated
    at once from the previous round, started from ``softmax(logp)``.

    logp : (n, k) float (-inf-free: the unary with its sign flipped), near, weight : (n, c) from
    :func:`neighbour_weights`; mu : (D, k, k) float (None: :func:`potts`), direction : (c,) int,
    the direction of each column in ``mu`` (None: all 0).
    """
    logp = np.ascontiguousarray(logp, np.float64)
    out = np.empty_like(logp)
    if mu is None and direction is None:  # Potts: the shorter loop, the same marginals up to rounding
        _kernels()["field_potts"](logp, np.ascontiguousarray(near, np.int64),
                                  np.ascontiguousarray(weight, np.float64), (float(lam),), int(rounds), out)
        return out
    mu = potts(logp.shape[1]) if mu is None else np.ascontiguousarray(mu, np.float64)
    direction = np.zeros(near.shape[1], np.int64) if direction is None else np.asarray(direction, np.int64)
    _kernels()["field"](logp, np.ascontiguousarray(near, np.int64), np.ascontiguousarray(weight, np.float64),
                        (float(lam), mu, direction), int(rounds), out)
    return out


def icm(unary, near, weight, lam: float, init=None, sweeps: int = 10) -> np.ndarray:
    """``(n,) int``: iterated conditional modes on the Potts energy ``sum_v unary[v, l_v] + lam
    sum_(v,w) weight_vw [l_v != l_w]`` (each pair counted once: ``weight`` holds it from both
    ends, so each voxel's move sees its whole neighbourhood), voxel by voxel in order, from
    ``init`` (None: the arg-min of ``unary``) until a sweep changes nothing or after ``sweeps``.
    The result is a local minimum: no single voxel's change lowers the energy."""
    unary = np.ascontiguousarray(unary, np.float64)
    labels = np.argmin(unary, axis=1) if init is None else np.array(init, np.int64)
    return _kernels()["modes"](unary, np.ascontiguousarray(near, np.int64),
                               np.ascontiguousarray(weight, np.float64), float(lam), labels, int(sweeps))


def grid_energy(labels, unary, near, weight, lam: float) -> float:
    """The Potts energy :func:`icm` minimises, each pair once."""
    labels = np.asarray(labels, np.int64)
    data = unary[np.arange(len(labels)), labels].sum()
    rows = np.repeat(np.arange(len(near)), near.shape[1])
    cut = (labels[rows] != labels[near.ravel()]) * weight.ravel()
    return float(data + lam * cut.sum() / 2)


def directions(points, near) -> np.ndarray:
    """``(c,) int``: the canonical direction of each column of a grid's neighbour table (0-5: -x,
    +x, -y, +y, -z, +z; the dominant axis of the mean offset to the column's neighbours; 0 for
    the voxel itself). The grid's axes map to canonical axes up to a rotation of the frame."""
    points = np.asarray(points, float)
    out = np.zeros(near.shape[1], np.int64)
    rows = np.arange(len(near))
    for j in range(1, near.shape[1]):
        there = near[:, j] != rows
        if there.any():
            v = (points[near[there, j]] - points[there]).mean(axis=0)
            axis = int(np.argmax(np.abs(v)))
            out[j] = 2 * axis + int(v[axis] > 0)
    return out


def learn_directional(chairs, train, k: int = 4) -> np.ndarray:
    """``(6, k, k)``: the directional cost of the module notes from the labelled chairs ``train``."""
    counts = np.full((6, k, k), 1e-3)
    for name in train:
        a = chairs.arrays[name]
        near, weight = neighbour_weights(grid_neighbours(a["index"].astype(np.int64), (32, 32, 32)))
        truth = a["truth"].astype(np.int64)
        d = directions(a["points"], near)
        c = np.zeros((6, k, k))
        for j in range(1, 7):
            ok = (weight[:, j] > 0) & (truth >= 0) & (truth[near[:, j]] >= 0)
            np.add.at(c[d[j]], (truth[ok], truth[near[ok, j]]), 1.0)
        counts += c / max(c.sum(), 1.0)
    p = counts / counts.sum(axis=(1, 2), keepdims=True)
    diag = np.einsum("dii->di", p)
    return np.clip(-np.log(p / np.sqrt(diag[:, :, None] * diag[:, None, :])), 0.0, 10.0)


def with_rare_rule(proba, label, min_share: float) -> np.ndarray:
    """``label(proba, allowed)`` once, then again without the labels given to fewer than
    ``min_share`` of the voxels (as :func:`primkit.segmentation.meshlabels.cut_faces`)."""
    k = proba.shape[1]
    labels = label(proba, np.ones(k, bool))
    counts = np.bincount(labels, minlength=k)
    rare = (counts > 0) & (counts < min_share * len(labels))
    if rare.any() and not rare[counts > 0].all():
        labels = label(proba, ~rare)
    return labels


def way(kind: str, lam: float = 1.0, *, smooth: int = 2, conn: int = 6, rounds: int = 5, normals: float = 0.0,
        cuboids: float = 1.0, directional: bool = False):
    """A way of labelling a chair's probabilities: ``f(proba, context) -> (n,) int``; ``kind`` one
    of ``library``, ``icm``, ``mean-field``, ``cut`` (the module notes)."""

    def run(proba, ctx):
        labeller = ctx["labeller"]
        smoothed = labeller.smooth(proba, None, ctx["near"]) if smooth == labeller.settings.smooth else \
            replace(labeller, settings=replace(labeller.settings, smooth=smooth)).smooth(proba, None, ctx["near"])
        if kind == "library":
            return decide(smoothed, labeller.settings.min_share)
        near, weight = neighbour_weights(ctx["near"], conn)
        if normals:
            n = ctx["normals"]
            weight = weight * np.exp(-((n[near] - n[:, None]) ** 2).sum(axis=-1) / normals)
        if cuboids != 1.0:
            nearest = ctx["nearest"]
            weight = np.where(nearest[near] != nearest[:, None], cuboids * weight, weight)

        def label(p, allowed):
            logp = np.log(np.maximum(p, FLOOR))
            logp[:, ~allowed] = -1e9  # a dropped label: never chosen
            if kind == "mean-field":
                mu, d = (ctx["directional"], directions(ctx["points"], near)) if directional else (None, None)
                return np.argmax(mean_field(logp, near, weight, lam, rounds, mu, d), axis=1)
            if kind == "icm":
                return icm(-logp, near, weight, lam)
            keep = np.flatnonzero(allowed)
            rows = np.repeat(np.arange(len(near)), near.shape[1])
            once = (rows < near.ravel()) & (weight.ravel() > 0)
            edges = np.stack([rows[once], near.ravel()[once]], axis=1)
            start = np.argmax(logp[:, keep], axis=1)
            return keep[graphcut.alpha_expansion(-logp[:, keep], edges, lam * weight.ravel()[once], init=start)]

        return with_rare_rule(smoothed, label, labeller.settings.min_share)

    return run


#: the ways compared (the first: the library's, the reference of the per-chair changes)
WAYS = {
    "library (19 nearest, twice; most probable)": way("library"),
    "icm, lam 1": way("icm", 1.0),
    "mean-field, lam 1": way("mean-field", 1.0),
    "mean-field, lam 1, one smoothing round": way("mean-field", 1.0, smooth=1),
    "mean-field, lam 2, 10 rounds, no smoothing": way("mean-field", 2.0, smooth=0, rounds=10),
    "mean-field, lam 2, normals 0.5": way("mean-field", 2.0, normals=0.5),
    "mean-field, lam 0.5, 26 neighbours": way("mean-field", 0.5, conn=26),
    "mean-field, lam 0.5, directional": way("mean-field", 0.5, directional=True),
    "cut, lam 0.5": way("cut", 0.5),
    "cut, lam 2": way("cut", 2.0),
    "cut, lam 2, normals 0.5": way("cut", 2.0, normals=0.5),
    "cut, lam 1, cuboids 0.3": way("cut", 1.0, cuboids=0.3),
}


def _chair_mean(truth, labels) -> float:
    """A chair's mean IoU over back, seat and legs (1 where a label is absent from both)."""
    out = []
    for k in range(3):
        a, b = truth == k, labels == k
        union = np.count_nonzero(a | b)
        out.append(1.0 if union == 0 else np.count_nonzero(a & b) / union)
    return float(np.mean(out))


def check(scratch: Path, sizes, draws: int, only=None) -> dict:
    chairs = lc.Chairs(scratch)
    evaluate = lc.order(chairs.validation, 0)[100:]
    settings = LabellerSettings()
    keep = lc._columns(chairs.parts, settings)
    ways = {k: v for k, v in WAYS.items() if not only or k in only or k == next(iter(WAYS))}
    print(f"validation: {len(evaluate)} chairs scored; settings {settings}")
    out = {}
    for n in sizes:
        runs = {k: [] for k in ways}
        change = {k: [] for k in ways}
        seconds = {k: 0.0 for k in ways}
        for d in range(draws):
            train = lc._validation_train(chairs, d)[:n]
            labeller = Labeller.fit([(chairs.full_features(c)[:, keep], chairs.arrays[c]["truth"].astype(np.int64))
                                     for c in train], lc.NAMES, chairs.parts, settings=settings, **lc.FIT)
            known = np.array([lc.NAMES.index(k) for k in labeller.names])
            directional = learn_directional(chairs, train, len(labeller.names)) if len(known) == 4 else None
            labels = {k: {} for k in ways}
            for i, c in enumerate(evaluate):
                a = chairs.arrays[c]
                near = grid_neighbours(a["index"].astype(np.int64), (32, 32, 32))
                proba = lc.grid_proba(chairs, labeller, c, settings, keep, near)
                ctx = {"labeller": labeller, "near": near, "normals": a["normals"].astype(float),
                       "nearest": a["nearest"].astype(np.int64), "points": a["points"].astype(float),
                       "directional": directional}
                names = list(ways)
                if i == 0:  # compile the Numba loops before any is timed
                    for k in names:
                        ways[k](proba, ctx)
                for k in names[i % len(names):] + names[: i % len(names)]:  # in turn
                    t0 = time.process_time()
                    labels[k][c] = known[ways[k](proba, ctx)]
                    seconds[k] += time.process_time() - t0
            truth = {c: chairs.arrays[c]["truth"].astype(np.int64) for c in evaluate}
            base = {c: _chair_mean(truth[c], labels[next(iter(ways))][c]) for c in evaluate}
            for k in ways:
                runs[k].append(lc.score(chairs, evaluate, labels[k]))
                change[k] += [_chair_mean(truth[c], labels[k][c]) - base[c] for c in evaluate]
                print(lc.line(f"{k}, {n}, draw {d}", runs[k][-1]), flush=True)
        for k in ways:
            mean = {m: float(np.mean([r[m] for r in runs[k]])) for m in ("mean", "arm_iou", "arm_f1")}
            x = np.array(change[k])
            row = {**mean, "draws": [r["mean"] for r in runs[k]], "change": float(x.mean()),
                   "change_se": float(x.std() / np.sqrt(len(x))), "better": int(np.sum(x > 1e-12)),
                   "worse": int(np.sum(x < -1e-12)), "ms_per_chair": 1000 * seconds[k] / (draws * len(evaluate))}
            out[f"{k}, {n} chairs"] = row
            print(f"{k:48s} {n:3d} chairs: {row['mean']:.4f} / {row['arm_iou']:.4f} / {row['arm_f1']:.3f}  draws "
                  f"{' '.join(f'{v:.3f}' for v in row['draws'])}  per chair {row['change']:+.4f} +- "
                  f"{row['change_se']:.4f} ({row['better']} better, {row['worse']} worse)  "
                  f"{row['ms_per_chair']:.2f} ms", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scratch", type=Path, required=True, help="labeller_curve's prepared chairs")
    ap.add_argument("--sizes", default="10,40", help="comma-separated numbers of labelled chairs")
    ap.add_argument("--draws", type=int, default=3)
    ap.add_argument("--only", action="append", default=None, help="these ways only (and the library's)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    out = check(args.scratch, [int(s) for s in args.sizes.split(",")], args.draws, args.only)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

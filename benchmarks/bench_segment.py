"""Co-segmentation cost: projecting points onto 20 cuboids, and labelling the faces of a mesh.

* points per second of :func:`primkit.primitives.assign_points` (chunked, one matrix product per
  chunk for all cuboids) against the straightforward way, a loop over the primitives that keeps
  the running minimum over all points (the same answer, checked), with peak memory of each;
* faces per second of :func:`primkit.segmentation.face_labels` (four quadrature points per face)
  against the released demo's rule (20 random points per face, the most common part), and how
  often the two agree.

Usage: ``python benchmarks/bench_segment.py [--points 1000000] [--parts 20] [--faces 300000]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np


from benchmarks._common import load_line, maxrss_kib, run_isolated, table  # noqa: E402
from primkit import primitives, segmentation  # noqa: E402


def random_cuboids(parts: int, seed: int = 0) -> primitives.Cuboids:
    rng = np.random.default_rng(seed)
    return primitives.Cuboids(rng.uniform(0.05, 0.3, (parts, 3)), rng.normal(size=(parts, 4)),
                              rng.uniform(-0.5, 0.5, (parts, 3)), np.ones(parts, bool))


def per_primitive_loop(points, cub):
    """The straightforward way: one cuboid at a time over all points, ties to the larger."""
    order = np.argsort(-cub.volumes, kind="stable")
    best = np.full(len(points), np.inf)
    label = np.zeros(len(points), np.int64)
    for k in order:
        local = (points - cub.translations[k]) @ cub.rotations[k]
        excess = np.maximum(np.abs(local) - cub.half_extents[k], 0.0)
        d2 = (excess**2).sum(axis=1)
        closer = d2 < best
        best[closer] = d2[closer]
        label[closer] = k
    return label


def _project(method: str, n: int, parts: int) -> dict:
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.8, 0.8, (n, 3))
    cub = random_cuboids(parts)
    before = maxrss_kib()
    fn = primitives.assign_points if method == "chunked" else per_primitive_loop
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        labels = fn(points, cub)
        times.append(time.perf_counter() - t0)
    return {"seconds": min(times), "extra_mib": (maxrss_kib() - before) / 1024,
            "checksum": int(np.bincount(labels, minlength=parts) @ np.arange(parts))}


def random_points_vote(vertices, faces, cub, per_face: int = 20, seed: int = 0):
    """The released demo's rule: ``per_face`` random points per face, the most common part wins."""
    rng = np.random.default_rng(seed)
    u = rng.random((len(faces), per_face, 2))
    flip = u.sum(-1) > 1
    u[flip] = 1 - u[flip]
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    pts = a[:, None] + u[..., :1] * (b - a)[:, None] + u[..., 1:] * (c - a)[:, None]
    labels = primitives.assign_points(pts.reshape(-1, 3), cub).reshape(len(faces), per_face)
    counts = np.zeros((len(faces), cub.count), np.int64)
    np.add.at(counts, (np.repeat(np.arange(len(faces)), per_face), labels.ravel()), 1)
    return counts.argmax(axis=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--parts", type=int, default=20)
    ap.add_argument("--faces", type=int, default=300_000)
    args = ap.parse_args()
    print(load_line())

    res = {m: run_isolated(_project, m, args.points, args.parts) for m in ("chunked", "loop")}
    assert res["chunked"]["checksum"] == res["loop"]["checksum"], "the two projections disagree"
    rows = [[m, f"{r['seconds'] * 1000:.0f}", f"{args.points / r['seconds'] / 1e6:.2f}", f"{r['extra_mib']:.0f}"]
            for m, r in res.items()]
    table(f"{args.points:,} points onto {args.parts} cuboids (best of 3, fresh process each)",
          ["method", "ms", "M points/s", "extra peak MiB"], rows,
          note="chunked: primitives.assign_points; loop: one cuboid at a time over all points (same labels).")

    # a random triangle soup around the cuboids: every face a small triangle
    rng = np.random.default_rng(2)
    centres = rng.uniform(-0.6, 0.6, (args.faces, 1, 3))
    vertices = (centres + rng.normal(scale=0.02, size=(args.faces, 3, 3))).reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    cub = random_cuboids(args.parts)
    t0 = time.perf_counter()
    quad = segmentation.face_labels(vertices, faces, cub)
    t_quad = time.perf_counter() - t0
    t0 = time.perf_counter()
    vote = random_points_vote(vertices, faces, cub)
    t_vote = time.perf_counter() - t0
    table(f"labels for {args.faces:,} faces", ["method", "ms", "k faces/s"],
          [["4-point quadrature (face_labels)", f"{t_quad * 1000:.0f}", f"{args.faces / t_quad / 1e3:.0f}"],
           ["20 random points per face (released demo)", f"{t_vote * 1000:.0f}", f"{args.faces / t_vote / 1e3:.0f}"]],
          note=f"the two rules agree on {np.mean(quad == vote):.1%} of faces (they differ only on faces split between parts).")


if __name__ == "__main__":
    main()

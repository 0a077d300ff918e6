"""Co-segmentation cost: projecting points onto 20 cuboids, and labelling the faces of a mesh.

* points per second of :func:`primkit.primitives.assign_points` (chunked, one matrix product per
  chunk for all cuboids) against the straightforward way, a loop over the primitives that keeps
  the running minimum over all points (the same answer, checked), with peak memory of each;
* faces per second of :func:`primkit.segmentation.face_labels` (four quadrature points per face)
  against the released demo's rule (20 random points per face, the most common part), and how
  often the two agree;
* seconds per shape of the graph-cut labelling (:mod:`primkit.segmentation.graphcut`) against the
  nearest labelling, alternating on the same shapes: procedural chairs' faces, their surface
  points and their 32^3 voxels, each part's box grown by 10% of the chair's size.

Usage: ``python benchmarks/bench_segment.py [--points 1000000] [--parts 20] [--faces 300000] [--chairs 6]``
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
    ap.add_argument("--chairs", type=int, default=6, help="procedural chairs for the graph-cut timing (0: skip)")
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

    if args.chairs:
        graphcut_section(args.chairs)


def _loose_boxes(vertices, faces, labels, grow: float = 0.1) -> primitives.Cuboids:
    """One axis-aligned box per part, grown by ``grow`` of the shape's size (so boxes overlap)."""
    size = np.ptp(vertices, axis=0)
    lo = np.array([vertices[np.unique(faces[labels == k])].min(axis=0) for k in np.unique(labels)]) - grow * size
    hi = np.array([vertices[np.unique(faces[labels == k])].max(axis=0) for k in np.unique(labels)]) + grow * size
    return primitives.Cuboids((hi - lo) / 2, [[1, 0, 0, 0]] * len(lo), (hi + lo) / 2, np.ones(len(lo), bool))


def graphcut_section(count: int) -> None:
    """Seconds per shape, nearest against graph cut, alternating shape by shape."""
    from primkit import geometry, io, synthetic

    times = {(kind, how): [] for kind in ("mesh faces", "points", "voxels") for how in ("nearest", "graphcut")}
    sizes = {"mesh faces": [], "points": [], "voxels": []}
    for seed in range(count):
        shape = synthetic.chair(seed)
        v, f = shape.vertices, shape.faces
        cub = _loose_boxes(v, f, np.asarray(shape.face_labels))
        cloud = io.PointCloud(geometry.sample_surface(v, f, 5000, seed=seed).points)
        lo, span = v.min(axis=0), np.ptp(v, axis=0).max() * 1.05
        centres = (np.indices((32, 32, 32)).reshape(3, -1).T + 0.5) / 32 * span + lo
        # the voxels the surface passes through (a shell), enough for timing
        cell = np.floor((geometry.sample_surface(v, f, 40000, seed=seed).points - lo) / span * 32).astype(int)
        inside = np.zeros((32, 32, 32), bool)
        inside[tuple(np.clip(cell, 0, 31).T)] = True
        inside = inside.reshape(-1)
        grid = io.VoxelGrid(inside.reshape(32, 32, 32), translate=lo, scale=span)
        sizes["mesh faces"].append(len(f))
        sizes["points"].append(len(cloud.points))
        sizes["voxels"].append(int(inside.sum()))
        for how in ("nearest", "graphcut"):
            for kind, fn in (("mesh faces", lambda: segmentation.segment_mesh(v, f, cub, labelling=how)),
                             ("points", lambda: segmentation.segment_points(cloud, cub, labelling=how)),
                             ("voxels", lambda: segmentation.label_voxels(grid, cub, labelling=how))):
                t0 = time.perf_counter()
                fn()
                times[(kind, how)].append(time.perf_counter() - t0)
    rows = []
    for kind in sizes:
        near, cut = np.median(times[(kind, "nearest")]), np.median(times[(kind, "graphcut")])
        rows.append([kind, f"{np.mean(sizes[kind]):,.0f}", f"{near * 1000:.1f}", f"{cut * 1000:.1f}", f"{cut / near:.0f}x"])
    table(f"labelling one shape: nearest vs graph cut ({count} procedural chairs, median, alternating)",
          ["elements", "count (mean)", "nearest ms", "graph cut ms", "ratio"], rows,
          note="graph cut: alpha-expansion on scipy's maximum_flow, default smoothness, started from nearest.")


if __name__ == "__main__":
    main()

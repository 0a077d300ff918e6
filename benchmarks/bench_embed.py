"""What the similarity search costs at scale: descriptors and nearest neighbours for 10,000 shapes.

Synthetic abstractions (random cuboids, 20 slots, ~70% present; no network needed), so the
figures are the embedding's own:

* descriptors of all shapes (:class:`primkit.embedding.PartDescriptor`, all parts and properties);
* the nearest neighbour of every shape through scikit-learn's index (``auto``: chunked brute force
  for these 320-dimensional vectors; ``ball_tree``) against the straightforward way, the full
  (s, s) distance matrix and an argmin per row; time and peak memory, each in a fresh process;
  the neighbours found are checked to be the same;
* one comparison of two shapes: descriptor distance against the voxel-IoU baseline (1 - IoU of
  32^3 grids), both as a full matrix over a few hundred shapes;
* parts by label (:class:`primkit.embedding.RegionDescriptor`): describing labelled 32^3 grids, the
  signature from at most 512 cells per part against the plain way, every pair of a part's cells.

Usage: ``python benchmarks/bench_embed.py [--shapes 10000] [--region-shapes 20] [--quick]``
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


from benchmarks._common import load_line, maxrss_kib, run_isolated, table  # noqa: E402


def random_cuboids(s: int, m: int = 20, seed: int = 0):
    from primkit.primitives import Cuboids

    rng = np.random.default_rng(seed)
    return [Cuboids(rng.uniform(0.02, 0.3, (m, 3)), rng.normal(size=(m, 4)), rng.uniform(-0.4, 0.4, (m, 3)),
                    rng.random(m) < 0.7) for _ in range(s)]


def descriptors(s: int):
    from primkit.embedding import PartDescriptor

    cubs = random_cuboids(s)
    t0 = time.perf_counter()
    X = PartDescriptor().fit_transform(cubs)
    return X, time.perf_counter() - t0


def job_index(s: int, algorithm: str) -> dict:
    from primkit.embedding import nearest_neighbors

    import sklearn.neighbors  # noqa: F401  (library imports outside the measured memory)

    X, t_desc = descriptors(s)
    base = maxrss_kib()
    t0 = time.perf_counter()
    nn = nearest_neighbors(X, 1, algorithm=algorithm)
    return {"seconds": time.perf_counter() - t0, "descriptor_seconds": t_desc, "dims": X.shape[1],
            "extra_mib": (maxrss_kib() - base) / 1024, "peak_mib": maxrss_kib() / 1024, "nn": nn.indices[:, 0].tolist()}


def job_full_matrix(s: int) -> dict:
    from primkit.embedding import descriptor_distances

    import scipy.spatial.distance  # noqa: F401
    import sklearn.neighbors  # noqa: F401

    X, _ = descriptors(s)
    base = maxrss_kib()
    t0 = time.perf_counter()
    D = descriptor_distances(X)
    np.fill_diagonal(D, np.inf)
    nn = np.argmin(D, axis=1)
    return {"seconds": time.perf_counter() - t0, "extra_mib": (maxrss_kib() - base) / 1024,
            "peak_mib": maxrss_kib() / 1024, "nn": nn.tolist()}


def pair_costs(s: int) -> list[list]:
    """Descriptor distances against voxel IoU, full matrices over ``s`` shapes (grids from the cuboids)."""
    from primkit.embedding import PartDescriptor, descriptor_distances, voxel_iou_distances
    from primkit.primitives import contains

    cubs = random_cuboids(s, seed=1)
    r = 32
    c = -0.5 + (np.arange(r) + 0.5) / r
    centres = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)
    grids = np.array([contains(centres, cub).any(axis=1).reshape(r, r, r) for cub in cubs])
    descriptor_distances(np.zeros((2, 3)))  # imports and first-call set-up out of the timings
    voxel_iou_distances(grids[:2])
    t0 = time.perf_counter()
    X = PartDescriptor().fit_transform(cubs)
    t_desc = time.perf_counter() - t0
    t0 = time.perf_counter()
    descriptor_distances(X)
    t_dd = time.perf_counter() - t0
    t0 = time.perf_counter()
    voxel_iou_distances(grids)
    t_iou = time.perf_counter() - t0
    pairs = s * s
    return [
        ["descriptor (all parts)", f"{t_desc:.3f} (describe)", f"{t_dd:.4f}", f"{t_dd / pairs * 1e9:.0f}", f"{X.shape[1] * 8} B"],
        ["voxel IoU (32^3 grids)", "from the preparation cache", f"{t_iou:.4f}", f"{t_iou / pairs * 1e9:.0f}", f"{r ** 3} B"],
    ]


def region_costs(s: int) -> list[list]:
    """Region descriptors of ``s`` labelled grids (the cuboids' cells, labelled by cuboid index mod 4):
    signatures from at most 512 cells per part against all of a part's cells."""
    from primkit.embedding import RegionDescriptor, RegionTable
    from primkit.primitives import contains

    cubs = random_cuboids(s, seed=2)
    r = 32
    c = -0.5 + (np.arange(r) + 0.5) / r
    centres = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)
    grids, labels = [], []
    for cub in cubs:
        inside = contains(centres, cub)
        occupied = inside.any(axis=1)
        grids.append(occupied.reshape(r, r, r))
        labels.append(np.where(occupied, np.argmax(inside, axis=1) % 4, -1).reshape(r, r, r))
    names = ["a", "b", "c", "d"]
    rows, found = [], []
    for label, cap in (("signature from <= 512 cells per part", 512), ("signature from every pair of cells", 10 ** 9)):
        t0 = time.perf_counter()
        table = RegionTable.from_grids(grids, labels, names, max_elements=cap)
        X = RegionDescriptor("a").fit_transform(table)
        seconds = time.perf_counter() - t0
        found.append(table.values["signature"])
        rows.append([label, f"{seconds:.2f}", f"{seconds / s * 1e3:.1f}", f"{X.shape[1]}"])
    gap = float(np.abs(found[0] - found[1]).sum(axis=-1).max())
    rows.append(["largest L1 gap between the two signatures", f"{gap:.3f}", "", ""])
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", type=int, default=10000)
    ap.add_argument("--pairs-shapes", type=int, default=300, help="shapes for the descriptor vs voxel-IoU matrices")
    ap.add_argument("--region-shapes", type=int, default=20, help="labelled grids for the region descriptors")
    ap.add_argument("--quick", action="store_true", help="2,000 shapes, 100 for the pair costs, 5 labelled grids")
    args = ap.parse_args(argv)
    s = 2000 if args.quick else args.shapes
    ps = 100 if args.quick else args.pairs_shapes
    rs = 5 if args.quick else args.region_shapes
    print(load_line())

    rows, found = [], {}
    for label, target, extra in (("index: auto (chunked brute force)", job_index, ("auto",)),
                                 ("index: ball_tree", job_index, ("ball_tree",)),
                                 ("full (s, s) matrix + argmin", job_full_matrix, ())):
        res = run_isolated(target, s, *extra)
        found[label] = np.array(res["nn"])
        if "descriptor_seconds" in res:
            desc_line = f"descriptors: {s} shapes x {res['dims']} columns in {res['descriptor_seconds']:.2f} s"
        rows.append([label, f"{res['seconds']:.2f}", f"{res['extra_mib']:.0f}", f"{res['peak_mib']:.0f}"])
    labels = list(found)
    same = all(np.array_equal(found[labels[0]], found[k]) for k in labels[1:])
    print(desc_line)
    table(f"nearest neighbour of each of {s} shapes (all parts, all properties)",
          ["method", "seconds", "extra MiB", "peak MiB"], rows,
          note=f"same neighbours found by all methods: {same}. Each method runs in a fresh process; "
               "'extra' is the peak resident memory added by the search.")
    table(f"one comparison: full distance matrix over {ps} shapes", ["distance", "set-up (s)", "matrix (s)", "ns per pair", "data per shape"],
          pair_costs(ps))
    table(f"parts by label: region descriptors of {rs} labelled 32^3 grids", ["method", "seconds", "ms per shape", "columns"],
          region_costs(rs))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: binding + deformation of a ~100k-vertex mesh against a per-vertex Python loop, and
distance-based against harmonic (igl.harmonic) blending weights.

    python benchmarks/bench_deform.py

The mesh is a procedural chair subdivided to ~100k vertices, bound to boxes around its labelled
parts and deformed by moving the back. The loop does the same computation one vertex at a time on
a 2,000-vertex subset (timed and extrapolated; results compared). Blending methods are compared on
the same deformation: time, flipped triangles and the 99th percentile of edge distortion inside
parts; the distance blend is also run with :func:`primkit.deformation.unfold`. The COSEG
figures (90 ordered pairs) are in the module docstring of primkit.deformation. Nothing is asserted: it prints and exits 0.
"""

import time

import numpy as np

from _common import table  # noqa: E402

from primkit import deformation as D, synthetic  # noqa: E402
from primkit.primitives import Cuboids  # noqa: E402


def main():
    import trimesh

    s = synthetic.generate("chair", 1, seed=0)[0]
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces)
    lab = np.asarray(s.face_labels)
    boxes = [(v[np.unique(f[lab == p])].min(0), v[np.unique(f[lab == p])].max(0)) for p in np.unique(lab)]
    lo, hi = np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes])
    m = len(boxes)
    cub = Cuboids((hi - lo) / 2 + 1e-3, np.tile([1.0, 0, 0, 0], (m, 1)), (hi + lo) / 2, np.ones(m, bool))
    back = list(s.part_names).index("back") if "back" in s.part_names else m - 1
    edit = D.edit_cuboids(cub, rotate={int(np.flatnonzero(np.unique(lab) == back)[0]): 20.0})
    small_v, small_f = v, f
    while len(v) < 100_000:
        v, f = trimesh.remesh.subdivide(v, f)
    t0 = time.perf_counter()
    b = D.bind(v, cub)
    t1 = time.perf_counter()
    out = b.apply(edit.transforms)
    t2 = time.perf_counter()
    sub = np.random.default_rng(0).choice(len(v), 2000, replace=False)
    t3 = time.perf_counter()
    loop = np.empty((len(sub), 3))
    for r, i in enumerate(sub):  # one vertex at a time: signed distances, weights, blended maps
        x = v[i]
        sd = []
        for k in range(m):
            loc = cub.rotations[k].T @ (x - cub.translations[k])
            q = np.abs(loc) - cub.half_extents[k]
            sd.append(np.linalg.norm(np.maximum(q, 0)) + min(q.max(), 0.0))
        sd = np.array(sd)
        a = np.clip((sd - sd.min()) / b.falloff, 0, 1)
        w = 1 - a * a * (3 - 2 * a)
        w /= w.sum()
        loop[r] = x + sum(w[k] * ((edit.transforms[k, :3, :3] - np.eye(3)) @ x + edit.transforms[k, :3, 3]) for k in range(m))
    t4 = time.perf_counter()
    err = np.abs(loop - out[sub]).max()
    table(f"binding + deformation, {len(v):,} vertices, {m} parts", ["method", "bind s", "apply s", "total s"],
          [["primkit (vectorised)", f"{t1 - t0:.3f}", f"{t2 - t1:.3f}", f"{t2 - t0:.3f}"],
           ["per-vertex loop (extrapolated from 2,000)", "", "", f"{(t4 - t3) * len(v) / len(sub):.1f}"]],
           note=f"max difference on the subset {err:.1e}")
    rows = []
    for name, (vv, ff) in {"procedural chair": (small_v, small_f)}.items():
        for method, unf in (("distance", False), ("harmonic", False), ("distance", True)):
            t0 = time.perf_counter()
            d = D.edit(vv, cub, rotate={int(np.flatnonzero(np.unique(lab) == back)[0]): 20.0}, faces=ff, method=method,
                       unfold=unf)
            dt = time.perf_counter() - t0
            q = d.quality(ff)
            rows.append([f"{name}: {method}{' + unfold' if unf else ''}", f"{dt:.3f}", f"{100 * q.flipped:.3f}", f"{q.distortion['all'].p99:.4f}"])
    table("blending weights", ["shape: method", "s", "flipped %", "distortion p99"], rows)


if __name__ == "__main__":
    main()

"""Benchmark: rendering training views, and image-model inference against the volume model.

    python benchmarks/bench_image.py [--quick]

What it measures, in one run:

1. Views per second from :func:`primkit.image.views.render_views` with one off-screen plotter reused for
   every view (:class:`primkit.image.views.ViewRenderer`), against the straightforward alternative of a
   new plotter per view; both at the default 64 x 64 with 2x supersampling, procedural chairs
   (surface extraction included, once per shape).
2. Inference per picture of the image network (:class:`primkit.image.inference.ImageAbstractor`, the
   bundled ``chair-image`` model when present, else an untrained network of the same shape) against
   the volume model (``Abstractor.load("chair")``) per prepared 32^3 grid; the raw network alone
   and with existence thresholding + pruning (``predict``), batched 64 and one at a time.

Procedural shapes (:mod:`primkit.synthetic`), no data set needed. Median of repeats after a warm-up.
Nothing asserts a time: it prints and exits 0.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from _common import load_line, table  # noqa: E402


def _median_time(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    import torch

    from primkit import data, io, synthetic
    from primkit import image as views
    from primkit.model.abstractor import Abstractor
    from primkit.image.inference import ImageAbstractor
    from primkit.image.network import ImageNet
    from primkit.model.bundled import bundled_models

    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    print(load_line())
    n_shapes = 3 if args.quick else 8
    per = 4
    shapes = [data.prepare(io.Mesh(s.vertices, s.faces), data.PrepareSettings(samples=2000))
              for s in synthetic.generate("chair", n_shapes, seed=3)]
    grids = [s.occupancy for s in shapes]
    settings = views.ViewSettings()

    # 1. rendering (a throwaway render first: the first plotter of a process pays for EGL and VTK's set-up)
    views.render_views(grids[:1], 1, settings=settings, seed=99)
    t = time.perf_counter()
    reused = views.render_views(grids, per, settings=settings, seed=0)
    t_reused = time.perf_counter() - t
    t = time.perf_counter()
    fresh = []
    for i, g in enumerate(grids):  # the alternative: a new plotter for every view
        v, f = views.shape_surface(g)
        for j in range(per):
            rng = np.random.default_rng([0, i, j])
            cam = views.random_camera(rng, settings)
            with views.ViewRenderer(settings) as r:
                fresh.append(r.render(v, f, cam, rng))
    t_fresh = time.perf_counter() - t
    k = len(reused)
    table("Rendering training views (64 x 64, 2x supersampled, procedural chairs, surfaces included)",
          ["method", "views", "seconds", "views/s"],
          [["one plotter reused (render_views)", k, f"{t_reused:.2f}", f"{k / t_reused:.1f}"],
           ["new plotter per view", k, f"{t_fresh:.2f}", f"{k / t_fresh:.1f}"]])

    # 2. inference
    bundled = bundled_models().get("chair-image")
    image_model = ImageAbstractor.load(bundled) if bundled else ImageAbstractor(ImageNet(), {})
    volume = Abstractor.load("chair")
    images = np.concatenate([reused.images] * (64 // k + 1))[:64]
    occ = np.stack([grids[i % len(grids)] for i in range(64)])
    prepared = [shapes[i % len(shapes)] for i in range(64)]
    reps = 3 if args.quick else 7
    rows = []
    for label, fn, count in [
        ("image net, raw, batch 64", lambda: image_model.predict_raw(images), 64),
        ("volume net, raw, batch 64", lambda: volume.predict_canonical(occ), 64),
        ("image net, raw, one at a time", lambda: [image_model.predict_raw(images[i:i + 1]) for i in range(16)], 16),
        ("volume net, raw, one at a time", lambda: [volume.predict_canonical(occ[i:i + 1]) for i in range(16)], 16),
        ("image predict (threshold + prune), batch 64", lambda: image_model.predict(images), 64),
        ("volume predict (threshold + prune), batch 64", lambda: volume.predict(prepared), 64),
    ]:
        sec = _median_time(fn, reps) / count
        rows.append([label, f"{sec * 1e3:.2f}", f"{1 / sec:.0f}"])
    table("Inference per item (image: 64 x 64 RGB; volume: 32^3 grid)", ["what", "ms/item", "items/s"], rows,
          note=f"image model: {'bundled chair-image' if bundled else 'untrained network of the same shape'}; "
               f"torch threads {torch.get_num_threads()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

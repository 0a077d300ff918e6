"""Benchmark: off-screen rendering throughput for a collection's thumbnails.

    python benchmarks/bench_render.py [--shapes N] [--size PX]

What it measures, in one run, on procedural chairs (:mod:`primkit.synthetic`) and their cuboids:

1. :class:`primkit.viz.render.ThumbnailRenderer`: one off-screen plotter (one OpenGL context) reused
   for every shape, actors cleared in between;
2. the straightforward alternative: a new ``pyvista.Plotter(off_screen=True)`` per shape, closed
   after its screenshot (what a loop over ``write_png`` does);
3. a grid of every shape in one picture (:func:`primkit.viz.render.render_tiles`), per shape.

Each picture draws a shape's mesh and, in a second pass, its cuboids (two thumbnails per shape).
Reported: shapes per second, median milliseconds per picture, first picture separately (context
creation and shader compilation). The first two are checked to give the same pixels. Nothing here
asserts a time: it prints and exits 0.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from _common import load_line, table  # noqa: E402

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _tiles(count: int):
    from primkit import synthetic
    from primkit.primitives import Cuboids
    from primkit.viz.render import Tile, cuboid_layer, mesh_layer

    rng = np.random.default_rng(0)
    tiles = []
    frame = np.array([[-0.5] * 3, [0.5] * 3])
    for s in synthetic.generate("chair", count, seed=1):
        # cuboids around the labelled parts (a stand-in for a model's output: no model needed)
        boxes = []
        for k in np.unique(s.face_labels):
            p = s.vertices[np.unique(s.faces[s.face_labels == k])]
            lo, hi = p.min(0), p.max(0)
            boxes.append((np.maximum((hi - lo) / 2, 1e-3), (hi + lo) / 2))
        m = len(boxes)
        cub = Cuboids([b[0] for b in boxes], np.tile([1.0, 0, 0, 0], (m, 1)), [b[1] for b in boxes], np.ones(m, bool))
        tiles.append((Tile("", [mesh_layer(s.vertices, s.faces)], frame=frame), Tile("", [cuboid_layer(cub)], frame=frame),
                      len(s.faces)))
    rng.shuffle(tiles)
    return tiles


def reused(tiles, size):
    from primkit.viz.render import ThumbnailRenderer

    times, images = [], []
    with ThumbnailRenderer(size=size, radius=np.sqrt(3) / 2) as r:
        for mesh, cubs, _ in tiles:
            t = time.perf_counter()
            images.append(r.render(mesh))
            images.append(r.render(cubs))
            times.append(time.perf_counter() - t)
    return times, images


def fresh(tiles, size):
    from primkit.viz.render import render_tiles

    times, images = [], []
    for mesh, cubs, _ in tiles:
        t = time.perf_counter()
        images.append(render_tiles([mesh], tile=size, radius=np.sqrt(3) / 2))
        images.append(render_tiles([cubs], tile=size, radius=np.sqrt(3) / 2))
        times.append(time.perf_counter() - t)
    return times, images


def grid(tiles, size):
    from primkit.viz.render import render_tiles

    t = time.perf_counter()
    render_tiles([x for m, c, _ in tiles for x in (m, c)], tile=size, columns=8, radius=np.sqrt(3) / 2)
    return time.perf_counter() - t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", type=int, default=24)
    ap.add_argument("--size", type=int, default=160)
    args = ap.parse_args(argv)
    print(load_line())
    tiles = _tiles(args.shapes)
    print(f"{len(tiles)} procedural chairs, {np.median([t[2] for t in tiles]):.0f} faces (median), "
          f"{args.size} px thumbnails, mesh + cuboids per shape")
    t_fresh, im_fresh = fresh(tiles, args.size)
    t_reused, im_reused = reused(tiles, args.size)
    t_grid = grid(tiles, args.size)
    diff = max(np.abs(a.astype(int) - b.astype(int)).max() for a, b in zip(im_fresh, im_reused))
    rows = []
    for name, t in (("new plotter per shape", t_fresh), ("one reused plotter (ThumbnailRenderer)", t_reused)):
        rows.append([name, f"{len(t) / sum(t):.1f}", f"{1000 * np.median(t[1:]) / 2:.1f}", f"{1000 * t[0]:.0f}"])
    rows.append(["one grid picture of all (render_tiles)", f"{len(tiles) / t_grid:.1f}", "-", "-"])
    table("Thumbnail rendering", ["method", "shapes/s", "ms/picture (median)", "first shape ms"], rows,
          note=f"largest pixel difference between the two thumbnail methods: {diff} (of 255)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

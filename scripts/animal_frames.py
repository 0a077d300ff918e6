"""Turn the shared four-legged animal meshes into one frame (+Y up, head toward +X) for training.

Usage (from the repository root, primkit importable)::

    python scripts/animal_frames.py OUT [--tiers core pose smal] [--sheet sheet.png]

The meshes in ``../shared/data/fourleg_animals`` come from seven sources with their own up axes,
head directions and units. The animal model is trained, like the ShapeNet models, on shapes that
share one frame, so each mesh is turned by one of the 24 axis-aligned rotations:

* **width**: the smallest extent (2nd to 98th percentile of surface samples) is across the body;
* **up**: of the four signed remaining axes, the one under which the lowest 15% of the surface covers the
  smallest share of the shape's footprint (seen from above, on a 32 x 32 grid): standing on four
  legs, only the feet and shins are down there; lying on a side, a flank is;
* **length**: the axis left goes along X;
* **head**: of the two ends (the outer fifth of the length each), the one whose highest points
  stand higher (the head is carried above the rump).

The rule is checked by eye on the contact sheet (``--sheet``: every animal from its right side in
the chosen frame); the files it gets wrong are listed in ``OVERRIDES`` with the turn read off the
sheet. Each turned mesh is written to ``OUT`` as PLY (name: source folder and stem), centred and
scaled to a longest side of 1 (``primkit prepare`` normalises again; this only makes the files
easy to look at). The training command then declares the frame:
``primkit train OUT --preset animal``.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import sys
from pathlib import Path

import numpy as np

from primkit import geometry, io

ANIMALS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "fourleg_animals"

#: Files the rule turns wrong, with (up, head) read off the contact sheet: signed source axes.
OVERRIDES: dict[str, tuple[str, str]] = {
    "infomr_shapedb/D00508.obj": ("-y", "-x"),
    "infomr_shapedb/D00583.obj": ("-y", "+x"),
    "infomr_shapedb/D00663.obj": ("-y", "-x"),
    "infomr_shapedb/D00794.obj": ("-y", "-x"),
    "infomr_shapedb/D00867.obj": ("-y", "-x"),
    "infomr_shapedb/m100.obj": ("+y", "+z"),
    "infomr_shapedb/m103.obj": ("+y", "+z"),
    "infomr_shapedb/m110.obj": ("+y", "+z"),
    "odedstein/odedstein_cat_lowres.obj": ("+y", "+x"),
    "quaternius_glb/quaternius_Rat.glb": ("+y", "+z"),
}

#: Poses that are not standing or walking (a leap, a rearing lion, a curled cat): left out.
LEFT_OUT = {
    "cragl_skinning/cragl_sumner_cat_pose0005.obj",
    "cragl_skinning/cragl_sumner_lion_pose5.obj",
    "tosca_sumner_misc/tosca_cat2.off",
}

def _signed(axis: int, sign: int) -> str:
    return ("+" if sign > 0 else "-") + "xyz"[axis]


def _samples(mesh: io.Mesh, n: int = 20000, seed: int = 0) -> np.ndarray:
    return geometry.sample_surface(mesh.vertices, mesh.faces, n, seed=seed).points


def _footprint(points2: np.ndarray, lo: np.ndarray, hi: np.ndarray, bins: int = 32) -> set:
    cells = np.floor((points2 - lo) / np.maximum(hi - lo, 1e-12) * (bins - 1e-9)).astype(int)
    return set(map(tuple, cells))


def find_frame(points: np.ndarray) -> tuple[str, str]:
    """(up, head) as signed source axes, by the rule in the module notes."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    extent = np.percentile(points, 98, axis=0) - np.percentile(points, 2, axis=0)
    width = int(np.argmin(extent))
    best = None
    for axis, sign in itertools.product([a for a in range(3) if a != width], (1, -1)):
        h = points[:, axis] * sign
        hmin, hmax = h.min(), h.max()
        low = h <= np.quantile(h, 0.15)
        others = [a for a in range(3) if a != axis]
        every = _footprint(points[:, others], lo[others], hi[others])
        feet = _footprint(points[low][:, others], lo[others], hi[others])
        share = len(feet) / max(1, len(every))
        if best is None or share < best[0]:
            best = (share, axis, sign)
    _, up_axis, up_sign = best
    length = 3 - width - up_axis
    h = points[:, up_axis] * up_sign
    x = points[:, length]
    ends = []
    for sign in (1, -1):
        xs = x * sign
        end = xs >= xs.max() - 0.2 * (xs.max() - xs.min())
        ends.append((np.percentile(h[end], 98), sign))
    head_sign = max(ends)[1]
    return _signed(up_axis, up_sign), _signed(length, head_sign)


def catalogue(tiers) -> list[Path]:
    with open(ANIMALS / "CATALOG.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["tier"] in tiers]
    return [ANIMALS / r["file"] for r in rows if r["file"] not in LEFT_OUT]


def sheet(items, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = 8
    rows = (len(items) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(cols * 2.4, rows * 2.0))
    for ax in np.ravel(axes):
        ax.axis("off")
    for ax, (name, pts) in zip(np.ravel(axes), items):
        order = np.argsort(pts[:, 2])  # the right side (+Z) drawn last, nearest the viewer
        ax.scatter(pts[order, 0], pts[order, 1], s=0.2, c=pts[order, 2], cmap="viridis")
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=7)
    fig.suptitle("animals in the training frame: +Y up, head to the right (+X), seen from +Z", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--tiers", nargs="+", default=["core", "pose", "smal"])
    ap.add_argument("--sheet", type=Path, default=None)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    items, failed = [], 0
    for path in catalogue(args.tiers):
        rel = path.relative_to(ANIMALS).as_posix()
        try:
            mesh = io.read_mesh(path)
        except io.ShapeFileError as exc:
            print(f"{rel}: {exc}", file=sys.stderr)
            failed += 1
            continue
        v = mesh.vertices - (mesh.vertices.min(axis=0) + mesh.vertices.max(axis=0)) / 2
        v = v / np.ptp(v, axis=0).max()
        up, head = OVERRIDES.get(rel) or find_frame(_samples(io.Mesh(v, mesh.faces)))
        turned = v @ geometry.axis_rotation(up, head).T
        name = f"{path.parent.name}_{path.stem}"
        io.write_mesh(args.out / f"{name}.ply", turned, mesh.faces)
        items.append((name, _samples(io.Mesh(turned, mesh.faces), 4000)))
        print(f"{rel}: up {up}, head {head}{' (override)' if rel in OVERRIDES else ''}")
    if args.sheet:
        sheet(items, args.sheet)
        print(f"sheet: {args.sheet}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

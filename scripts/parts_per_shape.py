"""Present parts per shape of bundled models on their held-out ShapeNetVox32 shapes: counts and a histogram.

Usage (from the repository root, primkit importable)::

    python scripts/parts_per_shape.py [--model table=../shared/data/shapenetvox32/04379243 ...]
                                      [--limit 100] [--png docs/images/parts-per-shape.png]

For each ``MODEL=FOLDER`` (by default the bundled table and airplane on their ShapeNetVox32
folders): the files the model held out from training (its recorded rule, every 10th file by sorted
path, :func:`primkit.data.split_files`), ``--limit`` of them evenly spaced, are abstracted with
default flags (:func:`primkit.model.abstraction.abstract_shapes`, as ``primkit abstract`` does), and
the present cuboids of each are counted. Writes the counts to ``--json`` (by default
``parts_per_shape.json`` beside this script) and one histogram panel per model to ``--png``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from primkit import data
from primkit.model.abstraction import abstract_shapes, load_model

HERE = Path(__file__).resolve().parent
SHAPENET = HERE.parents[0].parent / "shared" / "data" / "shapenetvox32"
DEFAULTS = {"table": SHAPENET / "04379243", "airplane": SHAPENET / "02691156"}


def held_out_files(abstractor, folder, limit: int) -> tuple[list, int]:
    """``limit`` of the model's held-out files of ``folder``, evenly spaced by sorted path, and how many it holds out."""
    _, held = data.split_files(data.find_shape_files(folder), abstractor.hold_out_every)
    total = len(held)
    if limit and total > limit:
        held = [held[i] for i in np.unique(np.linspace(0, total - 1, limit).round().astype(int))]
    return held, total


def present_parts(model, folder, limit: int, workers=None) -> dict:
    abstractor = load_model(model)
    files, total = held_out_files(abstractor, folder, limit)
    out = abstract_shapes(files, abstractor, workers=workers)
    counts = {a.name: int(a.canonical.existence.sum()) for a in out}
    values = np.array(list(counts.values()))
    return {"folder": str(folder), "held_out": total, "shapes": len(values), "slots": abstractor.parts,
            "mean": float(values.mean()), "median": float(np.median(values)),
            "histogram": np.bincount(values, minlength=abstractor.parts + 1).tolist(),
            "per_shape": counts, "errors": list(out.errors)}


def draw(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(report)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.2), squeeze=False, sharey=True)
    for ax, name in zip(axes[0], names):
        r = report[name]
        h = np.array(r["histogram"])
        ax.bar(np.arange(len(h)), h, width=0.8, color="#4c78a8")
        ax.axvline(r["mean"], color="#e45756", linestyle="--", label=f"mean {r['mean']:.2f}")
        ax.set_xticks(np.arange(0, len(h), 2 if len(h) > 12 else 1))
        ax.set_xlim(-0.6, len(h) - 0.4)
        ax.set_xlabel(f"present parts (of {r['slots']} slots)")
        ax.set_title(f"{name}: {r['shapes']} held-out shapes")
        ax.legend(frameon=False)
    axes[0][0].set_ylabel("shapes")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", action="append", metavar="MODEL=FOLDER", default=[],
                    help="a model (bundled name or file) and its training folder; repeat for several "
                         "(default: table and airplane on ShapeNetVox32)")
    ap.add_argument("--limit", type=int, default=100, help="held-out shapes per model, evenly spaced (0: all)")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--json", type=Path, default=HERE / "parts_per_shape.json")
    ap.add_argument("--png", type=Path, default=None, help="draw the histograms here")
    args = ap.parse_args(argv)
    pairs = dict(p.split("=", 1) for p in args.model) if args.model else DEFAULTS
    report = {}
    for model, folder in pairs.items():
        r = report[model] = present_parts(model, folder, args.limit, args.workers)
        print(f"{model}: {r['shapes']} of {r['held_out']} held-out shapes, present parts mean {r['mean']:.2f}, "
              f"median {r['median']:.0f}, histogram {r['histogram']}")
        for e in r["errors"]:
            print(e, file=sys.stderr)
    args.json.write_text(json.dumps(report, indent=1))
    if args.png:
        draw(report, args.png)
    return 1 if any(r["errors"] for r in report.values()) else 0


if __name__ == "__main__":
    sys.exit(main())

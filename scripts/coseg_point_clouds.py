"""Point clouds through ``primkit segment``: how often a point sampled from a COSEG chair gets the
label its mesh's face gets.

    python scripts/coseg_point_clouds.py [--points 10000] [--refine 0] [--seed 0]

Samples ``--points`` area-uniform points from each of the 10 COSEG chairs in ``../shared/data``
(keeping the face of each), writes them as ``.xyz`` clouds, runs ``primkit segment`` once on the
meshes and once on the clouds (bundled chair model, the frames found without flags, as a user runs
it) and compares, at every point, the cloud's label with the label of the face it was sampled
from. Prints the agreement per chair and over all points.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "coseg_chairs"


def measure(points: int = 10000, refine: int = 0, seed: int = 0, workers: int = 1) -> list[dict]:
    """One row per chair: ``name``, ``points``, ``agree`` (cloud label == its face's label)."""
    from primkit import geometry, io
    from primkit.cli import main

    files = sorted(SHARED.glob("*/shapes/*.off"))
    if not files:
        raise FileNotFoundError(f"{SHARED}: no COSEG chairs")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        faces_of = {}
        for f in files:
            mesh = io.read_mesh(f)
            s = geometry.sample_surface(mesh.vertices, mesh.faces, points, seed=seed)
            io.write_points(tmp / "clouds" / f"{f.stem}.xyz", s.points)  # the stems are unique
            faces_of[f.stem] = s.face_index
        common = ["--model", "chair", "--refine", str(refine), "--workers", str(workers), "--cache", str(tmp / "cache")]
        for kind, inputs in (("meshes", [str(f) for f in files]), ("clouds", [str(tmp / "clouds")])):
            if main(["segment", *inputs, "-o", str(tmp / f"seg-{kind}"), *common]) != 0:
                raise RuntimeError(f"primkit segment failed on the {kind}")
        for name, face_index in faces_of.items():
            face = io.read_labels(tmp / "seg-meshes" / f"{name}.seg")
            cloud = np.load(tmp / "seg-clouds" / f"{name}.parts.npy")
            rows.append({"name": name, "points": len(cloud), "agree": float(np.mean(cloud == face[face_index]))})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10000)
    ap.add_argument("--refine", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    rows = measure(args.points, args.refine, args.seed)
    for r in rows:
        print(f"{r['name']:28s} {r['agree']:.4f}")
    total = sum(r["agree"] * r["points"] for r in rows) / sum(r["points"] for r in rows)
    print(f"all {sum(r['points'] for r in rows)} points: {total:.4f} agree with their face's label "
          f"(lowest chair {min(r['agree'] for r in rows):.4f}); refine {args.refine}", file=sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

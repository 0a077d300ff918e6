"""Draw again the README's pictures that show cuboids, with the bundled chair model:

    xvfb-run -a python scripts/readme_pictures.py [--out docs/images] [--refine 200]

* ``chair-coseg-refined.png``: the 10 COSEG chairs in ``../shared/data`` (front +Z), refined 200
  steps, each beside its cuboids (the pictures of ``scripts/build_bundled_models.py --pictures``);
* ``chair-heldout.png``: the first 8 of the chair model's held-out ShapeNetVox32 chairs (every
  10th file by sorted path, then evenly spaced to at most 200, as the build script evaluates them);
* ``viewer-abstraction.png``, ``viewer-deformation.png``, ``viewer-collection.png`` (segmentation),
  ``viewer-embedding.png`` (chair_0000 chosen): the viewers in real windows (under X, e.g.
  ``xvfb-run``; off screen without a display), on procedural chairs (``primkit generate chair -n 8``).

Existing pictures are replaced (they are this script's outputs).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"


def _picture(abstractor, shapes, path, note="", **predict):
    from primkit import geometry, io
    from primkit.viz.render import render_abstractions

    results = abstractor.predict(shapes, **predict)
    meshes = []
    for s in shapes:
        shape = io.read_shape(Path(s.source))
        if isinstance(shape, io.Mesh):
            meshes.append((shape.vertices, shape.faces))
        else:  # voxel grids: their boundary, in the input frame like a mesh
            v, f = geometry.voxel_boundary_mesh(s.solid)
            meshes.append((s.frame.from_canonical(v), f))
    render_abstractions(results, meshes, path, canonical=True, note=note)
    print(f"wrote {path}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    ap.add_argument("--refine", type=int, default=200)
    ap.add_argument("--cache", default=None)
    args = ap.parse_args(argv)

    import torch

    torch.set_num_threads(1)
    from primkit import data
    from primkit.cli import main as cli
    from primkit.model.abstractor import Abstractor

    abstractor = Abstractor.load("chair")
    args.out.mkdir(parents=True, exist_ok=True)
    if (SHARED / "coseg_chairs").is_dir():
        files = sorted((SHARED / "coseg_chairs").glob("*/shapes/*.off"))
        coll = data.prepare_collection(files, data.PrepareSettings(up="+y", front="+z"), cache_dir=args.cache,
                                       progress=False)
        _picture(abstractor, list(coll), args.out / "chair-coseg-refined.png", " (refined)", refine=args.refine)
        found = []
        for inp in abstractor.metadata["training"]["data"]["inputs"]:
            where = Path(inp) if Path(inp).is_absolute() else ROOT / inp
            if where.exists():
                found += data.find_shape_files(where)
        _, held = data.split_files(found, abstractor.hold_out_every)
        if held:
            held = held[:: int(np.ceil(len(held) / 200))] if len(held) > 200 else held
            coll = data.prepare_collection(held[:8], abstractor.settings, cache_dir=args.cache, progress=False)
            _picture(abstractor, list(coll), args.out / "chair-heldout.png")
    else:
        print(f"{SHARED}: not found; the COSEG and ShapeNet pictures are skipped", file=sys.stderr)

    window = ["--window"] if os.environ.get("DISPLAY") else []
    with tempfile.TemporaryDirectory() as tmp:
        chairs = Path(tmp) / "chairs"
        assert cli(["generate", "chair", "-n", "8", "-o", str(chairs)]) == 0
        common = ["--model", "chair", "--force", "--workers", "1", "--cache", str(Path(tmp) / "cache")]
        assert cli(["view", "abstraction", str(chairs / "chair_0001.ply"), "--png", str(args.out / "viewer-abstraction.png"),
                    "--size", "1000x700", *window, *common]) == 0
        assert cli(["view", "deformation", str(chairs / "chair_0001.ply"), str(chairs / "chair_0004.ply"),
                    "--png", str(args.out / "viewer-deformation.png"), "--size", "1100x600", *window, *common]) == 0
        assert cli(["view", "collection", str(chairs), "--mode", "segmentation",
                    "--png", str(args.out / "viewer-collection.png"), "--size", "1100x700", *window, *common]) == 0
        assert cli(["view", "embedding", str(chairs), "--select", "0",
                    "--png", str(args.out / "viewer-embedding.png"), "--size", "1100x750", *window, *common]) == 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

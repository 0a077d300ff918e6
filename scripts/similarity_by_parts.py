"""Similarity by chosen parts on procedural chairs whose attributes are known (the figures of
``primkit.embedding``'s notes and docs/results-applications.md, "Similarity by parts").

    python scripts/similarity_by_parts.py [--count 400] [--model chair] [--refine 0 100]

Generates ``--count`` procedural chairs (``synthetic.write_collection(..., "chair", count)``,
seed 0), abstracts them with the model (once per ``--refine`` value), and prints for three
descriptors: how often a chair's nearest neighbour agrees on "has arms" (all parts; back and seat
only) and the Spearman correlation between the back-orientation distance to the most upright
chair and the true back tilt.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np


def measure(count: int = 400, model: str = "chair", refine: int = 0, folder=None) -> dict:
    """``arms_all``, ``arms_back_seat`` (nearest-neighbour agreement on "has arms"), ``tilt_spearman``,
    ``chance`` (agreement by chance) for ``count`` procedural chairs."""
    from scipy.stats import spearmanr

    import primkit
    from primkit import embedding, synthetic

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(folder or tmp)
        if not any(folder.glob("chair_*.ply")):
            synthetic.write_collection(folder, "chair", count, seed=0)
        files = sorted(folder.glob("chair_*.ply"))[:count]
        attributes = [json.loads(f.with_suffix(".json").read_text())["attributes"] for f in files]
        arms = np.array([a["has_arms"] for a in attributes], int)
        tilt = np.array([a["back_tilt_deg"] for a in attributes])
        out = primkit.abstract_shapes([str(f) for f in files], model=model, refine=refine)
        names = out.model.part_names

        def agreement(parts, what="size,position,orientation,presence"):
            X = embedding.PartDescriptor(parts=parts, what=what, part_names=names).fit_transform(out.results)
            return embedding.neighbour_agreement(embedding.nearest_neighbors(X, k=1).indices, arms)

        X = embedding.PartDescriptor(parts="back", what="orientation", part_names=names).fit_transform(out.results)
        upright = int(np.argmin(tilt))
        distance = np.linalg.norm(X - X[upright], axis=1)
        p = arms.mean()
        return {"count": len(files), "refine": refine, "chance": float(p * p + (1 - p) * (1 - p)),
                "arms_fraction": float(p), "arms_all": agreement(None), "arms_back_seat": agreement("back,seat"),
                "tilt_spearman": float(spearmanr(distance, tilt).statistic)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=400)
    parser.add_argument("--model", default="chair")
    parser.add_argument("--refine", type=int, nargs="+", default=[0, 100])
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for refine in args.refine:
            row = measure(args.count, args.model, refine, folder=tmp)
            print(json.dumps(row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

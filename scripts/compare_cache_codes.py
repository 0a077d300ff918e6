"""Summary of scripts/compare_cache_codes.sh: per run and per kind of cache, the stage-2 loss (mean
of the second half of stage 2's logged totals) and held-out Chamfer-L1, IoU and part count (the
held-out files prepared exactly, the default flags), and how far apart the two kinds' means are in
float32 standard deviations (the bar: under one, for the loss, Chamfer and IoU).

    python scripts/compare_cache_codes.py OUT
"""

import json
import sys
from pathlib import Path

import numpy as np


def main(folder) -> int:
    import torch

    from primkit import data, load_model, metrics

    torch.set_num_threads(1)
    folder = Path(folder)
    files = [Path(line.strip()) for line in open(folder / "files.txt")]
    _, held = data.split_files(files, 10)
    shapes = list(data.prepare_collection(held, data.PrepareSettings(), progress=False, cache_dir=folder / "cache-exact"))
    table = {}
    for kind in ("exact", "compact"):
        rows = []
        for model in sorted(folder.glob(f"{kind}-s*.safetensors")):
            results = load_model(model).predict(shapes)
            scores = [metrics.score(r.canonical, r.canonical_shape(s)) for r, s in zip(results, shapes)]
            history = json.loads(model.with_name(model.name.replace(".safetensors", ".history.json")).read_text())
            stage2 = [r["total"] for r in history if r["stage"] == 2]
            rows.append({"run": model.stem, "stage2_total": float(np.mean(stage2[len(stage2) // 2:])),
                         "chamfer": float(np.mean([x.chamfer for x in scores])),
                         "iou": float(np.mean([x.iou for x in scores])), "parts": float(np.mean([x.parts for x in scores]))})
            print(json.dumps(rows[-1]), flush=True)
        table[kind] = rows
    print(f"\n{len(shapes)} held-out chairs; Chamfer-L1 in the canonical frame (longest side 1)")
    for key in ("stage2_total", "chamfer", "iou", "parts"):
        a = np.array([r[key] for r in table["exact"]])
        b = np.array([r[key] for r in table["compact"]])
        if len(a) < 2 or not len(b):
            continue
        spread = a.std(ddof=1)
        print(f"{key:13s} float32 {a.mean():.5f} +- {spread:.5f} (n={len(a)})  compact {b.mean():.5f} +- "
              f"{b.std(ddof=1) if len(b) > 1 else 0:.5f} (n={len(b)})  |difference| = {abs(a.mean() - b.mean()) / spread:.2f} sd")
    (folder / "summary.json").write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))

#!/usr/bin/env bash
# Name the part indices of the bundled models from procedural part-labelled shapes that primkit
# generates itself (seed 7, never used in training or tests), so the names are learned on shapes
# other than any evaluation set. Rewrites primkit/model/bundled/<name>.safetensors (weights unchanged).
set -euo pipefail
cd "$(dirname "$0")/.."
work="${1:-$(mktemp -d)}"
for category in chair table airplane animal; do
  .venv/bin/primkit generate "$category" -n 40 --seed 7 -o "$work/$category" --force
  .venv/bin/primkit name-parts "$work/$category" --model "primkit/model/bundled/$category.safetensors" \
    -o "primkit/model/bundled/$category.safetensors" --refine 200 --cache "$work/cache" --force
done

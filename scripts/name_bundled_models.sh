#!/usr/bin/env bash
# Name the part indices of trained models before they are built into bundled models
# (scripts/build_bundled_models.py --runs RUNS/named):
# - chair: from real labels, the first 100 PartNet validation chairs (scripts/partnet_chairs.py's
#   split; PartNet's part boxes as voxel labels), never the test part;
# - table, airplane, animal: from 40 procedural part-labelled shapes that primkit generates itself
#   (seed 7, never used in training or tests); no labelled real tables, airplanes or animals are in
#   ../shared (the Princeton segmentations are kept for evaluation). The animal's eight procedural
#   parts are named body, head, neck, legs (four) and tail.
# Usage: scripts/name_bundled_models.sh RUNS   (reads RUNS/NAME.safetensors, writes RUNS/named/NAME.safetensors)
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:?usage: $0 RUNS}"
work="$(mktemp -d)"
mkdir -p "$runs/named"
for category in chair table airplane animal; do
  model="$runs/$category.safetensors"
  [ -f "$model" ] || { echo "$model: missing, skipped" >&2; continue; }
  if [ "$category" = chair ]; then
    mapfile -t files < <(PYTHONPATH=scripts .venv/bin/python -c 'import partnet_chairs as p
print("\n".join(str(f) for f in p.split()[0][:100]))')
    .venv/bin/primkit name-parts "${files[@]}" --model "$model" -o "$runs/named/$category.safetensors" \
      --labels ../shared/data/partnet_chair_boxes --force
  else
    names=()
    [ "$category" = animal ] && names=(--names "0=body,1=head,2=neck,3=legs,4=legs,5=legs,6=legs,7=tail")
    .venv/bin/primkit generate "$category" -n 40 --seed 7 -o "$work/$category" --force
    .venv/bin/primkit name-parts "$work/$category" --model "$model" -o "$runs/named/$category.safetensors" \
      --refine 200 --cache "$work/cache" --force "${names[@]}"
  fi
done

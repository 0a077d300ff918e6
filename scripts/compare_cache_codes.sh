#!/usr/bin/env bash
# Train with the float32 cache and with compact codes (PRIMKIT_CACHE_CODES=compact), several seeds
# each, then compare stage-2 losses and held-out Chamfer-L1 / IoU (scripts/compare_cache_codes.py).
#
#   bash scripts/compare_cache_codes.sh OUT [SHAPES=600] [SEEDS=5] [STAGE1=1500] [STAGE2=1000]
#
# The first SHAPES ShapeNetVox32 chairs of ../shared/data (sorted), the chair preset with the given
# schedule, every 10th file held out. The two runs of a seed go side by side, one thread each
# (about 5.5 min a pair on 2 cores at the defaults). Figures of 2026-12-02 are in the README's
# cache paragraph.
set -euo pipefail
cd "$(dirname "$0")/.."
out=$1; shapes=${2:-600}; seeds=${3:-5}; s1=${4:-1500}; s2=${5:-1000}
mkdir -p "$out"
ls ../shared/data/shapenetvox32/03001627 | sed -n "1,${shapes}p" | sed "s#^#$PWD/../shared/data/shapenetvox32/03001627/#; s#\$#/model.binvox#" > "$out/files.txt"
run() {  # name codes seed
  PRIMKIT_THREADS=1 OMP_NUM_THREADS=1 PRIMKIT_CACHE_CODES=$2 .venv/bin/primkit train $(cat "$out/files.txt") \
    -o "$out/$1.safetensors" --preset chair --stage1 "$s1" --stage2 "$s2" --seed "$3" \
    --cache "$out/cache-$2" --workers 1 --force > "$out/$1.log" 2>&1
}
for ((s = 0; s < seeds; s++)); do
  run "exact-s$s" exact "$s" & run "compact-s$s" compact "$s" & wait
done
.venv/bin/python scripts/compare_cache_codes.py "$out"

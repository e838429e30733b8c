#!/usr/bin/env bash
# The stage-1 cases beyond the paper (issue 32), trained on the simulator's training split:
#   input-pa  Input Fusion fine-tuned with the perturbation injected (α drawn as the refiner's
#             training draws it: 0 with probability 0.4, else 0.02 … 0.1)
#   input-tr  the same, with each voxel's mean tr(Ξ) as nz more input channels (they start at
#             zero, so the first step computes what Input Fusion computes)
# Both start from MODELS/input.safetensors (the v4 Input Fusion) and keep its recipe (transfer
# augmentation, no intensity). Resumable: re-run the same command after a kill; a finished model
# is skipped. Each model's wall time goes to OUT/times.tsv; the union cases (mlod-u, mlod-u-tr)
# need no training.
#
# Usage: scripts/train-beyond.sh DATA MODELS OUT
#   DATA    a folder holding train/ (scripts/train-v4.sh's)
#   MODELS  the folder holding input.safetensors
#   OUT     where the weights, loss CSVs, checkpoints and logs go
# STEPS (default 3000), SEED (default 5), LR (default 1e-3) and MLOD_BIN (default
# target/release/mlod) can be set in the environment.
set -euo pipefail
cd "$(dirname "$0")/.."
data=${1:?DATA}
models=${2:?MODELS}
out=${3:?OUT}
steps=${STEPS:-3000}
seed=${SEED:-5}
lr=${LR:-1e-3}
bin=${MLOD_BIN:-target/release/mlod}
mkdir -p "$out"
export MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=1000000000000 MALLOC_TOP_PAD_=1073741824
for c in input-pa input-tr; do
  if [ -f "$out/$c.safetensors" ]; then
    echo "$c: done"
    continue
  fi
  resume=()
  [ -f "$out/$c.ckpt.safetensors" ] && resume=(--resume)
  echo "$c: training ${resume[*]}"
  t0=$(date +%s)
  "$bin" train stage1 --case "$c" --dataset "$data/train" --init "$models/input.safetensors" \
    --out "$out/$c.safetensors" --steps "$steps" --seed "$seed" --lr "$lr" --transfer-aug --no-intensity \
    --checkpoint "$out/$c.ckpt.safetensors" "${resume[@]}" >> "$out/train-$c.log" 2>&1
  printf '%s\t%s\n' "$c" "$(( $(date +%s) - t0 ))" >> "$out/times.tsv"
done
echo "all done"

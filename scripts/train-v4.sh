#!/usr/bin/env bash
# The training chain of the shipped models (issue 29; first run for the v4 world, then for the
# walled one that ships): every stage-1 case trained from scratch with the transfer augmentation
# and without intensity, then temperatures, voting, both refiners and their decoding. Resumable: re-run the same
# command after a kill; a finished model is skipped and an interrupted one continues from its
# checkpoint. Each step's wall time goes to OUT/times.tsv.
#
# Usage: scripts/train-v4.sh DATA OUT [CASE...]
#   DATA  a folder holding train/, made by
#         mlod synth --out DATA/train --scenes 80 --samples-per-scene 20 --seed 101
#         (the walled world, the default; add --world v4 for the v4 world)
#   OUT   where the weights, loss CSVs, checkpoints and logs go
#   CASE  top input left right feature (default: all five, in that order); Result Fusion
#         reuses top/left/right
# The binary is target/release/mlod (cargo build --release); STEPS (default 6000, the stage-1
# steps), REFINER_STEPS (default 12000: 6000 left the refiner under-trained, docs/robustness.md
# "A third training lever") and SEED (default 4) can be set in the environment.
set -euo pipefail
cd "$(dirname "$0")/.."
data=${1:?DATA}
out=${2:?OUT}
shift 2
cases=("$@")
[ ${#cases[@]} -gt 0 ] || cases=(top input left right feature)
steps=${STEPS:-6000}
refiner_steps=${REFINER_STEPS:-12000}
seed=${SEED:-4}
mkdir -p "$out"
bin=${MLOD_BIN:-target/release/mlod}
export MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=1000000000000 MALLOC_TOP_PAD_=1073741824

for c in "${cases[@]}"; do
  if [ -f "$out/$c.safetensors" ]; then
    echo "$c: done"
    continue
  fi
  resume=()
  [ -f "$out/$c.ckpt.safetensors" ] && resume=(--resume)
  echo "$c: training ${resume[*]}"
  t0=$(date +%s)
  "$bin" train stage1 --case "$c" --dataset "$data/train" --out "$out/$c.safetensors" \
    --steps "$steps" --seed "$seed" --transfer-aug --no-intensity \
    --checkpoint "$out/$c.ckpt.safetensors" "${resume[@]}" >> "$out/train-$c.log" 2>&1
  printf '%s\t%s\n' "$c" "$(( $(date +%s) - t0 ))" >> "$out/times.tsv"
done

# Phase 2, once all five stage-1 models exist: Result Fusion's temperatures, box voting, the
# refiners' proposals, both refiners and their decoding, and the training data's summary. Each
# stage leaves OUT/.done-NAME and is skipped when that is there.
for c in top input left right feature; do
  [ -f "$out/$c.safetensors" ] || { echo "stage 1 incomplete ($c missing): phase 2 waits"; exit 0; }
done
stage() {
  local name=$1
  shift
  if [ -f "$out/.done-$name" ]; then
    echo "$name: done"
    return 0
  fi
  echo "$name: running"
  local t0
  t0=$(date +%s)
  "$@" >> "$out/$name.log" 2>&1
  printf '%s\t%s\n' "$name" "$(( $(date +%s) - t0 ))" >> "$out/times.tsv"
  touch "$out/.done-$name"
}
stage temperature "$bin" train calibrate-temperature --dataset "$data/train" --models "$out"
stage vote "$bin" train tune-vote --dataset "$data/train" --models "$out"
stage proposals "$bin" train proposals --dataset "$data/train" --models "$out" --out "$out/proposals"
refiner_resume=()
[ -f "$out/refiner.ckpt.safetensors" ] && refiner_resume=(--resume)
stage refiner "$bin" train refiner --dataset "$data/train" --proposals "$out/proposals" \
  --out "$out/refiner.safetensors" --steps "$refiner_steps" --seed 0 --log-every 100 "${refiner_resume[@]}"
notrace_resume=()
[ -f "$out/refiner-notrace.ckpt.safetensors" ] && notrace_resume=(--resume)
stage refiner-notrace "$bin" train refiner --dataset "$data/train" --proposals "$out/proposals" \
  --out "$out/refiner-notrace.safetensors" --steps "$refiner_steps" --seed 0 --log-every 100 --no-trace "${notrace_resume[@]}"
stage tune-refiner "$bin" train tune-refiner --dataset "$data/train" --models "$out"
stage tune-union "$bin" train tune-refiner --dataset "$data/train" --models "$out" --union-only \
  --union-cases mlod-u,mlod-ir-drop --union-nms 0.3,0.5,0.7 --union-vote 0.5,0.6,0.7
stage stats "$bin" stats --dataset "$data/train" --samples 200 --summary --update-manifest "$out"
echo "all done"

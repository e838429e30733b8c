#!/usr/bin/env bash
# v3 stage-1 models: every shipped v2 model fine-tuned 1000 steps with ground-truth sampling
# (SECOND's dataset sampling, paper §V-A-5). Resumable: re-run the same command after a kill; a
# finished model is skipped and an interrupted one continues from its checkpoint.
#
# Usage: scripts/train-v3.sh DATA OUT [CASE...]
#   DATA  a folder holding train/ (mlod synth --scenes 80 --samples-per-scene 20 --seed 101)
#   OUT   where the v3 weights, loss CSVs, checkpoints and logs go (its manifest.json gets entries);
#         assets/models/v3 holds the runs finished so far (scripts/train-v3.sh DATA assets/models/v3
#         trains only what is missing there)
#   CASE  top input left right feature (default: all five, in that order)
# Two runs go side by side with one thread each (the fastest use of 2 cores, see
# ../shared/notes/candle-cpu.md); the binary is target/release/mlod (cargo build --release).
set -euo pipefail
cd "$(dirname "$0")/.."
data=${1:?DATA}
out=${2:?OUT}
shift 2
cases=("$@")
[ ${#cases[@]} -gt 0 ] || cases=(top input left right feature)
mkdir -p "$out"
bin=target/release/mlod
# The starting points: the v2 models as committed in a62254a, with their manifest (so each v3
# entry records its v2 entry and the chain before it).
v2=a62254a
start="${TMPDIR:-/tmp}/mlod-v2-$v2"
mkdir -p "$start"
git show "$v2:assets/models/manifest.json" > "$start/manifest.json"
for c in "${cases[@]}"; do
  git show "$v2:assets/models/$c.safetensors" > "$start/$c.safetensors"
done
export RAYON_NUM_THREADS=1 MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=1000000000000 MALLOC_TOP_PAD_=1073741824

one() {
  local c=$1
  if [ -f "$out/$c.safetensors" ]; then
    echo "$c: done"
    return 0
  fi
  local resume=()
  [ -f "$out/$c.ckpt.safetensors" ] && resume=(--resume)
  echo "$c: training ${resume[*]}"
  "$bin" train stage1 --case "$c" --dataset "$data/train" --out "$out/$c.safetensors" \
    --init "$start/$c.safetensors" --steps 1000 --lr 5e-4 --seed 4 --gt-sample 40 \
    --checkpoint "$out/$c.ckpt.safetensors" "${resume[@]}" >> "$out/train-$c.log" 2>&1
}

# Two at a time.
i=0
while [ $i -lt ${#cases[@]} ]; do
  one "${cases[$i]}" &
  a=$!
  b=""
  if [ $((i + 1)) -lt ${#cases[@]} ]; then
    one "${cases[$((i + 1))]}" &
    b=$!
  fi
  wait $a
  [ -z "$b" ] || wait $b
  i=$((i + 2))
done
echo "all done"

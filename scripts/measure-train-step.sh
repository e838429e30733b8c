#!/usr/bin/env bash
# Side by side on this machine (issue 28): a stage-1 training step of BIN against PyTorch eager's.
#   scripts/measure-train-step.sh BIN [REPS] [DATA]
# Per rep: the whole step of `mlod train stage1` ((wall of --steps 25 − wall of --steps 5) / 20,
# data preparation included), the trainer's own network median (fwd + bwd + opt of steps 6–25)
# and PyTorch eager's median for the same network, loss and AdamW (scripts/torch_train_step.py,
# 2 threads). DATA (default data/small) is `mlod synth --out data/small --scenes 2
# --samples-per-scene 10 --seed 5`. PAUSE / RESUME, if set, are commands run before and after
# (e.g. to stop a background training that shares the cores).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=$(readlink -f "${1:?BIN}"); reps=${2:-3}; data=$(readlink -f "${3:-data/small}")
here=$(pwd)
export MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=1000000000000 MALLOC_TOP_PAD_=1073741824
[ -n "${PAUSE:-}" ] && eval "$PAUSE"
trap '[ -n "${RESUME:-}" ] && eval "$RESUME"' EXIT
d=$(mktemp -d)
for rep in $(seq "$reps"); do
  for s in 5 25; do
    t0=$(date +%s.%N)
    (cd "$d" && "$bin" train stage1 --case top --dataset "$data" --out "$d/top.safetensors" \
      --steps $s --seed 1 --log-every 1 > "$d/log-$rep-$s.txt" 2>&1)
    t1=$(date +%s.%N); eval "w$s=$(echo "$t1 - $t0" | bc)"
  done
  echo "rep $rep whole step ms: $(echo "($w25 - $w5) * 50" | bc)"
  python3 -c "import re,statistics as st; L=[l for l in open('$d/log-$rep-25.txt') if l.startswith('step ')][5:]; v=[sum(int(x) for x in re.search(r'fwd (\d+) bwd (\d+) opt (\d+)',l).groups()) for l in L]; print('  native network median', st.median(v), 'min', min(v))"
  python3 "$here/scripts/torch_train_step.py" --threads 2 --steps 20 2>&1 | grep stage1
done
sha256sum "$d/top.safetensors"

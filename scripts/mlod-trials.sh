#!/usr/bin/env bash
# Perturbation trials (issue 17): car moderate AP_3D@0.7, mean ± std over five perturbation
# draws (seeds 0-4), for each fusion scheme and its MLOD case, at each α.
# Usage: scripts/mlod-trials.sh DATASET [MODELS] [OUT]   (e.g. data/test assets/models out/trials)
# Each line is one `mlod eval --case C --alpha A --seeds 0,1,2,3,4`; its JSON goes to OUT/C-A.json.
# LiDAR-Top does not see the perturbation (only the auxiliary LiDARs are perturbed): its α = 0
# figure stands for every α.
set -euo pipefail
data=${1:?usage: scripts/mlod-trials.sh DATASET [MODELS] [OUT]}
models=${2:-assets/models}
out=${3:-out/trials}
mlod=${MLOD:-mlod}
mkdir -p "$out"
for a in ${ALPHAS:-0.04 0.1}; do
  for c in ${CASES:-input mlod-i feature mlod-f result mlod-r}; do
    "$mlod" eval --dataset "$data" --models "$models" --case "$c" --alpha "$a" --seeds "${SEEDS:-0,1,2,3,4}" \
      --out "$out/$c-$a.json"
  done
done

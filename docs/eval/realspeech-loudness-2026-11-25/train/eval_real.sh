#!/usr/bin/env bash
# usage: eval_real.sh NAME CKPT  -> real-speech validation split, Python reference, seeds 19-21 and 22-24
set -euo pipefail
name=$1 ckpt=$2
cd "$(dirname "$0")/../../../.."
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
D=docs/eval/realspeech-loudness-2026-11-25/real
for s in 19 22; do
  t0=$(date +%s)
  nice -n 10 $LIVEGESTURE_PY -m livegesture.eval.generalise --checkpoint $ckpt --n-realisations 3 --seed $s \
    --out $D/${name}_real_seeds$s-$((s+2)).json > /dev/null
  echo "$name real seed $s: $(( $(date +%s) - t0 )) s ($(date -u +%H:%M:%S))"
done

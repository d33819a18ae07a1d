#!/usr/bin/env bash
# real-speech rules 1-3 first, then export and the in-distribution seeds 7-12
set -euo pipefail
cd /work/wt-scratch16
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
T=docs/eval/realspeech-scratch-2026-11-25/train
CK=/work/runs-scratch16/scratch/final.pt
bash $T/eval_real.sh scratch $CK
t0=$(date +%s)
nice -n 10 $LIVEGESTURE_PY export/export.py --checkpoint $CK --out /tmp/scratch16/bundle \
  --reference-wav models/default/reference/clip.wav --reference-seconds 60 > /tmp/scratch16/export.log 2>&1
echo "export: $(( $(date +%s) - t0 )) s ($(date -u +%H:%M:%S))"
bash $T/eval_synth.sh scratch /tmp/scratch16/bundle
echo EVALDONE

#!/usr/bin/env bash
# fusewise recipe (third sitting of docs/eval/realspeech-ft-2026-11-25), training seed 11 instead of 7
set -euo pipefail
cd /work/wt-ft16
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
PY=$LIVEGESTURE_PY
COMMON="--config default --data /tmp/corpus_default --extra-data /tmp/corpus_default --extra-data /tmp/corpus_rs --speakers all --threads 1 --init-from models/default.train/checkpoint.pt --augment 0 --steps-experts 800 --steps-fuse 400 --seed 11"
t0=$(date +%s); echo "start $(date -u)"
nice -n 5 $PY -m livegesture.train $COMMON --out /work/runs-ft16/lr5e5_s11 --lr-ar 5e-5 --stage experts
t1=$(date +%s); echo "experts done $(date -u) $((t1-t0)) s"
mkdir -p /work/runs-ft16/lr5e5all_s11
cp /work/runs-ft16/lr5e5_s11/{svq1,svq2,experts}.pt /work/runs-ft16/lr5e5all_s11/
nice -n 5 $PY -m livegesture.train $COMMON --out /work/runs-ft16/lr5e5_s11 --lr-ar 2e-4
t2=$(date +%s); echo "fuse 2e-4 done $(date -u) $((t2-t1)) s"
nice -n 5 $PY -m livegesture.train $COMMON --out /work/runs-ft16/lr5e5all_s11 --lr-ar 5e-5
t3=$(date +%s); echo "fuse 5e-5 done $(date -u) $((t3-t2)) s"
echo TRAINDONE

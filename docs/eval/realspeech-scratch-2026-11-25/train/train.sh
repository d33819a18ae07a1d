#!/usr/bin/env bash
# the single candidate of README.md "The rule": all four stages from scratch, default stage lengths
set -euo pipefail
cd /work/wt-scratch16
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
L=docs/eval/realspeech-scratch-2026-11-25/train
t0=$(date +%s); echo "start $(date -u)"
nice -n 5 $LIVEGESTURE_PY -m livegesture.train --config default --data /tmp/corpus_default \
  --extra-data /tmp/corpus_default --extra-data /tmp/corpus_rs --out /work/runs-scratch16/scratch \
  --speakers all --threads 1 --augment 0 --seed 0
echo "train done $(date -u) $(( $(date +%s) - t0 )) s"
cp /work/runs-scratch16/scratch/train_log.jsonl $L/scratch_train_log.jsonl
echo TRAINDONE

#!/usr/bin/env bash
# usage: train.sh NAME  -> NAME = flux1 | flux2 (the original flux-driven corpora, training seed 1 | 2) or
# sylb1 .. sylb4 (the syllable-body corpora, seed 1 .. 4). The recipe of ../realspeech-loudness-2026-11-25 ("loud",
# "flux", "sylb" there were seed 0): svq1/svq2 from the shipped checkpoint, experts 3000 and fuse 1600 steps, the
# clean corpus counted twice + the real-like corpus (the real-speech TRAIN split x 8, espeak-ng and flite voices).
set -euo pipefail
name=$1
case $name in
  flux1|flux2) C=/tmp/corpus_default R=/tmp/corpus_rs ;;
  sylb1|sylb2|sylb3|sylb4) C=/tmp/corpus_sylb R=/tmp/corpus_rs_sylb ;;
  *) echo "usage: train.sh flux1|flux2|sylb1|sylb2|sylb3|sylb4" >&2; exit 2 ;;
esac
seed=${name: -1}
cd "$(dirname "$0")/../../../.."
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
L=docs/eval/realspeech-seeds-2026-11-26/train
t0=$(date +%s); echo "start $(date -u)"
nice -n 5 $LIVEGESTURE_PY -m livegesture.train --config default --data $C --extra-data $C --extra-data $R \
  --out /work/runs-seeds16/$name --speakers all --threads 1 --augment 0 --seed $seed \
  --svq-from models/default.train/checkpoint.pt --steps-experts 3000 --steps-fuse 1600
echo "train done $(date -u) $(( $(date +%s) - t0 )) s"
cp /work/runs-seeds16/$name/train_log.jsonl $L/${name}_train_log.jsonl
echo TRAINDONE

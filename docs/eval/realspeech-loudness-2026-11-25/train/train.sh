#!/usr/bin/env bash
# usage: train.sh NAME  -> NAME = loud (the candidate: loudness-driven corpora), flux (the ablation: the
# original flux-driven corpora, the same audio) or syl (the next sitting's candidate: syllable-driven corpora);
# recipe of README.md "The rule". A later sitting reuses the recipe with SEED (default 0), OUT (the run folder,
# default /work/runs-loud16/NAME) and LOG (where the training log is copied, default this folder's NAME_train_log.jsonl).
set -euo pipefail
name=$1
case $name in
  loud) C=/tmp/corpus_loud R=/tmp/corpus_rs_loud ;;
  flux) C=/tmp/corpus_default R=/tmp/corpus_rs ;;
  syl) C=/tmp/corpus_syl R=/tmp/corpus_rs_syl ;;
  sylb) C=/tmp/corpus_sylb R=/tmp/corpus_rs_sylb ;;
  *) echo "usage: train.sh loud|flux|syl|sylb" >&2; exit 2 ;;
esac
cd "$(dirname "$0")/../../../.."
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
OUT=${OUT:-/work/runs-loud16/$name}
LOG=${LOG:-docs/eval/realspeech-loudness-2026-11-25/train/${name}_train_log.jsonl}
t0=$(date +%s); echo "start $(date -u)"
nice -n 5 $LIVEGESTURE_PY -m livegesture.train --config default --data $C --extra-data $C --extra-data $R \
  --out "$OUT" --speakers all --threads 1 --augment 0 --seed "${SEED:-0}" \
  --svq-from models/default.train/checkpoint.pt --steps-experts 3000 --steps-fuse 1600
echo "train done $(date -u) $(( $(date +%s) - t0 )) s"
cp "$OUT/train_log.jsonl" "$LOG"
echo TRAINDONE

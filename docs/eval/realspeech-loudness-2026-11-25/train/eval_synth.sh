#!/usr/bin/env bash
# usage: eval_synth.sh NAME BUNDLE  -> synthetic test split of the ORIGINAL corpus (/tmp/corpus_default, flux-driven
# motion: the yardstick of today's figures), Rust tract, seeds 7-12, each seed scored alone
set -euo pipefail
name=$1 bundle=$2
cd "$(dirname "$0")/../../../.."
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
BIN=/tmp/loud16/livegesture
D=$PWD/docs/eval/realspeech-loudness-2026-11-25/synth
for s in ${SEEDS:-7 8 9 10 11 12}; do
  t0=$(date +%s)
  d=/tmp/loud16/ev_$name/generated_seed$s; mkdir -p $d
  for id in $(awk -F, '$2=="test"{print $1}' /tmp/corpus_default/train_test_split.csv); do
    nice -n 10 $BIN generate /tmp/corpus_default/wave16k/$id.wav -o $d/$id.npz --bundle $bundle \
      --backend tract --seed $s 2>/dev/null
  done
  t1=$(date +%s)
  (cd python && nice -n 10 $LIVEGESTURE_PY -m livegesture.eval --data /tmp/corpus_default --split test --generated $d \
    --fgd-encoder /tmp/corpus_default/fgd_encoder.pt --out $D/${name}_s$s.json > /dev/null)
  echo "$name synth seed $s: generate $((t1-t0)) s, score $(( $(date +%s) - t1 )) s ($(date -u +%H:%M:%S))"
done

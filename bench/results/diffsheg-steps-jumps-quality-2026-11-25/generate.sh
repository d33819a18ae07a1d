#!/usr/bin/env bash
# DiffSHEG steps x jumps quality (BENCHMARKS.md): every test clip of CORPUS, seeds 1 and 2, with the Rust CLI on ort.
#   CORPUS=DIR OUT=DIR bash bench/results/diffsheg-steps-jumps-quality-2026-11-25/generate.sh   (ORT_DYLIB_PATH set)
set -e
cd "$(dirname "$0")/../../.."
ids=$(awk -F, '$2=="test"{print $1}' ${CORPUS:-/tmp/dsheg/corpus_default}/train_test_split.csv | sort)
for sj in 10x1 10x2 25x1 25x2; do
  s=${sj%x*}; j=${sj#*x}
  t0=$(date +%s.%N)
  for seed in 1 2; do
    d=${OUT:-/tmp/dsheg/sjall}/$sj/seed$seed; mkdir -p $d
    for id in $ids; do
      ./target/release/livegesture generate ${CORPUS:-/tmp/dsheg/corpus_default}/wave16k/$id.wav -o $d/$id.npz --bundle models/diffsheg --backend ort --seed $seed --ddim-steps $s --jumps $j 2>/dev/null
    done
  done
  echo "$sj $(python3 -c "import time;print(round(time.time()-$t0,1))") s"
done

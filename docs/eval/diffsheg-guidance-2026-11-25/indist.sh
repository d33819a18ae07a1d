#!/usr/bin/env bash
# docs/eval/diffsheg-guidance-2026-11-25: the shipped DiffSHEG bundle on the SYNTHETIC test split (15 clips,
# 9.5 min) per guidance x jumps, through the Rust CLI (ort, 1 thread): seeds 1-3 of every clip from the
# corpus's own wave16k WAVs (what scripts/eval_bundle.sh does), then
#   - python -m livegesture.eval on seeds 1 and 2 (BC own/other, L1 div, FGD with CORPUS/fgd_encoder.pt,
#     face error: the same report as scripts/eval_bundle.sh ... 2),
#   - python -m livegesture.eval.generalise --synth on seeds 1-3 (own minus other audio, held-out synthetic).
#   O=OUT_DIR CORPUS=/tmp/corpus_default SETTINGS="1.25x2 2.0x1" bash docs/eval/diffsheg-guidance-2026-11-25/indist.sh
set -euo pipefail
cd "$(dirname "$0")/../../.."
O=${O:-/tmp/dsguide}; C=${CORPUS:-/tmp/corpus_default}; bin=${LIVEGESTURE_BIN:-./target/release/livegesture}
for gu in ${SETTINGS:?}; do
  g=${gu%x*}; u=${gu#*x}
  for seed in 1 2 3; do
    d=$O/$gu/synth_seed$seed; mkdir -p "$d"
    for id in $(awk -F, '$2=="test"{print $1}' "$C/train_test_split.csv"); do
      [ -f "$d/$id.npz" ] || nice -n 10 "$bin" generate "$C/wave16k/$id.wav" -o "$d/$id.npz" --bundle models/diffsheg \
        --backend ort --threads 1 --seed "$seed" --guidance "$g" --jumps "$u" 2>/dev/null
    done
  done
  echo "$gu generated $(date -u +%H:%M:%S)"
  (cd python && OMP_NUM_THREADS=1 nice -n 10 $LIVEGESTURE_PY -m livegesture.eval --data "$C" --split test \
    --generated "$O/$gu/synth_seed1" --generated "$O/$gu/synth_seed2" --out "$O/$gu/eval.json" > "$O/$gu/eval.txt" 2> "$O/$gu/eval.log")
  OMP_NUM_THREADS=1 nice -n 10 $LIVEGESTURE_PY -m livegesture.eval.generalise --no-real --synth "$C" \
    --generated-synth "$O/$gu/synth_seed1" --generated-synth "$O/$gu/synth_seed2" --generated-synth "$O/$gu/synth_seed3" \
    --out "$O/$gu/synth_123.json" > "$O/$gu/synth_123.log" 2>&1
  echo "$gu evaluated $(date -u +%H:%M:%S)"
done

#!/usr/bin/env bash
# docs/eval/diffsheg-confirm-2026-11-25: one DiffSHEG bundle through the Rust CLI (ort, 1 thread, guidance 3.0 x 2
# jumps), the same pipeline for the shipped and the continued model:
#   PART=real:  real-speech validation split, seeds 7-12 -> O/real/seedS, O/real_789101112.json (generalise, both
#               designs) and O/headtail_789101112.json (headtail.py, trims 0 / 0.5 / 1.0 s)
#   PART=synth: synthetic test split (15 clips, CORPUS/wave16k), seeds 1-2 -> O/synth_seedS, O/eval.json
#               (python -m livegesture.eval: BC, L1 div, FGD with CORPUS/fgd_encoder.pt, face MSE) and
#               O/synth_12.json (generalise --synth)
#   BUNDLE=/tmp/dstrain/bundle O=/tmp/dstrain/eval_cont PART=real bash docs/eval/diffsheg-confirm-2026-11-25/eval_bundle.sh
# Needs source scripts/env.sh and PYTHONPATH=python; LIVEGESTURE_BIN: the built CLI.
set -euo pipefail
cd "$(dirname "$0")/../../.."
D=docs/eval/diffsheg-confirm-2026-11-25
O=${O:?}; B=${BUNDLE:?}; C=${CORPUS:-/tmp/corpus_default}; bin=${LIVEGESTURE_BIN:-./target/release/livegesture}
gen() { [ -f "$2" ] || nice -n 10 "$bin" generate "$1" -o "$2" --bundle "$B" --backend ort --threads 1 --seed "$3" \
  --guidance 3.0 --jumps 2 2>/dev/null; }
case ${PART:?} in
real)
  [ -d "$O/audio/real" ] || $LIVEGESTURE_PY -m livegesture.eval.generalise --write-audio "$O/audio" >/dev/null
  args=()
  for s in 7 8 9 10 11 12; do
    mkdir -p "$O/real/seed$s"
    for wav in "$O"/audio/real/*.wav; do gen "$wav" "$O/real/seed$s/$(basename "$wav" .wav).npz" "$s"; done
    args+=(--generated-real "$O/real/seed$s")
    echo "real seed $s $(date -u +%H:%M:%S)"
  done
  OMP_NUM_THREADS=1 nice -n 10 $LIVEGESTURE_PY -m livegesture.eval.generalise "${args[@]}" --out "$O/real_789101112.json" \
    > "$O/real_789101112.log" 2>&1
  OMP_NUM_THREADS=1 nice -n 10 $LIVEGESTURE_PY $D/headtail.py ${args[@]//--generated-real/--generated} --trim 0 0.5 1.0 \
    --check "$O/real_789101112.json" --out "$O/headtail_789101112.json" > "$O/headtail_789101112.txt"
  ;;
synth)
  for s in 1 2; do
    mkdir -p "$O/synth_seed$s"
    for id in $(awk -F, '$2=="test"{print $1}' "$C/train_test_split.csv"); do
      gen "$C/wave16k/$id.wav" "$O/synth_seed$s/$id.npz" "$s"
    done
    echo "synth seed $s $(date -u +%H:%M:%S)"
  done
  (cd python && OMP_NUM_THREADS=1 nice -n 10 $LIVEGESTURE_PY -m livegesture.eval --data "$C" --split test \
    --fgd-encoder "$C/fgd_encoder.pt" --generated "$O/synth_seed1" --generated "$O/synth_seed2" --out "$O/eval.json" \
    > "$O/eval.txt" 2> "$O/eval.log")
  OMP_NUM_THREADS=1 nice -n 10 $LIVEGESTURE_PY -m livegesture.eval.generalise --no-real --synth "$C" \
    --generated-synth "$O/synth_seed1" --generated-synth "$O/synth_seed2" --out "$O/synth_12.json" > "$O/synth_12.log" 2>&1
  ;;
*) echo "PART must be real or synth" >&2; exit 2 ;;
esac
echo "$PART done $(date -u +%H:%M:%S)"

#!/usr/bin/env bash
# Sampling-settings sweep of a LiveGesture bundle (temperature x top_k; guidance stays the bundle's, SPEC 1.25):
# per setting, the in-distribution report (scripts/eval_bundle.sh: synthetic test split, 2 seeds, FGD with
# CORPUS/fgd_encoder.pt, BC, L1 diversity, face error) and the generalisation check (real-speech validation
# split, 3 seeds; synthetic test split = the same 2 seeds' motion), both designs.
#   bash docs/eval/realspeech-metric-2026-11-25/sweep.sh BUNDLE CORPUS OUT_DIR "T:K T:K ..." [BACKEND=tract]
# LIVEGESTURE_BIN: an already built CLI (otherwise target/release/livegesture is built).
set -euo pipefail
cd "$(dirname "$0")/../../.."
source scripts/env.sh >/dev/null
bundle=$1 corpus=$2 out=$3 settings=$4 backend=${5:-tract}
bin=${LIVEGESTURE_BIN:-./target/release/livegesture}
[ -n "${LIVEGESTURE_BIN:-}" ] || cargo build --release -q -p livegesture
export LIVEGESTURE_BIN=$bin PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}"
mkdir -p "$out"
"$LIVEGESTURE_PY" -m livegesture.eval.generalise --write-audio "$out/audio"
for tk in $settings; do
  t=${tk%%:*} k=${tk##*:}
  d="$out/T${t}_K${k}"; mkdir -p "$d"
  export GENERATE_ARGS="--temperature $t --top-k $k"
  echo "== temperature $t top_k $k ($(date -u +%H:%M:%S))"
  bash scripts/eval_bundle.sh "$bundle" "$corpus" "$d" 2 "$backend" > "$d/eval_bundle.log" 2>&1
  args=()
  for s in 1 2 3; do
    g="$d/generated_real_seed$s"; mkdir -p "$g"
    for wav in "$out/audio/real"/*.wav; do
      "$bin" generate "$wav" -o "$g/$(basename "$wav" .wav).npz" --bundle "$bundle" --backend "$backend" \
        --seed "$s" $GENERATE_ARGS 2>/dev/null
    done
    args+=(--generated-real "$g")
  done
  "$LIVEGESTURE_PY" -m livegesture.eval.generalise --synth "$corpus" "${args[@]}" \
    --generated-synth "$d/generated_seed1" --generated-synth "$d/generated_seed2" --out "$d/generalise.json" \
    > "$d/generalise.log" 2>&1
done
echo "sweep done ($(date -u +%H:%M:%S))"

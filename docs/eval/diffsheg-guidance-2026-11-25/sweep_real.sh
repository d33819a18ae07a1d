#!/usr/bin/env bash
# docs/eval/diffsheg-guidance-2026-11-25: the shipped DiffSHEG bundle on the real-speech VALIDATION split per
# classifier-free guidance scale x RePaint jumps, through the Rust CLI (ort, 1 thread), seeds SEEDS.
#   O=OUT_DIR SETTINGS="1.0x2 1.5x2 ..." SEEDS="1 2 3" bash docs/eval/diffsheg-guidance-2026-11-25/sweep_real.sh
# Needs source scripts/env.sh and PYTHONPATH=python; LIVEGESTURE_BIN: the built CLI (./target/release/livegesture).
# Writes O/audio/real/*.wav, O/GxU/seedS/*.npz and O/GxU/real_SEEDS.json (+ .txt): own minus other audio gaps.
set -euo pipefail
cd "$(dirname "$0")/../../.."
O=${O:-/tmp/dsguide}; bin=${LIVEGESTURE_BIN:-./target/release/livegesture}
SETTINGS=${SETTINGS:-"1.0x2 1.25x2 1.5x2 2.0x2 3.0x2 1.0x1 1.25x1 1.5x1 2.0x1 3.0x1"}; SEEDS=${SEEDS:-"1 2 3"}
[ -d "$O/audio/real" ] || $LIVEGESTURE_PY -m livegesture.eval.generalise --write-audio "$O/audio" >/dev/null
for gu in $SETTINGS; do
  g=${gu%x*}; u=${gu#*x}; args=()
  for seed in $SEEDS; do
    d=$O/$gu/seed$seed; mkdir -p "$d"
    for wav in "$O"/audio/real/*.wav; do
      id=$(basename "$wav" .wav)
      [ -f "$d/$id.npz" ] || nice -n 10 "$bin" generate "$wav" -o "$d/$id.npz" --bundle models/diffsheg \
        --backend ort --threads 1 --seed "$seed" --guidance "$g" --jumps "$u" 2>/dev/null
    done
    args+=(--generated-real "$d")
  done
  tag=$(echo $SEEDS | tr -d ' ')
  OMP_NUM_THREADS=1 nice -n 10 $LIVEGESTURE_PY -m livegesture.eval.generalise "${args[@]}" \
    --out "$O/$gu/real_$tag.json" > "$O/$gu/real_$tag.log" 2>&1
  echo "$gu seeds $tag done $(date -u +%H:%M:%S)"
done

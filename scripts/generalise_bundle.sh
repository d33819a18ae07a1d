#!/usr/bin/env bash
# Generalisation check of a bundle (any model family) through the Rust runtime: writes the 16 kHz mono WAVs
# of the real-speech validation split and of a synthetic corpus's test split, generates every clip with
# `livegesture generate` (N seeds), then runs python -m livegesture.eval.generalise on the npz folders.
#   bash scripts/generalise_bundle.sh BUNDLE SYNTH_CORPUS OUT_DIR [SEEDS=1] [BACKEND=tract]
# LIVEGESTURE_BIN: an already built CLI binary (otherwise ./target/release/livegesture, built with cargo).
# GENERATE_ARGS: more `livegesture generate` options for every clip, e.g. GENERATE_ARGS="--temperature 0.8".
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
bundle=$1 corpus=$2 out=$3 seeds=${4:-1} backend=${5:-tract}
bin=${LIVEGESTURE_BIN:-./target/release/livegesture}
if [ -z "${LIVEGESTURE_BIN:-}" ]; then
  cargo build --release -q -p livegesture
fi
export PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}"
mkdir -p "$out"
"$LIVEGESTURE_PY" -m livegesture.eval.generalise --synth "$corpus" --write-audio "$out/audio"
args=()
for set in real synth; do
  for s in $(seq 1 "$seeds"); do
    d="$out/generated_${set}_seed$s"; mkdir -p "$d"
    for wav in "$out/audio/$set"/*.wav; do
      id=$(basename "$wav" .wav)
      "$bin" generate "$wav" -o "$d/$id.npz" --bundle "$bundle" --backend "$backend" --seed "$s" ${GENERATE_ARGS:-} 2>/dev/null
    done
    args+=("--generated-$set" "$d")
  done
done
"$LIVEGESTURE_PY" -m livegesture.eval.generalise --synth "$corpus" "${args[@]}" --out "$out/generalise.json"

#!/usr/bin/env bash
# Evaluate a bundle on a BEAT2-layout corpus: generate every test clip with the Rust runtime (N seeds),
# then compute the BEAT2-style report with python -m livegesture.eval.
#   bash scripts/eval_bundle.sh BUNDLE CORPUS OUT_DIR [SEEDS=2] [BACKEND=tract]
# GENERATE_ARGS: more `livegesture generate` options for every clip, e.g. GENERATE_ARGS="--guidance 2 --jumps 1".
# FIRST_SEED: the seeds are FIRST_SEED .. FIRST_SEED + SEEDS - 1 (default 1), e.g. another set of realisations.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
bundle=$1 corpus=$2 out=$3 seeds=${4:-2} backend=${5:-tract}
mkdir -p "$out"
bin=${LIVEGESTURE_BIN:-./target/release/livegesture}   # LIVEGESTURE_BIN: use an already built CLI
[ -n "${LIVEGESTURE_BIN:-}" ] || cargo build --release -q -p livegesture
gen_args=()
first=${FIRST_SEED:-1}
for s in $(seq "$first" $((first + seeds - 1))); do
  d="$out/generated_seed$s"; mkdir -p "$d"
  for id in $(awk -F, '$2=="test"{print $1}' "$corpus/train_test_split.csv"); do
    "$bin" generate "$corpus/wave16k/$id.wav" -o "$d/$id.npz" --bundle "$bundle" \
      --backend "$backend" --seed "$s" ${GENERATE_ARGS:-} 2>/dev/null
  done
  gen_args+=(--generated "$d")
done
cd python
"$LIVEGESTURE_PY" -m livegesture.eval --data "$corpus" --split test "${gen_args[@]}" --out "$out/eval.json" | tee "$out/eval.txt"

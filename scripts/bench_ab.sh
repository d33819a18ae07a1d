#!/usr/bin/env bash
# A/B comparison of bundles (or binaries) on one core, interleaved so machine noise hits both sides alike:
# every round runs every (bundle, backend) once, in alternating order: single-stream chain and batched N=32
# step medians.
#
#   scripts/bench_ab.sh BUNDLE_A BUNDLE_B [...]          # e.g. an export before and after a graph change
#   BIN=/path/to/old/livegesture scripts/bench_ab.sh B   # the same bundle on another build
#   ROUNDS=3 BACKENDS="ort tract" STREAMS=32 scripts/bench_ab.sh ...
#   FORMS="canonical fused" scripts/bench_ab.sh B         # the graph forms of one bundle (SPEC 14; --form)
#
# Prints one line per run; quote medians over rounds, measured in one invocation (BENCHMARKS.md's log).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null 2>&1
BIN="${BIN:-$ROOT/target/release/livegesture}"
[ -x "$BIN" ] || cargo build --release -q -p livegesture
ROUNDS="${ROUNDS:-2}"; BACKENDS="${BACKENDS:-ort tract}"; STREAMS="${STREAMS:-32}"; CPU="${BENCH_CPU:-1}"
FORMS="${FORMS:-auto}"
[ $# -ge 1 ] || { echo "usage: scripts/bench_ab.sh BUNDLE [BUNDLE ...]" >&2; exit 2; }
printf "%-5s %-40s %-9s %-6s %12s %14s\n" round bundle form backend "chain ms" "N=$STREAMS step ms"
bundles=("$@")
for r in $(seq 1 "$ROUNDS"); do
  # odd rounds run the bundles in the given order, even rounds in reverse, so a host that speeds up or slows
  # down during the run does not favour one side
  order=("${bundles[@]}")
  if (( r % 2 == 0 )); then
    order=(); for (( i=${#bundles[@]}-1; i>=0; i-- )); do order+=("${bundles[$i]}"); done
  fi
  forms=($FORMS)
  if (( r % 2 == 0 )); then
    rev=(); for (( i=${#forms[@]}-1; i>=0; i-- )); do rev+=("${forms[$i]}"); done; forms=("${rev[@]}")
  fi
  for b in "${order[@]}"; do
    for f in "${forms[@]}"; do
      for be in $BACKENDS; do
        out=$(taskset -c "$CPU" "$BIN" bench --form "$f" --bundle "$b" --backend "$be" --threads 1 --steps 150 \
          --warmup 10 --latency-trials 1 --streams "$STREAMS" --batch-steps 10 --batch-warmup 2 --quiet)
        chain=$(awk '/whole chain/ {print $3}' <<<"$out")
        batched=$(awk -v n="$STREAMS" '$1 == n && NF >= 8 {print $3; exit}' <<<"$out")
        printf "%-5s %-40s %-9s %-6s %12s %14s\n" "$r" "$b" "$f" "$be" "$chain" "$batched"
      done
    done
  done
done

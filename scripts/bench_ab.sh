#!/usr/bin/env bash
# A/B comparison of bundles (or binaries) on one core, interleaved so machine noise hits both sides alike:
# every round runs every (bundle, backend) once, in alternating order: single-stream chain and batched N=32
# step medians.
#
#   scripts/bench_ab.sh BUNDLE_A BUNDLE_B [...]          # e.g. an export before and after a graph change
#   BIN=/path/to/old/livegesture scripts/bench_ab.sh B   # the same bundle on another build
#   ROUNDS=3 BACKENDS="ort tract" STREAMS=32 scripts/bench_ab.sh ...
#   FORMS="canonical fused" scripts/bench_ab.sh B         # the graph forms of one bundle (SPEC 14; --form)
#   GRAPHS=decoder scripts/bench_ab.sh ...                # also: the summed medians of the graphs whose name
#                                                         # contains GRAPHS, one stream and per batched step
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
FORMS="${FORMS:-auto}"; GRAPHS="${GRAPHS:-}"
[ $# -ge 1 ] || { echo "usage: scripts/bench_ab.sh BUNDLE [BUNDLE ...]" >&2; exit 2; }
printf "%-5s %-40s %-9s %-6s %12s %14s" round bundle form backend "chain ms" "N=$STREAMS step ms"
[ -z "$GRAPHS" ] || printf " %16s %18s" "$GRAPHS* 1 ms" "$GRAPHS* N=$STREAMS ms"
printf "\n"
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
        printf "%-5s %-40s %-9s %-6s %12s %14s" "$r" "$b" "$f" "$be" "$chain" "$batched"
        if [ -n "$GRAPHS" ]; then
          # one stream: the per-graph table's medians; batched: the "per graph" table's row for N
          one=$(awk -v g="$GRAPHS" '/^per-token step/ {t = 1; next} /sum of graphs/ {t = 0}
                t && index($1, g) {s += $2} END {printf "%.3f", s}' <<<"$out")
          many=$(awk -v g="$GRAPHS" -v n="$STREAMS" '/^batched, per graph/ {t = 1; next}
                t && $1 == "N" {for (i = 2; i <= NF; i++) h[i] = $i; next}
                t && $1 == n {for (i = 2; i <= NF; i++) if (index(h[i], g)) s += $i; t = 0}
                END {printf "%.3f", s}' <<<"$out")
          printf " %16s %18s" "$one" "$many"
        fi
        printf "\n"
      done
    done
  done
done

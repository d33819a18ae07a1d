#!/usr/bin/env bash
# A/B comparison of bundles (or binaries) on one core, interleaved so machine noise hits both sides alike:
# every round runs every (bundle, backend) once, in alternating order: single-stream chain and batched N=32
# step medians.
#
#   scripts/bench_ab.sh BUNDLE_A BUNDLE_B [...]          # e.g. an export before and after a graph change
#   BIN=/path/to/old/livegesture scripts/bench_ab.sh B   # the same bundle on another build
#   ROUNDS=3 BACKENDS="ort tract" STREAMS=32 scripts/bench_ab.sh ...
#   FORMS="canonical fused" scripts/bench_ab.sh B         # the graph forms of one bundle (docs/bundle.md#forms-and-precision; --form)
#   GRAPHS=decoder scripts/bench_ab.sh ...                # also: the graphs whose name contains GRAPHS,
#                                                         # one stream and per batched step: the median over
#                                                         # steps of their per-step sum (from the bench's
#                                                         # JSON samples; "-" for a binary without them), and
#                                                         # for comparison the sum of their per-graph medians
#                                                         # (biased on a shared core: see BENCHMARKS.md, "The
#                                                         # decoders at N = 32")
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
[ -z "$GRAPHS" ] || printf " %16s %18s %22s" "$GRAPHS* 1 ms" "$GRAPHS* N=$STREAMS ms" "sum of medians N=$STREAMS"
JSON="$(mktemp)"; trap 'rm -f "$JSON"' EXIT
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
          --warmup 10 --latency-trials 1 --streams "$STREAMS" --batch-steps 10 --batch-warmup 2 --quiet --json "$JSON")
        chain=$(awk '/whole chain/ {print $3}' <<<"$out")
        batched=$(awk -v n="$STREAMS" '$1 == n && NF >= 8 {print $3; exit}' <<<"$out")
        printf "%-5s %-40s %-9s %-6s %12s %14s" "$r" "$b" "$f" "$be" "$chain" "$batched"
        if [ -n "$GRAPHS" ]; then
          # the median over timed steps of the per-step sum of the matching graphs (one stream; batched
          # N), then the sum of their per-graph medians at N (the "per graph" table's row)
          read -r one many <<<"$("$LIVEGESTURE_PY" - "$JSON" "$GRAPHS" "$STREAMS" <<'PY'
import json, statistics, sys
r, g, n = json.load(open(sys.argv[1])), sys.argv[2], int(sys.argv[3])
def med(graphs):
    s = [x for x in graphs if g in x["graph"]]
    if not s or "samples_ms" not in s[0]:
        return "-"
    return "%.3f" % statistics.median(map(sum, zip(*(x["samples_ms"] for x in s))))
print(med(r["single"]["graphs"]), med(next(b for b in r["batched"] if b["streams"] == n)["graphs"]))
PY
)"
          sum_med=$(awk -v g="$GRAPHS" -v n="$STREAMS" '/^batched, per graph/ {t = 1; next}
                t && $1 == "N" {for (i = 2; i <= NF; i++) h[i] = $i; next}
                t && $1 == n {for (i = 2; i <= NF; i++) if (index(h[i], g)) s += $i; t = 0}
                END {printf "%.3f", s}' <<<"$out")
          printf " %16s %18s %22s" "$one" "$many" "$sum_med"
        fi
        printf "\n"
      done
    done
  done
done

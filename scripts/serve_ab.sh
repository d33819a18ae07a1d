#!/usr/bin/env bash
# A/B comparison of server builds under load, interleaved so machine noise hits both sides alike: every
# round starts a fresh `livegesture serve` of each binary pinned to CPU 0 (its scheduler trace on,
# docs/serve.md#the-scheduler-trace), drives it with that binary's `livegesture loadtest` pinned to CPU 1, and
# keeps the report, the trace and the server's /metrics counters. Odd rounds run the binaries in the given
# order, even rounds in reverse.
#
#   scripts/serve_ab.sh OLD_BIN NEW_BIN                          # ramp, ort, levels 64,80,96, 2 rounds
#   ROUNDS=3 LEVELS=48,56,64 scripts/serve_ab.sh A B
#   BACKEND=tract LEVELS=24,32,40 scripts/serve_ab.sh A B
#   PATTERN=burst LEVELS=64 scripts/serve_ab.sh A B               # a fresh server (--warm-sessions 64) per burst
#   BUNDLE=models/diffsheg LEVELS=2,4 P99_MS=1000 scripts/serve_ab.sh A B
#   CLIENT=NEW_BIN scripts/serve_ab.sh OLD_BIN@OLD_BUNDLE NEW_BIN  # a build with its own bundle (BIN@BUNDLE);
#                                                                 # CLIENT: one loadtest for every server
#
# Prints each run's table rows; everything is kept under $OUT (default target/serve_ab/<time>). Quote medians
# and ratios from one invocation, with the machine and its load (BENCHMARKS.md's log).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null 2>&1
cd "$ROOT"
[ $# -ge 2 ] || { echo "usage: scripts/serve_ab.sh BIN_A BIN_B [...]" >&2; exit 2; }
ROUNDS="${ROUNDS:-2}"; LEVELS="${LEVELS:-64,80,96}"; BACKEND="${BACKEND:-ort}"; PATTERN="${PATTERN:-ramp}"
BUNDLE="${BUNDLE:-models/default}"; P99_MS="${P99_MS:-150}"; PORT="${PORT:-8797}"
OUT="${OUT:-target/serve_ab/$(date -u +%Y%m%dT%H%M%S)}"
mkdir -p "$OUT"
bins=("$@")
for b in "${bins[@]}"; do
  [ -x "${b%%@*}" ] || { echo "serve_ab: ${b%%@*} is not an executable" >&2; exit 2; }
  if [[ "$b" == *@* ]]; then
    [ -f "${b#*@}/manifest.json" ] || { echo "serve_ab: ${b#*@} is not a bundle (no manifest.json)" >&2; exit 2; }
  fi
done
extra=(--levels "$LEVELS" --p99-ms "$P99_MS" --quiet)
if [ "$PATTERN" = burst ]; then
  extra+=(--pattern burst)
else
  extra+=(--hold 20 --keep-going)
fi
for r in $(seq 1 "$ROUNDS"); do
  order=("${bins[@]}")
  if (( r % 2 == 0 )); then
    order=(); for (( i=${#bins[@]}-1; i>=0; i-- )); do order+=("${bins[$i]}"); done
  fi
  for arg in "${order[@]}"; do
    b="${arg%%@*}"; bundle="$BUNDLE"
    [[ "$arg" == *@* ]] && bundle="${arg#*@}"
    tag="$(basename "$(dirname "$b")")-$(basename "$b")-$r"
    serve_extra=()
    # a burst meets a server warmed for its sessions (builds before 2026-11-27 have no --warm-sessions)
    if [ "$PATTERN" = burst ] && "$b" serve --help 2>/dev/null | grep -q -- --warm-sessions; then
      serve_extra+=(--warm-sessions "${LEVELS##*,}")
    fi
    LIVEGESTURE_SERVE_TRACE="$OUT/trace-$tag.txt" taskset -c 0 "$b" serve --backend "$BACKEND" --bundle "$bundle" \
      --max-sessions 256 --addr "127.0.0.1:$PORT" "${serve_extra[@]}" > "$OUT/serve-$tag.log" 2>&1 &
    pid=$!
    up=0
    for _ in $(seq 1 240); do
      if curl -sf "http://127.0.0.1:$PORT/healthz" >/dev/null 2>&1; then up=1; break; fi
      sleep 0.5
    done
    [ "$up" = 1 ] || { echo "serve_ab: $b did not come up (log: $OUT/serve-$tag.log)" >&2; kill "$pid"; exit 1; }
    taskset -c 1 "${CLIENT:-$b}" loadtest "ws://127.0.0.1:$PORT" --server-pid "$pid" "${extra[@]}" \
      --json "$OUT/$tag.json" > "$OUT/$tag.txt" 2>&1 || true
    curl -s "http://127.0.0.1:$PORT/metrics" | grep -E "^livegesture_(steps|streams_regrouped)_total" > "$OUT/metrics-$tag.txt" || true
    kill "$pid"; wait "$pid" 2>/dev/null || true
    echo "round $r $arg"
    grep -E "^\| [0-9]+ " "$OUT/$tag.txt" || tail -n 3 "$OUT/$tag.txt"
  done
done
echo "files: $OUT"

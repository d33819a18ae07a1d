#!/usr/bin/env bash
# The whole-process real-time factor of `livegesture generate` over a long input (BENCHMARKS.md, "20 minutes of
# speech"): the bundle's reference clip tiled to SECONDS (default 1200), then one run per backend, pinned to one
# core, one thread, timed with /usr/bin/time (the whole process: loading, frontend, every token, writing the npz).
#
#   scripts/bench_rtf.sh [BUNDLE]                     # default models/default
#   SECONDS_OF_SPEECH=600 BACKENDS=ort BENCH_CPU=0 scripts/bench_rtf.sh models/default
#   BIN=path/to/livegesture scripts/bench_rtf.sh models/diffsheg   # a given build (nothing compiled)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null 2>&1
BUNDLE="${1:-models/default}"
LEN="${SECONDS_OF_SPEECH:-1200}"; BACKENDS="${BACKENDS:-ort tract}"; CPU="${BENCH_CPU:-1}"
if [ -z "${BIN:-}" ]; then
  BIN="$ROOT/target/release/livegesture"
  cargo build --release -q -p livegesture
fi
WORK="$(mktemp -d)"; trap 'rm -rf "$WORK"' EXIT
"$LIVEGESTURE_PY" scripts/tile_clip.py "$BUNDLE" "$LEN" "$WORK/speech.wav"
echo "[rtf] $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg), commit $(git rev-parse --short HEAD)"
for be in $BACKENDS; do
  /usr/bin/time -f "%e %M" -o "$WORK/time" taskset -c "$CPU" "$BIN" generate "$WORK/speech.wav" -o "$WORK/out.npz" \
    --bundle "$BUNDLE" --backend "$be" --threads 1 >/dev/null 2>&1
  read -r wall rss < "$WORK/time"
  awk -v b="$be" -v w="$wall" -v l="$LEN" -v r="$rss" \
    'BEGIN { printf "%-6s wall %8.2f s   RTF %.4f   peak RSS %d MiB\n", b, w, w / l, r / 1024 }'
done
echo "[rtf] load at the end $(cut -d' ' -f1-3 /proc/loadavg)"

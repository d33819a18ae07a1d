#!/usr/bin/env bash
# The browser side by side in one run (issue 42 item 3, BENCHMARKS.md "The browser"): native tract (the CLI,
# one thread), tract in WebAssembly (Chromium, one worker) and onnxruntime-web (WebAssembly SIMD, 1 and 2
# threads, cross-origin isolated page), each round interleaving all engines on the same WAV, per token =
# (whole clip - its first second) / tokens. Medians and per-round ratios in $OUT/report.txt.
#
#   scripts/bench_browser.sh                   # ROUNDS=5 THREADS=1,2 BUNDLE=models/default OUT=target/bench-browser
#   SKIP_BUILD=1 scripts/bench_browser.sh      # reuse target/web-static and target/release/livegesture as they are
#   FORMS=canonical scripts/bench_browser.sh   # and both engines on each named form too (the same graphs on both)
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS="${ROUNDS:-5}"; THREADS="${THREADS:-1,2}"; FORMS="${FORMS:-}"; BUNDLE="${BUNDLE:-models/default}"; OUT="${OUT:-target/bench-browser}"
BIN="${BIN:-target/release/livegesture}"
if [ -z "${SKIP_BUILD:-}" ]; then
  cargo build --release -q -p livegesture --bin livegesture
  scripts/build_wasm.sh
  SKIP_WASM_BUILD=1 scripts/build_web_static.sh "$BUNDLE"
fi
echo "[browser] $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg), $(chromium --version 2>/dev/null | head -1)"
node runtime/web/tests/ortweb.mjs --site target/web-static --out "$OUT" \
  --bench "$BUNDLE/reference/clip.wav" --rounds "$ROUNDS" --threads "$THREADS" \
  --native "$BIN" --native-bundle "$BUNDLE" ${FORMS:+--forms "$FORMS"}
echo "[browser] load at the end $(cut -d' ' -f1-3 /proc/loadavg)"

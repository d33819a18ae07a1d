#!/usr/bin/env bash
# Every item of issue 42 (speed) measured in one sitting on one machine, each against a baseline build with its
# own bundles (the issue's baseline: the build and bundles of 2026-11-26, commit a6aad43), interleaved so the
# machine's noise hits both alike (BENCHMARKS.md, "Issue 42, every item in one sitting"):
#
#   1. one stream: the single-core roofline over the bytes of a token (python -m livegesture.bench weights),
#      the whole chain per token (`bench`, one thread, pinned), and 20 minutes of speech through `generate`
#      (scripts/bench_rtf.sh), ort and tract;
#   2. sessions per core: scripts/serve_ab.sh, ramp and burst (ort 64,80,96 / burst 96; tract 32,40,48 / 48);
#   3. the browser: scripts/bench_browser.sh (native tract, tract in WebAssembly, onnxruntime-web, each on its own
#      form and both on the canonical graphs; this build);
#   4. DiffSHEG: window and denoiser call (`bench`), the real-time factor through `generate` (20 minutes on
#      ort; SECONDS_TRACT of speech on tract), sessions per core on ort (ramp 1,2,3, p99 1000 ms).
#
#   scripts/bench_issue42.sh OLD_BIN OLD_ROOT        # OLD_ROOT holds the baseline's models/default, models/diffsheg
#   ONLY="1 4" ROUNDS=1 scripts/bench_issue42.sh OLD_BIN OLD_ROOT
#
# To make OLD_ROOT and OLD_BIN from the repository (the baseline build takes ~8 minutes):
#   git archive a6aad43 models/default models/diffsheg | tar -x -C /tmp/old
#   git worktree add /tmp/old-src a6aad43 && (cd /tmp/old-src && cargo build --release -p livegesture)
#
# Nothing is compiled: this build is target/release/livegesture (and target/web-static for item 3, made by
# scripts/build_wasm.sh and scripts/build_web_static.sh). Everything is written under $OUT (default
# target/bench-issue42/<time>); the summary is $OUT/summary.txt. Run it on a quiet machine (~40 minutes).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
[ $# -eq 2 ] || { echo "usage: scripts/bench_issue42.sh OLD_BIN OLD_ROOT" >&2; exit 2; }
OLD_BIN="$(realpath "$1")"; OLD_ROOT="$(realpath "$2")"
NEW_BIN="$ROOT/target/release/livegesture"
for b in "$OLD_BIN" "$NEW_BIN"; do [ -x "$b" ] || { echo "bench_issue42: $b is not an executable" >&2; exit 2; }; done
for m in default diffsheg; do
  [ -f "$OLD_ROOT/models/$m/manifest.json" ] || { echo "bench_issue42: $OLD_ROOT/models/$m is not a bundle" >&2; exit 2; }
done
ROUNDS="${ROUNDS:-2}"; ONLY="${ONLY:-1 2 3 4}"; CPU="${BENCH_CPU:-1}"; SECONDS_TRACT="${SECONDS_TRACT:-300}"
OUT="$(realpath -m "${OUT:-target/bench-issue42/$(date -u +%Y%m%dT%H%M%S)}")"
mkdir -p "$OUT"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null 2>&1
cd "$ROOT"
S="$OUT/summary.txt"
say() { echo "$*" | tee -a "$S"; }
say "[issue42] $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg), $(date -u +%FT%TZ), commit $(git rev-parse --short HEAD)"
say "[issue42] old: $OLD_BIN with $OLD_ROOT/models; new: $NEW_BIN with models/"
# the pairs (build, bundle root) in round order: odd rounds old first, even rounds new first
pairs() { if [ $(($1 % 2)) -eq 1 ]; then echo "old new"; else echo "new old"; fi; }
bin_of() { if [ "$1" = old ]; then echo "$OLD_BIN"; else echo "$NEW_BIN"; fi; }
root_of() { if [ "$1" = old ]; then echo "$OLD_ROOT"; else echo "$ROOT"; fi; }
has() { [[ " $ONLY " == *" $1 "* ]]; }

if has 1; then
  say "== item 1: the roofline of one token (this bundle)"
  for be in ort tract; do
    (cd python && taskset -c "$CPU" "$LIVEGESTURE_PY" -m livegesture.bench weights --bundle "$ROOT/models/default" \
      --backend "$be") > "$OUT/roofline_$be.json"
    "$LIVEGESTURE_PY" - "$OUT/roofline_$be.json" "$be" <<'EOF' | tee -a "$S"
import json, sys
r = json.load(open(sys.argv[1]))
print(f"{sys.argv[2]:6s} {r['form']}: {r['weight_bytes'] / 1e6:.1f} MB weights + {r['state_bytes'] / 1e6:.2f} MB state, "
      f"read {r['weights_and_state_read_ms']:.3f} ms, compute {r['compute_ms']:.3f} ms, roofline {r['roofline_ms']:.3f} ms "
      f"({r['bound']}), 1.6x goal {r['target_ms']:.3f} ms")
EOF
  done
  say "== item 1: one stream, whole chain per token (bench, 300 steps, pinned to CPU $CPU)"
  for r in $(seq 1 "$ROUNDS"); do
    for side in $(pairs "$r"); do
      for be in ort tract; do
        taskset -c "$CPU" "$(bin_of "$side")" bench --bundle "$(root_of "$side")/models/default" --backend "$be" \
          --streams "" --latency-trials 1 --steps 300 > "$OUT/chain_${side}_${be}_$r.txt" 2>&1
        say "round $r $side $be: $(grep -E 'whole chain' "$OUT/chain_${side}_${be}_$r.txt" | xargs)"
      done
    done
  done
  say "== item 1: 20 minutes of speech through generate (scripts/bench_rtf.sh)"
  for r in $(seq 1 "$ROUNDS"); do
    for side in $(pairs "$r"); do
      BIN="$(bin_of "$side")" BENCH_CPU="$CPU" scripts/bench_rtf.sh "$(root_of "$side")/models/default" \
        > "$OUT/rtf_${side}_$r.txt" 2>&1
      grep -E '^(ort|tract) ' "$OUT/rtf_${side}_$r.txt" | sed "s/^/round $r $side /" | tee -a "$S"
    done
  done
fi

if has 2; then
  say "== item 2: sessions per core (scripts/serve_ab.sh; server on CPU 0, client on CPU 1; one loadtest client: new)"
  run_ab() { # NAME, then env assignments
    local name="$1"; shift
    env "$@" ROUNDS=1 CLIENT="$NEW_BIN" OUT="$OUT/serve_$name" \
      scripts/serve_ab.sh "$OLD_BIN@$OLD_ROOT/models/default" "$NEW_BIN@$ROOT/models/default" \
      > "$OUT/serve_$name.txt" 2>&1 || true
    say "-- $name"; grep -E '^(round|\|)' "$OUT/serve_$name.txt" | tee -a "$S" || true
  }
  run_ab ort_ramp BACKEND=ort LEVELS=64,80,96
  run_ab ort_burst BACKEND=ort PATTERN=burst LEVELS=96
  run_ab tract_ramp BACKEND=tract LEVELS=32,40,48
  run_ab tract_burst BACKEND=tract PATTERN=burst LEVELS=48
fi

if has 3; then
  say "== item 3: the browser (scripts/bench_browser.sh, this build only)"
  # each engine on its own form, and both on the canonical graphs (the same graphs on both)
  SKIP_BUILD=1 ROUNDS="${BROWSER_ROUNDS:-3}" FORMS="${BROWSER_FORMS-canonical}" OUT="$OUT/browser" \
    scripts/bench_browser.sh > "$OUT/browser.txt" 2>&1 || true
  if [ -f "$OUT/browser/report.txt" ]; then tee -a "$S" < "$OUT/browser/report.txt"; else tail -20 "$OUT/browser.txt" | tee -a "$S"; fi
fi

if has 4; then
  say "== item 4: DiffSHEG, one window (bench --windows 3, pinned to CPU $CPU)"
  for side in old new; do
    for be in ort tract; do
      taskset -c "$CPU" "$(bin_of "$side")" bench --bundle "$(root_of "$side")/models/diffsheg" --backend "$be" \
        --windows 3 --table-steps "" --streams "" --latency-trials 1 > "$OUT/diffsheg_${side}_$be.txt" 2>&1
      say "$side $be: $(grep -E '^window \(|^  denoiser ' "$OUT/diffsheg_${side}_$be.txt" | xargs)"
    done
  done
  say "== item 4: DiffSHEG through generate (scripts/bench_rtf.sh: ort 1200 s, tract $SECONDS_TRACT s)"
  for side in old new; do
    BIN="$(bin_of "$side")" BACKENDS=ort BENCH_CPU="$CPU" scripts/bench_rtf.sh "$(root_of "$side")/models/diffsheg" \
      > "$OUT/diffsheg_rtf_${side}_ort.txt" 2>&1
    grep -E '^ort ' "$OUT/diffsheg_rtf_${side}_ort.txt" | sed "s/^/$side /" | tee -a "$S"
  done
  for side in old new; do
    SECONDS_OF_SPEECH="$SECONDS_TRACT" BIN="$(bin_of "$side")" BACKENDS=tract BENCH_CPU="$CPU" \
      scripts/bench_rtf.sh "$(root_of "$side")/models/diffsheg" > "$OUT/diffsheg_rtf_${side}_tract.txt" 2>&1
    grep -E '^tract ' "$OUT/diffsheg_rtf_${side}_tract.txt" | sed "s/^/$side /" | tee -a "$S"
  done
  say "== item 4: DiffSHEG sessions per core (ort ramp 1,2,3, p99 1000 ms: a window is 2.93 s of look-ahead)"
  env ROUNDS=1 CLIENT="$NEW_BIN" OUT="$OUT/serve_diffsheg" BACKEND=ort LEVELS=1,2,3 P99_MS=1000 \
    BUNDLE="$ROOT/models/diffsheg" scripts/serve_ab.sh "$OLD_BIN@$OLD_ROOT/models/diffsheg" \
    "$NEW_BIN@$ROOT/models/diffsheg" > "$OUT/serve_diffsheg.txt" 2>&1 || true
  grep -E '^(round|\|)' "$OUT/serve_diffsheg.txt" | tee -a "$S" || true
fi
say "[issue42] done $(date -u +%FT%TZ), load $(cut -d' ' -f1-3 /proc/loadavg)"

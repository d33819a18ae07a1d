#!/usr/bin/env bash
# Interleaved A/B of two `livegesture` builds on a DiffSHEG bundle (BENCHMARKS.md, "DiffSHEG per window"):
# per round and backend, build A then build B: `bench` (window time, denoiser per call) and the whole-process
# real-time factor of `generate` over the bundle's reference clip tiled to SECONDS_OF_SPEECH (default 1200),
# each pinned to one core (BENCH_CPU, default 1), one thread. Outputs of A and B are compared byte for byte.
# On a loaded machine the wall time moves with the load; the CPU time (user + sys) of the process much less:
# both are printed (RTF = wall / seconds of speech; CPU RTF = (user + sys) / seconds of speech).
#
#   scripts/bench_diffsheg_ab.sh BIN_A BIN_B [BUNDLE]        # default models/diffsheg
#   ROUNDS=3 BACKENDS="ort tract" SECONDS_OF_SPEECH=1200 WINDOWS=3 scripts/bench_diffsheg_ab.sh old/livegesture target/release/livegesture
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
[ $# -ge 2 ] || { echo "usage: $0 BIN_A BIN_B [BUNDLE]" >&2; exit 2; }
A="$1"; B="$2"; BUNDLE="${3:-models/diffsheg}"
for b in "$A" "$B"; do [ -x "$b" ] || { echo "$0: $b: not an executable" >&2; exit 2; }; done
LEN="${SECONDS_OF_SPEECH:-1200}"; BACKENDS="${BACKENDS:-ort tract}"; CPU="${BENCH_CPU:-1}"
ROUNDS="${ROUNDS:-3}"; WINDOWS="${WINDOWS:-3}"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null 2>&1
WORK="$(mktemp -d)"; trap 'rm -rf "$WORK"' EXIT
"$LIVEGESTURE_PY" scripts/tile_clip.py "$BUNDLE" "$LEN" "$WORK/speech.wav"
echo "[ab] $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg), A=$A B=$B bundle $BUNDLE, ${LEN} s of speech"
for r in $(seq 1 "$ROUNDS"); do
  for be in $BACKENDS; do
    for side in A B; do
      bin=$A; [ "$side" = B ] && bin=$B
      win=$(taskset -c "$CPU" "$bin" bench --bundle "$BUNDLE" --backend "$be" --windows "$WINDOWS" --table-steps "" \
        --streams "" --latency-trials 1 2>&1 | awk '/^window \(outpainting/ { print $6 } /^  denoiser/ { print $7 }' | paste -sd' ')
      /usr/bin/time -f "%e %M %U %S" -o "$WORK/time" taskset -c "$CPU" "$bin" generate "$WORK/speech.wav" \
        -o "$WORK/out-$be-$side.npz" --bundle "$BUNDLE" --backend "$be" --threads 1 >/dev/null 2>&1
      read -r wall rss usr sys < "$WORK/time"
      awk -v r="$r" -v b="$be" -v s="$side" -v win="$win" -v w="$wall" -v l="$LEN" -v m="$rss" -v c="$usr $sys" \
        'BEGIN { split(win, v, " "); split(c, t, " "); printf "round %s %-5s %s: window median %8s ms, denoiser per call %6s ms; generate %s s: wall %7.2f s, RTF %.4f, CPU %7.2f s, CPU RTF %.4f, peak RSS %d MiB\n", r, b, s, v[1], v[2], l, w, w / l, t[1] + t[2], (t[1] + t[2]) / l, m / 1024 }'
    done
    if cmp -s "$WORK/out-$be-A.npz" "$WORK/out-$be-B.npz"; then echo "round $r $be: A and B outputs identical (byte for byte)"
    else echo "round $r $be: A and B outputs DIFFER"; fi
  done
done
echo "[ab] load at the end $(cut -d' ' -f1-3 /proc/loadavg)"

#!/usr/bin/env bash
# The whole-process real-time factor of `livegesture generate` over a long input (BENCHMARKS.md, "20 minutes of
# speech"): the bundle's reference clip tiled to SECONDS (default 1200), then one run per backend, pinned to one
# core, one thread, timed with /usr/bin/time (the whole process: loading, frontend, every token, writing the npz).
#
#   scripts/bench_rtf.sh [BUNDLE]                     # default models/default
#   SECONDS_OF_SPEECH=600 BACKENDS=ort BENCH_CPU=0 scripts/bench_rtf.sh models/default
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null 2>&1
BUNDLE="${1:-models/default}"
LEN="${SECONDS_OF_SPEECH:-1200}"; BACKENDS="${BACKENDS:-ort tract}"; CPU="${BENCH_CPU:-1}"
BIN="$ROOT/target/release/livegesture"
cargo build --release -q -p livegesture
WORK="$(mktemp -d)"; trap 'rm -rf "$WORK"' EXIT
"$LIVEGESTURE_PY" - "$BUNDLE" "$LEN" "$WORK/speech.wav" <<'PY'
import json, sys, wave
from pathlib import Path
import numpy as np
bundle, seconds, out = Path(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
manifest = json.loads((bundle / "manifest.json").read_text())
clip = bundle / manifest.get("reference", {}).get("clip", "reference/clip.wav")
with wave.open(str(clip)) as w:
    rate, width, ch = w.getframerate(), w.getsampwidth(), w.getnchannels()
    data = np.frombuffer(w.readframes(w.getnframes()), dtype=np.int16 if width == 2 else np.int32)
n = int(seconds * rate) * ch
tiled = np.tile(data, -(-n // len(data)))[:n]
with wave.open(out, "wb") as w:
    w.setnchannels(ch); w.setsampwidth(width); w.setframerate(rate); w.writeframes(tiled.tobytes())
print(f"[rtf] {clip} tiled to {seconds:.0f} s ({rate} Hz)", file=sys.stderr)
PY
echo "[rtf] $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg), commit $(git rev-parse --short HEAD)"
for be in $BACKENDS; do
  /usr/bin/time -f "%e %M" -o "$WORK/time" taskset -c "$CPU" "$BIN" generate "$WORK/speech.wav" -o "$WORK/out.npz" \
    --bundle "$BUNDLE" --backend "$be" --threads 1 >/dev/null 2>&1
  read -r wall rss < "$WORK/time"
  awk -v b="$be" -v w="$wall" -v l="$LEN" -v r="$rss" \
    'BEGIN { printf "%-6s wall %8.2f s   RTF %.4f   peak RSS %d MiB\n", b, w, w / l, r / 1024 }'
done
echo "[rtf] load at the end $(cut -d' ' -f1-3 /proc/loadavg)"

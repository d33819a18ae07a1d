#!/usr/bin/env bash
# Every model variant of both families (python -m livegesture.train --list-variants; docs/model.md and
# docs/diffsheg.md "Variants"), end to end on the tiny config:
#   a few training steps on a small synthetic corpus -> export (every graph verified against torch by the
#   exporter; a shorter reference rollout than the shipped bundles') -> `livegesture parity` on ort and tract
#   -> `livegesture generate` on both backends.
# Variants that change only the training (Variant.changes_graphs false: no-ugm, no-detach, ...) are trained
# and their checkpoint's model config is checked to be the full model's: their bundle would have exactly the
# graphs of the family's `full` variant, which is exported and run here (the group shares its graphs).
# Called by scripts/test.sh (stage "variants"); alone: scripts/variants.sh [OUT] (default target/variants),
# with the release binary built (LIVEGESTURE_BIN overrides it). VARIANTS="livegesture/no-pilor diffsheg/reverse"
# limits the run to those.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=/dev/null
source scripts/env.sh
export PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}"
OUT="${1:-target/variants}"
BIN="${LIVEGESTURE_BIN:-$PWD/target/release/livegesture}"
[ -x "$BIN" ] || { echo "variants: no livegesture binary at $BIN (cargo build --release -p livegesture)" >&2; exit 1; }
rm -rf "$OUT"
mkdir -p "$OUT"
t0=$SECONDS

# 0.4 minutes of synthetic speech and motion (espeak-ng), every speaker
"$LIVEGESTURE_PY" -m livegesture.data.synth --out "$OUT/corpus" --minutes 0.4 --seed 3 --jobs 1 \
  --clip-seconds 10 14 >/dev/null 2>&1
# 6 s of the corpus' first clip's speech for generate
"$LIVEGESTURE_PY" - "$OUT" <<'PY'
import sys, wave
from pathlib import Path
out = Path(sys.argv[1])
src = sorted((out / "corpus").rglob("*.wav"))[0]
with wave.open(str(src), "rb") as r, wave.open(str(out / "speech.wav"), "wb") as w:
    w.setparams(r.getparams())
    w.writeframes(r.readframes(6 * r.getframerate()))
PY

serve_variant() {   # bundle-dir name: `serve` on the bundle (tract, loopback), one real-time session of 2 s
  # streamed by `loadtest`, which fails unless the server sends every frame the audio implies and `done`
  local dir="$1" name="$2" port pid rc=0
  port="$("$LIVEGESTURE_PY" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
  "$BIN" serve --bundle "$dir/bundle" --addr "127.0.0.1:$port" >"$dir.serve.log" 2>&1 &
  pid=$!
  for _ in $(seq 100); do
    curl -sf "http://127.0.0.1:$port/healthz" >/dev/null && break
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.1
  done
  "$BIN" loadtest "ws://127.0.0.1:$port" --audio "$OUT/speech.wav" --levels 1 --hold 2 --pause 0 --require 1 \
    --server-pid "$pid" -q >"$dir.loadtest.log" 2>&1 || rc=$?
  kill "$pid" 2>/dev/null; wait "$pid" 2>/dev/null || true
  if [ "$rc" != 0 ]; then
    tail -20 "$dir.serve.log" "$dir.loadtest.log" >&2; echo "variants: $name: serve failed" >&2; return 1
  fi
}

run_variant() {   # family variant graphs|training
  local fam="$1" v="$2" dir="$OUT/$1-$2" t=$SECONDS
  local steps=(--steps-svq1 3 --steps-svq2 3 --steps-experts 3 --steps-fuse 3)
  local rollout=(--reference-seconds 6 --rollout-tokens 40)
  if [ "$fam" = diffsheg ]; then steps=(--steps 3 --batch 4); rollout=(--reference-seconds 6 --rollout-windows 4); fi
  "$LIVEGESTURE_PY" -m livegesture.train --family "$fam" --config tiny --variant "$v" --data "$OUT/corpus" \
    --out "$dir/run" --speakers all --device cpu "${steps[@]}" >"$dir.train.log" 2>&1 \
    || { tail -20 "$dir.train.log" >&2; echo "variants: $fam/$v: training failed" >&2; return 1; }
  if [ "$3" = training ]; then   # the full model's graphs: the checkpoint's config is the full one but its name
    "$LIVEGESTURE_PY" - "$dir/run/final.pt" "$fam" "$v" <<'PY'
import sys
from livegesture import checkpoint as ckpt, families, variants
m = ckpt.load(sys.argv[1])
fam = families.get(sys.argv[2])
full = variants.apply(fam.get_config("tiny"), fam.name, "full").to_dict()
got = m.cfg.to_dict()
assert got["variant"] == sys.argv[3] and {**got, "variant": "full"} == full, f"{sys.argv[1]}: config {got}"
PY
    echo "variant $fam/$v: trained (training-only variant: the graphs of $fam/full) ($(( SECONDS - t )) s)"
    return 0
  fi
  "$LIVEGESTURE_PY" export/export.py --checkpoint "$dir/run/final.pt" --out "$dir/bundle" "${rollout[@]}" \
    >"$dir.export.log" 2>&1 \
    || { tail -20 "$dir.export.log" >&2; echo "variants: $fam/$v: export failed" >&2; return 1; }
  "$LIVEGESTURE_PY" - "$dir/bundle/manifest.json" "$fam" "$v" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
got = (m.get("family", "livegesture"), m["model"]["variant"]["name"], m["model"]["config"]["variant"])
assert got == (sys.argv[2], sys.argv[3], sys.argv[3]), f"{sys.argv[1]}: family/variant {got}, expected {sys.argv[2:]}"
PY
  "$BIN" parity --bundle "$dir/bundle" --backends ort,tract --junit "$dir.parity.xml" >"$dir.parity.log" 2>&1 \
    || { tail -30 "$dir.parity.log" >&2; echo "variants: $fam/$v: parity failed" >&2; return 1; }
  for backend in ort tract; do
    "$BIN" generate "$OUT/speech.wav" -o "$dir/motion-$backend.npz" --seed 1 --backend "$backend" \
      --bundle "$dir/bundle" >"$dir.generate.log" 2>&1 \
      || { cat "$dir.generate.log" >&2; echo "variants: $fam/$v: generate ($backend) failed" >&2; return 1; }
  done
  serve_variant "$dir" "$fam/$v" || return 1
  echo "variant $fam/$v: trained, exported, parity ort+tract, generate ort+tract, served ($(( SECONDS - t )) s)"
}

for fam in livegesture diffsheg; do
  # every listed variant; "graphs" or "training" (livegesture.variants.Variant.changes_graphs; full: graphs)
  kinds="$("$LIVEGESTURE_PY" -c "import sys; from livegesture import families
for n, v in families.get(sys.argv[1]).variants().items(): print(n, 'graphs' if v.changes_graphs or n == 'full' else 'training')" "$fam")"
  [ "$(echo "$kinds" | cut -d' ' -f1)" = "$("$LIVEGESTURE_PY" -m livegesture.train --family "$fam" --list-variants)" ] \
    || { echo "variants: the listing and the registry disagree" >&2; exit 1; }
  while read -r v kind; do
    if [ -n "${VARIANTS:-}" ] && [[ " $VARIANTS " != *" $fam/$v "* ]]; then continue; fi
    run_variant "$fam" "$v" "$kind" </dev/null
  done <<<"$kinds"
done
echo "variants: all done in $(( SECONDS - t0 )) s"

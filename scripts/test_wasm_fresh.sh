#!/usr/bin/env bash
# The must-fail test of scripts/wasm_fresh.sh: a module newer than its sources passes, one older than a
# source fails naming it (the old SKIP_WASM_BUILD path accepted both). Cheap: no build.
set -euo pipefail
cd "$(dirname "$0")/.."
d=$(mktemp -d); trap 'rm -rf "$d"' EXIT
mkdir -p "$d/src"; echo 'fn a() {}' > "$d/src/lib.rs"
touch -d '2026-01-01 00:00' "$d/src/lib.rs"
echo wasm > "$d/m.wasm"; touch -d '2026-01-02 00:00' "$d/m.wasm"
scripts/wasm_fresh.sh "$d/m.wasm" "$d/src" || { echo "test_wasm_fresh: a fresh module was refused" >&2; exit 1; }
touch -d '2026-01-03 00:00' "$d/src/lib.rs"
if out=$(scripts/wasm_fresh.sh "$d/m.wasm" "$d/src" 2>&1); then echo "test_wasm_fresh: a stale module passed" >&2; exit 1; fi
grep -q "lib.rs" <<<"$out" || { echo "test_wasm_fresh: the refusal does not name the newer source: $out" >&2; exit 1; }
if scripts/wasm_fresh.sh "$d/missing.wasm" "$d/src" 2>/dev/null; then echo "test_wasm_fresh: a missing module passed" >&2; exit 1; fi
echo "test_wasm_fresh: passed"

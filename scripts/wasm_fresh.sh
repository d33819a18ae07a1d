#!/usr/bin/env bash
# Fails when the WebAssembly module $1 is older than any source it is built from (issue 38: with
# SKIP_WASM_BUILD, scripts/build_web_static.sh reused whatever target/wasm-pkg held). Sources: the
# runtime's and the wasm binding's Rust, manifests and lock files, .cargo/config.toml. $2.. (optional):
# other source paths instead (for its own test).
#   scripts/wasm_fresh.sh target/wasm-pkg/livegesture_wasm_bg.wasm
set -euo pipefail
cd "$(dirname "$0")/.."
wasm="${1:?usage: wasm_fresh.sh WASM [SOURCES...]}"
shift
if [ $# -gt 0 ]; then srcs=("$@"); else
  srcs=(runtime/src runtime/Cargo.toml bindings/wasm/src bindings/wasm/Cargo.toml bindings/wasm/Cargo.lock Cargo.lock .cargo/config.toml)
fi
[ -f "$wasm" ] || { echo "wasm_fresh.sh: $wasm is missing; run scripts/build_wasm.sh" >&2; exit 1; }
existing=()
for s in "${srcs[@]}"; do [ -e "$s" ] && existing+=("$s"); done
[ ${#existing[@]} -gt 0 ] || { echo "wasm_fresh.sh: none of the sources exist: ${srcs[*]}" >&2; exit 1; }
newer=$(find "${existing[@]}" -type f -newer "$wasm" -print -quit)
if [ -n "$newer" ]; then
  echo "wasm_fresh.sh: $wasm is older than $newer: a stale build; run scripts/build_wasm.sh (or unset SKIP_WASM_BUILD)" >&2
  exit 1
fi

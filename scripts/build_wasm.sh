#!/usr/bin/env bash
# Builds the WebAssembly runtime (bindings/wasm, docs/wasm.md) into target/wasm-pkg/:
# livegesture_wasm.js + livegesture_wasm_bg.wasm (wasm-bindgen, --target web, for a module Worker).
# Installs what it needs: the rustup target wasm32-unknown-unknown, and the wasm-bindgen CLI of the
# exact version of the wasm-bindgen crate in bindings/wasm/Cargo.lock (cached in
# ~/.cache/livegesture/wasm-bindgen-<version>/, built from crates.io with cargo install).
# SIMD (+simd128) comes from .cargo/config.toml. Set NICE=0 to build at normal priority.
set -euo pipefail
cd "$(dirname "$0")/.."

rustup target list --installed | grep -qx wasm32-unknown-unknown || rustup target add wasm32-unknown-unknown

ver=$(awk '/^name = "wasm-bindgen"$/ { getline; gsub(/"/, "", $3); print $3; exit }' bindings/wasm/Cargo.lock)
[ -n "$ver" ] || { echo "build_wasm.sh: no wasm-bindgen in bindings/wasm/Cargo.lock" >&2; exit 1; }
root="${LIVEGESTURE_CACHE:-$HOME/.cache/livegesture}/wasm-bindgen-$ver"
bindgen="$root/bin/wasm-bindgen"
if ! [ -x "$bindgen" ] || ! "$bindgen" --version | grep -q " $ver"; then
  echo "build_wasm.sh: installing wasm-bindgen-cli $ver into $root"
  # not --locked: the CLI's own lock file may name versions the registry mirror does not serve
  nice -n "${NICE:-10}" cargo install wasm-bindgen-cli --version "=$ver" --root "$root"
fi

(cd bindings/wasm && nice -n "${NICE:-10}" cargo build --target wasm32-unknown-unknown --release)
out=target/wasm-pkg
rm -rf "$out"
mkdir -p "$out"
"$bindgen" --target web --no-typescript --out-dir "$out" \
  bindings/wasm/target/wasm32-unknown-unknown/release/livegesture_wasm.wasm
ls -l "$out"

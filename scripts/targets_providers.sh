#!/usr/bin/env bash
# The execution-provider and browser targets of the target matrix (docs/targets.md, the parity contract (docs/parity.md)
# "Targets"); scripts/targets.sh runs the instruction-set targets. Same interface and output:
#
#   scripts/targets_providers.sh [--bundle DIR] [--out DIR] [--allow-unsupported] TARGET...
#                                     TARGET: openvino webgpu wasm-tract wasm-ort-web
#
# Each target runs the parity suite of the bundle (default models/default) against the torch references
# made at export and writes OUT/TARGET.json (default OUT: target/targets):
#   {"target", "bundle", "passed": bool, ...the parity report}
# (native targets: `livegesture parity --json` (rows, notes, divergences); browser targets: the page's
# parity report (lines, comparisons passed/failed)). A target that cannot run writes
# {"target", "bundle", "passed": false, "error": "..."}. Exit 0 only when every named target passes.
# --allow-unsupported: a native target also passes when its only failed rows are graphs that the provider
# refuses to compile for an operator it does not support (its error says "does not support the following
# ONNX operations"; the JSON lists them in "unsupported"), every other comparison passing (OpenVINO 2025.4
# and the ONNX Attention operator of the tract form's fusion_attention graph: docs/targets.md).
#
#   openvino      ONNX Runtime 1.24.1 with the OpenVINO execution provider (CPU device), from PyPI's
#                 onnxruntime-openvino wheel (its libonnxruntime and provider libraries, loaded at run time)
#   webgpu        ONNX Runtime 1.27.0 with the WebGPU execution provider (Dawn on Vulkan; lavapipe from
#                 Debian's mesa-vulkan-drivers), from PyPI's onnxruntime-webgpu wheel
#   wasm-tract    tract in WebAssembly in Debian's chromium (the page's ?engine=wasm)
#   wasm-ort-web  the runtime in WebAssembly with its graphs on onnxruntime-web in chromium (?engine=ort-web)
#
# Needs target/release/livegesture (native targets) or target/web-static (browser targets:
# scripts/build_web_static.sh; the bundle is copied beside the page).
set -euo pipefail
cd "$(dirname "$0")/.."

bundle=models/default
out=target/targets
allow_unsupported=0
targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --bundle) bundle="${2:?--bundle needs a folder}"; shift 2 ;;
    --allow-unsupported) allow_unsupported=1; shift ;;
    --out) out="${2:?--out needs a folder}"; shift 2 ;;
    -h|--help) sed -n '2,31p' "$0"; exit 0 ;;
    openvino|webgpu|wasm-tract|wasm-ort-web) targets+=("$1"); shift ;;
    *) echo "targets_providers.sh: unknown target '$1' (expected openvino, webgpu, wasm-tract, wasm-ort-web)" >&2; exit 2 ;;
  esac
done
[ ${#targets[@]} -gt 0 ] || { echo "targets_providers.sh: name at least one target" >&2; exit 2; }
[ -f "$bundle/manifest.json" ] || { echo "targets_providers.sh: --bundle $bundle: no manifest.json (not a bundle)" >&2; exit 2; }
source scripts/env.sh >/dev/null
mkdir -p "$out"

# An ONNX Runtime build from a PyPI wheel, unpacked once (cached beside the venv); prints its library.
ort_wheel() {
  local pkg="$1" version="$2" dir
  dir="$(dirname "$LIVEGESTURE_VENV")/$pkg-$version"
  if [ ! -f "$dir/.complete" ]; then
    rm -rf "$dir"
    "$LIVEGESTURE_VENV/bin/pip" install -q --no-deps --target "$dir" "$pkg==$version" >&2
    touch "$dir/.complete"
  fi
  ls "$dir"/onnxruntime/capi/libonnxruntime.so.1* | head -n1
}

# {"target", "bundle", "passed": false, "error"} for a target that could not run.
write_error() {
  "$LIVEGESTURE_PY" - "$out/$1.json" "$1" "$bundle" "$2" <<'PY'
import json, sys
path, target, bundle, error = sys.argv[1:]
json.dump({"target": target, "bundle": bundle, "passed": False, "error": error}, open(path, "w"), indent=1)
PY
}

# the native parity suite on ONNX Runtime with an execution provider
native_ep() {
  local target="$1" lib="$2" ep="$3" log="$out/$1.log" rc=0
  [ -x target/release/livegesture ] || { echo "targets_providers.sh: target/release/livegesture is missing (cargo build --release -p livegesture)" >&2; return 2; }
  ORT_DYLIB_PATH="$lib" ./target/release/livegesture parity --bundle "$bundle" --backends ort --ep "$ep" --target-name "$target" \
    --json "$out/$target.json.part" >"$log" 2>&1 || rc=$?
  if [ -f "$out/$target.json.part" ]; then
    local ok=0
    "$LIVEGESTURE_PY" - "$out/$target.json.part" "$out/$target.json" "$target" "$bundle" "$ep" "$lib" <<'PY' || ok=$?
import json, sys
src, dst, target, bundle, ep, lib = sys.argv[1:]
r = json.load(open(src))
failed = [row for row in r["rows"] if not row["pass"]]
unsupported = [row for row in failed if "does not support the following ONNX operations" in (row.get("detail") or "")]
r["unsupported"] = sorted({row["what"] for row in unsupported})
# the operators the provider named for each such graph ("... the following ONNX operations: A, B")
r["unsupported_operators"] = {
    row["what"]: [op.strip() for op in row["detail"].split("the following ONNX operations:", 1)[1].strip().splitlines()[0].split(",")]
    for row in unsupported}
r["passed_except_unsupported"] = len(r["rows"]) > len(failed) and len(failed) == len(unsupported)
json.dump({"target": target, "bundle": bundle, "execution_provider": ep, "library": lib, **r}, open(dst, "w"), indent=1)
print(f"{target}: {len(r['rows']) - len(failed)} of {len(r['rows'])} comparisons pass"
      + (f"; the provider does not support graph(s) {', '.join(r['unsupported'])} (operators: "
         + "; ".join(f"{g}: {', '.join(ops)}" for g, ops in r["unsupported_operators"].items()) + ")" if unsupported else ""))
sys.exit(0 if r["passed_except_unsupported"] else 1)
PY
    rm -f "$out/$target.json.part"
    [ "$allow_unsupported" = 1 ] && [ "$ok" = 0 ] && rc=0
  else
    write_error "$target" "$(grep -v '^parity: ' "$log" | tail -n 5)"
  fi
  tail -n 4 "$log"
  return $rc
}

target_openvino() { native_ep openvino "$(ort_wheel onnxruntime-openvino 1.24.1)" openvino; }
target_webgpu() { native_ep webgpu "$(ort_wheel onnxruntime-webgpu 1.27.0)" webgpu; }

# the page's parity in chromium, one engine
browser() {
  local target="$1" engine="$2" rel
  [ -f target/web-static/index.html ] || { echo "targets_providers.sh: target/web-static is missing (scripts/build_web_static.sh)" >&2; return 2; }
  rel="targets/$(basename "$bundle")"
  mkdir -p target/web-static/targets
  rm -rf "target/web-static/$rel"
  scripts/copy_bundle.py "$bundle" "target/web-static/$rel" >/dev/null
  timeout 1800 node runtime/web/tests/ortweb.mjs --site target/web-static --out "$out/$target" --engine "$engine" \
    --parity "$rel/" --json "$out/$target.json" --target "$target" --bundle-name "$bundle"
}

target_wasm-tract() { browser wasm-tract wasm; }
target_wasm-ort-web() { browser wasm-ort-web ort-web; }

failed=()
for t in "${targets[@]}"; do
  echo "=== target $t: $bundle"
  if "target_$t"; then echo "target $t: passed"; else failed+=("$t"); echo "target $t: FAILED ($out/$t.json)"; fi
done
[ ${#failed[@]} -eq 0 ] || { echo "targets failed: ${failed[*]}" >&2; exit 1; }
echo "targets passed: ${targets[*]}"

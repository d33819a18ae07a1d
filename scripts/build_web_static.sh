#!/usr/bin/env bash
# The browser page as a static folder that any static file host can serve (docs/wasm.md):
#   target/web-static/            index.html (engine "this browser" by default), assets/, worklet.js,
#                                 worker.js, skeleton.json, face.bin
#   target/web-static/wasm/       the runtime in WebAssembly (scripts/build_wasm.sh)
#   target/web-static/bundle/     the bundle (default models/default; or the folder given as $1)
# Nothing is fetched from anywhere but this folder. Host it with e.g.
#   python3 -m http.server -d target/web-static 8080   ->  http://localhost:8080/
# Uses the committed runtime/web/dist (rebuild it with `cd runtime/web && npm install --no-save && npm run build`).
set -euo pipefail
cd "$(dirname "$0")/.."
bundle="${1:-models/default}"
out=target/web-static

[ -f "$bundle/manifest.json" ] || { echo "build_web_static.sh: $bundle: no manifest.json (not a bundle)" >&2; exit 2; }
[ -n "${SKIP_WASM_BUILD:-}" ] || scripts/build_wasm.sh
[ -f target/wasm-pkg/livegesture_wasm_bg.wasm ] || { echo "build_web_static.sh: target/wasm-pkg is missing; run scripts/build_wasm.sh" >&2; exit 1; }
# with SKIP_WASM_BUILD the module must not be older than what it is built from (a stale build would be
# tested and shipped as the current one)
scripts/wasm_fresh.sh target/wasm-pkg/livegesture_wasm_bg.wasm

rm -rf "$out"
mkdir -p "$out/wasm" "$out/bundle"
cp -r runtime/web/dist/. "$out/"
# the static page has no server: the engine is this browser unless ?engine= says otherwise
sed -i 's|<meta charset="utf-8">|<meta charset="utf-8">\n<meta name="livegesture-engine" content="wasm">|' "$out/index.html"
cp target/wasm-pkg/livegesture_wasm.js target/wasm-pkg/livegesture_wasm_bg.wasm "$out/wasm/"
# onnxruntime-web's WebAssembly CPU build for the page's second engine, ?engine=ort-web (ort-worker.js,
# docs/wasm.md), from runtime/web's locked npm packages
ortdist=runtime/web/node_modules/onnxruntime-web/dist
[ -f "$ortdist/ort.wasm.min.mjs" ] || (cd runtime/web && npm install --no-save --no-audit --no-fund --loglevel=error)
mkdir -p "$out/ort"
cp "$ortdist/ort.wasm.min.mjs" "$ortdist/ort-wasm-simd-threaded.mjs" "$ortdist/ort-wasm-simd-threaded.wasm" "$out/ort/"
# the skeleton the page poses, from the runtime itself
node --input-type=module -e "
import { readFileSync, writeFileSync } from 'node:fs';
const m = await import('$PWD/target/wasm-pkg/livegesture_wasm.js');
m.initSync({ module: readFileSync('target/wasm-pkg/livegesture_wasm_bg.wasm') });
writeFileSync('$out/skeleton.json', m.skeletonJson());
"
# the face mesh the page's figure wears (the asset compiled into the runtime; docs/face.md)
cp runtime/assets/face/ict_face.bin "$out/face.bin"
scripts/copy_bundle.py "$bundle" "$out/bundle"
du -sh "$out" "$out/wasm" "$out/ort" "$out/bundle"

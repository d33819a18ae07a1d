#!/usr/bin/env bash
# The project's test command (README "The two commands"; .ci/run calls it). Installs what it needs, then runs:
#   1. the Python test suite (PyTorch reference: step == offline, streaming contract, data, training,
#      metrics, export);
#   2. fresh exports of the tiny configs of both families (the exporter verifies every graph against torch);
#   3. the Rust build and the parity checks (torch vs ort vs tract) on those exports and on the shipped bundles
#      with the oldest supported and the newest ONNX Runtime (JUnit reports in target/parity/);
#   4. the Rust tests (runtime numerics, bundles, pipeline, CLI, serve, parity suite incl. its must-fail cases),
#      clippy -D warnings and rustdoc -D warnings on the whole workspace;
#   5. the bindings: the Python module's wheel, the C example and C# declarations (mono) against the CLI;
#   6. the serve protocol with independent Python/JS clients, BVH read back with a PyPI reader, and
#      a rolling restart of serve replicas behind HAProxy, the deployment files checked statically;
#   7. avatars: glTF and BVH of a real recording through the Khronos glTF validator and Blender's
#      importers (Debian's blender), the VRM retargeting's node tests;
#   8. the browser page in Debian's chromium with a fake microphone, the skinned figure, a .glb in
#      GLTFLoader and a VRM avatar following a WAV (screenshots in target/browser/); the page over
#      https with a token (target/browser-tls/);
#   9. the runtime compiled to WebAssembly: the static page in chromium (parity of both shipped bundles,
#      a perturbed weight, the microphone, a WAV vs native tract; report in target/browser-wasm/);
#  10. the page's second browser engine, onnxruntime-web, in chromium (parity of both shipped bundles, a
#      perturbed weight; report in target/browser-ortweb/);
#  11. the x86-64 levels (the release binary under qemu-x86_64 -cpu Haswell / Nehalem: AVX2+FMA and SSE-only
#      kernels of tract and ONNX Runtime; the host's own level is the parity stages of 3.) and the targets matrix
#      (docs/targets.md); the aarch64 musl and x86-64 musl release archives and the Windows one proven from the
#      archive alone (under qemu-aarch64, natively, under wine: docs/install.md), and the x86-64 glibc archive (ort
#      in lib/) and C SDK from the workspace build;
# and first, the docs check (scripts/check_docs.py: relative links in the Markdown resolve).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
# the package from THIS checkout, whichever checkout the (shared, cached) venv's editable install points at: a
# second checkout on the same machine that ran scripts/env.sh re-points it (a fresh-clone run here once imported
# another worktree's livegesture and looked for its real-speech data beside that worktree)
export PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}"

t0=$SECONDS
stage() { echo; echo "=== $* ($(( SECONDS - t0 )) s elapsed)"; }

stage "docs: every relative link in the Markdown resolves, no outside-specification reference"
"$LIVEGESTURE_PY" scripts/check_docs.py

stage "layout: no module cycle in a Rust crate, no long function or file without its reason"
# (scripts/check_structure.py, about a second; its must-fail cases: python/tests/test_check_structure.py)
"$LIVEGESTURE_PY" scripts/check_structure.py

stage "rust formatting (cargo fmt --check)"
cargo fmt --all -- --check

# The Python module (bindings/python, a workspace member) is compiled by the workspace build below and packed by
# maturin in the stage "bindings": both read this PyO3 configuration (abi3, CPython >= 3.10; what maturin writes
# itself on Linux), so maturin finds pyo3 and the module already built instead of compiling them again
export PYO3_CONFIG_FILE="$PWD/bindings/python/pyo3-config.txt"

# run_jobs FN...: the functions side by side, at most $(nproc) at a time (the background builds still running count
# as one), each with errexit, its output kept in target/jobs/FN.log and printed whole once it ends; fails when one
# failed, after all have ended, naming them
run_jobs() {
  local fn failed=() pids=()
  mkdir -p target/jobs
  for fn in "$@"; do
    while [ "$(jobs -rp | wc -l)" -ge "$(nproc)" ]; do wait -n 2>/dev/null || true; done
    rm -f "target/jobs/$fn.rc"
    ( set +e; ( set -e; "$fn" ) > "target/jobs/$fn.log" 2>&1; echo $? > "target/jobs/$fn.rc" ) &
    pids+=("$!")
  done
  wait "${pids[@]}" 2>/dev/null || true
  for fn in "$@"; do
    echo "--- $fn"; cat "target/jobs/$fn.log"
    [ "$(cat "target/jobs/$fn.rc" 2>/dev/null)" = 0 ] || failed+=("$fn (exit $(cat "target/jobs/$fn.rc" 2>/dev/null || echo '?'))")
  done
  if [ ${#failed[@]} -gt 0 ]; then echo "failed: ${failed[*]}" >&2; return 1; fi
}

# The Python tests and the three tiny exports (one Python process each, one after another) run side by side
# (run_jobs): both are single-threaded Python (torch at one thread), so one core stood idle while they ran one after
# the other (vmstat every 10 s: 45-50 % idle CPU for the first 316 s of a fresh clone on the 2-core EPYC)
python_tests() { "$LIVEGESTURE_PY" -m pytest -q python/tests; }
exports() {
  stage "export the tiny config (random weights) -> target/test-bundles/tiny"
  mkdir -p target/test-bundles
  "$LIVEGESTURE_PY" export/export.py --config tiny --random-seed 3 --out target/test-bundles/tiny
  stage "export the tiny config with the ring forms (docs/bundle.md#ring-caches) -> target/test-bundles/tiny-ring"
  # the same weights; each backend runs its ring form; a 300-token reference rollout (parity-tests/src/lib.rs)
  "$LIVEGESTURE_PY" export/export.py --config tiny --random-seed 3 --forms canonical,fused,attention,ring \
    --backend-forms ort=fused_ring,tract=attention_ring --rollout-tokens 300 --out target/test-bundles/tiny-ring
  stage "export the DiffSHEG tiny config (random weights) -> target/test-bundles/diffsheg-tiny"
  "$LIVEGESTURE_PY" export/export.py --family diffsheg --config tiny --random-seed 0 \
    --out target/test-bundles/diffsheg-tiny
}
stage "python tests and, beside them, the tiny exports (each one's output follows, whole)"
run_jobs python_tests exports
# the Rust tests (runtime and parity suite) use these fresh exports (parity-tests/src/lib.rs)
export LIVEGESTURE_TEST_BUNDLE="$PWD/target/test-bundles/tiny"
export LIVEGESTURE_RING_TEST_BUNDLE="$PWD/target/test-bundles/tiny-ring"
export LIVEGESTURE_DIFFSHEG_TINY_BUNDLE="$PWD/target/test-bundles/diffsheg-tiny"

stage "rust build (release)"
cargo build --release --workspace --all-targets

# The cross builds, one after another in the background (niced; not beside each other: two cargo builds would only
# share the two cores), each compiled once (profile dist) and waited for at the stage that needs it (wait_build).
# What the targets need (Debian packages, rustup targets) is installed first, in the foreground, so that no apt-get
# or rustup of theirs runs beside another stage's. (Started before the Python tests instead, which run on one core,
# the whole command was no shorter on the 2-core EPYC: 3961 s against 3922 s, the Python tests 225 s instead of
# 206 s and the workspace build 773 s instead of 648 s beside them; docs/experiments.md.)
#   aarch64   scripts/cross.sh aarch64-unknown-linux-musl: static, tract (the targets matrix and its archive)
#   x86-musl  scripts/cross.sh x86_64-unknown-linux-musl: static, tract (stage "release")
#   windows   scripts/cross.sh x86_64-pc-windows-gnu: mingw-w64, tract (stage "release")
# Each writes target/cross/NAME.log and, when it ends, its exit status to target/cross/NAME.rc. (The WebAssembly
# build is the wasm stage's own, in the foreground: measured 2026-12-07 on the 2-core EPYC, a fifth build in this
# chain made the whole command ~4 minutes slower, the machine being busy throughout either way.)
mkdir -p target/cross
rm -f target/cross/*.rc target/cross/*.log
for triple in aarch64-unknown-linux-musl x86_64-unknown-linux-musl x86_64-pc-windows-gnu; do
  scripts/cross.sh --install "$triple"
done
bg_build() {
  local name=$1 rc=0; shift
  "$@" > "target/cross/$name.log" 2>&1 || rc=$?
  echo "$rc" > "target/cross/$name.rc"
}
(
  bg_build aarch64 env CROSS_NICE=10 scripts/cross.sh aarch64-unknown-linux-musl
  bg_build x86-musl env CROSS_NICE=10 scripts/cross.sh x86_64-unknown-linux-musl
  bg_build windows env CROSS_NICE=10 scripts/cross.sh x86_64-pc-windows-gnu
) &
chain_pid=$!
# a stage that fails ends the command: the builds still running in the background end with it
kill_tree() { local c; for c in $(pgrep -P "$1"); do kill_tree "$c"; done; kill "$1" 2>/dev/null || true; }
end_chain() { local rc=$?; if kill -0 "$chain_pid" 2>/dev/null; then kill_tree "$chain_pid"; fi; exit "$rc"; }
trap end_chain EXIT

wait_build() {
  local name=$1
  while [ ! -f "target/cross/$name.rc" ]; do
    kill -0 "$chain_pid" 2>/dev/null || { echo "the background builds ended before $name ran" >&2; exit 1; }
    sleep 5
  done
  if [ "$(cat "target/cross/$name.rc")" != 0 ]; then
    tail -n 40 "target/cross/$name.log"; echo "the $name build failed (target/cross/$name.log)" >&2; exit 1
  fi
  grep -E "built in|Finished" "target/cross/$name.log" || true
}

# every parity run also writes its JUnit report (target/parity/*.xml) for CI systems to read; an earlier
# run's reports are removed first, so none can be read as this run's
rm -rf target/parity
mkdir -p target/parity
ORT_OLDEST="$("$LIVEGESTURE_PY" -c 'import onnxruntime; print(onnxruntime.__version__)')"
stage "parity: fresh tiny export, both backends (ONNX Runtime $ORT_OLDEST)"
./target/release/livegesture parity --bundle target/test-bundles/tiny --backends ort,tract \
  --junit target/parity/tiny.xml
stage "parity: fresh tiny export with the ring forms, both backends (ONNX Runtime $ORT_OLDEST)"
./target/release/livegesture parity --bundle target/test-bundles/tiny-ring --backends ort,tract \
  --junit target/parity/tiny-ring.xml
stage "parity: fresh DiffSHEG tiny export, both backends (ONNX Runtime $ORT_OLDEST)"
./target/release/livegesture parity --bundle target/test-bundles/diffsheg-tiny --backends ort,tract \
  --junit target/parity/diffsheg-tiny.xml

# The shipped bundles on the oldest supported ONNX Runtime (the venv's, python/requirements.txt) and the
# newest on PyPI, installed beside it with `pip install --target` (cached): `parity` prints the version
# the library reports, which must be the one asked for.
ORT_NEWEST=1.32.0
ORT_NEWEST_DIR="$(dirname "$LIVEGESTURE_VENV")/onnxruntime-$ORT_NEWEST"
if [ ! -f "$ORT_NEWEST_DIR/.complete" ]; then
  rm -rf "$ORT_NEWEST_DIR"
  "$LIVEGESTURE_VENV/bin/pip" install -q --no-deps --target "$ORT_NEWEST_DIR" "onnxruntime==$ORT_NEWEST"
  touch "$ORT_NEWEST_DIR/.complete"
fi
ORT_NEWEST_LIB="$(ls "$ORT_NEWEST_DIR"/onnxruntime/capi/libonnxruntime.so.1* | head -n1)"
# tract's rows do not depend on ONNX Runtime's version: the newest runs ort alone (against torch, and its rollout)
for ort in "$ORT_OLDEST:$ORT_DYLIB_PATH:ort,tract" "$ORT_NEWEST:$ORT_NEWEST_LIB:ort"; do
  version="${ort%%:*}"; rest="${ort#*:}"; lib="${rest%:*}"; backends="${rest##*:}"
  for bundle in default diffsheg; do
    stage "parity: models/$bundle, backends $backends, ONNX Runtime $version"
    ORT_DYLIB_PATH="$lib" ./target/release/livegesture parity --bundle "models/$bundle" --backends "$backends" \
      --junit "target/parity/$bundle-ort-$version.xml" | tee target/parity/last.txt
    grep -q "^runtimes: .*ONNX Runtime $version " target/parity/last.txt || {
      echo "parity did not run ONNX Runtime $version ($lib)" >&2; exit 1; }
  done
done
# docs/parity.md: a JUnit report in which nothing was compared fails (issue 38); each must hold test cases
for x in target/parity/*.xml; do
  if ! grep -q '<testcase' "$x" || grep -q 'tests="0"' "$x"; then
    echo "$x: a JUnit report with no test case" >&2; exit 1
  fi
done

stage "variants: every model variant of both families trained a few steps, exported, parity ort+tract, generate"
# (scripts/variants.sh; docs/model.md "Variants and fidelity choices", docs/diffsheg.md "Variants")
LIVEGESTURE_BIN="$PWD/target/release/livegesture" scripts/variants.sh target/variants

stage "rust tests"
if command -v cargo-nextest >/dev/null 2>&1; then
  cargo nextest run --workspace --release --no-fail-fast
  # nextest does not run doctests: they run here
  cargo test --workspace --release --doc
else
  cargo test --workspace --release --no-fail-fast
fi

stage "lints: clippy -D warnings on every crate and target, rustdoc -D warnings (broken or private doc links)"
# (clippy checks the dependencies once, without code generation; rustdoc reuses that check; about 6 min on the
# loaded 2-core VM for both, a few seconds once they are checked)
cargo clippy --version >/dev/null 2>&1 || rustup component add clippy
cargo clippy --release --workspace --all-targets -- -D warnings
RUSTDOCFLAGS="-D warnings" cargo doc --release --workspace --no-deps

stage "face: lip sync of the runtime's face channel on the held-out real speech (docs/face.md)"
# pocketsphinx (its wheel's en-us acoustic model and phone LM) labels the recordings; not in
# python/requirements.txt, whose hash names the cached venv
"$LIVEGESTURE_PY" -c 'import pocketsphinx' 2>/dev/null || "$LIVEGESTURE_VENV/bin/pip" install -q pocketsphinx==5.1.1
face_out=target/face-eval
face_rs="$("$LIVEGESTURE_PY" -c 'from livegesture.data.real_speech import real_speech_dir; print(real_speech_dir())')"
rm -rf "$face_out" && mkdir -p "$face_out"
for id in $("$LIVEGESTURE_PY" -c 'from livegesture.data.real_speech import VALIDATION; print(*VALIDATION)'); do
  ./target/release/livegesture generate "$face_rs/$id.wav" -o "$face_out/$id.npz" \
    --seed 0 --backend tract --bundle models/default
done
"$LIVEGESTURE_PY" -m livegesture.face.evaluate --npz-dir "$face_out" --real-speech "$face_rs" \
  --out "$face_out/report.json" --check

stage "bindings: the Python module (wheel), the C example and the C# P/Invoke declarations vs the CLI"
# The wheel (docs/python.md): maturin into the project venv (not in python/requirements.txt, whose hash names
# the cached venv). It builds in this target/, where the workspace build above compiled the module with the same
# features and PyO3 configuration (PYO3_CONFIG_FILE), so it only packs the wheel (~3 s).
"$LIVEGESTURE_VENV/bin/maturin" --version 2>/dev/null | grep -qx "maturin 1.16.0" || \
  "$LIVEGESTURE_VENV/bin/pip" install -q maturin==1.16.0
rm -rf target/wheels
"$LIVEGESTURE_VENV/bin/maturin" build --release --manifest-path bindings/python/Cargo.toml \
  --interpreter "$LIVEGESTURE_PY" --out target/wheels 2>&1 | tee target/maturin.log
# a crate compiled again here means the package-alone build resolved other features than the workspace build
# (bindings/python/Cargo.toml names them); that costs ~4 minutes of this command, so it fails instead
if grep -E '^ *Compiling ' target/maturin.log | grep -v 'livegesture-python'; then
  echo "maturin compiled the crates above again: their features differ from the workspace build's" \
    "(compare \`cargo tree --workspace -e features\` with \`cargo tree -p livegesture-python -e features\`)" >&2
  exit 1
fi
"$LIVEGESTURE_VENV/bin/pip" install -q --no-deps --force-reinstall target/wheels/livegesture_runtime-*.whl
# the C library was built by the workspace build above (target/release/liblivegesture_c.{a,so})
scripts/build_c_example.sh --prebuilt
# Debian's mono compiles and runs the C# P/Invoke declarations of docs/c.md (bindings/tests/test_csharp.py)
if ! command -v mcs >/dev/null 2>&1 || ! command -v mono >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then _sudo=""; else _sudo="sudo"; fi
  $_sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $_sudo apt-get install -y -qq mono-mcs >/dev/null
fi
LIVEGESTURE_BIN="$PWD/target/release/livegesture" "$LIVEGESTURE_PY" -m pytest -q \
  bindings/tests/test_python.py bindings/tests/test_c_example.py bindings/tests/test_csharp.py

stage "serve and BVH: independent Python/JS clients vs generate, BVH read back by the bvh package"
# (pyyaml: the Kubernetes manifests' check, runtime/tests/py/test_deploy_files.py)
"$LIVEGESTURE_VENV/bin/pip" install -q websockets==15.0.1 bvh==0.3 pyyaml==6.0.3
# replicas behind a load balancer (runtime/tests/py/test_haproxy.py, docs/deploy.md): Debian's haproxy
if ! command -v haproxy >/dev/null 2>&1 || ! command -v openssl >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then _sudo=""; else _sudo="sudo"; fi
  $_sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $_sudo apt-get install -y -qq haproxy openssl >/dev/null
fi
export LIVEGESTURE_REQUIRE_HAPROXY=1
LIVEGESTURE_BIN="$PWD/target/release/livegesture" "$LIVEGESTURE_PY" -m pytest -q runtime/tests/py

stage "web page: the committed runtime/web/dist (embedded in the binary) is what runtime/web/src builds"
# the locked versions (see the browser stage below on why not `npm ci`); vite's build is reproducible,
# so a dist that differs from a fresh build is stale: rebuild it (cd runtime/web && npm run build)
(cd runtime/web && npm install --no-save --no-audit --no-fund --loglevel=error)
rm -rf target/web-dist-fresh
(cd runtime/web && npx vite build --outDir ../../target/web-dist-fresh --emptyOutDir --logLevel error)
if ! diff -r target/web-dist-fresh runtime/web/dist >/dev/null; then
  diff -rq target/web-dist-fresh runtime/web/dist || true
  echo "runtime/web/dist is stale: it differs from a fresh build of runtime/web (run: cd runtime/web && npm run build; commit dist)" >&2
  exit 1
fi

stage "avatars: glTF/BVH of a real recording, Khronos glTF validator, Blender imports, retargeting tests"
# the locked versions (see the browser stage below on why not `npm ci`)
(cd runtime/web && npm install --no-save --no-audit --no-fund --loglevel=error)
(cd runtime/web && node --test tests/retarget.test.mjs tests/compare.test.mjs)
avatar_out=target/avatar
mkdir -p "$avatar_out"
# the first 12 s of the bundle's reference recording, every output format from the same seed
"$LIVEGESTURE_PY" - "$avatar_out/speech.wav" <<'PY'
import sys, wave
with wave.open("models/default/reference/clip.wav", "rb") as r, wave.open(sys.argv[1], "wb") as w:
    w.setparams(r.getparams())
    w.writeframes(r.readframes(12 * r.getframerate()))
PY
for ext in npz bvh glb gltf; do
  ./target/release/livegesture generate "$avatar_out/speech.wav" -o "$avatar_out/motion.$ext" \
    --seed 3 --backend tract --bundle models/default
done
node runtime/web/tests/gltf-validate.mjs "$avatar_out/motion.glb" "$avatar_out/motion.gltf"
if ! command -v blender >/dev/null 2>&1 || ! dpkg -s python3-numpy >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then _sudo=""; else _sudo="sudo"; fi
  $_sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $_sudo apt-get install -y -qq blender python3-numpy >/dev/null  # the glTF importer needs numpy
fi
timeout 300 blender -b --factory-startup --python-exit-code 1 --python runtime/tests/blender/check_import.py -- \
  "$avatar_out/motion.glb" "$avatar_out/motion.bvh" "$avatar_out/motion.npz"

stage "browser: the served page in Debian's chromium with a fake microphone (playwright-core)"
if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then _sudo=""; else _sudo="sudo"; fi
  $_sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $_sudo apt-get install -y -qq chromium >/dev/null
fi
# the locked versions; not `npm ci`, which refuses the lock file where the registry serves only this
# platform's build of rollup (404 for the other @rollup/rollup-* packages, as on this project's machine)
(cd runtime/web && npm install --no-save --no-audit --no-fund --loglevel=error)
timeout 600 node runtime/web/tests/browser.mjs target/release/livegesture models/default \
  models/default/reference/clip.wav target/browser
# the page over https (a certificate the test makes) with a token: a session over wss receives frames;
# without the token, or with a wrong one, or from another origin, the session is refused (docs/deploy.md)
timeout 300 node runtime/web/tests/tls.mjs target/release/livegesture models/default \
  models/default/reference/clip.wav target/browser-tls

stage "wasm: the runtime in WebAssembly as a static page, parity and the microphone in chromium (docs/wasm.md)"
# installs the wasm32 target and the wasm-bindgen CLI if missing; builds target/wasm-pkg and target/web-static
scripts/build_web_static.sh models/default
# the staleness check build_web_static.sh applies under SKIP_WASM_BUILD, shown to fail a stale module
scripts/test_wasm_fresh.sh
mkdir -p target/web-static/bundles target/browser-wasm
scripts/copy_bundle.py models/diffsheg target/web-static/bundles/diffsheg
rm -rf target/web-static/bundles/broken
"$LIVEGESTURE_PY" parity-tests/tools/break_bundle.py target/test-bundles/tiny target/web-static/bundles/broken \
  --graph expert_hands --perturb-weight
./target/release/livegesture generate models/default/reference/clip.wav -o target/browser-wasm/native.npz \
  --backend tract --seed 7
timeout 1500 node runtime/web/tests/wasm.mjs --site target/web-static --out target/browser-wasm \
  --wav models/default/reference/clip.wav --native target/browser-wasm/native.npz --seed 7 \
  --parity bundle/ --parity bundles/diffsheg/ --broken bundles/broken/:expert_hands \
  --serve target/release/livegesture

stage "providers: onnxruntime-web in chromium, the page's ?engine=ort-web (docs/wasm.md, docs/targets.md)"
# the page's second engine on the same bundles as the wasm stage above: every graph vs torch at 1e-5, the
# seeded rollouts, a perturbed weight that must fail naming its graph (~1.5 min on a loaded 2-core VM)
timeout 900 node runtime/web/tests/ortweb.mjs --site target/web-static --out target/browser-ortweb \
  --parity bundle/ --parity bundles/diffsheg/ --broken bundles/broken/:expert_hands

stage "targets under emulation, side by side: the x86-64 levels (qemu-x86_64 -cpu Haswell / Nehalem), the aarch64 parity matrix (docs/targets.md) and the aarch64 release archive proven from the archive alone"
# Each job below is one emulated process on one core (no build: the release binary above, the aarch64 build of the
# background chain), so they run as a pool of $(nproc) at a time (run_jobs): on the 2-core VM the stages took 160 s
# and 308 s one after another (2026-12-07).
#
# The x86-64 levels: every x86 kernel path tract and ONNX Runtime dispatch to, on the tiny bundles; CPUID changed by
# qemu. The native level (x86-64-v4 on an AVX-512 host, v3 on an AVX2-only one; the parity reports' `target.cpu`) is
# the parity stages above, on real hardware and with every check: qemu runs only the other levels.
native_level=x86-64-v2
grep -qw avx2 /proc/cpuinfo && grep -qw fma /proc/cpuinfo && native_level=x86-64-v3
grep -qw avx512f /proc/cpuinfo && native_level=x86-64-v4
levels=()
for l in x86-64-v3 x86-64-v2; do [ "$l" = "$native_level" ] || levels+=("$l"); done
echo "this host's level: $native_level (the parity stages above); under qemu: ${levels[*]}"
x86_tiny() { scripts/targets.sh --bundle target/test-bundles/tiny --out target/targets/tiny "${levels[@]}"; }
x86_diffsheg() {
  scripts/targets.sh --bundle target/test-bundles/diffsheg-tiny --out target/targets/diffsheg-tiny "${levels[@]}"
}
# must fail on TARGET: the tiny bundle with one expert_hands weight x 1.02 (relative), a graph check that fails
# naming expert_hands; the broken copy and the report under target/targets/broken-tiny[-SUFFIX], broken[-SUFFIX]
must_fail_on() {
  local t=$1 sfx=${2:+-$2}
  "$LIVEGESTURE_PY" parity-tests/tools/break_bundle.py target/test-bundles/tiny "target/targets/broken-tiny$sfx" \
    --graph expert_hands --perturb-weight --delta 0.02 --relative
  if scripts/targets.sh --bundle "target/targets/broken-tiny$sfx" --out "target/targets/broken$sfx" --checks graph \
      "$t" > "target/targets/broken$sfx.txt" 2>&1; then
    cat "target/targets/broken$sfx.txt"; echo "targets.sh on $t passed a bundle with a perturbed weight" >&2; return 1
  fi
  grep -q "^FAIL graph expert_hands" "target/targets/broken$sfx/$t.txt" || {
    cat "target/targets/broken$sfx.txt"; echo "targets.sh on $t did not name expert_hands" >&2; return 1; }
  echo "$t: the perturbed expert_hands fails, named"
}
x86_broken() { must_fail_on x86-64-v2 x86; }   # the SSE-only path too
# aarch64 (qemu-aarch64), the static build. The x86-64 targets are not in this matrix yet: not yet run with
# --target-name (docs/targets.md)
a64_tiny() { scripts/targets.sh --bundle target/test-bundles/tiny --out target/targets/tiny aarch64-musl; }
a64_diffsheg() {
  scripts/targets.sh --bundle target/test-bundles/diffsheg-tiny --out target/targets/diffsheg-tiny aarch64-musl
}
a64_broken() { must_fail_on aarch64-musl; }   # target/targets/broken-tiny, as docs/targets.md's commands use
# NEON-only aarch64 (`qemu-aarch64 -cpu cortex-a72`: no SVE, as on Graviton 2 or a Raspberry Pi 4): the same static
# build must take tract's arm64simd kernels there and pass on the tiny bundle (63-98 s under qemu, loaded 2-core VM)
a64_neon() {
  scripts/targets.sh --bundle target/test-bundles/tiny --out target/targets/tiny aarch64-musl-neon
  "$LIVEGESTURE_PY" - target/targets/tiny/aarch64-musl-neon.json <<'PY'
import json, sys
cpu = json.load(open(sys.argv[1]))["target"]["cpu"]
if cpu["tract_rung"] != "neon" or any("sve" in t for t in cpu["tract_mmm_tiers"]):
    sys.exit(f"aarch64-musl-neon: tract took {cpu['tract_rung']} {cpu['tract_mmm_tiers']}, not the NEON-only arm64simd path")
# and it names the f32 kernels it picked: arm64simd's, for every matmul shape
picks = cpu.get("tract_f32_mmm_picks") or {}
if not picks or not all(str(k).startswith("arm64simd_") for k in picks.values()):
    sys.exit(f"aarch64-musl-neon: tract's f32 matmul picks {picks} are not all arm64simd kernels")
print("aarch64-musl-neon: tract took the NEON-only arm64simd kernels")
PY
}
# the release archive for aarch64 Linux (static), proven from the archive alone under qemu-aarch64
a64_prove() { scripts/release.sh --prove aarch64-unknown-linux-musl; }
wait_build aarch64
# the binaries the background builds made: no cargo here (it would wait for the lock the Windows build holds)
export CROSS_NO_BUILD=1
mkdir -p target/targets
run_jobs x86_tiny a64_tiny a64_neon a64_prove a64_broken x86_broken a64_diffsheg x86_diffsheg

stage "release: the x86-64 glibc archive (ONNX Runtime in lib/) and C SDK, proven from the archive alone"
# no compile: both take the workspace build above (target/release), so this stage runs before the two that wait for
# the background builds (run last, it had one core idle beside it); the archive's --backend ort finds lib/'s library,
# tract is byte-identical to the native build; the SDK's example built from the extracted archive with pkg-config
# and with CMake, shared and static (docs/install.md)
scripts/release.sh --prove x86_64-unknown-linux-gnu c-sdk

stage "release: the x86-64 musl (static) archive, proven from the archive alone (docs/install.md)"
wait_build x86-musl
# static (file, ldd); its generate output, with no --bundle, the same bytes as the native gnu build's tract output
scripts/release.sh --prove x86_64-unknown-linux-musl

stage "release: the Windows archive (.zip), proven from the archive alone under wine (docs/install.md)"
wait_build windows
# livegesture.exe under Debian's wine, no --bundle: ceil(duration x 30) frames, the native build's tokens
scripts/release.sh --prove x86_64-pc-windows-gnu

stage "all tests passed"

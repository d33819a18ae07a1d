#!/usr/bin/env bash
# Proves release archives from the archive alone (docs/install.md): scripts/prove_release.sh TARGET...
# (Rust triples whose archives scripts/release.sh wrote to target/dist/, and `c-sdk`, `web`, `wheel-x86_64`,
# `wheel-aarch64`: see prove_c_sdk, prove_web and prove_wheel below.)
#
# For each: `sha256sum -c` against target/dist/SHA256SUMS; the archive extracted into an empty folder outside
# the repository; `--version` names the commit and the target; the musl binaries are static (`file`, `ldd`); then
# `generate` on a WAV (5.23 s of the bundle's reference speech, written into that folder) with no --bundle
# (the bundle is found next to the executable) and no environment from the project, natively, under qemu-user
# or under wine. The output must have ceil(duration x 30) frames, all finite, and equal the native x86-64 build
# (target/release/livegesture, tract, same seed): the same bytes (cmp of the .npz) for x86-64 Linux (musl, gnu);
# within 1e-4 (scaled), i.e. the same motion tokens, for Windows (bit-identity reported) and other instruction
# sets. Every archive carries LICENSES/livegesture-LICENSE and crates.txt. Exit 0 only when all pass.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh >/dev/null
repo="$PWD"
dist="$repo/target/dist"
VERSION="$(sed -n 's/^version = "\(.*\)"/\1/p' runtime/Cargo.toml | head -n1)"
# the native reference build (x86-64 gnu, this checkout's target/release unless LIVEGESTURE_NATIVE_BIN names another)
native="${LIVEGESTURE_NATIVE_BIN:-$repo/target/release/livegesture}"
[ -x "$native" ] || { echo "prove_release.sh: $native is missing (cargo build --release -p livegesture)" >&2; exit 2; }
work="$(mktemp -d /tmp/livegesture-prove.XXXXXX)"
trap 'rm -rf "$work"' EXIT
# wine's prefix lives in the cache folder beside the venv: its first start (wineboot, ~700 MB) is paid once per
# machine or CI run, not once per archive
export WINEPREFIX="${WINEPREFIX:-$(dirname "$LIVEGESTURE_VENV")/wine}"

# the WAV and the native reference output (x86-64 gnu build of this checkout, tract)
"$LIVEGESTURE_PY" - models/default/reference/clip.wav "$work/speech.wav" <<'PY'
import sys, wave
with wave.open(sys.argv[1], "rb") as r, wave.open(sys.argv[2], "wb") as w:
    w.setparams(r.getparams())
    w.writeframes(r.readframes(int(5.23 * r.getframerate())))
PY
"$native" generate "$work/speech.wav" -o "$work/native.npz" --backend tract --seed 3 \
  --bundle models/default 2>/dev/null

failed=()
checksum() {  # FILE (in target/dist): its line of SHA256SUMS checks
  (cd "$dist" && grep " $1\$" SHA256SUMS | sha256sum -c --quiet)
}
# NPZ_OR_F32 EXACT: ceil(duration x 30) frames, finite, equal to the native x86-64 tract output (EXACT=1: every
# value; else within 1e-4 scaled, i.e. the same motion tokens). A .f32 file is the C example's poses.
check_output() {
  "$LIVEGESTURE_PY" - "$work/speech.wav" "$1" "$work/native.npz" "$2" <<'PY'
import math, sys, wave
import numpy as np
wav, got_p, want_p, exact = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4] == "1"
with wave.open(wav) as w:
    frames = math.ceil(w.getnframes() / w.getframerate() * 30)
want = np.load(want_p)
if got_p.endswith(".f32"):
    raw = np.fromfile(got_p, dtype="<f4")
    assert raw.size % 165 == 0 and raw.size > 0, f"{got_p}: {raw.size} float32 values, not frames x 165"
    got, keys = {"poses": raw.reshape(-1, 165)}, ("poses",)
else:
    got, keys = np.load(got_p), ("poses", "trans", "expressions")
for k in keys:
    g, r = got[k], want[k]
    assert g.shape[0] == frames, f"{k}: {g.shape[0]} frames, expected ceil(duration x 30) = {frames}"
    assert np.isfinite(g).all(), f"{k}: non-finite values"
    if exact:
        assert g.shape == r.shape and np.array_equal(g, r), \
            f"{k}: differs from the native x86-64 build (max |diff| {np.abs(g - r).max() if g.shape == r.shape else 'shape'})"
    else:
        assert g.shape == r.shape, f"{k}: shape {g.shape}, the native x86-64 build's {r.shape}"
        err = float(np.abs(g - r).max() / max(1.0, float(np.abs(r).max())))
        assert err <= 1e-4, f"{k}: {err:.3e} (scaled) from the native x86-64 build, bound 1e-4"
same = all(np.array_equal(got[k], want[k]) for k in keys)
print(f"{frames} frames = ceil(duration x 30), finite, " + ("bit-identical to" if same else "within 1e-4 (scaled) of")
      + " the native x86-64 tract output" + ("" if len(keys) == 3 else " (poses)"))
PY
}

# the C SDK (TRIPLE: x86_64- or aarch64-unknown-linux-gnu): headers, stripped libraries, pkg-config and CMake
# files; the example compiled against the extracted SDK four ways (pkg-config shared/static, CMake shared/static;
# aarch64: cross-compiled with Debian's aarch64-linux-gnu-gcc, CMake told so), each run on the WAV with the bundle
# copied out of the repository (the SDK ships no bundle), natively or under qemu-aarch64 -L /usr/aarch64-linux-gnu:
# x86-64: the same poses as the native CLI, bit for bit (the same code and kernels on the same machine;
# bindings/tests/test_c_example.py checks the same in the tree); aarch64: within 1e-4 (scaled), the same tokens
prove_c_sdk() {
  local triple="$1" name="livegesture-c-$VERSION-$1" d="$work/c-sdk-$1" sdk f exe cc=cc run=() exact=1 cm_cross=()
  if [ "$triple" = aarch64-unknown-linux-gnu ]; then
    cc=aarch64-linux-gnu-gcc; run=(qemu-aarch64 -L /usr/aarch64-linux-gnu); exact=0
    cm_cross=(-DCMAKE_SYSTEM_NAME=Linux -DCMAKE_SYSTEM_PROCESSOR=aarch64 -DCMAKE_C_COMPILER=aarch64-linux-gnu-gcc)
  fi
  [ -f "$dist/$name.tar.gz" ] || { echo "no $name.tar.gz in target/dist"; return 1; }
  checksum "$name.tar.gz" || return 1
  # the SDK's users build with CMake and pkg-config: Debian's, installed when missing (a fresh CI machine has
  # neither cmake nor necessarily pkg-config)
  if ! command -v cmake >/dev/null 2>&1 || ! command -v pkg-config >/dev/null 2>&1; then
    local _sudo=""; [ "$(id -u)" = 0 ] || _sudo=sudo
    $_sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $_sudo apt-get install -y -qq --no-install-recommends cmake pkg-config >/dev/null
  fi
  mkdir -p "$d" && tar -C "$d" -xzf "$dist/$name.tar.gz"
  sdk="$d/$name"
  for f in include/livegesture.h lib/liblivegesture_c.so lib/liblivegesture_c.a lib/pkgconfig/livegesture.pc \
      lib/pkgconfig/livegesture-static.pc lib/cmake/livegesture/livegestureConfig.cmake \
      share/livegesture/examples/generate.c LICENSES/livegesture-LICENSE LICENSES/crates.txt README.md; do
    [ -s "$sdk/$f" ] || { echo "c-sdk: $f missing or empty"; return 1; }
  done
  file -b "$sdk/lib/liblivegesture_c.so" | grep -q ", stripped" || { file "$sdk/lib/liblivegesture_c.so"; echo "c-sdk: the shared library is not stripped"; return 1; }
  # (readelf reads every member's sections whatever the machine, unlike the host's objdump)
  if readelf -S -W "$sdk/lib/liblivegesture_c.a" 2>/dev/null | grep -q '\.debug_info'; then echo "c-sdk: the static library carries debug info"; return 1; fi
  # its SONAME, so that a program linked by the library's path (CMake) needs `liblivegesture_c.so`, not that path
  local soname; soname="$(readelf -d "$sdk/lib/liblivegesture_c.so")"
  [[ $soname == *"Library soname: [liblivegesture_c.so]"* ]] || { echo "c-sdk: liblivegesture_c.so has no SONAME liblivegesture_c.so"; return 1; }
  local machine; machine="$(readelf -h "$sdk/lib/liblivegesture_c.so" | sed -n 's/^ *Machine: *//p')"
  echo "c-sdk $triple: static library $(stat -c %s "$sdk/lib/liblivegesture_c.a") bytes ($(du -h "$sdk/lib/liblivegesture_c.a" | cut -f1)), shared $(stat -c %s "$sdk/lib/liblivegesture_c.so") bytes, $machine"
  "$LIVEGESTURE_PY" scripts/copy_bundle.py models/default "$d/bundle" >/dev/null
  mkdir -p "$d/build" && cd "$d/build"
  local ex="$sdk/share/livegesture/examples/generate.c" cflags=(-std=c11 -Wall -Wextra -Werror -O2)
  "$cc" "${cflags[@]}" "$ex" $(PKG_CONFIG_PATH="$sdk/lib/pkgconfig" pkg-config --cflags --libs livegesture) \
    -Wl,-rpath,"$sdk/lib" -o pc-shared || { cd "$repo"; return 1; }
  "$cc" "${cflags[@]}" "$ex" $(PKG_CONFIG_PATH="$sdk/lib/pkgconfig" pkg-config --cflags --libs livegesture-static) -o pc-static \
    || { cd "$repo"; return 1; }
  cat > CMakeLists.txt <<CMAKE
cmake_minimum_required(VERSION 3.16)
project(livegesture_sdk_proof C)
find_package(livegesture REQUIRED)
add_executable(cmake-shared "$ex")
target_link_libraries(cmake-shared livegesture::livegesture)
add_executable(cmake-static "$ex")
target_link_libraries(cmake-static livegesture::static)
CMAKE
  { cmake -S . -B cm -DCMAKE_PREFIX_PATH="$sdk" -DCMAKE_BUILD_TYPE=Release "${cm_cross[@]}" >/dev/null && cmake --build cm >/dev/null; } \
    || { cd "$repo"; echo "c-sdk: CMake could not build the example"; return 1; }
  cd "$repo"
  # the shared builds need the SDK's .so (and find it by their rpath), the static ones no liblivegesture_c at all
  # (readelf -d: the dynamic section, for any machine; ldd could not read a foreign one)
  local dyn
  for exe in pc-shared cm/cmake-shared pc-static cm/cmake-static; do
    readelf -h "$d/build/$exe" | grep -q "Machine: *$machine" || { echo "c-sdk: $exe is not built for $machine"; return 1; }
    dyn="$(readelf -d "$d/build/$exe")"
    case "$exe" in
      *shared) [[ $dyn == *"[liblivegesture_c.so]"* ]] || { echo "$dyn"; echo "c-sdk: $exe does not need liblivegesture_c.so"; return 1; } ;;
      *static) [[ $dyn != *liblivegesture_c* ]] || { echo "$dyn"; echo "c-sdk: $exe needs liblivegesture_c.so"; return 1; } ;;
    esac
  done
  if [ ${#run[@]} = 0 ]; then
    local l; l="$(ldd "$d/build/pc-shared")"   # (not piped into grep -q: with pipefail, ldd's SIGPIPE fails it)
    [[ $l == *"$sdk/lib/liblivegesture_c.so"* ]] || { echo "$l"; echo "c-sdk: pc-shared does not load the SDK's .so"; return 1; }
  fi
  for exe in pc-shared pc-static cm/cmake-shared cm/cmake-static; do
    (cd "$work" && env -i PATH=/usr/bin:/bin HOME="$work" "${run[@]}" "$d/build/$exe" "$d/bundle" speech.wav 3 tract > "$d/$(basename "$exe").f32") \
      || { echo "c-sdk: $exe failed"; return 1; }
    echo -n "c-sdk $exe: "; check_output "$d/$(basename "$exe").f32" "$exact" || return 1
  done
}

# the web archive: extracted, served by a static file server, the page's WebAssembly engine in chromium
# (runtime/web/tests/wasm.mjs): the WAV through the page within 1e-4 of native tract, the microphone path
prove_web() {
  local name="livegesture-web-$VERSION" d="$work/web" f
  [ -f "$dist/$name.tar.gz" ] || { echo "no $name.tar.gz in target/dist"; return 1; }
  checksum "$name.tar.gz" || return 1
  mkdir -p "$d" && tar -C "$d" -xzf "$dist/$name.tar.gz"
  for f in index.html wasm/livegesture_wasm_bg.wasm wasm/livegesture_wasm.js bundle/manifest.json \
      LICENSES/livegesture-LICENSE LICENSES/crates.txt; do
    [ -s "$d/$name/$f" ] || { echo "web: $f missing or empty"; return 1; }
  done
  [ ! -e "$d/$name/bundles/broken" ] || { echo "web: the test command's broken bundle is in the archive"; return 1; }
  timeout 900 node runtime/web/tests/wasm.mjs --site "$d/$name" --out "$d/report" --wav "$work/speech.wav" \
    --native "$work/native.npz" --seed 3
}

# a wheel: auditwheel names manylinux_2_17 (manylinux2014) for its architecture; x86-64: installed into a fresh
# venv of this machine's CPython, `generate` from Python equal to the native CLI bit for bit; aarch64: Debian's
# arm64 CPython under qemu-aarch64, `generate` within 1e-4 (scaled) of the native output (the same tokens).
# Both: the module's ELF machine, its exported PyInit and its dynamic dependencies are printed.
prove_wheel() {
  local arch="$1" whl d="$work/wheel-$1" py
  whl="$(cd "$dist" && ls livegesture_runtime-*-cp310-abi3-manylinux*_"$arch".whl 2>/dev/null | head -n1)"
  [ -n "$whl" ] || { echo "no livegesture_runtime-*_$arch.whl in target/dist"; return 1; }
  checksum "$whl" || return 1
  "$LIVEGESTURE_VENV/bin/auditwheel" show "$dist/$whl" > "$work/auditwheel-$arch.txt" 2>&1 || { cat "$work/auditwheel-$arch.txt"; return 1; }
  grep -q "manylinux_2_17_$arch" "$work/auditwheel-$arch.txt" || { cat "$work/auditwheel-$arch.txt"; echo "auditwheel: not manylinux_2_17_$arch"; return 1; }
  echo "auditwheel: $(tr '\n' ' ' < "$work/auditwheel-$arch.txt" | grep -o 'consistent with the following platform tag: "[^"]*"')"
  mkdir -p "$d" && (cd "$d" && "$LIVEGESTURE_PY" -m zipfile -e "$dist/$whl" unpacked)
  local so; so="$(ls "$d"/unpacked/livegesture_runtime/livegesture_runtime*.so)"
  local machine; machine="$(readelf -h "$so" | sed -n 's/^ *Machine: *//p')"
  case "$arch" in x86_64) [[ $machine == *X86-64* ]] ;; aarch64) [[ $machine == *AArch64* ]] ;; esac \
    || { echo "$whl: the module is built for $machine"; return 1; }
  readelf --dyn-syms -W "$so" | grep -q " PyInit_livegesture_runtime$" || { echo "$whl: no PyInit_livegesture_runtime"; return 1; }
  echo "$whl: module $(basename "$so"), $machine, needs $(readelf -d "$so" | sed -n 's/.*Shared library: \[\(.*\)\]/\1/p' | tr '\n' ' ')"
  "$LIVEGESTURE_PY" scripts/copy_bundle.py models/default "$d/bundle" >/dev/null
  if [ "$arch" = x86_64 ]; then
    /usr/bin/python3 -m venv "$d/venv"
    "$d/venv/bin/pip" install -q "$dist/$whl"
    py=("$d/venv/bin/python")
  else
    # Debian's arm64 CPython 3.11 under qemu-aarch64 (scripts/aarch64_python.sh); the wheel and numpy's aarch64
    # wheel from PyPI installed by pip for that platform into one folder, the emulated CPython's only import path
    local emu; emu="$(scripts/aarch64_python.sh)" || return 1
    "$LIVEGESTURE_VENV/bin/pip" install -q --no-compile --platform manylinux2014_aarch64 --only-binary=:all: \
      --python-version 3.11 --implementation cp --target "$d/site" "$dist/$whl"
    py=(env PYTHONPATH="$d/site" PYTHONNOUSERSITE=1 $emu)
  fi
  (cd "$work" && env -u PYTHONHOME "${py[@]}" - "$d/bundle" speech.wav "$d/out.npz" "$d" <<'PY'
import sys
import numpy as np
import livegesture_runtime as lgr
# the module of the wheel (the fresh venv, or the folder it was unpacked into), not another install
assert lgr.__file__.startswith(sys.argv[4]), f"livegesture_runtime imported from {lgr.__file__}"
model = lgr.Model(sys.argv[1], backend="tract")
out = model.generate(sys.argv[2], seed=3)
np.savez(sys.argv[3], **out)
print(f"{model} from {lgr.__file__}")
PY
  ) || { echo "$whl: generate from Python failed"; return 1; }
  echo -n "wheel $arch: "; check_output "$d/out.npz" "$([ "$arch" = x86_64 ] && echo 1 || echo 0)"
}

for triple in "$@"; do
  case "$triple" in
    c-sdk|c-sdk-x86_64) echo "=== prove c-sdk"; prove_c_sdk x86_64-unknown-linux-gnu || failed+=("c-sdk"); continue ;;
    c-sdk-aarch64) echo "=== prove c-sdk-aarch64"; prove_c_sdk aarch64-unknown-linux-gnu || failed+=("c-sdk-aarch64"); continue ;;
    web) echo "=== prove web"; prove_web || failed+=("web"); continue ;;
    wheel-x86_64|wheel-aarch64) echo "=== prove $triple"; prove_wheel "${triple#wheel-}" || failed+=("$triple"); continue ;;
  esac
  name="livegesture-$VERSION-$triple"
  archive=""
  for a in "$name.tar.gz" "$name.zip"; do [ -f "$dist/$a" ] && archive="$a"; done
  echo "=== prove $triple"
  if [ -z "$archive" ]; then failed+=("$triple (no archive in target/dist)"); continue; fi
  checksum "$archive" || { failed+=("$triple (checksum)"); continue; }
  d="$work/$triple"; mkdir -p "$d"
  case "$archive" in
    *.zip) (cd "$d" && "$LIVEGESTURE_PY" -m zipfile -e "$dist/$archive" .) ;;
    *) tar -C "$d" -xzf "$dist/$archive" ;;
  esac
  exe="$d/$name/bin/livegesture"; runner="$(scripts/cross.sh --runner "$triple")"
  if [[ $triple == *windows* ]]; then
    exe="$exe.exe"; export WINEDEBUG=-all
    if [ ! -f "$WINEPREFIX/system.reg" ]; then   # wine's first start on this machine, measured
      ws=$SECONDS; wineboot -i >/dev/null 2>&1; wineserver -w
      echo "wine: prefix $WINEPREFIX created (wineboot) in $(( SECONDS - ws )) s"
    fi
    # Debian 12's wine (8.0) lacks bcryptprimitives.dll, whose ProcessPrng Rust's standard library (1.78+)
    # imports and Windows 10+ ships: the prefix (not the archive) gets a small one that forwards to
    # RtlGenRandom (scripts/wine/bcryptprimitives.c); without it the exe does not start under this wine
    sys32="$WINEPREFIX/drive_c/windows/system32"
    if [ ! -f "$sys32/bcryptprimitives.dll" ]; then
      x86_64-w64-mingw32-gcc -O2 -shared -Wl,--kill-at -o "$sys32/bcryptprimitives.dll" \
        scripts/wine/bcryptprimitives.c -ladvapi32
      echo "wine: $sys32/bcryptprimitives.dll (ProcessPrng) built from scripts/wine/bcryptprimitives.c"
    fi
  fi
  [ -s "$d/$name/LICENSES/livegesture-LICENSE" ] && [ -s "$d/$name/LICENSES/crates.txt" ] \
    && [ -s "$d/$name/LICENSES/real-speech-SOURCES.md" ] \
    || { failed+=("$triple (LICENSES/livegesture-LICENSE, crates.txt or real-speech-SOURCES.md missing)"); continue; }
  # static: the musl builds (armv7 is a dynamic glibc build: scripts/cross.sh says why)
  if [[ $triple == *musl* ]]; then
    file "$exe" | grep -qE "statically linked|static-pie linked" || { file "$exe"; failed+=("$triple (not static)"); continue; }
    l="$(ldd "$exe" 2>&1 || true)"
    [[ $l == *"not a dynamic executable"* || $l == *"statically linked"* ]] || { echo "$l"; failed+=("$triple (ldd: dynamic)"); continue; }
    echo "static: $(file -b "$exe" | cut -d, -f1-5); ldd: $l"
  fi
  # from the extracted folder only: no repository, no project environment, the bundle next to the exe
  clean=(env -i PATH=/usr/bin:/bin HOME="$work" WINEDEBUG=-all WINEPREFIX="$WINEPREFIX")
  v="$(cd "$work" && "${clean[@]}" $runner "$exe" --version 2>&1 | tr -d '\r')"
  echo "$v"
  [[ $v == *"$triple"* && $v == *"commit "* ]] || { failed+=("$triple (--version: $v)"); continue; }
  start=$SECONDS
  if ! (cd "$work" && "${clean[@]}" $runner "$exe" generate speech.wav -o "$triple.npz" --backend tract --seed 3); then
    failed+=("$triple (generate failed)"); continue
  fi
  echo "generate: $(( SECONDS - start )) s ($([ -n "$runner" ] && echo "under $runner" || echo native))"
  # x86-64 Linux (musl, gnu): the same code and kernels as the native build, so the same bytes: the whole .npz
  # (its members carry a fixed timestamp) must equal the native one. Windows: its C runtime's libm is not
  # glibc's, so bit-identity is reported, not required: frames within 1e-4 (scaled), which a different motion
  # token (another codebook entry, O(1) apart) cannot meet. Other instruction sets: within 1e-4 likewise.
  exact=0
  if [[ $triple == x86_64-unknown-linux-* ]]; then
    exact=1
    cmp "$work/$triple.npz" "$work/native.npz" || { failed+=("$triple (.npz differs from the native build's)"); continue; }
    echo "cmp: $triple.npz is byte-identical to the native x86-64 gnu build's tract output"
  fi
  check_output "$work/$triple.npz" "$exact" || { failed+=("$triple (output)"); continue; }
  # the glibc archives carry ONNX Runtime in lib/: `--backend ort` finds it next to the executable (no
  # ORT_DYLIB_PATH, no --ort-lib) and gives the same motion tokens as native tract (within 1e-4, scaled)
  if [[ $triple == *-linux-gnu ]]; then
    ls "$d/$name"/lib/libonnxruntime.so.* >/dev/null 2>&1 && [ -s "$d/$name/LICENSES/onnxruntime-LICENSE" ] \
      || { failed+=("$triple (lib/libonnxruntime.so.* or LICENSES/onnxruntime-LICENSE missing)"); continue; }
    start=$SECONDS
    if ! (cd "$work" && "${clean[@]}" $runner "$exe" generate speech.wav -o "$triple-ort.npz" --backend ort --seed 3); then
      failed+=("$triple (generate --backend ort failed)"); continue
    fi
    echo -n "ort ($(basename "$(ls "$d/$name"/lib/libonnxruntime.so.*)") from lib/, $(( SECONDS - start )) s): "
    check_output "$work/$triple-ort.npz" 0 || { failed+=("$triple (ort output)"); continue; }
  fi
done
if [ ${#failed[@]} -gt 0 ]; then echo "prove_release.sh: FAILED: ${failed[*]}" >&2; exit 1; fi
echo "prove_release.sh: every archive proven: $*"

#!/usr/bin/env bash
# The downloadable release (docs/install.md): writes target/dist/
#
#   scripts/release.sh [--prove] [TARGET...]
#
# TARGET: a Rust triple that scripts/cross.sh builds (x86_64-unknown-linux-musl, aarch64-unknown-linux-musl,
# armv7-unknown-linux-gnueabihf, x86_64-unknown-linux-gnu, aarch64-unknown-linux-gnu, x86_64-pc-windows-gnu),
# `c-sdk` / `c-sdk-aarch64` (the C SDK for x86-64 / aarch64 Linux, glibc), `web` (the static web build,
# scripts/build_web_static.sh),
# `wheel-x86_64` / `wheel-aarch64` (the Python module as a manylinux2014 abi3 wheel, CPython >= 3.10: maturin
# --zig, checked by auditwheel), or none: all.
# For each CLI target: livegesture-VERSION-TARGET.tar.gz (.zip for Windows) holding
#   bin/livegesture[.exe]                     the CLI (profile dist: no debug info, stripped)
#   share/livegesture/models/{default,diffsheg}  the shipped bundles (default found next to the executable)
#   lib/libonnxruntime.so.*                   (gnu targets) ONNX Runtime from PyPI's wheel, found next to the exe
#   README.md                                 the quick start
#   LICENSES/                                 every linked crate's licence text (cargo metadata of that build),
#                                             the project's (LICENSE: Apache-2.0), ONNX Runtime's, the bundles' and data's
# and SHA256SUMS over every archive. --prove then proves each archive from the archive alone
# (scripts/prove_release.sh): extracted in an empty folder outside the repository, `generate` on a WAV natively,
# under qemu-user or wine, ceil(duration x 30) valid frames, equal to the native x86-64 build.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh >/dev/null

ALL="x86_64-unknown-linux-musl aarch64-unknown-linux-musl armv7-unknown-linux-gnueabihf x86_64-unknown-linux-gnu aarch64-unknown-linux-gnu x86_64-pc-windows-gnu c-sdk c-sdk-aarch64 web wheel-x86_64 wheel-aarch64"
prove=0
targets=()
for a in "$@"; do
  case "$a" in
    --prove) prove=1 ;;
    -h|--help) sed -n '2,21p' "$0"; exit 0 ;;
    -*) echo "release.sh: unknown option $a" >&2; exit 2 ;;
    *) targets+=("$a") ;;
  esac
done
[ ${#targets[@]} -gt 0 ] || targets=($ALL)
VERSION="$(sed -n 's/^version = "\(.*\)"/\1/p' runtime/Cargo.toml | head -n1)"
COMMIT="$(git rev-parse --short=12 HEAD)"
dist="$PWD/target/dist"
mkdir -p "$dist"
t0=$SECONDS

# every crate linked into one build, with its licence texts (from cargo's registry sources), as one file
licences() {  # TRIPLE FEATURES PACKAGE OUT
  "$LIVEGESTURE_PY" scripts/licences.py "$3" "$1" "$2" "$4"
}

# The workspace's release build, exactly as scripts/test.sh's stage "rust build (release)" runs it (same command,
# same PyO3 configuration): the x86-64 glibc archive and the x86-64 C SDK take their binary and libraries from it
# (target/release), so after the test command's build they compile nothing (a narrower `cargo build -p` would
# resolve the dependencies' features differently and compile tract and the core again: 14 min measured)
workspace_build() {
  PYO3_CONFIG_FILE="$PWD/bindings/python/pyo3-config.txt" nice -n "${CROSS_NICE:-0}" \
    cargo build --release --workspace --all-targets >&2
}

ort_lib_for() {  # TRIPLE -> path of libonnxruntime for it (gnu targets)
  case "$1" in
    x86_64-unknown-linux-gnu) echo "$ORT_DYLIB_PATH" ;;
    aarch64-unknown-linux-gnu) scripts/cross.sh --ort-lib aarch64-unknown-linux-gnu ;;
  esac
}

common_files() {  # STAGE_DIR
  local s="$1"
  mkdir -p "$s/share/livegesture/models" "$s/LICENSES"
  for b in default diffsheg; do
    scripts/copy_bundle.py "models/$b" "$s/share/livegesture/models/$b" >/dev/null
  done
  cp models/README.md "$s/share/livegesture/models/README.md"
  cp models/real-speech-SOURCES.md "$s/LICENSES/real-speech-SOURCES.md"
  cp LICENSE "$s/LICENSES/livegesture-LICENSE"
  cat > "$s/LICENSES/README.md" <<EOF
Licences of livegesture $VERSION (commit $COMMIT)

- livegesture itself: Apache-2.0 (livegesture-LICENSE, the repository's LICENSE).
- crates.txt: every Rust crate linked into this build, with the licence texts each crate ships
  (collected from \`cargo metadata\` of this exact build by scripts/release.sh).
- The bundles in share/livegesture/models: trained by this project on synthetic motion and speech; the
  training data and its licences are described in share/livegesture/models/README.md and each bundle's
  manifest.json (training_data); real-speech-SOURCES.md lists the real recordings used in
  training and their licences.
- onnxruntime-LICENSE (gnu archives only): ONNX Runtime (MIT), shipped in lib/.
EOF
}

quick_start() {  # STAGE_DIR EXE RUN
  cat > "$1/README.md" <<EOF
# livegesture $VERSION for $2

Streaming speech-to-gesture generation (SMPL-X motion at 30 fps) from a WAV file or live audio.
Built from commit $COMMIT. Docs: https://github.com/ (the project's docs/install.md).

Quick start (no Rust, no Python needed):

    $3 --version
    $3 generate speech.wav -o motion.npz          # BEAT2 .npz, ceil(duration x 30) frames
    $3 generate speech.wav -o motion.bvh          # or .bvh / .glb / .gltf
    $3 info                                       # the shipped bundle, found next to the executable
    $3 generate speech.wav -o face.npz --bundle share/livegesture/models/diffsheg   # the DiffSHEG model

The default bundle is share/livegesture/models/default, found relative to the executable (no --bundle needed).
Backends: tract (pure Rust, every build)$4.
Verify the download first: \`sha256sum -c SHA256SUMS --ignore-missing\`.
EOF
}

build_cli() {  # TRIPLE
  local triple="$1" bin exe name stage features run ort=""
  if [ "$triple" = x86_64-unknown-linux-gnu ]; then
    # the host build: the workspace's release build (default features: ort, parity, bench, serve, loadtest),
    # stripped below as the dist profile strips the cross builds
    workspace_build; bin="$PWD/target/release/livegesture"; features=""
  else
    bin="$(scripts/cross.sh "$triple")"
    features="$(scripts/cross.sh --features "$triple")"
  fi
  exe="$(basename "$bin")"
  name="livegesture-$VERSION-$triple"
  stage="$dist/stage/$name"
  rm -rf "$stage"; mkdir -p "$stage/bin"
  cp "$bin" "$stage/bin/$exe"
  [ "$triple" = x86_64-unknown-linux-gnu ] && strip "$stage/bin/$exe"
  common_files "$stage"
  licences "$triple" "$features" livegesture "$stage/LICENSES/crates.txt"
  run="bin/$exe"; [[ $triple == *windows* ]] && run='bin\livegesture.exe'
  if [[ $triple == *-linux-gnu ]]; then
    local lib; lib="$(ort_lib_for "$triple")"
    mkdir -p "$stage/lib"; cp "$lib" "$stage/lib/"
    # the wheel's package folder (onnxruntime/, above capi/) holds its LICENSE (MIT) and ThirdPartyNotices.txt
    local pkg; pkg="$(dirname "$(dirname "$lib")")"
    [ -s "$pkg/LICENSE" ] || { echo "release.sh: $name: no LICENSE of ONNX Runtime in $pkg" >&2; exit 1; }
    cp "$pkg/LICENSE" "$stage/LICENSES/onnxruntime-LICENSE"
    [ -s "$pkg/ThirdPartyNotices.txt" ] && cp "$pkg/ThirdPartyNotices.txt" "$stage/LICENSES/onnxruntime-ThirdPartyNotices.txt"
    ort=", and ort (ONNX Runtime $(basename "$lib" | sed 's/libonnxruntime.so.//'), in lib/, loaded at run time: --backend ort)"
  fi
  quick_start "$stage" "$triple" "$run" "$ort"
  rm -f "$dist/$name.tar.gz" "$dist/$name.zip"
  if [[ $triple == *windows* ]]; then
    (cd "$dist/stage" && zip -qr -X "$dist/$name.zip" "$name")
  else
    tar -C "$dist/stage" --owner=0 --group=0 --sort=name -czf "$dist/$name.tar.gz" "$name"
  fi
  echo "release.sh: $name: $(du -h "$dist/$name".* | cut -f1) (binary $(du -h "$bin" | cut -f1))" >&2
}

build_c_sdk() {  # TRIPLE: the C SDK for Linux (gnu): header, stripped shared and static library, pkg-config, CMake
  local triple="$1" name="livegesture-c-$VERSION-$1" stage libdir strip_tool
  stage="$dist/stage/$name"
  case "$triple" in
    # x86-64: the workspace's release build (target/release/liblivegesture_c.*, as the test command makes it): no
    # second compile of the whole dependency tree; its debug info is stripped below
    x86_64-unknown-linux-gnu) workspace_build; libdir="$PWD/target/release"; strip_tool=strip ;;
    # aarch64: scripts/cross.sh builds the C library in the same cargo build as that target's CLI (profile dist)
    aarch64-unknown-linux-gnu) scripts/cross.sh "$triple" >/dev/null; libdir="$(scripts/cross.sh --c-lib "$triple")"
      strip_tool=aarch64-linux-gnu-strip ;;
    *) echo "release.sh: no C SDK for $triple" >&2; exit 2 ;;
  esac
  rm -rf "$stage"; mkdir -p "$stage/include" "$stage/lib/pkgconfig" "$stage/lib/cmake/livegesture" "$stage/share/livegesture/examples" "$stage/LICENSES"
  cp bindings/c/include/*.h "$stage/include/"
  cp "$libdir/liblivegesture_c.so" "$libdir/liblivegesture_c.a" "$stage/lib/"
  "$strip_tool" --strip-unneeded "$stage/lib/liblivegesture_c.so"
  "$strip_tool" --strip-debug "$stage/lib/liblivegesture_c.a"
  cp examples/c/generate.c "$stage/share/livegesture/examples/"
  cat > "$stage/README.md" <<EOF_README
# livegesture C SDK $VERSION for $triple (commit $COMMIT)

include/livegesture.h, lib/liblivegesture_c.so (shared) and lib/liblivegesture_c.a (static); backends tract
and ort (ONNX Runtime loaded at run time: the path the API is given, ORT_DYLIB_PATH, or the system's). The
bundles (models/default, models/diffsheg) are in the CLI archives (share/livegesture/models) or the repository.

    # pkg-config: shared (livegesture) or static (livegesture-static)
    export PKG_CONFIG_PATH=\$PWD/lib/pkgconfig
    cc share/livegesture/examples/generate.c \$(pkg-config --cflags --libs livegesture) -Wl,-rpath,\$PWD/lib -o generate
    cc share/livegesture/examples/generate.c \$(pkg-config --cflags --libs livegesture-static) -o generate-static
    ./generate-static BUNDLE speech.wav 7 tract > poses.f32    # float32 little-endian, frames x 165

    # CMake: find_package(livegesture) with CMAKE_PREFIX_PATH=<this folder>;
    # imported targets livegesture::livegesture (shared) and livegesture::static
EOF_README
  cat > "$stage/lib/pkgconfig/livegesture.pc" <<EOF
prefix=\${pcfiledir}/../..
libdir=\${prefix}/lib
includedir=\${prefix}/include
Name: livegesture
Description: Streaming speech-to-gesture runtime (C API)
Version: $VERSION
Libs: -L\${libdir} -llivegesture_c
Libs.private: -lgcc_s -lutil -lrt -lpthread -lm -ldl -lc
Cflags: -I\${includedir}
EOF
  cat > "$stage/lib/cmake/livegesture/livegestureConfig.cmake" <<'EOF'
# find_package(livegesture): imported targets livegesture::livegesture (shared) and livegesture::static
get_filename_component(_lg_prefix "${CMAKE_CURRENT_LIST_DIR}/../../.." ABSOLUTE)
add_library(livegesture::livegesture SHARED IMPORTED)
set_target_properties(livegesture::livegesture PROPERTIES
  IMPORTED_LOCATION "${_lg_prefix}/lib/liblivegesture_c.so"
  INTERFACE_INCLUDE_DIRECTORIES "${_lg_prefix}/include")
add_library(livegesture::static STATIC IMPORTED)
set_target_properties(livegesture::static PROPERTIES
  IMPORTED_LOCATION "${_lg_prefix}/lib/liblivegesture_c.a"
  INTERFACE_INCLUDE_DIRECTORIES "${_lg_prefix}/include"
  INTERFACE_LINK_LIBRARIES "gcc_s;util;rt;pthread;m;dl;c"
  INTERFACE_LINK_OPTIONS "-Wl,-z,noexecstack")
set(livegesture_FOUND TRUE)
EOF
  cat > "$stage/lib/pkgconfig/livegesture-static.pc" <<EOF
prefix=\${pcfiledir}/../..
libdir=\${prefix}/lib
includedir=\${prefix}/include
Name: livegesture-static
Description: Streaming speech-to-gesture runtime (C API), linked statically
Version: $VERSION
Libs: \${libdir}/liblivegesture_c.a -lgcc_s -lutil -lrt -lpthread -lm -ldl -lc -Wl,-z,noexecstack
Cflags: -I\${includedir}
EOF
  echo "set(PACKAGE_VERSION \"$VERSION\")" > "$stage/lib/cmake/livegesture/livegestureConfigVersion.cmake"
  licences "$triple" "" livegesture-c "$stage/LICENSES/crates.txt"
  cp LICENSE "$stage/LICENSES/livegesture-LICENSE"
  rm -f "$dist/$name.tar.gz"
  tar -C "$dist/stage" --owner=0 --group=0 --sort=name -czf "$dist/$name.tar.gz" "$name"
  echo "release.sh: $name: static library $(du -h "$stage/lib/liblivegesture_c.a" | cut -f1), shared $(du -h "$stage/lib/liblivegesture_c.so" | cut -f1)" >&2
}

build_web() {  # the static web build (page, wasm, bundles) as one archive
  [ -f target/web-static/index.html ] || scripts/build_web_static.sh models/default >&2
  local name="livegesture-web-$VERSION"
  rm -rf "$dist/stage/$name"; mkdir -p "$dist/stage"
  cp -r target/web-static "$dist/stage/$name"
  rm -rf "$dist/stage/$name/bundles/broken"   # the test command's negative case, not a release file
  local lic="$dist/stage/$name/LICENSES" p f
  mkdir -p "$lic"
  cp LICENSE "$lic/livegesture-LICENSE"
  cp models/real-speech-SOURCES.md "$lic/real-speech-SOURCES.md"
  # the Rust crates in the wasm (bindings/wasm is a workspace of its own) and the npm packages in the page
  (cd bindings/wasm && "$LIVEGESTURE_PY" ../../scripts/licences.py livegesture-wasm wasm32-unknown-unknown "" "$lic/crates.txt")
  for p in three @pixiv/three-vrm onnxruntime-web; do
    f="$(ls runtime/web/node_modules/$p/LICENSE* 2>/dev/null | head -n1 || true)"
    # onnxruntime-web's npm package carries no LICENSE file (package.json: "MIT"); it is built from the same
    # repository (microsoft/onnxruntime) as PyPI's onnxruntime, whose package folder holds that MIT licence text
    if [ -z "$f" ] && [ "$p" = onnxruntime-web ]; then
      f="$("$LIVEGESTURE_PY" -c 'import onnxruntime, os; print(os.path.join(os.path.dirname(onnxruntime.__file__), "LICENSE"))')"
      [ -s "$f" ] || f=""
    fi
    [ -n "$f" ] || { echo "release.sh: web: no licence file for the npm package $p (cd runtime/web && npm install)" >&2; exit 1; }
    cp "$f" "$lic/npm-${p//\//-}-LICENSE"
  done
  rm -f "$dist/$name.tar.gz"
  tar -C "$dist/stage" --owner=0 --group=0 --sort=name -czf "$dist/$name.tar.gz" "$name"
  echo "release.sh: $name: $(du -h "$dist/$name.tar.gz" | cut -f1)" >&2
}

build_wheel() {  # ARCH: the Python module as a manylinux2014 abi3 wheel (CPython >= 3.10) for ARCH-unknown-linux-gnu
  local arch="$1" triple="$1-unknown-linux-gnu" out="$dist/stage/wheel-$1" whl
  # zig (PyPI's ziglang) links against glibc 2.17's symbols, so the wheel runs on any manylinux2014 system;
  # auditwheel (PyPI) reads the .so's symbol versions and names the tag
  "$LIVEGESTURE_PY" -c 'import ziglang' 2>/dev/null || "$LIVEGESTURE_VENV/bin/pip" install -q ziglang==0.17.1
  "$LIVEGESTURE_VENV/bin/auditwheel" --version >/dev/null 2>&1 || "$LIVEGESTURE_VENV/bin/pip" install -q auditwheel==6.8.2
  "$LIVEGESTURE_VENV/bin/maturin" --version 2>/dev/null | grep -qx "maturin 1.16.0" || \
    "$LIVEGESTURE_VENV/bin/pip" install -q maturin==1.16.0
  rustup target list --installed | grep -qx "$triple" || rustup target add "$triple" >&2
  rm -rf "$out"; mkdir -p "$out"
  # the venv first on PATH: maturin finds its python-zig; no PYO3_CONFIG_FILE: abi3-py310 needs no interpreter
  env -u PYO3_CONFIG_FILE PATH="$LIVEGESTURE_VENV/bin:$PATH" nice -n "${CROSS_NICE:-0}" \
    "$LIVEGESTURE_VENV/bin/maturin" build --release --zig --target "$triple" --compatibility manylinux2014 \
    --manifest-path bindings/python/Cargo.toml --out "$out" >&2
  whl="$(ls "$out"/livegesture_runtime-*-cp310-abi3-manylinux*_"$arch".whl)"
  "$LIVEGESTURE_VENV/bin/auditwheel" show "$whl" | tee "$out/auditwheel.txt" >&2
  grep -q "manylinux_2_17_$arch" "$out/auditwheel.txt" || {
    echo "release.sh: auditwheel does not name manylinux_2_17_$arch for $whl" >&2; exit 1; }
  rm -f "$dist"/livegesture_runtime-*_"$arch".whl
  cp "$whl" "$dist/"
  echo "release.sh: $(basename "$whl"): $(du -h "$whl" | cut -f1)" >&2
}

for t in "${targets[@]}"; do
  case "$t" in
    c-sdk|c-sdk-x86_64) build_c_sdk x86_64-unknown-linux-gnu ;;
    c-sdk-aarch64) build_c_sdk aarch64-unknown-linux-gnu ;;
    web) build_web ;;
    wheel-x86_64) build_wheel x86_64 ;;
    wheel-aarch64) build_wheel aarch64 ;;
    *) build_cli "$t" ;;
  esac
done
(cd "$dist" && shopt -s nullglob && sha256sum livegesture-*.tar.gz livegesture-*.zip livegesture_runtime-*.whl > SHA256SUMS)
rm -rf "$dist/stage"
echo "release.sh: target/dist/ written in $(( SECONDS - t0 )) s:"
cat "$dist/SHA256SUMS"
if [ $prove = 1 ]; then
  scripts/prove_release.sh "${targets[@]}"
fi

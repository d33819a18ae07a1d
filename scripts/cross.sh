#!/usr/bin/env bash
# Cross-builds the `livegesture` CLI for one target (docs/targets.md, docs/install.md):
#
#   scripts/cross.sh TARGET            builds it (once: cargo skips an up-to-date build) and prints its path;
#                                      with CROSS_NO_BUILD=1 only prints the path of the binary already built
#                                      (no cargo: it would wait on the lock another target's build holds)
#   scripts/cross.sh --path TARGET     prints the path it is (or would be) built at, builds nothing
#   scripts/cross.sh --features TARGET prints the cargo features the CLI is built with for TARGET
#   scripts/cross.sh --runner TARGET   prints the command prefix that runs it on this x86-64 machine
#                                      (empty: native; qemu-aarch64 ...; wine)
#   scripts/cross.sh --c-lib TARGET    (aarch64 gnu) prints the folder of the C library built with the CLI
#   scripts/cross.sh --install TARGET  installs what TARGET needs (below) and builds nothing: scripts/test.sh does
#                                      this for its targets before it starts their builds in the background, so
#                                      no apt-get or rustup runs beside the other stages' own
#   scripts/cross.sh --ort-lib TARGET  (aarch64 gnu) fetches ONNX Runtime's library for TARGET from PyPI's
#                                      wheel of the venv's onnxruntime version (cached) and prints its path
#
# Installs what the target needs, idempotently: the rustup target, Debian's cross compiler / musl-tools /
# mingw-w64, qemu-user or wine. Every target builds in the `dist` profile (Cargo.toml: release without debug
# info, stripped) into target/TRIPLE/dist/. One function per target below; add a target by adding one.
#
# TARGET is a Rust triple or an alias: aarch64 (aarch64-unknown-linux-gnu), armv7 (armv7-unknown-linux-gnueabihf),
# x86_64-musl, aarch64-musl, windows (x86_64-pc-windows-gnu), x86_64 (the host, x86_64-unknown-linux-gnu).
set -euo pipefail
cd "$(dirname "$0")/.."

# Features of the CLI per build. The gnu builds: ONNX Runtime (loaded at run time), parity, serve. The static
# (musl) and Windows builds: tract only, the CLI and parity (no `serve`: its TLS library `ring` needs a C cross
# compiler for musl that Debian does not ship for aarch64/armv7; no `ort`: a static binary cannot dlopen).
FEATURES_FULL="cli,parity,ort,serve"
FEATURES_STATIC="cli,parity"

# --- one function per target: sets TRIPLE, APT (Debian packages), FEATURES, RUNNER, and cargo's env ---------
t_x86_64_unknown_linux_gnu() {
  TRIPLE=x86_64-unknown-linux-gnu; APT=""; FEATURES=$FEATURES_FULL; RUNNER=""
}
t_x86_64_unknown_linux_musl() {
  TRIPLE=x86_64-unknown-linux-musl; APT="musl-tools"; FEATURES=$FEATURES_STATIC; RUNNER=""
  export CC_x86_64_unknown_linux_musl=musl-gcc
}
t_aarch64_unknown_linux_gnu() {
  TRIPLE=aarch64-unknown-linux-gnu; APT="gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user"
  # qemu-aarch64 with an aarch64 /proc/cpuinfo: ONNX Runtime's aarch64 library segfaults while loading under plain
  # qemu-user on an x86-64 host (scripts/qemu_aarch64_cpuinfo.sh says why)
  FEATURES=$FEATURES_FULL; RUNNER="$PWD/scripts/qemu_aarch64_cpuinfo.sh -L /usr/aarch64-linux-gnu"
  # the C library (the C SDK, scripts/release.sh c-sdk-aarch64) in the same cargo build: one feature resolution,
  # so the dependencies compile once for both
  WITH_C=1
  export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
  export CC_aarch64_unknown_linux_gnu=aarch64-linux-gnu-gcc
}
t_aarch64_unknown_linux_musl() {
  # Debian has no aarch64 musl compiler: the gnu cross gcc compiles tract's assembly and links with the
  # musl C library and start files that rustup ships with the target (link-self-contained)
  TRIPLE=aarch64-unknown-linux-musl; APT="gcc-aarch64-linux-gnu qemu-user"
  FEATURES=$FEATURES_STATIC; RUNNER="qemu-aarch64"
  export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_MUSL_LINKER=aarch64-linux-gnu-gcc
  export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_MUSL_RUSTFLAGS="-C link-self-contained=yes -C target-feature=+crt-static"
  export CC_aarch64_unknown_linux_musl=aarch64-linux-gnu-gcc
}
t_armv7_unknown_linux_gnueabihf() {
  # gnueabihf, not musleabihf: rustup's rust-std for armv7-unknown-linux-musleabihf (and armv7-musleabi,
  # arm-musleabihf) is not downloadable for this toolchain (HTTP 404, measured 2026-11-27 and 2026-11-28); Debian
  # ships the gnueabihf cross compiler. Dynamically linked against glibc (armhf glibc 2.36 or newer: Raspberry Pi
  # OS 12): linked statically (`-C target-feature=+crt-static`, 2026-11-28) the binary crashed before its first
  # system call under qemu-arm 7.2 (SIGSEGV at address 0x53, even for `--version`), so that build is not shipped.
  TRIPLE=armv7-unknown-linux-gnueabihf; APT="gcc-arm-linux-gnueabihf libc6-dev-armhf-cross qemu-user"
  FEATURES=$FEATURES_STATIC; RUNNER="qemu-arm -L /usr/arm-linux-gnueabihf"
  export CARGO_TARGET_ARMV7_UNKNOWN_LINUX_GNUEABIHF_LINKER=arm-linux-gnueabihf-gcc
  export CC_armv7_unknown_linux_gnueabihf=arm-linux-gnueabihf-gcc
}
t_x86_64_pc_windows_gnu() {
  TRIPLE=x86_64-pc-windows-gnu; APT="gcc-mingw-w64-x86-64 wine wine64"; FEATURES=$FEATURES_STATIC; RUNNER="wine"
  export CARGO_TARGET_X86_64_PC_WINDOWS_GNU_LINKER=x86_64-w64-mingw32-gcc
  export CC_x86_64_pc_windows_gnu=x86_64-w64-mingw32-gcc
}

resolve() {
  WITH_C=0
  case "$1" in
    x86_64|x86-64|native) t_x86_64_unknown_linux_gnu ;;
    aarch64) t_aarch64_unknown_linux_gnu ;;
    armv7) t_armv7_unknown_linux_gnueabihf ;;
    x86_64-musl) t_x86_64_unknown_linux_musl ;;
    aarch64-musl) t_aarch64_unknown_linux_musl ;;
    windows) t_x86_64_pc_windows_gnu ;;
    *)
      local f="t_${1//-/_}"
      if ! declare -F "$f" >/dev/null; then
        echo "cross.sh: unknown target '$1'; expected one of: $(declare -F | awk '{print $3}' | grep '^t_' \
          | sed 's/^t_//; s/_/-/g' | tr '\n' ' ')(or an alias: x86_64 aarch64 armv7 x86_64-musl aarch64-musl windows)" >&2
        exit 2
      fi
      "$f" ;;
  esac
  EXE=livegesture; [[ $TRIPLE == *windows* ]] && EXE=livegesture.exe
  OUT="$PWD/target/$TRIPLE/dist/$EXE"
}

install_deps() {
  local missing=()
  for p in $APT; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
  if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" = 0 ]; then _sudo=""; else _sudo="sudo"; fi
    echo "cross.sh: installing ${missing[*]}" >&2
    for try in 1 2 3 4 5 6; do   # dpkg may be locked by another apt-get for a while
      if DEBIAN_FRONTEND=noninteractive $_sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null; then
        break
      fi
      [ $try = 6 ] && { echo "cross.sh: apt-get install ${missing[*]} failed" >&2; exit 1; }
      sleep 20
      $_sudo apt-get update -qq || true
    done
  fi
  if [ "$TRIPLE" != x86_64-unknown-linux-gnu ] && ! rustup target list --installed | grep -qx "$TRIPLE"; then
    rustup target add "$TRIPLE" >&2
  fi
}

# ONNX Runtime for aarch64 Linux: PyPI's wheel of the venv's onnxruntime version (manylinux, glibc), cached
ort_lib() {
  [ "$TRIPLE" = aarch64-unknown-linux-gnu ] || { echo "cross.sh: --ort-lib: only for aarch64-unknown-linux-gnu" >&2; exit 2; }
  source scripts/env.sh >/dev/null
  local v dir
  v="$("$LIVEGESTURE_PY" -c 'import onnxruntime; print(onnxruntime.__version__)')"
  dir="$(dirname "$LIVEGESTURE_VENV")/onnxruntime-$v-aarch64"
  if [ ! -f "$dir/.complete" ]; then
    rm -rf "$dir"; mkdir -p "$dir/wheel"
    "$LIVEGESTURE_VENV/bin/pip" download -q --no-deps --only-binary=:all: --python-version 3.11 \
      --platform manylinux2014_aarch64 --platform manylinux_2_27_aarch64 --platform manylinux_2_28_aarch64 \
      -d "$dir/wheel" "onnxruntime==$v" >&2
    (cd "$dir" && "$LIVEGESTURE_PY" -m zipfile -e wheel/*.whl unpacked)
    touch "$dir/.complete"
  fi
  ls "$dir"/unpacked/onnxruntime/capi/libonnxruntime.so.1* | head -n1
}

mode=build
case "${1:-}" in
  --path|--runner|--install|--ort-lib|--features|--c-lib) mode="${1#--}"; shift ;;
  -h|--help|"") sed -n '2,20p' "$0"; [ -n "${1:-}" ]; exit $? ;;
esac
[ $# -eq 1 ] || { echo "cross.sh: expected one TARGET, got $#" >&2; exit 2; }
resolve "$1"
case $mode in
  path) echo "$OUT"; exit 0 ;;
  runner) echo "$RUNNER"; exit 0 ;;
  features) echo "$FEATURES"; exit 0 ;;
  c-lib) [ "$WITH_C" = 1 ] || { echo "cross.sh: --c-lib: the C library is built only for aarch64-unknown-linux-gnu" >&2; exit 2; }
    echo "$(dirname "$OUT")"; exit 0 ;;
  install) install_deps; exit 0 ;;
  ort-lib) install_deps; ort_lib; exit 0 ;;
esac
if [ "${CROSS_NO_BUILD:-0}" = 1 ]; then
  [ -x "$OUT" ] || { echo "cross.sh: CROSS_NO_BUILD=1 and $OUT is missing (build it: scripts/cross.sh $1)" >&2; exit 1; }
  echo "$OUT"; exit 0
fi
install_deps
t=$SECONDS
echo "cross.sh: building $EXE for $TRIPLE (profile dist, features $FEATURES)" >&2
clib=(); feats="$FEATURES"
if [ "$WITH_C" = 1 ]; then clib=(-p livegesture-c --lib); feats="$(echo "$FEATURES" | sed 's/\([^,]*\)/livegesture\/\1/g')"; fi
nice -n "${CROSS_NICE:-0}" cargo build --profile dist --target "$TRIPLE" -p livegesture --bin livegesture "${clib[@]}" \
  --no-default-features --features "$feats" >&2
[ -x "$OUT" ] || { echo "cross.sh: cargo finished but $OUT is missing" >&2; exit 1; }
echo "cross.sh: $TRIPLE built in $(( SECONDS - t )) s: $(du -h "$OUT" | cut -f1)" >&2
echo "$OUT"

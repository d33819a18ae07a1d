#!/usr/bin/env bash
# An emulated aarch64 CPython 3.11 on this x86-64 machine, to run the aarch64 wheel (scripts/prove_release.sh,
# docs/install.md): Debian 12's own arm64 packages of python3.11 and the libraries it loads, fetched with apt-get
# into a private apt state (the system's dpkg architectures and lists are left alone) and unpacked into a
# sysroot in the cache folder, run under qemu-user (`qemu-aarch64 -L SYSROOT`). About 11 MB, a few seconds, once.
#
#   scripts/aarch64_python.sh      prints the command that runs it: qemu-aarch64 -L SYSROOT SYSROOT/usr/bin/python3.11
set -euo pipefail
root="${LIVEGESTURE_CACHE:-$HOME/.cache/livegesture}/aarch64-python"
pkgs="python3.11-minimal libpython3.11-minimal libpython3.11-stdlib libc6 libexpat1 zlib1g libffi8 libssl3
  libbz2-1.0 liblzma5 libcrypt1 libgcc-s1 libstdc++6 libuuid1 libtinfo6 libncursesw6 libreadline8 libsqlite3-0"
if [ ! -f "$root/.complete" ]; then
  command -v qemu-aarch64 >/dev/null || DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends qemu-user >/dev/null
  rm -rf "$root"
  mkdir -p "$root/apt/lists/partial" "$root/apt/cache/archives/partial" "$root/debs" "$root/sysroot"
  touch "$root/apt/status"
  apt=(-q -o APT::Architecture=arm64 -o APT::Architectures::=arm64 -o Dir::State::Lists="$root/apt/lists"
       -o Dir::Cache="$root/apt/cache" -o Dir::State::status="$root/apt/status" -o Debug::NoLocking=1
       -o APT::Sandbox::User=root)
  apt-get "${apt[@]}" update >&2
  # shellcheck disable=SC2086
  (cd "$root/debs" && apt-get "${apt[@]}" download $pkgs >&2)
  for f in "$root"/debs/*.deb; do dpkg-deb -x "$f" "$root/sysroot"; done
  rm -rf "$root/apt"
  out="$(qemu-aarch64 -L "$root/sysroot" "$root/sysroot/usr/bin/python3.11" -c 'import platform; print(platform.machine())')"
  [ "$out" = aarch64 ] || { echo "aarch64_python.sh: the emulated CPython says '$out', not aarch64" >&2; exit 1; }
  touch "$root/.complete"
fi
echo "qemu-aarch64 -L $root/sysroot $root/sysroot/usr/bin/python3.11"

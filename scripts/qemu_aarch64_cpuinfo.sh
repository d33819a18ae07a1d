#!/usr/bin/env bash
# qemu-aarch64 with an aarch64 /proc/cpuinfo (docs/targets.md, "aarch64 with ONNX Runtime under qemu-user"):
#
#   scripts/qemu_aarch64_cpuinfo.sh [QEMU OPTIONS] PROGRAM [ARGS...]     (the arguments of qemu-aarch64)
#
# Why: Debian 12's qemu-user (7.2) passes a guest's reads of /proc/cpuinfo through to the host's, which on this
# x86-64 machine lists no ARM processor. ONNX Runtime's aarch64 library (PyPI's wheel) initialises pytorch's
# `cpuinfo` when it is loaded, and `cpuinfo` then dereferences a null processor list: dlopen segfaults
# (measured 2026-11-27 with onnxruntime 1.31.1: SIGSEGV at address 0 right after it reads
# /sys/devices/system/cpu/*/cache). tract does not crash without it, but reads fp16 (`asimdhp`) and the core
# (`CPU part`) from /proc/cpuinfo, and dotprod and SVE from the auxiliary vector.
# This wrapper runs qemu-aarch64 in a private mount namespace (unshare -m; as non-root, a user namespace too) in
# which /proc/cpuinfo is an aarch64 one (ARM Neoverse N1 cores, one per host CPU; Cortex-A72 cores with
# `-cpu cortex-a72`), so nothing outside it changes.
# The instruction set itself still comes from qemu's CPU model (-cpu): ONNX Runtime's MLAS takes its features from
# the auxiliary vector (AT_HWCAP), which qemu fills for the emulated CPU; the text here gives `cpuinfo` a processor
# list and a microarchitecture, and must agree with the model (below), since tract believes its fp16 flag.
set -euo pipefail
if [ -z "${LIVEGESTURE_QEMU_NS:-}" ]; then
  ns=(-m); [ "$(id -u)" = 0 ] || ns=(-r -m)
  LIVEGESTURE_QEMU_NS=1 exec unshare "${ns[@]}" "$0" "$@"
fi
# The text matches the CPU model: tract reads fp16 (`asimdhp`) and the core (`CPU part`) from it, so a Cortex-A72
# (`-cpu cortex-a72`: ARMv8.0, NEON only) must not be described as a Neoverse N1 (ARMv8.2, fp16, dotprod)
features="fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid asimdrdm lrcpc dcpop asimddp"
variant=0x3 part=0xd0c revision=1   # Neoverse N1: qemu's default `max` model has these features (and more)
prev=""
for a in "$@"; do
  if [ "$prev" = -cpu ] && [ "$a" = cortex-a72 ]; then
    features="fp asimd evtstrm crc32 cpuid"; variant=0x0 part=0xd08 revision=3
  fi
  prev="$a"
done
ci="$(mktemp)"
for ((i = 0; i < $(nproc); i++)); do
  printf 'processor\t: %d\nBogoMIPS\t: 50.00\nFeatures\t: %s\nCPU implementer\t: 0x41\nCPU architecture: 8\nCPU variant\t: %s\nCPU part\t: %s\nCPU revision\t: %s\n\n' \
    "$i" "$features" "$variant" "$part" "$revision"
done >"$ci"
mount --bind "$ci" /proc/cpuinfo
rm -f "$ci"   # the bind mount keeps the file's contents for this namespace
exec qemu-aarch64 "$@"

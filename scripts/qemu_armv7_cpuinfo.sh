#!/usr/bin/env bash
# qemu-arm with an armv7 /proc/cpuinfo (docs/targets.md, "armv7: VFP and NEON"):
#
#   scripts/qemu_armv7_cpuinfo.sh [QEMU OPTIONS] PROGRAM [ARGS...]     (the arguments of qemu-arm)
#
# Why: tract decides whether an armv7 CPU has NEON from /proc/cpuinfo (its `Features` line; tract-linalg's
# arm32::has_neon, there is no auxiliary-vector probe on 32-bit ARM) and picks its matrix-vector kernels by the
# `CPU part` (Cortex-A7, Cortex-A9 or generic). Debian 12's qemu-user (7.2) passes a guest's reads of
# /proc/cpuinfo through to this x86-64 host's, which has no `Features` line: under plain qemu-arm tract takes its
# VFP-only kernels (armvfpv2), as on an armv7 without NEON. This wrapper runs qemu-arm in a private mount
# namespace (unshare -m; as non-root, a user namespace too) in which /proc/cpuinfo is a Raspberry Pi 2's
# (Cortex-A7, part 0xc07, NEON + VFPv4), so tract takes its armv7neon kernels; nothing outside it changes.
# Pair it with `-cpu cortex-a7` so that the instructions qemu executes are that CPU's.
set -euo pipefail
if [ -z "${LIVEGESTURE_QEMU_NS:-}" ]; then
  ns=(-m); [ "$(id -u)" = 0 ] || ns=(-r -m)
  LIVEGESTURE_QEMU_NS=1 exec unshare "${ns[@]}" "$0" "$@"
fi
ci="$(mktemp)"
for ((i = 0; i < $(nproc); i++)); do
  printf 'processor\t: %d\nmodel name\t: ARMv7 Processor rev 5 (v7l)\nBogoMIPS\t: 38.40\nFeatures\t: half thumb fastmult vfp edsp neon vfpv3 tls vfpv4 idiva idivt vfpd32 lpae evtstrm\nCPU implementer\t: 0x41\nCPU architecture: 7\nCPU variant\t: 0x0\nCPU part\t: 0xc07\nCPU revision\t: 5\n\n' "$i"
done >"$ci"
mount --bind "$ci" /proc/cpuinfo
rm -f "$ci"   # the bind mount keeps the file's contents for this namespace
exec qemu-arm "$@"

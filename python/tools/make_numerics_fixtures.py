"""Write ``runtime/tests/fixtures/numerics.npz``: reference values from the Python numerics for the Rust
cross-language tests in ``runtime/tests/it/numerics.rs``.

Contents (all produced by the ``livegesture`` package, the single source of truth for numerics):

- ``audio`` (33600,) float32: 2.1 s of synthetic 16 kHz audio (silence, tones, an amplitude-modulated
  partial, a loud near-clipping burst and Gaussian noise; fixed seed);
- ``logmel64`` / ``logmel16`` (n_frames, n_mels) float32: ``frontend.logmel(audio)`` with
  ``FrontendConfig(n_mels=64)`` and ``FrontendConfig(n_mels=16)``;
- ``splitmix_seed42`` (20,) uint64: the first 20 ``SplitMix64(42).next_u64()`` outputs;
- sampler cases ``samp{i}_*`` for i < ``samp_count``: ``cond`` (K,) float32, ``uncond`` (K,) float32
  (absent when guidance is off), ``seed`` (1,) uint64, ``params`` float64 ``[gamma, temperature,
  top_k]``, ``tokens`` (50,) int64 drawn with ``sampling.sample_token`` from one generator;
- rotations: ``rot_aa_in`` (N, 3) float32 with ``rot_d6_of_aa`` (N, 6) float64, and ``rot_d6_in``
  (M, 6) float32 with ``rot_aa_of_d6`` (M, 3) float64 (inputs cast to float64 before converting).

Run from the repository root::

    PYTHONPATH=python python python/tools/make_numerics_fixtures.py
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from livegesture.frontend import FrontendConfig, logmel
from livegesture.rotation import np_axis_angle_to_rot6d, np_rot6d_to_axis_angle
from livegesture.sampling import SplitMix64, sample_token

REPO = Path(__file__).resolve().parents[2]
DEFAULT_OUT = REPO / "runtime" / "tests" / "fixtures" / "numerics.npz"
N_DRAWS = 50


def synthetic_audio(seed: int = 1234) -> np.ndarray:
    sr = 16000
    n = int(2.1 * sr)
    rng = np.random.default_rng(seed)
    t = np.arange(n) / sr
    x = (0.30 * np.sin(2 * np.pi * 220.0 * t)
         + 0.20 * np.sin(2 * np.pi * 1234.5 * t + 0.3)
         + 0.05 * np.sin(2 * np.pi * 5000.0 * t)
         + 0.10 * (1 + np.sin(2 * np.pi * 3.0 * t)) * np.sin(2 * np.pi * 640.0 * t)
         + 0.02 * rng.standard_normal(n))
    x[:1600] = 0.0                                   # 0.1 s of exact silence at the start
    x[1600:2400] *= 1e-4                             # very quiet stretch
    burst = slice(20000, 21000)                      # loud, near clipping
    x[burst] = 0.98 * np.sign(np.sin(2 * np.pi * 300.0 * t[burst]))
    return np.clip(x, -1.0, 1.0).astype(np.float32)


def sampler_cases(rng: np.random.Generator) -> list[dict]:
    cases = []

    def add(cond, uncond, seed, gamma, temperature, top_k):
        cases.append(dict(cond=np.asarray(cond, np.float32),
                          uncond=None if uncond is None else np.asarray(uncond, np.float32),
                          seed=seed, gamma=gamma, temperature=temperature, top_k=top_k))

    # K = 32
    add(rng.normal(0, 1.5, 32), rng.normal(0, 1.5, 32), 0, 1.25, 1.0, 0)
    q = np.round(rng.normal(0, 1.0, 32) * 2) / 2            # 0.5 grid: many exact ties
    add(q, None, 42, 1.25, 0.7, 5)                           # top_k cuts through tie groups
    add(np.full(32, 0.5), None, 7, 1.25, 1.0, 0)             # all tied: uniform, index order
    add(q, q + 0.25, 11, 1.0, 1.0, 1)                        # greedy with ties: lowest index
    # K = 256
    add(rng.normal(0, 2.0, 256), rng.normal(0, 2.0, 256), 123456789, 1.25, 1.0, 32)
    add(rng.normal(0, 1.0, 256), rng.normal(0, 1.0, 256), (1 << 63) + 5, 2.0, 1.3, 0)
    c = np.round(rng.uniform(-1, 1, 256) * 4) / 4             # 0.25 grid, few distinct (c, u) pairs
    u = np.round(rng.uniform(-1, 1, 256) * 2) / 2
    add(c, u, 99, 1.25, 1.0, 17)
    add(rng.normal(0, 30.0, 256), None, 2024, 1.25, 0.5, 256)  # peaked; top_k == K keeps all
    add(rng.normal(0, 0.3, 256), rng.normal(0, 0.3, 256), 0xFFFFFFFFFFFFFFFF, 1.25, 2.5, 100)
    return cases


def rotation_inputs(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    axes = rng.normal(size=(40, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0, math.pi, 40)
    aa = [axes * angles[:, None]]
    special_axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, -0.8, 0], [1, 2, -3]], np.float64)
    special_axes /= np.linalg.norm(special_axes, axis=1, keepdims=True)
    for ang in [0.0, 1e-9, 1e-6, 1e-4, 1e-2, math.pi / 2, math.pi - 1e-3, math.pi - 1e-5, math.pi,
                3.5, 2 * math.pi - 0.1]:
        aa.append(special_axes * ang)
    aa = np.concatenate(aa).astype(np.float32)

    d6 = np_axis_angle_to_rot6d(aa.astype(np.float64))
    noisy = d6[:40] + rng.normal(0, 0.05, (40, 6))             # not orthonormal
    scaled = d6[40:60] * rng.uniform(0.2, 5.0, (20, 1))         # not unit length
    d6_in = np.concatenate([d6, noisy, scaled]).astype(np.float32)
    return aa, d6_in


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args()

    out: dict[str, np.ndarray] = {}
    audio = synthetic_audio()
    out["audio"] = audio
    out["logmel64"] = logmel(audio, FrontendConfig(n_mels=64))
    out["logmel16"] = logmel(audio, FrontendConfig(n_mels=16))

    g = SplitMix64(42)
    out["splitmix_seed42"] = np.array([g.next_u64() for _ in range(20)], dtype=np.uint64)

    rng = np.random.default_rng(20240601)
    cases = sampler_cases(rng)
    for i, c in enumerate(cases):
        gen = SplitMix64(c["seed"])
        toks = [sample_token(c["cond"], c["uncond"], gen, gamma=c["gamma"], temperature=c["temperature"],
                             top_k=c["top_k"]) for _ in range(N_DRAWS)]
        out[f"samp{i}_cond"] = c["cond"]
        if c["uncond"] is not None:
            out[f"samp{i}_uncond"] = c["uncond"]
        out[f"samp{i}_seed"] = np.array([c["seed"]], dtype=np.uint64)
        out[f"samp{i}_params"] = np.array([c["gamma"], c["temperature"], c["top_k"]], dtype=np.float64)
        out[f"samp{i}_tokens"] = np.array(toks, dtype=np.int64)
    out["samp_count"] = np.array(len(cases), dtype=np.int64)

    aa_in, d6_in = rotation_inputs(rng)
    out["rot_aa_in"] = aa_in
    out["rot_d6_of_aa"] = np_axis_angle_to_rot6d(aa_in.astype(np.float64))
    out["rot_d6_in"] = d6_in
    out["rot_aa_of_d6"] = np_rot6d_to_axis_angle(d6_in.astype(np.float64))

    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(args.out, **out)   # uncompressed: the Rust reader (ndarray-npy without deflate) reads stored entries
    size = args.out.stat().st_size
    print(f"wrote {args.out} ({size / 1024:.0f} KiB, {len(out)} arrays, "
          f"{out['logmel64'].shape[0]} mel frames, {len(cases)} sampler cases)")
    for i in range(len(cases)):
        print(f"  samp{i}: distinct tokens {len(set(out[f'samp{i}_tokens'].tolist()))}")


if __name__ == "__main__":
    main()

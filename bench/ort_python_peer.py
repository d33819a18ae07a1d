#!/usr/bin/env python
"""The second peer of the Rust runtime (issue 15, deliverable 4): the bundle's exported step graphs chained
from Python with onnxruntime, the way an ML engineer would script it.

One ``onnxruntime.InferenceSession`` per graph (1 intra-op and 1 inter-op thread, default graph
optimisation), numpy feeds, every ``new_cache.*`` output fed back as the next step's ``cache.*`` input, the
guided sampler of ``livegesture.sampling`` (the manifest's guidance, temperature, top-k and the SplitMix64
draw), the decoders, and ``livegesture.motion.features_to_motion`` for the frames: the same work per token
as a token step of the Rust runtime (``LiveGestureGraphs::step``; ``MotionModel::step_many`` runs the same chain on stacked caches) (and as ``python -m livegesture.bench torch``, on the ONNX graphs
instead of the torch modules).

    taskset -c 1 python bench/ort_python_peer.py --bundle models/default --audio models/default/reference/clip.wav \
        --tokens 300 --warmup 20 --streams 1,32 --json bench/results/ort_python_default.json

It first proves that it runs the same computation: the bundle's reference rollout (``reference/rollout.npz``:
``reference/clip.wav`` repeated ``clip_repeats`` times, the manifest's rollout seed) is stepped for
``--check-tokens`` tokens and every token must equal the reference token (exit status 1 otherwise, naming
the first differing step and region). The batched run checks its first stream likewise for as long as it
stays in the batch. Then it times:

- one stream: wall time per token step (all graphs, both guidance branches as a batch of 2 in the experts
  and the fusion, sampling, frames), ``--warmup`` untimed steps then ``--tokens`` timed ones; per graph,
  each ``session.run`` is timed too. The log-mel frontend is computed up front and not timed (as in
  ``livegesture bench``'s chain figure).
- batched (``--streams``): N streams stacked on the batch axis of every graph (2N rows in the guided
  graphs: the N conditional rows, then the N unconditional ones), each stream at its own place in the audio
  with its own seed, with churn as in ``livegesture bench``: at every step after the first the stream at
  position ``step % N`` leaves and a fresh one (zero caches, BOS, new seed, audio from the start) takes its
  rows; resetting the rows is timed. ``--batch-warmup`` untimed steps, then up to ``--batch-steps`` timed
  steps, capped at ``--batch-seconds`` of timed steps (at least ``--batch-min-steps``).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "python"))

from livegesture.ort_chain import (Chain, Streams, TokenMismatch, check_tokens, read_wav, reference,  # noqa: E402,F401
                                   token_mels)


def stats(ts: list[float]) -> dict:
    a = np.asarray(ts, dtype=np.float64)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "p99": float(np.percentile(a, 99)),
            "mean": float(a.mean()), "min": float(a.min()), "n": int(len(a))}


def time_single(chain: Chain, mels: np.ndarray, seed: int, warmup: int, tokens: int) -> dict:
    s = Streams(chain, 1, [seed], [0])
    for v in chain.graph_ms.values():
        v.clear()
    ts = []
    for t in range(warmup + tokens):
        mel = mels[t % len(mels)][None]
        t0 = time.perf_counter()
        s.step(mel)
        dt = (time.perf_counter() - t0) * 1e3
        if t >= warmup:
            ts.append(dt)
        if t == warmup - 1:
            for v in chain.graph_ms.values():
                v.clear()
    graphs = {g: float(np.median(v)) for g, v in chain.graph_ms.items() if v}
    st = stats(ts)
    token_ms = 1000.0 * chain.frontend.frames_per_token / chain.frontend.fps
    return {"step_ms": st, "samples_ms": ts, "graphs_ms_median": graphs,
            "graphs_sum_ms": float(sum(graphs.values())), "real_time_factor": st["median"] / token_ms}


def time_batched(chain: Chain, mels: np.ndarray, n: int, seed: int, warmup: int, steps: int, min_steps: int,
                 seconds: float, ref_tokens: np.ndarray | None, churn: bool = True) -> dict:
    """N streams with churn; stream 0 (seed ``seed``, audio from position 0) is checked against the
    reference tokens while it stays in the batch (when the audio is the reference audio)."""
    s = Streams(chain, n, [seed + i for i in range(n)], [(i * 7) % len(mels) for i in range(n)])
    next_seed = seed + n
    ts, checked, first_alive = [], 0, True
    timed_start = None
    capped = False
    for step in range(warmup + steps):
        if step == warmup:
            timed_start = time.perf_counter()
        if timed_start is not None and len(ts) >= min_steps and time.perf_counter() - timed_start > seconds:
            capped = True
            break
        t0 = time.perf_counter()
        if churn and step > 0 and n > 1:
            leaving = step % n
            if leaving == 0:
                first_alive = False
            s.reset_stream(leaving, next_seed)
            next_seed += 1
        block = np.stack([mels[p] for p in s.pos])
        tokens, _ = s.step(block)
        dt = (time.perf_counter() - t0) * 1e3
        if step >= warmup:
            ts.append(dt)
        if first_alive and ref_tokens is not None and step < len(ref_tokens):
            if not np.array_equal(tokens[0], ref_tokens[step]):
                raise TokenMismatch(f"{chain.bundle}: batched N={n}, stream 0, token {step}: {tokens[0].tolist()} vs "
                                    f"the reference rollout's {ref_tokens[step].tolist()}")
            checked += 1
        s.pos = [(p + 1) % len(mels) for p in s.pos]
    st = stats(ts)
    token_ms = 1000.0 * chain.frontend.frames_per_token / chain.frontend.fps
    return {"streams": n, "churn": churn and n > 1, "warmup_steps": warmup, "timed_steps": len(ts),
            "capped": capped, "step_ms": st, "per_stream_ms": st["median"] / n,
            "realtime_streams": n * token_ms / st["median"], "stream0_tokens_checked": checked}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--audio", help="16 kHz wav for the timed runs (default: the bundle's reference rollout audio)")
    ap.add_argument("--tokens", type=int, default=300, help="timed single-stream steps")
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--check-tokens", type=int, default=2000,
                    help="tokens of the reference rollout to reproduce first (at most its length; 0: no check)")
    ap.add_argument("--streams", default="1", help="comma-separated N of the batched runs ('' for none); "
                                                   "N = 1 is the single-stream run")
    ap.add_argument("--batch-steps", type=int, default=100)
    ap.add_argument("--batch-warmup", type=int, default=3)
    ap.add_argument("--batch-min-steps", type=int, default=5)
    ap.add_argument("--batch-seconds", type=float, default=20.0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--denormal-as-zero", action="store_true",
                    help="ort session option session.set_denormal_as_zero (off: what a script gets by default)")
    ap.add_argument("--seed", type=int, default=None, help="seed of the timed streams (default: the rollout's)")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        chain = Chain(Path(args.bundle), args.threads, args.denormal_as_zero)
        ref_audio, ref_seed, ref_tokens = reference(chain)
    except (ValueError, KeyError) as e:
        print(f"ort_python_peer: {e}", file=sys.stderr)
        return 2
    out = {"peer": "onnxruntime (Python), one InferenceSession per graph",
           "bundle": str(args.bundle), "config": chain.manifest["model"]["config_name"],
           "precision": chain.manifest.get("precision", {}).get("weights", "float32"),
           "guidance": chain.guidance, "onnxruntime": chain.ort_version, "python": platform.python_version(),
           "threads": args.threads, "denormal_as_zero": args.denormal_as_zero,
           "loadavg_start": " ".join(open("/proc/loadavg").read().split()[:3])}
    try:
        if args.check_tokens > 0:
            t0 = time.perf_counter()
            out["check"] = check_tokens(chain, args.check_tokens)
            out["check"]["seconds"] = time.perf_counter() - t0
            print(f"check: {out['check']['tokens_checked']} tokens identical to the reference rollout", file=sys.stderr)
        audio = read_wav(Path(args.audio)) if args.audio else ref_audio
        same_audio = args.audio is None or (len(audio) <= len(ref_audio)
                                            and np.array_equal(audio, ref_audio[: len(audio)]))
        mels = token_mels(chain, audio)
        seed = ref_seed if args.seed is None else args.seed
        if args.tokens > 0:
            out["single"] = time_single(chain, mels, seed, args.warmup, args.tokens)
            print(f"one stream: {out['single']['step_ms']['median']:.3f} ms per token (median of {args.tokens})",
                  file=sys.stderr)
        out["batched"] = []
        for n in [int(x) for x in args.streams.split(",") if x.strip()]:
            b = time_batched(chain, mels, n, seed, args.batch_warmup, args.batch_steps, args.batch_min_steps,
                             args.batch_seconds, ref_tokens if (same_audio and seed == ref_seed) else None)
            out["batched"].append(b)
            print(f"N={n}: {b['step_ms']['median']:.2f} ms per batched step ({b['timed_steps']} steps"
                  f"{', capped' if b['capped'] else ''}), {b['realtime_streams']:.1f} real-time streams", file=sys.stderr)
    except TokenMismatch as e:
        print(f"ort_python_peer: FAILED: {e}", file=sys.stderr)
        return 1
    out["loadavg_end"] = " ".join(open("/proc/loadavg").read().split()[:3])
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

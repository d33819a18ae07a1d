"""Per-token overhead of the Python module over the Rust core (docs/python.md#overhead).

Pushes the same 16 kHz audio, one token's worth (2133 samples, 4 frames at 30 fps) per call, and measures
the module's own cost per call in two ways:

  1. on the same call: `Stream._push_timed` is `Stream.push` returning also the seconds its Rust core
     (`PcmStream::push`: the stream's resampler and `MotionStream::push_audio`) took inside it; the
     overhead of a call is the Python wall time around it minus that (argument parsing, copying the
     samples, releasing and taking the GIL, the stream's lock, the result dict of numpy arrays). The
     model's compute, by far the noisiest part, is not in the difference;
  2. A/B, as a check: the Rust core alone (`MotionStream::push_audio` in a Rust loop,
     `livegesture_runtime._bench_push_audio`) and the Python `Stream.push` loop, alternately (A B A B ...)
     in one process; the difference of their medians per push.

Also the cost of a call with no samples (the fixed part). Run after `pip install ./bindings/python`, pinned
to one core:

  taskset -c 1 python bindings/python/bench_overhead.py --bundle models/default --seconds 20 --rounds 7
"""
import argparse
import pathlib
import statistics
import time
import wave

import numpy as np

import livegesture_runtime as lgr

ROOT = pathlib.Path(__file__).resolve().parents[2]


def pct(xs, q):
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", default=str(ROOT / "models/default"))
    ap.add_argument("--backend", default="tract")
    ap.add_argument("--seconds", type=float, default=20.0, help="audio per round (the reference clip, repeated)")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--chunk", type=int, default=2133, help="samples per push (2133 = one token at 16 kHz)")
    a = ap.parse_args()

    with wave.open(str(ROOT / "models/default/reference/clip.wav"), "rb") as w:
        clip = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2").astype(np.float32) / 32768
    n = int(a.seconds * 16000)
    pcm = np.resize(clip, n).astype(np.float32)
    chunks = [pcm[i : i + a.chunk] for i in range(0, n, a.chunk)]
    model = lgr.Model(a.bundle, backend=a.backend)

    same_call, rust, py = [], [], []
    for r in range(a.rounds + 1):  # round 0 warms up (plans, caches) and is not counted
        # 1. the binding's cost on each call
        s = model.stream(seed=0)
        frames_timed, over = 0, []
        for c in chunks:
            t0 = time.perf_counter()
            out, core = s._push_timed(c, 16000)
            over.append(time.perf_counter() - t0 - core)
            frames_timed += len(out["index"])
        # 2. A/B: the Rust loop, then the Python loop
        secs, frames_rust = lgr._bench_push_audio(model, pcm, a.chunk, 0)
        s = model.stream(seed=0)
        frames_py = 0
        t0 = time.perf_counter()
        for c in chunks:
            frames_py += len(s.push(c, 16000)["index"])
        t_py = time.perf_counter() - t0
        assert frames_py == frames_rust == frames_timed, (frames_py, frames_rust, frames_timed)
        if r > 0:
            same_call += over
            rust.append(secs / len(chunks))
            py.append(t_py / len(chunks))
    # the fixed part: a call with no samples
    s = model.stream(seed=0)
    empty = np.zeros(0, np.float32)
    s.push(empty, 16000)
    calls = []
    for _ in range(20000):
        t0 = time.perf_counter()
        s.push(empty, 16000)
        calls.append(time.perf_counter() - t0)

    mr, mp = statistics.median(rust), statistics.median(py)
    print(f"bundle {a.bundle} ({model.family}, {a.backend}), {len(chunks)} pushes of {a.chunk} samples, "
          f"{frames_rust} frames per round, {a.rounds} rounds")
    print(f"1. binding cost on the same call (Python wall - Rust core), {len(same_call)} pushes: "
          f"median {statistics.median(same_call) * 1e6:.1f} us, p10 {pct(same_call, 0.1) * 1e6:.1f} us, "
          f"p90 {pct(same_call, 0.9) * 1e6:.1f} us")
    print(f"   a push with no samples: median {statistics.median(calls) * 1e6:.1f} us "
          f"(p90 {pct(calls, 0.9) * 1e6:.1f} us, {len(calls)} calls)")
    print(f"2. A/B per push, medians of {a.rounds} rounds: rust core loop {mr * 1e3:.3f} ms, "
          f"python Stream.push loop {mp * 1e3:.3f} ms, difference {(mp - mr) * 1e6:.1f} us ({(mp / mr - 1) * 100:+.2f} %)")
    deltas = sorted((p - q) * 1e6 for p, q in zip(py, rust))
    print("   per-round difference (us): " + " ".join(f"{d:.1f}" for d in deltas))
    print(f"   binding cost / rust core per push: {statistics.median(same_call) / mr * 100:.3f} %")


if __name__ == "__main__":
    main()

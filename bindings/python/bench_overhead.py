"""Per-token overhead of the Python module over the Rust core (docs/python.md#overhead).

Pushes the same 16 kHz audio, one token's worth (2133 samples, 4 frames at 30 fps) per call, through
  A: the Rust core alone: `MotionStream::push_audio` in a Rust loop (livegesture_runtime._bench_push_audio);
  B: Python: `Stream.push(chunk, 16000)` per chunk (argument parsing, copy, GIL release, result dict);
alternately (A B A B ...) in one process, and prints the median time per push of each and their
difference. Run after `pip install ./bindings/python`:

  python bindings/python/bench_overhead.py --bundle models/default --seconds 20 --rounds 7
"""
import argparse
import pathlib
import statistics
import time
import wave

import numpy as np

import livegesture_runtime as lgr

ROOT = pathlib.Path(__file__).resolve().parents[2]


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

    rust, py = [], []
    for r in range(a.rounds + 1):  # round 0 warms up (plans, caches) and is not counted
        secs, frames_rust = lgr._bench_push_audio(model, pcm, a.chunk, 0)
        s = model.stream(seed=0)
        frames_py = 0
        t0 = time.perf_counter()
        for c in chunks:
            frames_py += len(s.push(c, 16000)["index"])
        t_py = time.perf_counter() - t0
        assert frames_py == frames_rust, (frames_py, frames_rust)
        if r > 0:
            rust.append(secs / len(chunks))
            py.append(t_py / len(chunks))
    mr, mp = statistics.median(rust), statistics.median(py)
    print(f"bundle {a.bundle} ({model.family}, {a.backend}), {len(chunks)} pushes of {a.chunk} samples, "
          f"{frames_rust} frames per round, {a.rounds} rounds (A/B interleaved)")
    print(f"rust core (MotionStream::push_audio loop): {mr * 1e3:.3f} ms per push (median)")
    print(f"python Stream.push loop:                   {mp * 1e3:.3f} ms per push (median)")
    print(f"overhead per push: {(mp - mr) * 1e6:.1f} us ({(mp / mr - 1) * 100:+.2f} %)")
    deltas = sorted((p - q) * 1e6 for p, q in zip(py, rust))
    print("per-round overhead (us): " + " ".join(f"{d:.1f}" for d in deltas))


if __name__ == "__main__":
    main()

"""Two streams of one Model on two threads vs the same two one after the other (docs/python.md#threads).

Each repetition runs the same work twice, in alternating order (A B, B A, ...): two streams (seeds 1 and 2)
of ONE `Model`, each pushing `--seconds` of the reference clip in `--chunk`-sample pushes and finishing,

  sequential: stream 1 then stream 2, on the calling thread;
  threads:    stream 1 and stream 2 at once, one Python thread each (every call releases the GIL).

It prints the median wall time of each and their ratio (threads / sequential: 1.0 means no parallelism,
0.5 two cores fully used), and checks that the threaded streams' frames equal the sequential ones exactly
(same seed, same frames, whatever the interleaving). The first repetition warms up (plans, the second run
state or session of each graph) and is not counted. It also prints the resident memory after one stream at
a time and after two at once (the cost of the second run state or session per graph). Run after `pip install ./bindings/python`:

  python bench/python_threads.py --backend tract --seconds 20 --reps 7
  python bench/python_threads.py --backend ort --seconds 20 --reps 7

Exit status 1 when the frames differ. The ratio is printed, not checked: it depends on the machine and its
load (the script prints the load average before and after).
"""
import argparse
import os
import pathlib
import statistics
import threading
import time
import wave

import numpy as np

try:
    import livegesture_runtime as lgr
except ImportError:  # --help works without the module (a fresh venv before the bindings are installed)
    lgr = None

ROOT = pathlib.Path(__file__).resolve().parents[1]


def run_stream(model, seed, chunks, out, start=None):
    """One stream: every chunk pushed, then finish; its frames (poses) go to out[seed]."""
    if start is not None:
        start.wait()
    s = model.stream(seed=seed)
    poses = [s.push(c)["poses"] for c in chunks]
    poses.append(s.finish()["poses"])
    out[seed] = np.concatenate(poses)


def rss_mib():
    """Resident memory of this process (Linux /proc), MiB; None elsewhere."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def sequential(model, work):
    out = {}
    t0 = time.perf_counter()
    for seed, chunks in work:
        run_stream(model, seed, chunks, out)
    return time.perf_counter() - t0, out


def threaded(model, work):
    out = {}
    start = threading.Barrier(len(work) + 1)
    ts = [threading.Thread(target=run_stream, args=(model, seed, chunks, out, start)) for seed, chunks in work]
    for t in ts:
        t.start()
    start.wait()
    t0 = time.perf_counter()
    for t in ts:
        t.join()
    return time.perf_counter() - t0, out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", default=str(ROOT / "models/default"))
    ap.add_argument("--backend", default="tract", choices=["tract", "ort"])
    ap.add_argument("--seconds", type=float, default=20.0, help="audio per stream (the reference clip, repeated)")
    ap.add_argument("--reps", type=int, default=7, help="counted repetitions of each mode (plus one warm-up)")
    ap.add_argument("--chunk", type=int, default=2133, help="samples per push (2133 = one token at 16 kHz)")
    a = ap.parse_args()
    if lgr is None:
        raise SystemExit("python_threads.py: the livegesture_runtime module is not installed "
                         "(pip install ./bindings/python)")

    with wave.open(str(ROOT / "models/default/reference/clip.wav"), "rb") as w:
        clip = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2").astype(np.float32) / 32768
    n = int(a.seconds * 16000)
    work = []
    for k, seed in enumerate((1, 2)):
        pcm = np.roll(np.resize(clip, n), 7919 * k).astype(np.float32)
        work.append((seed, [pcm[i : i + a.chunk] for i in range(0, n, a.chunk)]))
    model = lgr.Model(a.bundle, backend=a.backend)
    load0 = os.getloadavg()
    # memory of the second run state / session per graph: one sequential run, then one threaded run
    sequential(model, work)
    rss_one = rss_mib()
    threaded(model, work)
    rss_two = rss_mib()
    seq, par = [], []
    for r in range(a.reps + 1):
        order = (sequential, threaded) if r % 2 == 0 else (threaded, sequential)
        got = {}
        for mode in order:
            secs, frames = mode(model, work)
            got[mode.__name__] = frames
            if r > 0:
                (seq if mode is sequential else par).append(secs)
        for seed, _ in work:
            if not np.array_equal(got["sequential"][seed], got["threaded"][seed]):
                raise SystemExit(f"seed {seed}: the frames on two threads differ from the sequential run")
    load1 = os.getloadavg()
    ms, mp = statistics.median(seq), statistics.median(par)
    print(f"bundle {a.bundle}, backend {a.backend}, 2 streams x {a.seconds:g} s of audio, {a.reps} reps (interleaved)")
    print(f"load average (1 min) before {load0[0]:.2f}, after {load1[0]:.2f}; {os.cpu_count()} CPUs")
    print(f"sequential: median {ms:.3f} s  (all: {', '.join(f'{x:.3f}' for x in seq)})")
    print(f"threads:    median {mp:.3f} s  (all: {', '.join(f'{x:.3f}' for x in par)})")
    print(f"ratio threads / sequential: {mp / ms:.3f}  (frames identical)")
    if rss_one is not None and rss_two is not None:
        print(
            f"resident memory after one stream at a time {rss_one:.1f} MiB, after two at once {rss_two:.1f} MiB "
            f"(+{rss_two - rss_one:.1f} MiB: the second run state or session of each graph, and the second "
            "stream's buffers)"
        )


if __name__ == "__main__":
    main()

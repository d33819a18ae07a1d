"""Training throughput per stage, both families: steps/s, samples/s, GPU utilisation, peak GPU memory.

    python -m livegesture.bench_train --data CORPUS --device cuda --out bench_train.json
    python -m livegesture.bench_train --data CORPUS --device cpu --configs tiny --steps 3 --warmup 1   # smoke

For every family (``livegesture``: the stages svq1, svq2, experts, fuse; ``diffsheg``: its one stage), every
``--configs`` entry and every variant, a model with fresh weights trains ``--warmup`` steps, then ``--steps``
timed steps, through the trainers' own loops (``livegesture.train.run_stage``,
``livegesture.diffsheg.train.train``) with their batch sizes for that config. Variants:

- ``before``: ``--amp off --prefetch 0`` (float32, batches drawn on the training thread);
- ``after``: the CUDA defaults (bf16 autocast, 4 batches prefetched on a background thread, pinned memory);
- ``compile`` (only with ``--variants ...,compile``): ``after`` plus ``torch.compile``.

Timing: ``torch.cuda.synchronize()`` at the end of the last warm-up step and of the last timed step; the
rate is timed steps / seconds between. samples/s = steps/s x windows per step (``batch_svq`` windows of
every region for svq1/svq2, ``batch_ar`` windows for experts/fuse, ``batch`` for DiffSHEG). GPU utilisation:
the mean of ``nvidia-smi`` readings (every 100 ms) over the timed steps (absent without nvidia-smi).
The loss values of a benchmark run mean nothing (fresh weights, few steps); checkpoints go to a temporary
folder. On CPU the same code runs (to check the script); its rates are not GPU rates.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from . import families

VARIANTS = {"before": dict(amp="off", prefetch=0), "after": dict(), "compile": dict(compile=True)}


class GpuSampler:
    """``nvidia-smi`` utilisation readings with their times, from a background process."""

    def __init__(self, period_ms: int = 100):
        self.samples: list[tuple[float, float]] = []
        self.proc = None
        if shutil.which("nvidia-smi") is None:
            return
        try:
            self.proc = subprocess.Popen(["nvidia-smi", "--query-gpu=utilization.gpu", "--format=csv,noheader,nounits",
                                          f"-lms={period_ms}"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                         text=True)
        except OSError:
            self.proc = None
            return
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            try:
                self.samples.append((time.perf_counter(), float(line.strip().split(",")[0])))
            except ValueError:
                pass

    def mean(self, t0: float, t1: float) -> float | None:
        v = [u for t, u in self.samples if t0 <= t <= t1]
        return round(float(np.mean(v)), 1) if v else None

    def close(self):
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=5)


class Timer:
    """A ``step_hook``: synchronises and reads the clock after the last warm-up step and the last step."""

    def __init__(self, first: int, warmup: int, total: int, cuda: bool):
        self.mark_at, self.end_at, self.cuda = first + warmup - 1, first + total - 1, cuda
        self.t0 = self.t1 = None

    def __call__(self, step):
        if step in (self.mark_at, self.end_at):
            if self.cuda:
                torch.cuda.synchronize()
            if step == self.mark_at:
                self.t0 = time.perf_counter()
            if step == self.end_at:
                self.t1 = time.perf_counter()


def _row(family, config, stage, variant, timer, steps, batch, gpu, device):
    sec = timer.t1 - timer.t0
    row = {"family": family, "config": config, "stage": stage, "variant": variant, "steps": steps,
           "seconds": round(sec, 3), "steps_per_s": round(steps / sec, 2),
           "samples_per_s": round(steps * batch / sec, 1),
           "windows_per_step": batch, "gpu_util_pct": gpu.mean(timer.t0, timer.t1)}
    if torch.device(device).type == "cuda" and torch.cuda.is_available():
        row["peak_mem_gib"] = round(torch.cuda.max_memory_allocated() / 2 ** 30, 2)
        torch.cuda.reset_peak_memory_stats()
    print(json.dumps(row), flush=True)
    return row


def bench_livegesture(config, data_dir, device, variant, warmup, steps, gpu, tmp) -> list[dict]:
    from .config import get_config
    from .models.model import LiveGesture
    from .train import BUILDERS, STAGES, Logger, TrainConfig, TrainData, init_codebooks, run_stage, tokenize_clips
    from .trainkit import RunOptions
    cfg = get_config(config)
    tcfg = replace(TrainConfig.for_model(cfg.name), log_every=10 ** 9, save_every=10 ** 9, speakers=None,
                   dead_code_every=10 ** 9)
    opts = RunOptions.for_device(device, **VARIANTS[variant])
    torch.manual_seed(0)
    model = LiveGesture(cfg).to(device)
    data = TrainData(data_dir, cfg, None)
    stats = data.stats.to_dict()["regions"]
    stats["mel"] = {"mean": data.mel_mean.tolist(), "std": data.mel_std.tolist()}
    model.set_normalisation(stats)
    rows = []
    out = Path(tempfile.mkdtemp(dir=tmp))
    for name in STAGES:
        if name == "svq2":
            init_codebooks(model, data, tcfg, device, np.random.default_rng(0))
        if name == "experts":
            tokenize_clips(model, data, device)
        model.train()
        params, step_fn, state_fn = BUILDERS[name](model, data, tcfg, device)
        timer = Timer(0, warmup, warmup + steps, opts.cuda)
        run_stage(name, model, params, warmup + steps, step_fn, tcfg, out, Logger(out), device, state_fn, opts=opts,
                  step_hook=timer)
        model.eval()
        for p in model.parameters():
            p.requires_grad_(True)
        batch = tcfg.batch_svq if name.startswith("svq") else tcfg.batch_ar
        rows.append(_row("livegesture", config, name, variant, timer, steps, batch, gpu, device))
        del params, step_fn, state_fn
    return rows


def bench_diffsheg(config, data_dir, device, variant, warmup, steps, gpu, tmp) -> list[dict]:
    from .diffsheg.train import DiffSHEGTrainConfig, train
    from .trainkit import RunOptions
    opts = RunOptions.for_device(device, **VARIANTS[variant])
    timer = Timer(0, warmup, warmup + steps, opts.cuda)
    batch = DiffSHEGTrainConfig.for_model(config).batch
    train(config, data_dir, str(Path(tempfile.mkdtemp(dir=tmp))), device=device, opts=opts, step_hook=timer,
          overrides={"steps": warmup + steps, "log_every": 10 ** 9, "save_every": 10 ** 9, "speakers": None})
    return [_row("diffsheg", config, "diffsheg", variant, timer, steps, batch, gpu, device)]


def table(rows: list[dict]) -> str:
    head = ("| family | config | stage | variant | steps/s | samples/s | GPU util % | peak GiB |\n"
            "|---|---|---|---|---|---|---|---|")
    lines = [f"| {r['family']} | {r['config']} | {r['stage']} | {r['variant']} | {r['steps_per_s']} | "
             f"{r['samples_per_s']} | {r['gpu_util_pct'] if r['gpu_util_pct'] is not None else '-'} | "
             f"{r.get('peak_mem_gib', '-')} |" for r in rows]
    return "\n".join([head] + lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="BEAT2-layout corpus (e.g. python -m livegesture.data.synth output)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--families", default=",".join(families.NAMES))
    ap.add_argument("--configs", default="default,paper")
    ap.add_argument("--variants", default="before,after", help="before, after, compile (comma-separated)")
    ap.add_argument("--warmup", type=int, default=5, help="untimed steps per stage")
    ap.add_argument("--steps", type=int, default=20, help="timed steps per stage")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    ap.add_argument("--out", help="write the rows as JSON here (and the table as OUT with .md)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.warmup < 1 or args.steps < 1:
        raise SystemExit("--warmup and --steps must be >= 1")
    variants = [v for v in args.variants.split(",") if v]
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise SystemExit(f"--variants: unknown {bad}; choose from {sorted(VARIANTS)}")
    if not Path(args.data).is_dir():
        raise SystemExit(f"--data {args.data}: no such corpus folder")
    gpu = GpuSampler()
    rows = []
    tmp = tempfile.mkdtemp(prefix="bench_train_")
    meta = {"device": args.device, "torch": torch.__version__, "warmup": args.warmup, "steps": args.steps,
            "gpu": torch.cuda.get_device_name() if torch.device(args.device).type == "cuda" else None}
    print(json.dumps(meta), flush=True)
    try:
        for fam in [f for f in args.families.split(",") if f]:
            try:
                runner = families.get(fam).resolve(families.get(fam).train_bench)
            except ValueError as e:
                raise SystemExit(f"--families: {e}") from None
            for config in [c for c in args.configs.split(",") if c]:
                for v in variants:
                    t0 = time.time()
                    rows += runner(config, args.data, args.device, v, args.warmup, args.steps, gpu, tmp)
                    print(f"# {fam} {config} {v}: {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
    finally:
        gpu.close()
        shutil.rmtree(tmp, ignore_errors=True)
        md = table(rows)
        print(md)
        if args.out:
            Path(args.out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
            Path(args.out).with_suffix(".md").write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

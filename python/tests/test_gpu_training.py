"""Both families train, evaluate and stream on a GPU: every tensor is made where the model is.

These run on CPU-only machines: ``devicecheck.VirtualCuda`` emulates a CUDA device (tensors moved to "cuda"
stay on the CPU but remember it; an operation mixing them with host tensors raises as on a GPU). The
DiffSHEG crash of issue 33 (``sinusoidal`` multiplying the diffusion steps on the GPU with frequencies on the
CPU) is reproduced here with the old function and must raise. The training loops must not read the GPU back
at every step (``.item()`` only at logging steps), and the prefetched batches must give the very training of
the inline ones.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from devicecheck import VirtualCuda
from livegesture import checkpoint as ckpt
from livegesture.checkpoint import random_model
from livegesture.config import get_config
from livegesture.models.model import LiveGesture
from livegesture.trainkit import Prefetcher, RunOptions

pytestmark = pytest.mark.filterwarnings("ignore:User provided device_type of 'cuda'")

PY_ROOT = Path(__file__).resolve().parents[1]
LG_STEPS = dict(steps_svq1=2, steps_svq2=2, steps_experts=2, steps_fuse=3, save_every=100, speakers=None)


def _old_sinusoidal(pos, dim, base=10000.0):
    """``diffsheg.layers.sinusoidal`` before the fix: the frequencies on the CPU whatever the input's device."""
    half = dim // 2
    freqs = torch.exp(-math.log(base) * torch.arange(half, dtype=torch.float32) / half)
    ang = pos.float()[..., None] * freqs
    return torch.cat([torch.cos(ang), torch.sin(ang)], dim=-1)


# ----------------------------------------------------------------------------- the emulated device itself

def test_virtual_cuda_raises_where_a_gpu_raises():
    with VirtualCuda():
        a = torch.ones(3).to("cuda")
        assert a.device.type == "cuda" and a.is_cuda
        with pytest.raises(RuntimeError, match="same device"):
            _ = a * torch.arange(3.0)                        # a host tensor in a GPU operation
        with pytest.raises(RuntimeError, match="same device"):
            torch.cat([a, torch.zeros(2)])
        with pytest.raises(TypeError, match="numpy"):
            a.numpy()
        _ = a * torch.tensor(2.0)                            # 0-dim host tensors are scalars on CUDA too
        b = torch.zeros(3, device=a.device) + a              # made on the input's device: fine
        assert b.cpu().numpy().tolist() == [1.0, 1.0, 1.0]
        a[torch.tensor([0, 2])] = 5.0                        # host indices: allowed
        m = torch.nn.Linear(3, 2).to("cuda")
        assert next(m.parameters()).device.type == "cuda"
        m(a).sum().backward()
        torch.optim.Adam(m.parameters()).step()


def test_the_old_sinusoidal_crashes_diffsheg_training(tiny_corpus, tmp_path, monkeypatch):
    """Issue 33's crash, on a CPU-only machine: the old function fails in the first step."""
    from livegesture.diffsheg import denoiser
    from livegesture.diffsheg.train import train
    monkeypatch.setattr(denoiser, "sinusoidal", _old_sinusoidal)
    with VirtualCuda(), pytest.raises(RuntimeError, match="found at least two devices"):
        train("tiny", str(tiny_corpus), str(tmp_path / "run"), device="cuda", overrides={"steps": 2, "batch": 2})
    monkeypatch.undo()
    with VirtualCuda():
        final = train("tiny", str(tiny_corpus), str(tmp_path / "run2"), device="cuda",
                      overrides={"steps": 2, "batch": 2})
    assert ckpt.load(final).provenance["steps"] == 2


# ----------------------------------------------------------------------------- training on the device

def test_livegesture_trains_on_cuda(tiny_corpus, tmp_path):
    from livegesture.train import train
    with VirtualCuda() as vc:
        final = train("tiny", str(tiny_corpus), str(tmp_path), device="cuda", overrides=LG_STEPS,
                      opts=RunOptions.for_device("cuda", prefetch=2))
    assert vc.ops > 1000
    m = ckpt.load(final)
    assert m.provenance["stages_done"] == ["svq1", "svq2", "experts", "fuse"]


def _stage_syncs(model, data, tcfg, name, steps, tmp_path):
    from livegesture.train import BUILDERS, Logger, run_stage
    with VirtualCuda() as vc:
        model.to("cuda")
        model.train()
        params, step_fn, state_fn = BUILDERS[name](model, data, tcfg, "cuda")
        run_stage(name, model, params, steps, step_fn, tcfg, tmp_path, Logger(tmp_path), "cuda", state_fn,
                  opts=RunOptions.for_device("cuda", prefetch=1))
        n = vc.count_syncs()
    for p in model.parameters():
        p.requires_grad_(True)
    return n, vc.syncs


def test_training_steps_do_not_wait_for_the_gpu(tiny_corpus, tmp_path):
    """Host synchronisations happen at logging steps only: 2 and 7 steps (logging the first and the last
    step only) synchronise equally often, in every stage."""
    from dataclasses import replace

    from livegesture.train import TrainConfig, TrainData, init_codebooks, tokenize_clips
    cfg = get_config("tiny")
    tcfg = replace(TrainConfig.for_model("tiny"), log_every=1000, save_every=1000, dead_code_every=1000)
    torch.manual_seed(0)
    model = LiveGesture(cfg)
    data = TrainData(tiny_corpus, cfg, None)
    for name in ("svq1", "svq2", "experts", "fuse"):
        if name == "svq2":
            init_codebooks(model, data, tcfg, "cpu", np.random.default_rng(0))
        if name == "experts":
            tokenize_clips(model, data, "cpu")
        model.to("cpu")
        short, _ = _stage_syncs(model, data, tcfg, name, 2, tmp_path)
        model.to("cpu")
        long, syncs = _stage_syncs(model, data, tcfg, name, 7, tmp_path)
        # the premise: the counter sees the logging steps' syncs (0 == 0 would pass a counter that counts nothing)
        assert short > 0, f"stage {name}: no host sync counted in 2 steps: the counter is not counting"
        assert long == short, f"stage {name}: {long - short} more host syncs in 5 more steps: {syncs}"
    model.to("cpu")


def test_a_livegesture_sync_per_step_would_be_seen(tiny_corpus, tmp_path, monkeypatch):
    """The LiveGesture check above fails on a loop that reads the loss at every step: the same count, with one
    host sync injected per step, differs by exactly the 5 extra steps (issue 38 item 8: a positive control)."""
    from dataclasses import replace

    from livegesture import trainkit
    from livegesture.train import TrainConfig, TrainData
    real = trainkit.LossTrack.update

    def update_and_read(self, loss):
        real(self, loss)
        float(loss.detach())
    monkeypatch.setattr(trainkit.LossTrack, "update", update_and_read)
    cfg = get_config("tiny")
    tcfg = replace(TrainConfig.for_model("tiny"), log_every=1000, save_every=1000, dead_code_every=1000)
    torch.manual_seed(0)
    model = LiveGesture(cfg)
    data = TrainData(tiny_corpus, cfg, None)
    short, _ = _stage_syncs(model, data, tcfg, "svq1", 2, tmp_path)
    model.to("cpu")
    long, _ = _stage_syncs(model, data, tcfg, "svq1", 7, tmp_path)
    model.to("cpu")
    assert short > 0 and long - short == 5, (short, long)


def test_diffsheg_steps_do_not_wait_for_the_gpu(tiny_corpus, tmp_path):
    from livegesture.diffsheg.train import train
    counts = []
    for steps in (2, 7):
        with VirtualCuda() as vc:
            train("tiny", str(tiny_corpus), str(tmp_path / f"s{steps}"), device="cuda",
                  overrides={"steps": steps, "batch": 2, "log_every": 1000, "save_every": 1000})
        counts.append(vc.count_syncs())
    assert counts[0] > 0, f"no host sync counted in 2 steps: the counter is not counting ({counts})"
    assert counts[0] == counts[1], counts


def test_a_sync_per_step_would_be_seen(tiny_corpus, tmp_path, monkeypatch):
    """The check above fails on a loop that reads the loss at every step (the loop before issue 33)."""
    from livegesture import trainkit
    from livegesture.diffsheg import train as dtrain
    real = trainkit.LossTrack.update

    def update_and_read(self, loss):
        real(self, loss)
        float(loss.detach())
    monkeypatch.setattr(dtrain.LossTrack, "update", update_and_read)
    counts = []
    for steps in (2, 7):
        with VirtualCuda() as vc:
            dtrain.train("tiny", str(tiny_corpus), str(tmp_path / f"s{steps}"), device="cuda",
                         overrides={"steps": steps, "batch": 2, "log_every": 1000, "save_every": 1000})
        counts.append(vc.count_syncs())
    assert counts[1] - counts[0] == 5


# ----------------------------------------------------------------------------- bf16 autocast

def test_bf16_autocast_trains_both_families(tiny_corpus, tmp_path):
    """The mixed-precision path (bf16 autocast, float32 weights) runs every stage of both families; on CPU
    here (``--amp bf16 --device cpu``), the same code as on CUDA. Module inputs stay float32 (the LiveGesture
    modules refuse bf16 inputs: the experts stage failed this before its audio features were cast back)."""
    from livegesture.diffsheg.train import train as train_diffsheg
    from livegesture.train import train
    opts = RunOptions.for_device("cpu", amp="bf16", prefetch=1)
    assert opts.amp == "bf16"
    for final in (train("tiny", str(tiny_corpus), str(tmp_path / "lg"), overrides={**LG_STEPS, "log_every": 1},
                        opts=opts),
                  train_diffsheg("tiny", str(tiny_corpus), str(tmp_path / "ds"), overrides={"steps": 3, "batch": 2,
                                                                                          "log_every": 1}, opts=opts)):
        log = [json.loads(x) for x in (final.parent / "train_log.jsonl").read_text().splitlines()]
        assert log and all(math.isfinite(x["loss"]) for x in log)
        sd = _weights(final)
        assert {v.dtype for v in sd.values() if v.is_floating_point()} == {torch.float32}


# ----------------------------------------------------------------------------- the same results on CPU

def _weights(path):
    return torch.load(path, map_location="cpu", weights_only=False)["state_dict"]


def test_prefetched_batches_give_the_same_training(tiny_corpus, tmp_path):
    """Batches drawn ahead on a background thread are those drawn inline (same random numbers, same order):
    bit-identical weights and logs, both families."""
    from livegesture.diffsheg.train import train as train_diffsheg
    from livegesture.train import train
    runs = {}
    for depth in (0, 3):
        out = tmp_path / f"lg{depth}"
        train("tiny", str(tiny_corpus), str(out), overrides={**LG_STEPS, "steps_fuse": 6},
              opts=RunOptions(device="cpu", prefetch=depth))
        dout = tmp_path / f"ds{depth}"
        train_diffsheg("tiny", str(tiny_corpus), str(dout), overrides={"steps": 5, "batch": 2},
                       opts=RunOptions(device="cpu", prefetch=depth))
        runs[depth] = (out, dout)
    for a, b in zip(runs[0], runs[3]):
        wa, wb = _weights(a / "final.pt"), _weights(b / "final.pt")
        assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)
        strip = lambda line: {k: v for k, v in json.loads(line).items() if k != "seconds"}  # noqa: E731
        la = [strip(x) for x in (a / "train_log.jsonl").read_text().splitlines()]
        lb = [strip(x) for x in (b / "train_log.jsonl").read_text().splitlines()]
        assert la == lb and la


def test_prefetcher_order_errors_and_defaults():
    rng = np.random.default_rng(0)
    feed = Prefetcher(lambda step, r: {"x": r.random(3), "step": step}, rng, range(2, 6), depth=2)
    got = [feed.get(s) for s in range(2, 6)]
    feed.close()
    inline = np.random.default_rng(0)
    assert [g["step"] for g in got] == [2, 3, 4, 5]
    assert all(np.array_equal(g["x"].numpy(), inline.random(3)) for g in got)

    def broken(step, r):
        raise ValueError("bad clip")
    feed = Prefetcher(broken, rng, range(3), depth=2)
    with pytest.raises(ValueError, match="bad clip"):
        feed.get(0)
    feed.close()
    assert RunOptions.for_device("cpu").describe() == {"device": "cpu", "amp": "off", "prefetch": 0, "compile": False}
    o = RunOptions.for_device("cuda")
    assert (o.amp, o.prefetch) == ("bf16", 4)
    assert RunOptions.for_device("cuda", amp="off", prefetch=0).amp == "off"
    with pytest.raises(SystemExit, match="amp"):
        RunOptions.for_device("cuda", amp="fp8")


# ----------------------------------------------------------------------------- streaming and evaluation

def _cpu_vs_cuda(model, fn):
    ref = fn(model.to("cpu"))
    with VirtualCuda():
        model.to("cuda")
        got = fn(model)
    model.to("cpu")
    return ref, got


@pytest.mark.parametrize("form", ["canonical", "fused", "attention"])
def test_livegesture_stream_runs_on_cuda(form):
    from livegesture.stream import generate_clip
    audio = np.random.default_rng(1).standard_normal(12000).astype(np.float32) * 0.1
    ref, got = _cpu_vs_cuda(random_model("tiny"), lambda m: generate_clip(m, audio, seed=2, form=form, finish=True))
    assert len(got["poses"]) == math.ceil(len(audio) * 30 / 16000)
    for k in ("poses", "trans", "expressions", "tokens"):
        assert np.array_equal(ref[k], got[k]), k


def test_diffsheg_stream_and_batched_clips_run_on_cuda():
    from livegesture.diffsheg.foppas import generate_clip, generate_clips
    audio = np.random.default_rng(1).standard_normal(24000).astype(np.float32) * 0.1
    model = random_model("tiny", family="diffsheg")
    ref, got = _cpu_vs_cuda(model, lambda m: generate_clip(m, audio, seed=3, chunk=5000))
    assert np.array_equal(ref["poses"], got["poses"]) and len(got["poses"]) == 45
    ref, got = _cpu_vs_cuda(model, lambda m: generate_clips(m, [audio, audio[:9000]], [1, 2]))
    assert all(np.array_equal(a["poses"], b["poses"]) for a, b in zip(ref, got))


@pytest.mark.parametrize("family", ["livegesture", "diffsheg"])
def test_evaluation_generates_on_cuda(tmp_path, family):
    from livegesture.eval.__main__ import _generate
    path = tmp_path / f"{family}.pt"
    ckpt.save(random_model("tiny", family=family), path)
    audio = {"a": np.random.default_rng(4).standard_normal(8000).astype(np.float32) * 0.1}
    ref = _generate(str(path), ["a"], audio, 1, 0, None, None)
    with VirtualCuda():
        got = _generate(str(path), ["a"], audio, 1, 0, None, None, device="cuda")
    assert np.array_equal(ref[0][0]["poses"], got[0][0]["poses"])


# ----------------------------------------------------------------------------- several processes

def test_torchrun_two_cpu_processes_train_both_families(tiny_corpus, tmp_path):
    """``torchrun --nproc_per_node 2 -m livegesture.train ...`` on CPU (gloo): one model, gradients averaged,
    process 0 writes. On CUDA the same command gives each process its GPU (LOCAL_RANK, NCCL)."""
    env = {**os.environ, "PYTHONPATH": str(PY_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "OMP_NUM_THREADS": "1"}
    base = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
            "-m", "livegesture.train", "--config", "tiny", "--data", str(tiny_corpus), "--speakers", "all",
            "--device", "cpu"]
    for family, extra in (("livegesture", ["--steps-svq1", "2", "--steps-svq2", "2", "--steps-experts", "2",
                                           "--steps-fuse", "2"]),
                          ("diffsheg", ["--steps", "3", "--batch", "2"])):
        out = tmp_path / family
        r = subprocess.run(base + ["--family", family, "--out", str(out)] + extra, env=env, capture_output=True,
                           text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-3000:]
        m = ckpt.load(out / "final.pt")
        assert m.provenance["world_size"] == 2, m.provenance


# ----------------------------------------------------------------------------- the benchmark script

def test_bench_train_runs_on_cpu(tiny_corpus, tmp_path):
    """The GPU benchmark (python -m livegesture.bench_train) on the tiny config, on CPU: one row per stage and
    variant, positive rates."""
    from livegesture.bench_train import main
    out = tmp_path / "bench.json"
    assert main(["--data", str(tiny_corpus), "--device", "cpu", "--configs", "tiny", "--warmup", "1", "--steps", "2",
                 "--variants", "before,after", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["family"], r["stage"], r["variant"]) for r in rows] == \
        [("livegesture", s, v) for v in ("before", "after") for s in ("svq1", "svq2", "experts", "fuse")] + \
        [("diffsheg", "diffsheg", v) for v in ("before", "after")]
    assert all(r["steps_per_s"] > 0 and r["samples_per_s"] == pytest.approx(r["steps_per_s"] * r["windows_per_step"],
                                                                           rel=0.02) for r in rows)
    assert "| livegesture | tiny | fuse | after |" in out.with_suffix(".md").read_text()
    with pytest.raises(SystemExit, match="variants"):
        main(["--data", str(tiny_corpus), "--variants", "fastest"])


# ----------------------------------------------------------------------------- a real GPU (skipped without one)

@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_real_cuda_trains_both_families_with_bf16_and_prefetch(tiny_corpus, tmp_path):
    from livegesture.diffsheg.train import train as train_diffsheg
    from livegesture.stream import generate_clip
    from livegesture.train import train
    opts = RunOptions.for_device("cuda")
    assert (opts.amp, opts.prefetch, opts.pin) == ("bf16", 4, True)
    lg = ckpt.load(train("tiny", str(tiny_corpus), str(tmp_path / "lg"), device="cuda", overrides=LG_STEPS, opts=opts))
    ds = ckpt.load(train_diffsheg("tiny", str(tiny_corpus), str(tmp_path / "ds"), device="cuda",
                                  overrides={"steps": 3, "batch": 2}, opts=opts))
    audio = np.random.default_rng(1).standard_normal(16000).astype(np.float32) * 0.1
    for m in (lg, ds):
        ref = generate_clip(m, audio, seed=1)
        got = generate_clip(m.to("cuda"), audio, seed=1)
        assert np.isfinite(got["poses"]).all() and got["poses"].shape == ref["poses"].shape

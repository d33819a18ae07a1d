"""DiffSHEG training (paper section 3.4): epsilon prediction on windows of N frames.

    python -m livegesture.train --family diffsheg --config default --data DIR --out runs/diffsheg --speakers all

One stage (``diffsheg``). Per step: a batch of windows (normalised motion x0 (B, n, D), their log-mel
frames (B, 2n, n_mels), speaker ids), t ~ U{0..999}, eps ~ N(0, I), ``x_t = sqrt(ab_t) x0 + sqrt(1-ab_t) eps``,
the audio condition dropped (null audio) with probability ``null_cond_prob`` for classifier-free guidance.
Loss (eq. 8): ``10 * L_t + 1 * L_v + 1 * L_delta`` with L_t the noise MSE (eq. 4), and on the predicted
clean motion ``x0' = (x_t - sqrt(1-ab_t) eps') / sqrt(ab_t)``: L_v the velocity MSE (eq. 6) and L_delta the
Huber loss (eq. 7, delta = ``huber_delta``), each weighted per sample by min(1, SNR_t) resp.
min(1, sqrt(SNR_t)) (our addition: unweighted, the x0-space losses are ~3000x the noise loss at high noise). Window lengths: N, and with probability ``short_p`` a shorter
n in [``short_min``, N] (the last FOPPAS window is shorter). Adam, gradient clipping, an EMA of the weights
(the EMA weights are what ``final.pt`` holds). Resumable: ``OUT/diffsheg.resume.pt`` every ``save_every`` steps.
"""
from __future__ import annotations

import copy
import json
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from .. import checkpoint as ckpt
from .. import families, variants
from ..trainkit import (Logger, LossTrack, Prefetcher, RunOptions, TrainData, dist_info, log_values, sync_grads,
                        to_device)
from .config import get_config
from .model import MOTION_ORDER, DiffSHEG
from .schedule import alphas_cumprod


@dataclass
class DiffSHEGTrainConfig:
    steps: int = 100000
    batch: int = 128
    lr: float = 2e-4
    warmup: int = 200
    null_cond_prob: float = 0.2       # the authors' code default
    lambda_t: float = 10.0
    lambda_v: float = 1.0
    lambda_huber: float = 1.0
    huber_delta: float = 1.0
    short_p: float = 0.2
    short_min: int = 16
    ema: float = 0.999
    grad_clip: float = 1.0
    save_every: int = 250
    log_every: int = 25
    seed: int = 0
    max_minutes: float = 0.0          # > 0: stop after this much training time (over resumes) and finish
    speakers: tuple[int, ...] | None = None
    augment: int = 0                  # augmented copies of every clip's audio (livegesture.data.augment)

    @staticmethod
    def for_model(name: str) -> "DiffSHEGTrainConfig":
        if name == "tiny":
            return DiffSHEGTrainConfig(steps=30, batch=4, lr=2e-3, warmup=5, save_every=20, log_every=5, short_min=8,
                                       ema=0.9)
        if name == "default":
            return DiffSHEGTrainConfig(steps=4000, batch=16, lr=5e-4, warmup=200, save_every=200, log_every=25)
        return DiffSHEGTrainConfig()


class WindowData:
    """Normalised motion (F, D) and log-mel (2F, n_mels) per training clip, with speaker ids. With audio
    augmentation (``TrainData(augment=N)``) every window reads the clean mel or one of the clip's N degraded
    copies, at random (the motion target is the same: every effect keeps the length and timing)."""

    def __init__(self, train_data, speaker_index):
        self.x = [np.concatenate([f[r] for r in MOTION_ORDER], axis=1).astype(np.float32) for f in train_data.feats]
        self.mel = train_data.mel
        self.mel_variants = getattr(train_data, "mel_variants", [[m] for m in self.mel])
        self.spk = np.array([speaker_index[c.speaker] for c in train_data.clips], dtype=np.int64)
        self.frames = np.array([len(x) for x in self.x])

    def windows(self, rng, n, B):
        """(x0 (B, n, D) float32, mel (B, 2n, n_mels) float32, speaker ids (B,) int64), numpy (host)."""
        ok = np.nonzero(self.frames >= n)[0]
        if len(ok) == 0:
            raise SystemExit(f"no training clip has {n} frames")
        w = (self.frames[ok] - n + 1).astype(np.float64)
        ci = rng.choice(ok, size=B, p=w / w.sum())
        st = [int(rng.integers(0, self.frames[c] - n + 1)) for c in ci]
        x0 = np.stack([self.x[c][s:s + n] for c, s in zip(ci, st)])
        if len(self.mel_variants[0]) > 1:
            v = rng.integers(0, len(self.mel_variants[0]), size=B)
            mel = np.stack([self.mel_variants[c][k][2 * s:2 * (s + n)] for c, s, k in zip(ci, st, v)])
        else:
            mel = np.stack([self.mel[c][2 * s:2 * (s + n)] for c, s in zip(ci, st)])
        return x0, mel, self.spk[ci]

    def batch(self, rng, n, B):
        return tuple(torch.from_numpy(v) for v in self.windows(rng, n, B))


def losses(model: DiffSHEG, x0, mel, spk, t, eps, cond, tc: DiffSHEGTrainConfig, sab, s1mab):
    a = sab[t][:, None, None]
    b = s1mab[t][:, None, None]
    x_t = a * x0 + b * eps
    pred = model(mel, x_t, t, spk, cond).float()   # (bf16 under autocast) the losses in float32
    l_t = F.mse_loss(pred, eps)
    x0p = (x_t - b * pred) / a
    # x0' = x0 + sqrt((1-ab)/ab) (eps - eps'): at high noise its error is amplified up to 156x; unweighted, L_v
    # is ~3000x L_t at initialisation and swamps it. Min-SNR weights (ours, the paper gives none) bound both
    # x0-space losses by the noise loss: min(1, SNR) on the squared L_v, min(1, sqrt(SNR)) on the Huber.
    snr = (a / b) ** 2
    w_v = torch.clamp(snr, max=1.0)
    w_h = torch.clamp(a / b, max=1.0)
    l_v = (w_v * ((x0p[:, 1:] - x0p[:, :-1]) - (x0[:, 1:] - x0[:, :-1])) ** 2).mean()
    l_h = (w_h * F.huber_loss(x0p, x0, delta=tc.huber_delta, reduction="none")).mean()
    return tc.lambda_t * l_t + tc.lambda_v * l_v + tc.lambda_huber * l_h, {"l_eps": l_t, "l_vel": l_v, "l_huber": l_h}


# long: the training run in order (config, data, model, resume, the loop, checkpoints)
def train(config: str, data_dir: str, out: str, device: str = "cpu", overrides: dict | None = None,
          init_from: str | None = None, opts: RunOptions | None = None, step_hook=None,
          variant: str | None = None) -> Path:
    """``init_from``: fine-tune a trained DiffSHEG checkpoint (its config, weights, motion and mel
    normalisation and style ids are kept; ``config`` must name the same config). Fresh Adam state and warm-up.
    ``opts``: how to run (:class:`livegesture.trainkit.RunOptions`; default: those of ``device``): batches
    drawn ahead on a background thread, bf16 autocast on CUDA, ``torch.compile``. Under ``torchrun`` the
    processes train one model data-parallel (gradients averaged); process 0 writes. ``step_hook(step)``
    (benchmarks) runs after each step."""
    opts = opts or RunOptions.for_device(str(device))
    rank, world = dist_info()
    cfg = variants.apply(get_config(config), families.DIFFSHEG.name, variant)   # livegesture.variants
    src = None
    if init_from:
        src = ckpt.load_to_fine_tune(init_from, "diffsheg", cfg, config)
    tc = DiffSHEGTrainConfig.for_model(cfg.name)
    overrides = {**(overrides or {}), **variants.train_overrides(families.DIFFSHEG.name, variant)}
    if overrides:
        tc = replace(tc, **{k: v for k, v in overrides.items() if k in DiffSHEGTrainConfig.__dataclass_fields__})
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    final = out / "final.pt"
    if final.exists():
        if rank == 0:
            print(f"[diffsheg] done already ({final})")
        return final
    torch.manual_seed(tc.seed)
    model = DiffSHEG(cfg).to(device)
    data = TrainData(data_dir, cfg, tc.speakers, augment=tc.augment, seed=tc.seed)
    numbers = sorted({c.speaker for c in data.clips})
    if src is not None:
        # keep the source model's input/output normalisation and style ids: its weights were trained on them
        from ..data.features import NormStats
        from ..regions import REGION_NAMES
        model.load_state_dict(src.state_dict())
        norm = src.normalisation()
        data.stats = NormStats(mean={r: np.asarray(norm[r]["mean"], np.float32) for r in REGION_NAMES},
                               std={r: np.asarray(norm[r]["std"], np.float32) for r in REGION_NAMES},
                               source=f"normalisation of {init_from}")
        data.feats = [data.stats.normalize(c.features) for c in data.clips]
        spk_index = {s: model.speaker_index(s) for s in numbers}
    else:
        stats = data.stats.to_dict()["regions"]
        stats["mel"] = {"mean": data.mel_mean.tolist(), "std": data.mel_std.tolist()}
        model.set_normalisation(stats)
        model.set_speakers(numbers)
        spk_index = {s: i for i, s in enumerate(numbers)}
    wd = WindowData(data, spk_index)
    ema = copy.deepcopy(model).eval()
    for p in ema.parameters():
        p.requires_grad_(False)
    params = list(model.parameters())
    fused = opts.cuda and torch.cuda.is_available()
    opt = torch.optim.Adam(params, lr=tc.lr, **({"fused": True} if fused else {}))
    ab = alphas_cumprod(cfg.diffusion_steps, cfg.beta_start, cfg.beta_end)
    sab = torch.from_numpy(ab ** 0.5).float().to(device)
    s1mab = torch.from_numpy((1 - ab) ** 0.5).float().to(device)
    info = {"family": "diffsheg", "config": cfg.name, "variant": cfg.variant, "train_config": asdict(tc), "data": str(Path(data_dir).resolve()),
            **({"world_size": world} if world > 1 else {}),
            "train_clips": len(data.clips), "train_frames": int(wd.frames.sum()),
            "train_minutes": round(float(wd.frames.sum()) / 30 / 60, 2), "speakers": numbers,
            "augment": tc.augment, **({"init_from": str(init_from)} if init_from else {})}
    resume = out / "diffsheg.resume.pt"
    start, spent = 0, 0.0
    if resume.exists():
        st = torch.load(resume, map_location="cpu", weights_only=False)
        model.load_state_dict(st["model"])
        ema.load_state_dict(st["ema"])
        opt.load_state_dict(st["opt"])
        start, spent = st["step"], st.get("seconds", 0.0)
        if rank == 0:
            print(f"[diffsheg] resuming at step {start}")
    logger = Logger(out)
    # process 0 draws what a single process draws; the others their own streams
    rng = np.random.default_rng(tc.seed * 1000 + start if rank == 0 else [tc.seed * 1000 + start, rank])
    torch.manual_seed(tc.seed * 1000 + start + 7919 * rank)

    def sample(step, rng):
        # every host random number of a step, in order: window length, windows, diffusion steps
        n = cfg.window if rng.random() >= tc.short_p else int(rng.integers(min(tc.short_min, cfg.window), cfg.window + 1))
        x0, mel, spk = wd.windows(rng, n, tc.batch)
        t = rng.integers(0, cfg.diffusion_steps, tc.batch)
        return {"x0": x0, "mel": mel, "spk": spk, "t": t}

    def compute(batch):
        x0 = batch["x0"]
        eps = torch.randn_like(x0)
        cond = (torch.rand(tc.batch, device=x0.device) >= tc.null_cond_prob).float()
        return losses(fwd, x0, batch["mel"], batch["spk"], batch["t"], eps, cond, tc, sab, s1mab)

    if opts.compile:            # in place (state dict unchanged); window lengths vary: dynamic shapes
        model.compile(dynamic=True)
    fwd = model
    feed = Prefetcher(sample, rng, range(start, tc.steps), depth=opts.prefetch, pin=opts.pin)
    ema_p, model_p = list(ema.parameters()), [p.detach() for p in params]
    model.train()
    bar = tqdm(range(start, tc.steps), desc="diffsheg", dynamic_ncols=True, mininterval=2.0, disable=rank != 0)
    t0, track, done = time.time(), LossTrack(), start
    try:
        for step in bar:
            if tc.max_minutes > 0 and spent + time.time() - t0 > 60 * tc.max_minutes:
                if rank == 0:
                    print(f"[diffsheg] time budget of {tc.max_minutes} min reached at step {step}")
                break
            batch = to_device(feed.get(step), device, non_blocking=opts.cuda)
            for g in opt.param_groups:
                g["lr"] = tc.lr * min(1.0, (step + 1) / tc.warmup)
            with opts.autocast():
                loss, parts = compute(batch)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            sync_grads(params)
            torch.nn.utils.clip_grad_norm_(params, tc.grad_clip)
            opt.step()
            with torch.no_grad():
                d = min(tc.ema, (1 + step) / (10 + step))
                torch._foreach_mul_(ema_p, d)
                torch._foreach_add_(ema_p, model_p, alpha=1 - d)
                for be, bm in zip(ema.buffers(), model.buffers()):
                    be.copy_(bm)
            done = step + 1
            track.update(loss)
            if step_hook:
                step_hook(step)
            if step % tc.log_every == 0 or step == tc.steps - 1:
                bar.set_postfix(loss=f"{track.value():.4f}", eps=f"{float(parts['l_eps'].detach()):.4f}")
                logger.log(stage="diffsheg", step=step, loss=float(loss.detach()), **log_values(parts),
                           window=int(batch["x0"].shape[1]), seconds=round(spent + time.time() - t0, 2))
            if rank == 0 and (step + 1) % tc.save_every == 0 and step + 1 < tc.steps:
                tmp = resume.with_suffix(".tmp")
                torch.save({"model": model.state_dict(), "ema": ema.state_dict(), "opt": opt.state_dict(),
                            "step": step + 1, "seconds": spent + time.time() - t0}, tmp)
                os.replace(tmp, resume)
    finally:
        feed.close()
    avg = track.value()
    if rank != 0:
        return final
    seconds = round(spent + time.time() - t0, 1)
    prov = {**info, "stages_done": ["diffsheg"], "final_losses": {"diffsheg": avg}, "steps": done,
            "train_seconds": seconds, "weights": f"EMA (decay {tc.ema}) of the trained weights",
            "training_data": f"{info['train_minutes']} minutes, {len(data.clips)} clips of {Path(data_dir).name}"}
    ckpt.save(ema, final, provenance=prov, extra={"final_loss": avg, "seconds": seconds})
    if resume.exists():
        resume.unlink()
    (out / "train_summary.json").write_text(json.dumps(prov, indent=1, default=str))
    print(f"[diffsheg] final loss {avg:.4f} in {seconds:.0f}s -> {final}")
    return final


def train_from_args(args, device, opts, speakers):
    """``python -m livegesture.train --family diffsheg`` (the family registry's trainer)."""
    ov = {"steps": args.steps, "batch": args.batch, "lr": args.lr, "seed": args.seed,
          "max_minutes": args.max_minutes, "augment": args.augment, "speakers": speakers}
    return train(args.config, args.data, args.out, device=device,
                 overrides={k: v for k, v in ov.items() if v is not None or k == "speakers"},
                 init_from=args.init_from, opts=opts, variant=args.variant)

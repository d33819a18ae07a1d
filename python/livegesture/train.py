"""The paper's four-stage training pipeline (docs/model.md, paper section 3.3 and supp. B).

    python -m livegesture.train --config default --data DIR --out runs/NAME              # all stages
    python -m livegesture.train --config default --data DIR --out runs/NAME --stage svq1 # one stage
    python -m livegesture.train --config tiny --variant no-pilor --data DIR --out runs/x # a paper variant
    python -m livegesture.train --list-variants                                          # their names

Stages (each writes ``OUT/<stage>.pt``; a finished stage is skipped on re-run, an interrupted one resumes
from its last periodic save; the stages may run in different sittings with different ``--lr-*``: each stage
checkpoint records its own learning rate, steps and time, and ``final.pt``'s provenance lists them under
``stages``, while ``train_config`` is the last sitting's):

1. ``svq1``: per-region streamable autoencoder (bidirectional encoder, causal decoder), L1, windows of 16
   frames;
2. ``svq2``: encoder and decoder frozen; codebook (EMA, decay ``ema_decay``, dead-code reset) + code-space
   projection + projection head W^region; L1 + 0.2 x codebook loss, straight-through;
3. ``experts``: the streamable audio encoder and the four region eXperts, teacher forcing, Gaussian noise
   (sigma 0.1, p 0.2) on the history embeddings, audio dropped with p 0.1 for classifier-free guidance;
4. ``fuse``: SVQ, audio encoder and eXperts frozen; PILOR adapters, xAR-Fuse and the (shared) region
   classifiers trained with uncertainty-guided token masking (ratio on a cosine ramp up to 0.5), random
   region masking (p_drop ramped up to 0.5), CFG dropout 0.1, loss 0.3 x local + 1.0 x fuse.

Fine-tuning: ``--init-from CKPT`` starts from every weight and statistic of a trained checkpoint, keeps its
motion tokenizer (svq1/svq2) and trains the experts and fuse stages further (give a lower ``--lr-ar``);
``--extra-data DIR`` (repeatable) mixes the train split of more corpora into ``--data``'s.

``OUT/final.pt`` is the finished checkpoint (``livegesture.checkpoint.load``); ``OUT/train_log.jsonl`` holds
every logged loss. Runs on CPU or one GPU (``--device``), and data-parallel over several processes with
``torchrun --nproc_per_node N -m livegesture.train ...`` (gradients and EMA statistics are all-reduced; on
CUDA one GPU per process, ``cuda:LOCAL_RANK``, NCCL; on CPU gloo). On a GPU (``livegesture.trainkit``):
batches are drawn ahead on a background thread into pinned memory (``--prefetch``, default 4; the same
batches as drawn inline), bf16 autocast with float32 weights (``--amp bf16|off``, default bf16; the
codebook stage svq2 stays float32), ``--compile`` for ``torch.compile``, and the loss is read back only at
logging steps. ``python -m livegesture.bench_train`` measures the rates.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from tqdm import tqdm

from . import checkpoint as ckpt
from . import families, variants
from .config import get_config
from .data.features import NormStats
from .models.model import LiveGesture
from .regions import split as split_regions
from .trainkit import (Logger, LossTrack, Prefetcher, RunOptions, TrainData, all_reduce_mean_,  # noqa: F401
                       dist_info, finish_distributed, init_distributed, log_values, sync_grads, to_device)

STAGES = ("svq1", "svq2", "experts", "fuse")


@dataclass
class TrainConfig:
    """Training hyper-parameters. Adam 1e-4 / batch 128 for experts and fuse, the masking, noise and loss values
    are the paper's (supp. B); the step counts and the SVQ stages' batch and learning rate are the project's
    choice (the paper gives none). ``for_model`` scales step counts."""
    steps_svq1: int = 20000
    steps_svq2: int = 20000
    steps_experts: int = 50000
    steps_fuse: int = 50000
    batch_svq: int = 256
    batch_ar: int = 128
    lr_svq: float = 2e-4
    lr_ar: float = 1e-4
    svq_window_frames: int = 16
    ar_window_tokens: int = 64
    cb_weight: float = 0.2
    dead_code_every: int = 200
    noise_sigma: float = 0.1
    noise_p: float = 0.2
    cfg_dropout: float = 0.1
    ugm_max_ratio: float = 0.5
    region_drop_max: float = 0.5
    local_weight: float = 0.3
    fuse_weight: float = 1.0
    grad_clip: float = 1.0
    save_every: int = 500
    log_every: int = 25
    seed: int = 0
    speakers: tuple[int, ...] | None = (2,)
    augment: int = 0                  # augmented copies of every clip's audio (livegesture.data.augment)
    # variants and fidelity options (docs/model.md "Variants and fidelity choices"; defaults: what models/default
    # was trained with)
    svq_stages: int = 2               # 2: svq1 then svq2 (section 3.1); 1: encoder, decoder, quantizer together
    noise_p_uniform: bool = False     # False: p_noise = noise_p (supp. B); True: p_noise ~ U(0, noise_p) per batch (Table 8)
    region_drop_ramp: bool = True     # True: p_drop's top ramps to region_drop_max (supp. B); False: U(0, max) (Table 7)
    fuse_loss_masked: bool = False    # True: the fuse loss only on the tokens whose history input was masked

    @staticmethod
    def for_model(name: str) -> "TrainConfig":
        if name == "tiny":
            return TrainConfig(steps_svq1=30, steps_svq2=30, steps_experts=30, steps_fuse=30, batch_svq=16,
                               batch_ar=4, lr_svq=2e-3, lr_ar=2e-3, ar_window_tokens=12, save_every=20,
                               log_every=5, dead_code_every=10)
        if name == "default":
            # CPU budget: minutes per stage on 2 cores; larger learning rates than the paper's batch-128 runs
            return TrainConfig(steps_svq1=1500, steps_svq2=800, steps_experts=1500, steps_fuse=800,
                               batch_svq=64, batch_ar=16, lr_svq=1e-3, lr_ar=5e-4, ar_window_tokens=48,
                               save_every=250, log_every=25, dead_code_every=100)
        return TrainConfig()


# ----------------------------------------------------------------------------- stages

# The first stage each variant field changes (livegesture.variants): the stages before it compute exactly what the
# `full` model's compute (same seed, data, config and initial weights), so an ablation run may take them from a
# `full` run of the same budget (scripts/ablation.sh). A field not listed is taken to change every stage.
FIRST_STAGE_OF_FIELD = {
    # model config
    "pilor": "fuse", "fuse_spatial": "fuse", "fuse_temporal": "fuse", "fuse_audio": "fuse", "fusion": "fuse",
    "audio_fusion": "experts",
    # training config
    "ugm_max_ratio": "fuse", "region_drop_max": "fuse", "region_drop_ramp": "fuse", "local_weight": "fuse",
    "fuse_loss_masked": "fuse", "steps_fuse": "fuse", "noise_p_uniform": "experts",
}


def first_changed_stage(variant: str | None) -> str | None:
    """The first training stage in which LiveGesture variant ``variant`` differs from ``full`` (None: none)."""
    if variant in (None, "full"):
        return None
    v = variants.get(families.LIVEGESTURE.name, variant)
    fields = set(v.model_fields(get_config("tiny"))) | set(v.train)
    return min((FIRST_STAGE_OF_FIELD.get(f, STAGES[0]) for f in fields), key=STAGES.index, default=None)



def cosine_ramp(step, total, top):
    """0 at the start, ``top`` at the end, cosine-shaped."""
    return top * 0.5 * (1 - math.cos(math.pi * min(step / max(total, 1), 1.0)))


class StageStep:
    """One stage's training step, in two halves: ``sample(step, rng)`` draws the batch on the host (numpy
    arrays; every numpy random number of the step, in order; no torch random numbers) and
    ``compute(step, batch)`` runs the model on the device batch and returns ``(loss, parts)``.
    ``step_fn(step, rng)`` does both (tests). ``amp``: the stage may run under bf16 autocast."""

    def __init__(self, sample, compute, device, amp: bool = True):
        self.sample, self.compute, self.device, self.amp = sample, compute, device, amp

    def __call__(self, step, rng):
        return self.compute(step, to_device(self.sample(step, rng), self.device))


def run_stage(name, model, params, total, step_fn, tcfg, out: Path, logger, device, state_fn=None,
              opts: RunOptions | None = None, step_hook=None):
    """Generic loop: Adam, gradient clipping, periodic resumable saves, tqdm progress with the loss.

    ``opts`` (:class:`livegesture.trainkit.RunOptions`, default: those of ``device``): batches prepared
    ahead on a background thread, pinned and copied asynchronously, bf16 autocast on CUDA, ``torch.compile``.
    The loss is read back from the device only at logging steps. ``state_fn(step, None)`` runs after each
    optimiser step (the numpy generator belongs to the batch sampler). ``step_hook(step)`` (benchmarks) runs
    after each step."""
    rank, world = dist_info()
    opts = opts or RunOptions.for_device(str(device))
    cuda = opts.cuda
    lr = tcfg.lr_svq if name.startswith("svq") else tcfg.lr_ar
    # on CUDA the fused Adam kernel (one launch for all parameters); on CPU the default implementation
    opt = torch.optim.Adam(params, lr=lr, **({"fused": True} if cuda and torch.cuda.is_available() else {}))
    resume = out / f"{name}.resume.pt"
    start = 0
    if resume.exists():
        st = torch.load(resume, map_location="cpu", weights_only=False)
        model.load_state_dict(st["model"])
        opt.load_state_dict(st["opt"])
        start = st["step"]
        if rank == 0:
            print(f"[{name}] resuming at step {start}")
    rng = np.random.default_rng(tcfg.seed * 1000 + STAGES.index(name) * 100 + rank + start)
    torch.manual_seed(tcfg.seed * 1000 + rank + start)
    split = isinstance(step_fn, StageStep)
    if opts.compile:
        compile_modules(model)
    if split:
        compute = step_fn.compute
        feed = Prefetcher(step_fn.sample, rng, range(start, total), depth=opts.prefetch, pin=opts.pin)
    bar = tqdm(range(start, total), desc=name, disable=rank != 0, dynamic_ncols=True, mininterval=2.0)
    t0, track = time.time(), LossTrack()
    try:
        for step in bar:
            if split:
                batch = to_device(feed.get(step), device, non_blocking=cuda)
                with opts.autocast(step_fn.amp):
                    loss, parts = compute(step, batch)
            else:
                loss, parts = step_fn(step, rng)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            sync_grads(params)
            torch.nn.utils.clip_grad_norm_(params, tcfg.grad_clip)
            opt.step()
            if state_fn:
                state_fn(step, None if split else rng)
            track.update(loss)
            if step_hook:
                step_hook(step)
            if step % tcfg.log_every == 0 or step == total - 1:
                bar.set_postfix(loss=f"{track.value():.4f}")
                logger.log(stage=name, step=step, loss=float(loss.detach()), **log_values(parts),
                           seconds=round(time.time() - t0, 2))
            if rank == 0 and ((step + 1) % tcfg.save_every == 0) and step + 1 < total:
                tmp = resume.with_suffix(".tmp")
                torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "step": step + 1}, tmp)
                os.replace(tmp, resume)
    finally:
        if split:
            feed.close()
    if resume.exists() and rank == 0:
        resume.unlink()
    return track.value()


def compile_modules(model):
    """``torch.compile`` the modules a training step calls (in place: names and state dict unchanged). The
    step functions themselves are not compiled: they take host numbers (masking ratios) that change every step."""
    names = model.region_names
    mods = [model.audio_encoder, model.fuse] + [model.experts[r] for r in names] + \
        [m for r in names for m in (model.svq[r].encoder, model.svq[r].decoder)]
    # the four regions' modules share their classes' code: room for their shapes (windows, whole clips)
    cfg = torch._dynamo.config
    name = "recompile_limit" if hasattr(cfg, "recompile_limit") else "cache_size_limit"
    setattr(cfg, name, max(64, getattr(cfg, name)))
    for m in mods:
        if getattr(m, "_compiled_call_impl", None) is None:
            m.compile()


def stage_svq1(model, data, tcfg, device):
    names = model.region_names
    params = [p for r in names for m in (model.svq[r].encoder, model.svq[r].decoder) for p in m.parameters()]

    def sample(step, rng):
        return {r: data.svq_window(rng, r, tcfg.svq_window_frames, tcfg.batch_svq) for r in names}

    def compute(step, batch):
        losses = {}
        for r in names:
            x = batch[r]
            losses[f"l1_{r}"] = F.l1_loss(model.svq[r].autoencode(x).float(), x)
        return sum(losses.values()), losses
    return params, StageStep(sample, compute, device), None


@torch.no_grad()
def init_codebooks(model, data, tcfg, device, rng):
    """Start each codebook from encoder outputs of random training windows."""
    names = model.region_names
    for r in names:
        q = model.svq[r].quantizer
        x = data.svq_batch(rng, r, tcfg.svq_window_frames, max(4 * q.K // 4, 64), device)
        e = q.pre(model.svq[r].encoder(x.transpose(1, 2)).transpose(1, 2)).reshape(-1, q.codebook.shape[1])
        pick = e[torch.randperm(len(e))[:q.K].to(e.device)]
        if len(pick) < q.K:
            extra = torch.randint(len(pick), (q.K - len(pick),)).to(e.device)
            pick = torch.cat([pick, pick[extra] + 0.01 * torch.randn(q.K - len(pick), pick.shape[1]).to(e.device)])
        q.codebook.copy_(pick)
        q.ema_sum.copy_(pick)
        q.ema_count.fill_(1.0)
        q.usage.fill_(1.0)


def stage_svq2(model, data, tcfg, device):
    names = model.region_names
    one_stage = tcfg.svq_stages == 1     # Table 2c "1-stage": the autoencoder is trained with the quantizer
    for r in names:
        for p in list(model.svq[r].encoder.parameters()) + list(model.svq[r].decoder.parameters()):
            p.requires_grad_(one_stage)
    parts = ("quantizer.pre", "head") + (("encoder", "decoder") if one_stage else ())
    params = [p for r in names for name in parts for p in model.svq[r].get_submodule(name).parameters()]
    recent = {}

    def sample(step, rng):
        return {r: data.svq_window(rng, r, tcfg.svq_window_frames, tcfg.batch_svq) for r in names}

    def compute(step, batch):
        losses = {}
        for r in names:
            svq = model.svq[r]
            x = batch[r]
            rec, _, cb = svq.quantize(x, update=True)
            losses[f"l1_{r}"] = F.l1_loss(rec, x)
            losses[f"cb_{r}"] = cb
            if (step + 1) % tcfg.dead_code_every == 0:      # only the steps that reset dead codes read them
                with torch.no_grad():
                    e = svq.quantizer.pre(svq.encoder(x.transpose(1, 2)).transpose(1, 2))
                    recent[r] = e.reshape(-1, svq.cfg.code_dim)
        total = sum(v for k, v in losses.items() if k.startswith("l1")) + \
            tcfg.cb_weight * sum(v for k, v in losses.items() if k.startswith("cb"))
        return total, losses

    def state_fn(step, rng):
        for r in names:
            q = model.svq[r].quantizer
            all_reduce_mean_([q.codebook, q.ema_sum, q.ema_count, q.usage])
            if (step + 1) % tcfg.dead_code_every == 0 and dist_info()[0] == 0:
                q.reset_dead_codes(recent[r])
            if dist_info()[1] > 1:
                for b in (q.codebook, q.ema_sum, q.ema_count, q.usage):
                    dist.broadcast(b, 0)
    # the codebook (nearest code, EMA statistics) stays in float32: no autocast in this stage
    return params, StageStep(sample, compute, device, amp=False), state_fn


@torch.no_grad()
def tokenize_clips(model, data, device):
    names = model.region_names
    data.tokens = []
    for f in data.feats:
        toks = [model.svq[r].tokenize(torch.from_numpy(f[r][None]).to(device))[0].cpu().numpy() for r in names]
        data.tokens.append(np.stack(toks, -1))   # (n_tok, R)


def teacher_inputs(model, tok):
    """Shift tokens right with BOS: the input at t is x_{t-1}."""
    bos = torch.full_like(tok[:, :1], model.cfg.bos_token)
    return torch.cat([bos, tok[:, :-1]], 1)


def cfg_cond(batch, p, device):
    return (torch.rand(batch, device=device) >= p).float()


def stage_experts(model, data, tcfg, device):
    names = model.region_names
    params = list(model.audio_encoder.parameters()) + [p for r in names for p in model.experts[r].parameters()]

    def sample(step, rng):
        mel, tok = data.ar_window(rng, tcfg.ar_window_tokens, tcfg.batch_ar)
        # Table 8: p_noise ~ U(0, noise_p) per batch (an extra draw only with the option: default streams unchanged)
        p = float(rng.uniform(0, tcfg.noise_p)) if tcfg.noise_p_uniform else tcfg.noise_p
        return mel, tok, p

    def compute(step, batch):
        mel, tok, noise_p = batch
        audio = model.audio_encoder(mel).float()   # (bf16 under autocast) the eXperts take float32 inputs
        cond = cfg_cond(len(tok), tcfg.cfg_dropout, tok.device)
        losses = {}
        for i, r in enumerate(names):
            _, logits = model.experts[r](teacher_inputs(model, tok[..., i]), audio, cond,
                                         noise_sigma=tcfg.noise_sigma, noise_p=noise_p)
            losses[f"ce_{r}"] = F.cross_entropy(logits.reshape(-1, logits.shape[-1]).float(), tok[..., i].reshape(-1))
        return sum(losses.values()) / len(names), losses
    return params, StageStep(sample, compute, device), None


def stage_fuse(model, data, tcfg, device):
    names = model.region_names
    frozen = [model.audio_encoder] + [model.svq[r] for r in names] + \
        [model.experts[r] for r in names]
    for m in frozen:
        for p in m.parameters():
            p.requires_grad_(False)
    classifiers = [model.experts[r].classifier for r in names]
    for c in classifiers:
        for p in c.parameters():
            p.requires_grad_(True)
    params = [p for p in model.fuse.parameters() if p.requires_grad]
    total_steps = tcfg.steps_fuse
    R = len(names)

    def sample(step, rng):
        # every host random number of the step, in the order the step has always drawn them
        mel, tok = data.ar_window(rng, tcfg.ar_window_tokens, tcfg.batch_ar)
        B = len(tok)
        ratio_top = cosine_ramp(step, total_steps, tcfg.ugm_max_ratio)
        ratio = float(rng.uniform(0, ratio_top)) if ratio_top > 0 else 0.0
        p_top = cosine_ramp(step, total_steps, tcfg.region_drop_max) if tcfg.region_drop_ramp else tcfg.region_drop_max
        p_drop = float(rng.uniform(0, p_top)) if p_top > 0 else 0.0
        drop = rng.random(B) < p_drop
        which = rng.integers(0, R, B)
        region_mask = drop[:, None] & (np.arange(R)[None, :] == which[:, None])    # (B, R): region dropped
        return {"mel": mel, "tok": tok, "region_mask": region_mask, "ratio": ratio, "p_drop": p_drop}

    def compute(step, batch):
        mel, tok = batch["mel"], batch["tok"]
        ratio, p_drop = batch["ratio"], batch["p_drop"]                   # host numbers
        B, T, R_ = tok.shape
        dev = tok.device
        with torch.no_grad():
            audio = model.audio_encoder(mel).float()   # module inputs are float32 (bf16 outputs under autocast)
            clean_in = torch.stack([teacher_inputs(model, tok[..., i]) for i in range(R_)], -1)
            # uncertainty-guided masking: the least confident ground-truth history tokens are masked
            conf = []
            ones = torch.ones(B, device=dev)
            for i, r in enumerate(names):
                _, lg = model.experts[r](clean_in[..., i], audio, ones)
                conf.append(lg.float().log_softmax(-1).gather(-1, tok[..., i:i + 1])[..., 0])
            conf = torch.stack(conf, -1)                     # confidence of x_t, t = 0..T-1
            corrupted = clean_in.clone()
            n_mask = int(ratio * T * R_)
            # the history inputs masked (at t), for the masked-only fuse loss (no work, no host sync otherwise)
            masked = torch.zeros(B, T, R_, dtype=torch.bool, device=dev) if tcfg.fuse_loss_masked else None
            if n_mask > 0:
                # x_t is the history input at t+1
                c = conf[:, :-1].reshape(B, -1)
                idx = c.argsort(dim=1)[:, :n_mask]
                m = torch.zeros_like(c, dtype=torch.bool).scatter_(1, idx, True).reshape(B, T - 1, R_)
                corrupted[:, 1:] = torch.where(m, model.cfg.mask_token, corrupted[:, 1:])
                if masked is not None:
                    masked[:, 1:] |= m
            # random region masking: p_drop ramps up to region_drop_max (drawn with the batch)
            corrupted[:, 1:] = torch.where(batch["region_mask"][:, None, :], model.cfg.mask_token, corrupted[:, 1:])
            if masked is not None:
                masked[:, 1:] |= batch["region_mask"][:, None, :]
            cond = cfg_cond(B, tcfg.cfg_dropout, dev)
            hidden = torch.stack([model.experts[r](corrupted[..., i], audio, cond)[0].float()
                                  for i, r in enumerate(names)], 2)   # (B, T, R, d)
        local = sum(F.cross_entropy(classifiers[i](hidden[:, :, i]).reshape(-1, model.cfg.codebook_size).float(),
                                    tok[..., i].reshape(-1)) for i in range(R_)) / R_
        logits = model.fuse(hidden, audio, cond)
        if tcfg.fuse_loss_masked:     # only where the history was corrupted (none masked: no fuse loss this step)
            ce = F.cross_entropy(logits.reshape(-1, model.cfg.codebook_size).float(), tok.reshape(-1), reduction="none")
            w = masked.reshape(-1).float()
            fuse = (ce * w).sum() / w.sum().clamp(min=1.0)
        else:
            fuse = F.cross_entropy(logits.reshape(-1, model.cfg.codebook_size).float(), tok.reshape(-1))
        loss = tcfg.local_weight * local + tcfg.fuse_weight * fuse
        return loss, {"local": local, "fuse": fuse, "mask_ratio": torch.tensor(ratio), "p_drop": torch.tensor(p_drop)}
    return params, StageStep(sample, compute, device), None


BUILDERS = {"svq1": stage_svq1, "svq2": stage_svq2, "experts": stage_experts, "fuse": stage_fuse}


# ----------------------------------------------------------------------------- driver

def train(config: str, data_dir: str, out: str, stages=STAGES, device: str = "cpu", tcfg: TrainConfig | None = None,
          overrides: dict | None = None, svq_from: str | None = None, init_from: str | None = None,
          extra_data: tuple | list = (), opts: RunOptions | None = None, variant: str | None = None) -> Path:
    """Run the stages; returns ``OUT/final.pt``. ``svq_from``: reuse another checkpoint's motion tokenizer and
    train the audio-side stages from scratch. ``init_from``: FINE-TUNE another checkpoint: every weight and
    every normalisation statistic (motion and mel) is taken from it; svq1/svq2 are kept as they are and the
    experts and fuse stages continue from its weights (usually with a lower ``lr_ar``). ``extra_data``: more
    corpus folders whose train split is mixed with ``data_dir``'s. ``opts``: how to run (autocast, prefetching,
    compilation; :class:`livegesture.trainkit.RunOptions`, default: those of ``device``). ``variant``: one of
    ``livegesture.variants`` (its model fields change the config, its training fields win over ``overrides``)."""
    if svq_from and init_from:
        raise SystemExit("--svq-from and --init-from exclude each other (--init-from keeps the tokenizer too)")
    base = get_config(config)
    cfg = variants.apply(base, families.LIVEGESTURE.name, variant)
    tcfg = tcfg or TrainConfig.for_model(base.name)
    tcfg = replace(tcfg, **{**(overrides or {}), **variants.train_overrides(families.LIVEGESTURE.name, variant)})
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rank, world = dist_info()
    logger = Logger(out)
    torch.manual_seed(tcfg.seed)
    model = LiveGesture(cfg).to(device)
    roots = [data_dir, *extra_data]
    data = TrainData(roots if extra_data else data_dir, cfg, tcfg.speakers, augment=tcfg.augment, seed=tcfg.seed)
    src_model = None
    if init_from:
        src_model = ckpt.load_to_fine_tune(init_from, "livegesture", cfg, config)
        svq_from = init_from
    if svq_from:
        # reuse a trained motion tokenizer (svq1 + svq2 of another checkpoint, with its motion statistics):
        # the SVQ never sees audio, so only the stages that do (experts, fuse) are trained here
        src = ckpt.load(svq_from)
        if tuple(src.region_names) != tuple(model.region_names):
            raise SystemExit(f"--svq-from {svq_from}: its regions {list(src.region_names)} differ from this "
                             f"model's {list(model.region_names)}")
        norm = src.normalisation()
        mean = split_regions({r: np.asarray(norm[r]["mean"], np.float32) for r in model.region_names})
        std = split_regions({r: np.asarray(norm[r]["std"], np.float32) for r in model.region_names})
        data.set_stats(NormStats(mean=mean, std=std, source=f"svq of {svq_from}"))
        for r in model.region_names:
            model.svq[r].load_state_dict(src.svq[r].state_dict())
    if src_model is not None:
        # every weight, and the source's mel statistics: its audio encoder was trained on mels normalised
        # with them, so they stay (this run's data would shift them)
        model.load_state_dict(src_model.state_dict())
    else:
        stats = data.stats.to_dict()["regions"]
        stats["mel"] = {"mean": data.mel_mean.tolist(), "std": data.mel_std.tolist()}
        model.set_normalisation(stats)
    if svq_from and rank == 0:
        for name in ("svq1", "svq2"):
            if not (out / f"{name}.pt").exists():
                ckpt.save(model, out / f"{name}.pt", provenance={"svq_from": str(svq_from)},
                          extra={"final_loss": None, "reused_from": str(svq_from)})
    info = {"config": cfg.name, "variant": cfg.variant, "train_config": asdict(tcfg), "data": str(Path(data_dir).resolve()),
            "train_clips": len(data.clips), "train_tokens": int(data.n_tok.sum()),
            "train_minutes": round(float(data.n_tok.sum()) * 4 / 30 / 60, 2), "world_size": world,
            "augment": tcfg.augment,
            **({"extra_data": [str(Path(d).resolve()) for d in extra_data]} if extra_data else {}),
            **({"init_from": str(init_from)} if init_from else {"svq_from": str(svq_from)} if svq_from else {})}
    prev = None
    builders = BUILDERS
    # a variant without a stage trains it for 0 steps (one-stage SVQ: svq1; eXperts only: fuse)
    steps = {"svq1": tcfg.steps_svq1 if tcfg.svq_stages == 2 else 0, "svq2": tcfg.steps_svq2,
             "experts": tcfg.steps_experts, "fuse": tcfg.steps_fuse}
    if tcfg.svq_stages not in (1, 2):
        raise SystemExit(f"svq_stages {tcfg.svq_stages}: expected 1 or 2")
    summary = {}
    stage_log = {}   # per stage, from its own checkpoint: a run may train its stages in different sittings
    for name in STAGES:
        path = out / f"{name}.pt"
        if path.exists():
            payload = ckpt.load_payload(path)
            model.load_state_dict(payload["state_dict"])
            summary[name] = payload["extra"].get("final_loss")
            stage_log[name] = {k: payload["extra"].get(k) for k in ("lr", "steps", "seconds", "final_loss")}
            prev = name
            if rank == 0:
                print(f"[{name}] done already ({path})")
            continue
        if name not in stages:
            break
        if name in ("experts", "fuse") and data.tokens is None:
            tokenize_clips(model, data, device)
        if name == "svq2":
            init_codebooks(model, data, tcfg, device, np.random.default_rng(tcfg.seed))
        model.train()
        params, step_fn, state_fn = builders[name](model, data, tcfg, device)
        t0 = time.time()
        final = (run_stage(name, model, params, steps[name], step_fn, tcfg, out, logger, device, state_fn, opts=opts)
                 if steps[name] > 0 else None)
        summary[name] = final
        model.eval()
        for p in model.parameters():
            p.requires_grad_(True)
        if rank == 0:
            lr = tcfg.lr_svq if name.startswith("svq") else tcfg.lr_ar
            extra = {"final_loss": final, "seconds": round(time.time() - t0, 1), "lr": lr, "steps": steps[name]}
            stage_log[name] = {k: extra[k] for k in ("lr", "steps", "seconds", "final_loss")}
            ckpt.save(model, path, provenance={**info, "stages_done": STAGES[:STAGES.index(name) + 1]},
                      extra=extra)
            print(f"[{name}] " + (f"final loss {final:.4f}" if final is not None else "not trained (0 steps)")
                  + f" in {time.time() - t0:.0f}s -> {path}")
        prev = name
    if all((out / f"{s}.pt").exists() for s in STAGES) and rank == 0:
        if data.tokens is None:
            tokenize_clips(model, data, device)
        usage = {r: int(len(np.unique(np.concatenate([t[:, i] for t in data.tokens]))))
                 for i, r in enumerate(model.region_names)}
        prov = {**info, "stages_done": list(STAGES), "final_losses": summary, "stages": stage_log,
                "codebook_usage_train": usage,
                "training_data": f"{info['train_minutes']} minutes, {len(data.clips)} clips of "
                                 f"{' + '.join(Path(d).name for d in roots)}"}
        ckpt.save(model, out / "final.pt", provenance=prov)
        print(f"done: {out / 'final.pt'}")
    return out / "final.pt"


def train_from_args(args, device, opts, speakers):
    """``python -m livegesture.train`` for a LiveGesture model (the family registry's trainer)."""
    ov = {k: getattr(args, k) for k in ("steps_svq1", "steps_svq2", "steps_experts", "steps_fuse", "batch_svq",
                                          "batch_ar", "seed", "lr_svq", "lr_ar", "augment")
          if getattr(args, k) is not None}
    ov["speakers"] = speakers
    stages = STAGES if args.stage == "all" else STAGES[:STAGES.index(args.stage) + 1]
    return train(args.config, args.data, args.out, stages=stages, device=device, overrides=ov, svq_from=args.svq_from,
                 init_from=args.init_from, extra_data=args.extra_data, opts=opts, variant=args.variant)


def add_run_arguments(ap):
    """The options of how a training runs (both families)."""
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu",
                    help="cpu or cuda (under torchrun: one GPU per process, cuda:LOCAL_RANK)")
    ap.add_argument("--amp", choices=("bf16", "off"), default=None,
                    help="bf16 autocast with float32 weights (default on CUDA: bf16; on CPU: off)")
    ap.add_argument("--prefetch", type=int, default=None,
                    help="batches prepared ahead on a background thread, pinned for the GPU (default: 4 on CUDA, "
                         "0 on CPU; the batches are the same either way)")
    ap.add_argument("--compile", action="store_true", help="torch.compile the training step's computation")
    ap.add_argument("--threads", type=int, default=1,
                    help="CPU threads for torch (default 1: on a shared machine more threads can be far slower)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--family", default=families.DEFAULT.name, choices=families.NAMES,
                    help="model family (diffsheg: livegesture.diffsheg.train, one stage)")
    ap.add_argument("--config", default="default", help="model config: tiny, default or paper")
    ap.add_argument("--variant", default=None,
                    help="a variant of the family's model (livegesture.variants; --list-variants names them)")
    ap.add_argument("--list-variants", action="store_true",
                    help="print the family's variant names, one a line, and exit")
    ap.add_argument("--data", required=("--list-variants" not in (argv if argv is not None else sys.argv)), help="BEAT2-layout corpus (real BEAT2 or livegesture.data.synth output)")
    ap.add_argument("--out", required=("--list-variants" not in (argv if argv is not None else sys.argv)),
                    help="run folder (checkpoints, train_log.jsonl)")
    ap.add_argument("--stage", default="all", choices=("all",) + STAGES,
                    help="run the stages up to and including this one (earlier finished stages are reused)")
    add_run_arguments(ap)
    ap.add_argument("--speakers", default="2", help="comma-separated speaker numbers, or 'all' (BEAT2 benchmark: 2)")
    for f in ("steps_svq1", "steps_svq2", "steps_experts", "steps_fuse", "batch_svq", "batch_ar", "seed", "augment"):
        ap.add_argument("--" + f.replace("_", "-"), type=int, default=None)
    for f in ("lr_svq", "lr_ar"):
        ap.add_argument("--" + f.replace("_", "-"), type=float, default=None)
    ap.add_argument("--svq-from", help="take svq1/svq2 (the motion tokenizer and its motion statistics) from this "
                                       "checkpoint instead of training them; experts and fuse are trained")
    ap.add_argument("--init-from", help="fine-tune this trained checkpoint of the same family and config: all its "
                                        "weights and statistics are loaded, with a fresh optimiser. LiveGesture: "
                                        "svq1/svq2 kept, experts and fuse continue from its weights (use a lower "
                                        "--lr-ar); DiffSHEG: normalisation and style ids kept")
    ap.add_argument("--extra-data", action="append", default=[],
                    help="another corpus folder whose train split is mixed in (repeatable)")
    ap.add_argument("--steps", type=int, default=None, help="diffsheg: training steps")
    ap.add_argument("--batch", type=int, default=None, help="diffsheg: batch size (windows)")
    ap.add_argument("--lr", type=float, default=None, help="diffsheg: learning rate")
    ap.add_argument("--max-minutes", type=float, default=None, help="diffsheg: stop after this training time")
    args = ap.parse_args(argv)
    fam = families.get(args.family)
    if args.list_variants:
        print("\n".join(fam.variants()))
        return 0
    if args.variant is not None and args.variant not in fam.variants():
        ap.error(f"--variant {args.variant}: not a {fam.title} variant; choose one of {', '.join(fam.variants())}")
    if args.threads:
        torch.set_num_threads(args.threads)
    device = init_distributed(args.device)       # torchrun: one process per GPU (or gloo on CPU)
    opts = RunOptions.for_device(device, amp=args.amp, prefetch=args.prefetch, compile=args.compile)
    speakers = None if args.speakers == "all" else tuple(int(s) for s in args.speakers.split(","))
    try:
        fam.resolve(fam.trainer)(args, device, opts, speakers)
    finally:
        finish_distributed()
    return 0


if __name__ == "__main__":
    sys.exit(main())

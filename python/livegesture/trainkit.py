"""What the trainers of both model families share (``livegesture.train``, ``livegesture.diffsheg.train``).

- the training corpus in memory (:class:`TrainData`) and the loss log (:class:`Logger`);
- data parallelism over processes (``torchrun``): :func:`init_distributed` (one GPU per process, NCCL on CUDA,
  gloo on CPU), :func:`sync_grads` (one flattened all-reduce of the gradients);
- running on a GPU without waiting for it (:class:`RunOptions`): batches drawn on the host ahead of time by a
  background thread (:class:`Prefetcher`; the same random numbers in the same order as drawn inline, so the
  results do not depend on it), pinned host memory and asynchronous copies (:func:`to_device`), bf16
  autocast (:meth:`RunOptions.autocast`; float32 master weights), optional ``torch.compile``, and no host
  synchronisation per step (:class:`LossTrack` keeps the running loss on the device; values are read at
  logging intervals only).
"""
from __future__ import annotations

import contextlib
import json
import os
import queue
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from tqdm import tqdm

from .data.beat2 import get_corpus


# ----------------------------------------------------------------------------- devices and run options

@dataclass
class RunOptions:
    """How a training runs (not what it learns). ``amp``: "bf16" (autocast to bfloat16 on CUDA, float32 weights
    and optimiser) or "off"; ``prefetch``: batches prepared ahead on a background thread (0: on the training
    thread); ``compile``: ``torch.compile`` the step's computation."""
    device: str = "cpu"
    amp: str = "off"
    prefetch: int = 0
    compile: bool = False

    @staticmethod
    def for_device(device: str, amp: str | None = None, prefetch: int | None = None,
                   compile: bool = False) -> "RunOptions":
        """Defaults: on CUDA bf16 autocast and 4 batches ahead; on CPU neither (the results are the same)."""
        cuda = torch.device(device).type == "cuda"
        if amp not in (None, "bf16", "off"):
            raise SystemExit(f"--amp must be bf16 or off, got {amp!r}")
        return RunOptions(device=device, amp=amp or ("bf16" if cuda else "off"),
                          prefetch=(4 if cuda else 0) if prefetch is None else max(0, int(prefetch)),
                          compile=bool(compile))

    @property
    def cuda(self) -> bool:
        return torch.device(self.device).type == "cuda"

    @property
    def pin(self) -> bool:
        return self.cuda and torch.cuda.is_available()

    def autocast(self, enabled: bool = True):
        """bf16 autocast when ``amp == "bf16"`` (and ``enabled``), else nothing. On CUDA by default; on CPU only
        when asked for (``--amp bf16 --device cpu``: slow, but it runs the same mixed-precision code)."""
        if enabled and self.amp == "bf16":
            return torch.autocast(device_type="cuda" if self.cuda else "cpu", dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def describe(self) -> dict:
        return {"device": str(self.device), "amp": self.amp, "prefetch": self.prefetch, "compile": self.compile}


def to_device(batch, device, non_blocking: bool = False):
    """numpy arrays / tensors (nested in dicts, lists, tuples) -> tensors on ``device``."""
    if isinstance(batch, dict):
        return {k: to_device(v, device, non_blocking) for k, v in batch.items()}
    if isinstance(batch, (list, tuple)):
        return type(batch)(to_device(v, device, non_blocking) for v in batch)
    if isinstance(batch, np.ndarray):
        batch = torch.from_numpy(batch)
    if isinstance(batch, torch.Tensor):
        return batch.to(device, non_blocking=non_blocking)
    return batch


def _to_host(batch, pin: bool):
    if isinstance(batch, dict):
        return {k: _to_host(v, pin) for k, v in batch.items()}
    if isinstance(batch, (list, tuple)):
        return type(batch)(_to_host(v, pin) for v in batch)
    if isinstance(batch, np.ndarray):
        t = torch.from_numpy(np.ascontiguousarray(batch))
        return t.pin_memory() if pin else t
    return batch


class Prefetcher:
    """Host batches ``sample(step, rng)`` for ``steps`` in order, ``depth`` ahead on one background thread
    (depth 0: drawn on demand on the caller's thread). One thread and one ``rng``: the batches, and every
    random number drawn for them, are those of the inline loop. The sampler must use ``rng`` only (no torch
    random numbers: those stay on the training thread, in their order)."""

    _END = object()

    def __init__(self, sample, rng, steps, depth: int = 0, pin: bool = False):
        self.sample, self.rng, self.steps, self.depth, self.pin = sample, rng, list(steps), depth, pin
        self._stop = threading.Event()
        self._thread = None
        if depth > 0 and self.steps:
            self._q: queue.Queue = queue.Queue(maxsize=depth)
            self._thread = threading.Thread(target=self._run, name="livegesture-prefetch", daemon=True)
            self._thread.start()

    def _run(self):
        try:
            for step in self.steps:
                item = (step, _to_host(self.sample(step, self.rng), self.pin))
                while not self._stop.is_set():
                    try:
                        self._q.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if self._stop.is_set():
                    return
        except BaseException as e:   # noqa: BLE001 - handed to the training thread
            self._q.put(("error", e))
            return
        self._q.put(self._END)

    def get(self, step):
        """The batch of ``step`` (the steps are consumed in order)."""
        if self._thread is None:
            return _to_host(self.sample(step, self.rng), self.pin)
        item = self._q.get()
        if item is self._END:
            raise RuntimeError("prefetch: no more batches")
        if item[0] == "error":
            raise item[1]
        got, batch = item
        if got != step:
            raise RuntimeError(f"prefetch: batch of step {got} where {step} was expected")
        return batch

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)


class LossTrack:
    """The running mean (0.95 / 0.05) of the loss, kept on the device in float64: the same arithmetic as
    Python floats, without reading the loss back at every step."""

    def __init__(self):
        self.ema = None

    def update(self, loss: torch.Tensor):
        v = loss.detach().double()
        self.ema = v if self.ema is None else 0.95 * self.ema + 0.05 * v

    def value(self) -> float | None:
        return None if self.ema is None else float(self.ema)


def log_values(parts: dict) -> dict:
    """Loss parts (tensors or numbers) -> floats (reads them back from the device: logging steps only)."""
    return {k: float(v.detach()) if isinstance(v, torch.Tensor) else float(v) for k, v in parts.items()}


def init_distributed(device: str) -> str:
    """Under ``torchrun`` (WORLD_SIZE > 1): join the process group, one GPU per process (``LOCAL_RANK`` ->
    ``cuda:LOCAL_RANK``, NCCL) or CPU processes (gloo). Returns the device this process trains on."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1 or (dist.is_available() and dist.is_initialized()):
        return device
    if torch.device(device).type == "cuda":
        local = int(os.environ.get("LOCAL_RANK", 0))
        if not torch.cuda.is_available() or local >= torch.cuda.device_count():
            raise SystemExit(f"torchrun: process {local} needs GPU {local}, but "
                             f"{torch.cuda.device_count() if torch.cuda.is_available() else 0} GPU(s) are visible")
        device = f"cuda:{local}"
        torch.cuda.set_device(local)
        dist.init_process_group("nccl", device_id=torch.device(device))
    else:
        dist.init_process_group("gloo")
    return device


def finish_distributed():
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


# ----------------------------------------------------------------------------- distributed helpers

def dist_info():
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def all_reduce_mean_(tensors):
    rank, world = dist_info()
    if world == 1:
        return
    for t in tensors:
        dist.all_reduce(t, op=dist.ReduceOp.SUM)
        t.div_(world)


def sync_grads(params):
    """Average the gradients over the processes: one all-reduce of all of them, flattened (no-op alone)."""
    if dist_info()[1] == 1:
        return
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return
    flat = torch._utils._flatten_dense_tensors(grads)
    all_reduce_mean_([flat])
    for g, f in zip(grads, torch._utils._unflatten_dense_tensors(flat, grads)):
        g.copy_(f)


# ----------------------------------------------------------------------------- data

class TrainData:
    """Training clips in memory: normalised region features, log-mel frames, tokens (after svq2)."""

    def __init__(self, root, cfg, speakers, split="train", stats=None, augment=0, seed=0):
        # ``root``: one corpus folder, or a list of them (a mix: the ``split`` clips of every corpus, windows
        # drawn in proportion to clip length across all of them)
        roots = [root] if isinstance(root, (str, os.PathLike)) else list(root)
        if not roots:
            raise SystemExit("no training corpus given")
        self.clips, self.clip_corpus = [], []
        for r in roots:
            corpus = get_corpus(r, cfg.frontend)
            ids = corpus.ids(split, speakers)
            if not ids:
                raise SystemExit(f"{r}: no clip in split {split!r} for speakers {speakers}")
            clips = corpus.clips(ids, progress=dist_info()[0] == 0)
            self.clips += clips
            self.clip_corpus += [corpus] * len(clips)
        self.corpus = self.clip_corpus[0]
        if stats is None:
            if len(roots) == 1:
                stats = self.corpus.stats(split, speakers)
            else:
                from .data.features import RunningStats
                rs = RunningStats()
                for c in self.clips:
                    rs.update(c.features)
                stats = rs.finish()
                stats.source = f"{', '.join(Path(r).name for r in roots)}: split={split!r} clips={len(self.clips)}"
        from .regions import model_regions
        self.regions = model_regions(cfg)   # the model's regions (the full-body SVQ's: one made of the four)
        self.set_stats(stats)
        self.mel = [c.mel for c in self.clips]
        self.n_tok = np.array([c.n_tokens for c in self.clips])
        self.tokens = None
        # audio augmentation: ``augment`` channel-degraded copies of every clip's audio (noise, reverb, band
        # limits, codecs, gain, pitch; livegesture.data.augment), drawn once at load time; each training
        # window reads the clean mel or one of the copies, at random. Motion targets are unchanged (every
        # effect keeps the length and timing).
        self.mel_variants = [[m] for m in self.mel]
        if augment:
            from .data.augment import augment as augment_wave
            from .frontend import logmel
            from .regions import frame_start_sample
            fcfg = cfg.frontend
            for ci, c in enumerate(tqdm(self.clips, desc=f"augmenting x{augment}", disable=dist_info()[0] != 0)):
                x = self.clip_corpus[ci].audio(c.id)[:frame_start_sample(c.n_frames, fcfg.sample_rate, fcfg.fps)]
                for v in range(augment):
                    y = augment_wave(x, fcfg.sample_rate, np.random.default_rng([seed, ci, v]))
                    self.mel_variants[ci].append(logmel(y, fcfg))
        all_mel = np.concatenate([m for ms in self.mel_variants for m in ms])
        self.mel_mean = all_mel.mean(0)
        self.mel_std = np.maximum(all_mel.std(0), 1e-3)

    def set_stats(self, stats):
        """Normalise every clip's base-region features with ``stats`` and add the model's composite regions'
        (``livegesture.regions.compose``; a normalised composite is its normalised members side by side)."""
        from .regions import compose
        self.stats = stats
        self.feats = []
        for c in self.clips:
            f = self.stats.normalize(c.features)
            self.feats.append({**f, **compose(f, self.regions)})

    def _pick(self, rng, n_tokens, batch):
        ok = np.nonzero(self.n_tok >= n_tokens)[0]
        if len(ok) == 0:
            raise SystemExit(f"no training clip is {n_tokens} tokens long")
        w = self.n_tok[ok] - n_tokens + 1
        ci = rng.choice(ok, size=batch, p=w / w.sum())
        return [(c, int(rng.integers(0, self.n_tok[c] - n_tokens + 1))) for c in ci]

    def svq_window(self, rng, region, frames, batch) -> np.ndarray:
        """(batch, frames, dim) float32 normalised windows of one region (host memory)."""
        picks = self._pick(rng, frames // 4, batch)
        return np.stack([self.feats[c][region][4 * s:4 * s + frames] for c, s in picks])

    def svq_batch(self, rng, region, frames, batch, device):
        return torch.from_numpy(self.svq_window(rng, region, frames, batch)).to(device)

    def ar_window(self, rng, n_tokens, batch) -> tuple[np.ndarray, np.ndarray]:
        """(mel (batch, 8 n_tokens, n_mels) float32, tokens (batch, n_tokens, R) int64), host memory."""
        picks = self._pick(rng, n_tokens, batch)
        if len(self.mel_variants[0]) > 1:
            v = rng.integers(0, len(self.mel_variants[0]), size=len(picks))
            mel = np.stack([self.mel_variants[c][k][8 * s:8 * (s + n_tokens)] for (c, s), k in zip(picks, v)])
        else:
            mel = np.stack([self.mel[c][8 * s:8 * (s + n_tokens)] for c, s in picks])
        tok = np.stack([self.tokens[c][s:s + n_tokens] for c, s in picks]).astype(np.int64)   # (B, N, R)
        return mel, tok

    def ar_batch(self, rng, n_tokens, batch, device):
        mel, tok = self.ar_window(rng, n_tokens, batch)
        return torch.from_numpy(mel).to(device), torch.from_numpy(tok).to(device)


# ----------------------------------------------------------------------------- logging

class Logger:
    def __init__(self, out: Path):
        self.path = out / "train_log.jsonl"
        self.rank = dist_info()[0]

    def log(self, **kv):
        if self.rank == 0:
            with open(self.path, "a") as f:
                f.write(json.dumps(kv) + "\n")



"""The bundle's exported LiveGesture step graphs chained from Python with onnxruntime: one
``onnxruntime.InferenceSession`` per graph, every ``new_cache.*`` output fed back as the next step's ``cache.*``
input, the guided sampler of ``livegesture.sampling``, the decoders and ``livegesture.motion.features_to_motion``.

Used by ``bench/ort_python_peer.py`` (the second peer of the Rust runtime: its timings and token check) and by
``export/quantize.py`` (the reduced bundle's rollout against the f32 one). Needs onnxruntime (the ``export`` extra).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .frontend import FrontendConfig, logmel
from .motion import features_to_motion
from .sampling import SplitMix64, sample_token


class TokenMismatch(RuntimeError):
    pass


def read_wav(path: Path) -> np.ndarray:
    """16 kHz mono wav -> float32 samples as the Rust runtime reads them (int16 / 32768)."""
    from scipy.io import wavfile
    sr, x = wavfile.read(str(path))
    if sr != 16000:
        raise ValueError(f"{path}: sample rate {sr}, the peer reads 16 kHz wav files only")
    if x.dtype == np.int16:
        x = x.astype(np.float32) / 32768.0
    x = np.asarray(x, dtype=np.float32)
    return x.mean(1) if x.ndim == 2 else x


class Chain:
    """The bundle's graphs, one InferenceSession each, and the pipeline of the manifest."""

    def __init__(self, bundle: Path, threads: int = 1, denormal_as_zero: bool = False):
        import onnxruntime as ort
        self.bundle = Path(bundle)
        mpath = self.bundle / "manifest.json"
        try:
            self.manifest = json.loads(mpath.read_text())
        except (OSError, ValueError) as e:
            raise ValueError(f"{mpath}: cannot read the manifest: {e}") from e
        m = self.manifest
        self.regions = list(m["sampling"]["region_order"])
        self.bos = int(m["vocab"]["bos_token"])
        self.guidance = float(m["sampling"]["guidance"])
        self.temperature = float(m["sampling"]["temperature"])
        self.top_k = int(m["sampling"]["top_k"])
        self.frontend = FrontendConfig(**{k: m["frontend"][k] for k in FrontendConfig.__dataclass_fields__})
        # the canonical graphs, chained the way a script would (a bundle's fused eXperts form is not loaded)
        self.specs = {g["name"]: g for g in m["graphs"] if g.get("form", "canonical") == "canonical"}
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        if denormal_as_zero:
            opts.add_session_config_entry("session.set_denormal_as_zero", "1")
        self.sessions = {}
        for name, g in self.specs.items():
            self.sessions[name] = ort.InferenceSession(str(self.bundle / g["file"]), opts,
                                                       providers=["CPUExecutionProvider"])
        self.out_names = {n: [o.name for o in s.get_outputs()] for n, s in self.sessions.items()}
        self.graph_ms = {n: [] for n in self.sessions}
        self.ort_version = ort.__version__

    @property
    def guided(self) -> bool:
        return self.guidance != 1.0

    def rows(self, name: str, n: int) -> int:
        """Batch rows of a graph for n streams: experts and fusion run both guidance branches."""
        guided_graph = name.startswith("expert_") or name == "fusion"
        return 2 * n if (guided_graph and self.guided) else n

    def zero_caches(self, name: str, rows: int) -> dict[str, np.ndarray]:
        out = {}
        for c in self.specs[name]["caches"]:
            if c["init"] != "zeros":
                raise ValueError(f"manifest: graph '{name}', cache '{c['name']}': init '{c['init']}' is not supported")
            out[c["input"]] = np.zeros([rows, *c["shape"][1:]], dtype=np.dtype(c["dtype"]))
        return out

    def run(self, name: str, feed: dict, caches: dict) -> dict[str, np.ndarray]:
        """One session.run; the new caches replace the old ones in ``caches``."""
        t0 = time.perf_counter()
        res = self.sessions[name].run(None, {**feed, **caches})
        self.graph_ms[name].append((time.perf_counter() - t0) * 1e3)
        out = dict(zip(self.out_names[name], res))
        for c in self.specs[name]["caches"]:
            caches[c["input"]] = out[c["output"]]
        return out


class Streams:
    """N streams stepped together (N = 1: one stream)."""

    def __init__(self, chain: Chain, n: int, seeds: list[int], positions: list[int]):
        self.c, self.n = chain, n
        self.caches = {g: chain.zero_caches(g, chain.rows(g, n)) for g in chain.sessions}
        self.prev = np.full((n, len(chain.regions)), chain.bos, dtype=np.int64)
        self.rngs = [SplitMix64(s) for s in seeds]
        self.pos = list(positions)
        g = 2 if chain.guided else 1
        self.cond = np.concatenate([np.ones(n, np.float32), np.zeros(n, np.float32)])[: g * n]

    def reset_stream(self, i: int, seed: int):
        """Stream i leaves; a fresh one (cold start) takes its rows."""
        c = self.c
        for g, caches in self.caches.items():
            rows = [i, self.n + i] if c.rows(g, self.n) == 2 * self.n else [i]
            for v in caches.values():
                v[rows] = 0
        self.prev[i] = c.bos
        self.rngs[i] = SplitMix64(seed)
        self.pos[i] = 0

    def step(self, mel_tokens: np.ndarray) -> tuple[np.ndarray, list[dict]]:
        """One token step of every stream; mel_tokens (n, mel_frames_per_token, n_mels). Returns the tokens
        (n, regions) and each stream's frames."""
        c, n = self.c, self.n
        guided = c.guided
        audio = c.run("audio_encoder", {"mel": mel_tokens}, self.caches["audio_encoder"])["audio"]
        audio2 = np.concatenate([audio, audio]) if guided else audio
        hidden = {}
        for j, r in enumerate(c.regions):
            prev = np.concatenate([self.prev[:, j], self.prev[:, j]]) if guided else self.prev[:, j].copy()
            hidden[f"hidden_{r}"] = c.run(f"expert_{r}", {"prev_token": prev, "audio": audio2, "cond": self.cond},
                                          self.caches[f"expert_{r}"])["hidden"]
        logits = c.run("fusion", {**hidden, "audio": audio2, "cond": self.cond}, self.caches["fusion"])["logits"]
        tokens = np.empty((n, len(c.regions)), dtype=np.int64)
        for i in range(n):
            for j in range(len(c.regions)):
                tokens[i, j] = sample_token(logits[i, j], logits[n + i, j] if guided else None, self.rngs[i],
                                            c.guidance, c.temperature, c.top_k)
        feats = {}
        for j, r in enumerate(c.regions):
            feats[r] = c.run(f"decoder_{r}", {"token": tokens[:, j].copy()}, self.caches[f"decoder_{r}"])["motion"]
        frames = [features_to_motion({r: feats[r][i] for r in c.regions}) for i in range(n)]
        self.prev = tokens
        return tokens, frames


def token_mels(chain: Chain, audio: np.ndarray) -> np.ndarray:
    """(n_tokens, mel_frames_per_token, n_mels): the log-mel frames of every complete token (the offline
    frontend, identical to the streaming one: docs/streaming.md chunk-size invariance)."""
    f = chain.frontend
    mel = logmel(audio, f)
    return mel.reshape(-1, f.mel_frames_per_token, f.n_mels)


def reference(chain: Chain) -> tuple[np.ndarray, int, np.ndarray]:
    """The reference rollout's audio, seed and tokens."""
    ref = chain.manifest.get("reference", {})
    rpath = chain.bundle / ref.get("rollout", "reference/rollout.npz")
    try:
        ro = np.load(rpath)
        tokens = np.asarray(ro["tokens"], dtype=np.int64)
        reps = int(ro["clip_repeats"]) if "clip_repeats" in ro.files else 1
        seed = int(ro["seed"]) if "seed" in ro.files else int(ref["rollout_seed"])
    except (OSError, KeyError, ValueError) as e:
        raise ValueError(f"{rpath}: cannot read the reference rollout: {e}") from e
    clip = read_wav(chain.bundle / ref.get("clip", "reference/clip.wav"))
    return np.tile(clip, reps), seed, tokens


def check_tokens(chain: Chain, n_tokens: int) -> dict:
    """Steps the reference rollout's audio and seed for n_tokens (at most the rollout's length) and compares
    every token with the reference. Raises TokenMismatch at the first difference."""
    audio, seed, want = reference(chain)
    mels = token_mels(chain, audio)
    n = min(n_tokens, len(want), len(mels))
    s = Streams(chain, 1, [seed], [0])
    for t in range(n):
        got, _ = s.step(mels[t][None])
        if not np.array_equal(got[0], want[t]):
            j = int(np.nonzero(got[0] != want[t])[0][0])
            raise TokenMismatch(f"{chain.bundle}: token {t}, region '{chain.regions[j]}': onnxruntime (Python) drew "
                                f"{int(got[0, j])}, the reference rollout has {int(want[t, j])} "
                                f"(tokens {got[0].tolist()} vs {want[t].tolist()})")
    return {"tokens_checked": n, "reference_tokens": int(len(want)), "seed": seed, "identical": True}

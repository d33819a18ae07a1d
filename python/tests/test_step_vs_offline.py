"""Step-by-step equals the offline causal forward for every component (docs/parity.md: max abs 1e-5),
on sequences longer than every window; cold start from zero caches is exact."""
import pytest
import torch

from helpers import scrambled_model
from livegesture.regions import REGION_NAMES

BOUND = 1e-5


def max_err(a, b):
    return (a - b).abs().max().item()


def seq_len(cfg):
    return max(cfg.history, cfg.audio_window, cfg.fuse_window) + 9


@pytest.fixture(scope="module", params=["tiny", "default"])
def model(request):
    torch.manual_seed(0)
    return scrambled_model(request.param)


def test_audio_encoder(model):
    cfg, enc = model.cfg, model.audio_encoder
    T, M = seq_len(cfg), cfg.frontend.mel_frames_per_token
    mel = torch.randn(3, M * T, cfg.frontend.n_mels) * 2 - 5
    with torch.no_grad():
        off = enc(mel)
        cache = enc.init_cache(3)
        steps = []
        for t in range(T):
            o, cache = enc.step(mel[:, M * t:M * (t + 1)], cache)
            steps.append(o["audio"])
    err = max_err(off, torch.stack(steps, 1))
    assert err <= BOUND, f"audio_encoder: audio max abs {err:.3g} > {BOUND}"


@pytest.mark.parametrize("region", REGION_NAMES)
def test_decoder(model, region):
    svq = model.svq[region]
    T = seq_len(model.cfg)
    tokens = torch.randint(0, model.cfg.codebook_size, (2, T))
    with torch.no_grad():
        off = svq.decode(tokens)
        cache = svq.init_cache(2)
        steps = []
        for t in range(T):
            o, cache = svq.step(tokens[:, t], cache)
            steps.append(o["motion"])
    err = max_err(off, torch.cat(steps, 1))
    assert err <= BOUND, f"decoder_{region}: motion max abs {err:.3g} > {BOUND}"


def expert_inputs(cfg, T, B=2):
    prev = torch.randint(0, cfg.codebook_size, (B, T))
    prev[:, 0] = cfg.bos_token
    audio = torch.randn(B, T, cfg.audio_dim)
    cond = torch.tensor([1.0, 0.0] * (B // 2) + [1.0] * (B % 2))
    return prev, audio, cond


@pytest.mark.parametrize("region", REGION_NAMES)
def test_expert(model, region):
    ex, T = model.experts[region], seq_len(model.cfg)
    prev, audio, cond = expert_inputs(model.cfg, T)
    with torch.no_grad():
        h_off, _ = ex(prev, audio, cond)
        cache = ex.init_cache(2)
        steps = []
        for t in range(T):
            o, cache = ex.step(prev[:, t], audio[:, t], cond, cache)
            steps.append(o["hidden"])
    err = max_err(h_off, torch.stack(steps, 1))
    assert err <= BOUND, f"expert_{region}: hidden max abs {err:.3g} > {BOUND}"


def test_fusion(model):
    cfg, fuse = model.cfg, model.fuse
    T, R = seq_len(cfg), len(REGION_NAMES)
    hidden = torch.randn(2, T, R, cfg.d_model)
    audio = torch.randn(2, T, cfg.audio_dim)
    cond = torch.tensor([1.0, 0.0])
    with torch.no_grad():
        off = fuse(hidden, audio, cond)
        cache = fuse.init_cache(2)
        steps = []
        for t in range(T):
            o, cache = fuse.step({r: hidden[:, t, i] for i, r in enumerate(REGION_NAMES)}, audio[:, t], cond, cache)
            steps.append(o["logits"])
    err = max_err(off, torch.stack(steps, 1))
    assert err <= BOUND, f"fusion: logits max abs {err:.3g} > {BOUND}"


def test_cold_start_ignores_unfilled_slots(model):
    """Masks come from the step counter: garbage in not-yet-filled attention slots changes nothing."""
    cfg = model.cfg
    ex = model.experts["upper"]
    prev, audio, cond = expert_inputs(cfg, 4)
    with torch.no_grad():
        c0 = ex.init_cache(2)
        cg = {k: (v if k == "step" else torch.randn_like(v) * 100) for k, v in c0.items()}
        for t in range(4):
            o0, c0 = ex.step(prev[:, t], audio[:, t], cond, c0)
            og, cg = ex.step(prev[:, t], audio[:, t], cond, cg)
            assert torch.equal(o0["hidden"], og["hidden"]), f"step {t}: unfilled cache slots leak into the output"


def test_broken_cache_update_is_detected(model):
    """The equality check can fail: a step that drops its cache update no longer matches offline."""
    ex, T = model.experts["face"], seq_len(model.cfg)
    prev, audio, cond = expert_inputs(model.cfg, T)
    with torch.no_grad():
        h_off, _ = ex(prev, audio, cond)
        cache = ex.init_cache(2)
        steps = []
        for t in range(T):
            o, new = ex.step(prev[:, t], audio[:, t], cond, cache)
            new["layer0.xattn.k"] = cache["layer0.xattn.k"]      # drop one cache update
            cache = new
            steps.append(o["hidden"])
    assert max_err(h_off, torch.stack(steps, 1)) > BOUND

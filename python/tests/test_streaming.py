"""The streaming contract (docs/streaming.md) on the reference loop."""
import numpy as np
import pytest
import torch

from helpers import scrambled_model
from livegesture.compare import assert_within, diff
from livegesture.frontend import FrontendConfig
from livegesture.regions import REGION_NAMES
from livegesture.stream import LiveGestureStream, generate_clip


def speechy(seconds, seed=0, sr=16000):
    rng = np.random.RandomState(seed)
    t = np.arange(int(seconds * sr)) / sr
    env = (np.sin(2 * np.pi * 3.1 * t) > 0.2) * (0.5 + 0.5 * np.sin(2 * np.pi * 0.7 * t))
    x = env * (np.sin(2 * np.pi * 180 * t) + 0.5 * np.sin(2 * np.pi * 360 * t)) + 0.05 * rng.randn(len(t))
    return (0.3 * x).astype(np.float32)


@pytest.fixture(scope="module")
def tiny():
    return scrambled_model("tiny", seed=3)


def test_chunk_size_invariance(tiny):
    audio = speechy(1.5)
    ref = generate_clip(tiny, audio, seed=7)
    assert ref["poses"].shape == (4 * FrontendConfig().n_tokens(len(audio)), 165)
    for chunk in (1, 160, 3200, 16000):
        out = generate_clip(tiny, audio, seed=7, chunk=chunk)
        for k in ("poses", "trans", "expressions", "tokens"):
            assert np.array_equal(out[k], ref[k]), f"chunk {chunk}: '{k}' differs from the whole-clip run"


def test_zero_look_ahead(tiny):
    """Changing only future audio changes no earlier token or frame; and later output does change."""
    cfg = FrontendConfig()
    a = speechy(3.0, seed=1)
    cut = cfg.token_end(9)                       # tokens 0..9 have all their audio before `cut`
    b = a.copy()
    b[cut:] = speechy(3.0, seed=2)[cut:] * 3
    oa, ob = generate_clip(tiny, a, seed=5), generate_clip(tiny, b, seed=5)
    assert np.array_equal(oa["tokens"][:10], ob["tokens"][:10])
    assert np.array_equal(oa["poses"][:40], ob["poses"][:40])
    assert np.array_equal(oa["trans"][:40], ob["trans"][:40])
    assert not np.array_equal(oa["poses"][40:], ob["poses"][40:]), "test is vacuous: future audio had no effect"


def test_frames_emitted_as_soon_as_token_audio_arrives(tiny):
    cfg = FrontendConfig()
    s = LiveGestureStream(tiny, seed=0)
    audio = speechy(1.0)
    end0 = cfg.token_end(0)
    assert s.push(audio[:end0 - 1]) == []
    frames = s.push(audio[end0 - 1:end0])
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert frames[1].time_s == pytest.approx(1 / 30)


def assert_same_run(a, b):
    """Two runs with the same seed and guidance: identical tokens, frames equal value for value."""
    assert np.array_equal(a["tokens"], b["tokens"])
    for k in ("poses", "trans", "expressions"):
        assert_within(a[k], b[k], 0.0, f"same seed: '{k}'")


def assert_guidance_changes(guided, unguided):
    """Guidance changes the output: other tokens, and poses that differ by more than the rollout's frame
    bound (1e-4, docs/parity.md); shapes alone prove nothing."""
    assert guided["poses"].shape == unguided["poses"].shape
    assert np.isfinite(guided["poses"]).all() and np.isfinite(unguided["poses"]).all()
    assert not np.array_equal(guided["tokens"], unguided["tokens"]), "guidance changed no token"
    assert not diff(unguided["poses"], guided["poses"]).within(1e-4), "guidance changed no pose"


def test_guidance_changes_output_and_seed_is_deterministic(tiny):
    audio = speechy(1.0)
    g = generate_clip(tiny, audio, seed=1, guidance=1.25)
    assert_same_run(g, generate_clip(tiny, audio, seed=1, guidance=1.25))
    assert not np.array_equal(g["tokens"], generate_clip(tiny, audio, seed=2, guidance=1.25)["tokens"])
    u = generate_clip(tiny, audio, seed=1, guidance=1.0)
    assert_guidance_changes(g, u)
    # the checks fail on a broken input: the same guidance twice, or a run whose frames were changed
    with pytest.raises(AssertionError, match="guidance changed no"):
        assert_guidance_changes(g, generate_clip(tiny, audio, seed=1, guidance=1.25))
    moved = {**g, "poses": g["poses"].copy()}
    moved["poses"][3, 7] += 1e-6
    with pytest.raises(AssertionError, match="same seed: 'poses'"):
        assert_same_run(g, moved)
    moved["poses"][3, 7] = np.nan
    with pytest.raises(AssertionError, match="non-finite"):
        assert_same_run(g, moved)


def periodic_errors(step_fn, period, n_steps):
    """Run n_steps with inputs of a fixed period; return the largest difference between outputs one period
    apart once every window is full. Bounded positions make the stream exactly periodic."""
    outs = []
    for t in range(n_steps):
        outs.append(step_fn(t % period))
    a = torch.stack(outs[-period:])
    b = torch.stack(outs[-2 * period:-period])
    return (a - b).abs().max().item(), a


def test_ten_thousand_steps_stay_finite_and_bounded(tiny):
    """10 000 steps of every attention component: finite, and exactly periodic under periodic input,
    so nothing inside the graphs grows with the stream length."""
    cfg = tiny.cfg
    N, P = 10_000, 7
    g = torch.Generator().manual_seed(0)
    audio = torch.randn(P, 2, cfg.audio_dim, generator=g)
    prev = torch.randint(0, cfg.codebook_size, (P, 2), generator=g)
    hid = torch.randn(P, 2, cfg.d_model, generator=g)
    cond = torch.tensor([1.0, 0.0])
    with torch.no_grad():
        ex = tiny.experts["hands"]
        c = ex.init_cache(2)

        def ex_step(i):
            nonlocal c
            o, c = ex.step(prev[i], audio[i], cond, c)
            return o["hidden"]
        err, last = periodic_errors(ex_step, P, N)
        assert torch.isfinite(last).all() and last.abs().max() < 1e3
        assert err <= 1e-5, f"expert_hands drifts after {N} steps: {err:.3g}"
        assert int(c["step"][0]) == N

        fc = tiny.fuse.init_cache(2)

        def fuse_step(i):
            nonlocal fc
            o, fc = tiny.fuse.step({r: hid[i] for r in REGION_NAMES}, audio[i], cond, fc)
            return o["logits"]
        err, last = periodic_errors(fuse_step, P, N)
        assert torch.isfinite(last).all()
        assert err <= 1e-5, f"fusion drifts after {N} steps: {err:.3g}"


def test_step_rejects_bad_shapes(tiny):
    cfg = tiny.cfg
    ex = tiny.experts["lower"]
    cache = ex.init_cache(2)
    with pytest.raises(ValueError, match=r"expert_lower: input 'audio' has shape \(2, 3\), expected \(2, 16\)"):
        ex.step(torch.zeros(2, dtype=torch.int64), torch.zeros(2, 3), torch.ones(2), cache)
    with pytest.raises(ValueError, match=r"expert_lower: input 'prev_token' has dtype torch.float32"):
        ex.step(torch.zeros(2), torch.zeros(2, cfg.audio_dim), torch.ones(2), cache)
    with pytest.raises(ValueError, match=r"expert_lower: input 'cache.layer0.xattn.k' has shape"):
        bad = dict(cache)
        bad["layer0.xattn.k"] = torch.zeros(2, 1, 1)
        ex.step(torch.zeros(2, dtype=torch.int64), torch.zeros(2, cfg.audio_dim), torch.ones(2), bad)
    with pytest.raises(ValueError, match=r"audio_encoder: input 'mel' has shape \(1, 7, 16\), expected \(B, 8, 16\)"):
        tiny.audio_encoder.step(torch.zeros(1, 7, 16), tiny.audio_encoder.init_cache(1))
    with pytest.raises(ValueError, match=r"decoder_face: input 'token' has dtype"):
        tiny.svq["face"].step(torch.zeros(1), tiny.svq["face"].init_cache(1))
    with pytest.raises(ValueError, match="NaN or Inf"):
        LiveGestureStream(tiny).push(np.array([0.0, np.nan], dtype=np.float32))


def test_finish_covers_the_whole_audio(tiny):
    """docs/output.md: the last partial token is completed with silence and cut at the audio's end, so
    ceil(duration x 30) frames come out; the same rule as the runtime's finish (runtime/tests/it/coverage.rs)."""
    cfg = FrontendConfig()
    audio = speechy(1.0, seed=4)
    for n in (1, 1000, cfg.token_end(3), cfg.token_end(3) + 1, cfg.token_end(3) - 1):
        out = generate_clip(tiny, audio[:n], seed=7, finish=True)
        assert out["poses"].shape[0] == (n * 30 + 15999) // 16000, n
        # the complete tokens are those of the plain run; finishing only appends
        plain = generate_clip(tiny, audio[:n], seed=7)
        assert np.array_equal(out["poses"][:len(plain["poses"])], plain["poses"])
    n = cfg.token_end(5) + 1
    ref = generate_clip(tiny, audio[:n], seed=7, finish=True)
    for chunk in (1, 160, 3331):
        assert np.array_equal(generate_clip(tiny, audio[:n], seed=7, chunk=chunk, finish=True)["poses"], ref["poses"])
    # the input's own rate fixes the count: 44.1 kHz input of 30 001 samples -> ceil(30001 * 30 / 44100) frames
    s = LiveGestureStream(tiny, seed=0)
    frames = s.push(audio[:30001 * 16000 // 44100])
    frames += s.finish(30001, 44100)
    assert len(frames) == (30001 * 30 + 44099) // 44100
    with pytest.raises(ValueError):
        LiveGestureStream(tiny).finish(16000, 16000)       # claims a second of audio never pushed

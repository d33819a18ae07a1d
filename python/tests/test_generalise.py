"""The generalisation check (livegesture.eval.generalise): motion that follows its audio shows positive
own-minus-other gaps; motion that does not (another clip's motion, time-reversed motion) shows none, and
the check's targets then fail."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from livegesture.data import real_speech, synth, synth_speech
from livegesture.eval import generalise as G
from livegesture.regions import FPS, SAMPLE_RATE


def speechlike(seed: int, seconds: float, sr: int = SAMPLE_RATE) -> np.ndarray:
    """Syllable trains: harmonic + noise bursts with Hann envelopes, short gaps and longer pauses."""
    rng = np.random.default_rng(seed)
    n = int(seconds * sr)
    x = np.zeros(n)
    pos = int(0.3 * sr)
    while pos < n - int(0.6 * sr):
        d = int(rng.uniform(0.1, 0.3) * sr)
        t = np.arange(d) / sr
        f0 = rng.uniform(100, 220)
        s = sum(np.sin(2 * np.pi * f0 * h * t + rng.uniform(0, 6)) / h for h in range(1, 8))
        s = s + 0.3 * rng.normal(size=d)
        x[pos:pos + d] += rng.uniform(0.2, 0.9) * np.hanning(d) * s / 3
        pos += d + int(rng.uniform(0.03, 0.15) * sr)
        if rng.random() < 0.15:
            pos += int(rng.uniform(0.4, 1.0) * sr)
    x += rng.normal(0, 1e-3, n)
    return np.clip(x, -1, 1)


def follow(audio: np.ndarray, seed: int) -> dict:
    """Motion computed from the audio by the synthetic corpus generator's motion model."""
    return G.reference_real_motion(audio, seed)


@pytest.fixture(scope="module")
def clips():
    audios = [speechlike(100 + i, 8.0) for i in range(6)]
    motions = [follow(a, i) for i, a in enumerate(audios)]
    return [f"c{i}" for i in range(6)], audios, motions


def test_envelope_and_pearson():
    a = speechlike(1, 3.0)
    env = G.speech_envelope(a)
    assert env.shape == (len(a) * FPS // SAMPLE_RATE,)
    assert 0.0 <= env.min() and env.max() <= 1.0 and env.std() > 0.1
    assert G.pearson(env, env) == pytest.approx(1.0)
    assert G.pearson(env, -env) == pytest.approx(-1.0)
    assert G.pearson(env, np.ones_like(env)) == 0.0
    with pytest.raises(ValueError):
        G.derangement(1)
    assert G.derangement(3) == [1, 2, 0]
    lo, hi = G.bootstrap_ci([0.1, 0.2, 0.3, 0.4], n_boot=500)
    assert 0.1 <= lo < 0.25 < hi <= 0.4


def test_following_motion_passes(clips):
    ids, audios, motions = clips
    r = G.evaluate_set(ids, [[m] for m in motions], audios, n_boot=500)
    s = r["summary"]
    assert s["jaw_env"]["gap"] > 0.6 and s["jaw_env"]["gap_ci95"][0] > 0.3
    assert s["speed_env"]["gap"] > 0.15
    assert s["bc"]["wins"] > 0.5 and s["bc"]["gap"] > 0
    assert G.targets_met(r)["all"]
    assert len(r["per_clip"]) == 6 and r["per_clip"][0]["other_audio"] == "c1"


@pytest.mark.parametrize("broken", ["other_clip", "reversed"])
def test_motion_that_ignores_its_audio_fails(clips, broken):
    ids, audios, motions = clips
    if broken == "other_clip":   # clip i's motion is that of clip i+3: neither its own nor the mismatched audio
        bad = [motions[(i + 3) % 6] for i in range(6)]
    else:
        bad = [{k: v[::-1].copy() for k, v in m.items()} for m in motions]
    r = G.evaluate_set(ids, [[m] for m in bad], audios, n_boot=500)
    s = r["summary"]
    assert abs(s["jaw_env"]["gap"]) < 0.3
    assert abs(s["speed_env"]["gap"]) < 0.15
    assert not G.targets_met(r)["all"]


def test_cli_real_split_any_rate_and_generated_folders(tmp_path, clips):
    """The real set is read from a folder at 22.05/24 kHz, stereo and float WAVs (resampled to 16 kHz
    mono); generated folders are scored; --require-targets passes for following motion, fails for
    another clip's motion."""
    from scipy.io import wavfile
    from scipy.signal import resample_poly
    from livegesture.motion import beat2_npz_dict

    rs = tmp_path / "real"
    rs.mkdir()
    good, bad = tmp_path / "good", tmp_path / "bad"
    good.mkdir()
    bad.mkdir()
    ids = sorted(real_speech.VALIDATION)
    audio16 = {}
    for k, cid in enumerate(ids):
        a = speechlike(200 + k, 5.0)
        if k % 3 == 0:    # 24 kHz int16 stereo
            a24 = resample_poly(a, 3, 2)
            wavfile.write(rs / f"{cid}.wav", 24000, (np.stack([a24, a24], 1) * 20000).astype(np.int16))
        elif k % 3 == 1:  # 22.05 kHz float32
            wavfile.write(rs / f"{cid}.wav", 22050, resample_poly(a, 441, 320).astype(np.float32))
        else:
            wavfile.write(rs / f"{cid}.wav", 16000, (a * 20000).astype(np.int16))
    loaded_ids, loaded = G.real_set(rs)
    assert loaded_ids == ids
    for cid, x in zip(loaded_ids, loaded):
        audio16[cid] = x
        assert abs(len(x) - 5 * SAMPLE_RATE) <= 80
    for k, cid in enumerate(ids):
        np.savez(good / f"{cid}.npz", **beat2_npz_dict(follow(audio16[cid], k)))
        np.savez(bad / f"{cid}.npz", **beat2_npz_dict(follow(audio16[ids[(k + 4) % len(ids)]], k)))
    out = tmp_path / "rep.json"
    assert G.main(["--real-speech", str(rs), "--generated-real", str(good), "--out", str(out),
                   "--bootstrap", "200", "--require-targets"]) == 0
    rep = json.loads(out.read_text())
    assert rep["targets_real_model"]["all"] is True
    assert rep["real"]["model"]["summary"]["jaw_env"]["gap"] > 0.6
    assert out.with_suffix(".txt").exists()
    ms = rep["real"]["motion_swap"]["model"]
    assert ms["design"] == "motion_swap" and ms["summary"]["jaw_env"]["gap"] > 0.6
    assert rep["targets_real_model_motion_swap"]["all"] is True and rep["targets_design"] == "audio_swap"
    assert len(rep["real"]["onset_power"]["reference"]["per_clip"]) == len(ids)
    assert "motion swap" in out.with_suffix(".txt").read_text()
    assert G.main(["--real-speech", str(rs), "--generated-real", str(bad), "--bootstrap", "200",
                   "--require-targets"]) == 1
    assert G.main(["--real-speech", str(rs), "--generated-real", str(good), "--bootstrap", "200",
                   "--require-targets", "--targets-design", "motion_swap"]) == 0
    assert G.main(["--real-speech", str(rs), "--generated-real", str(bad), "--bootstrap", "200",
                   "--require-targets", "--targets-design", "motion_swap"]) == 1
    (good / f"{ids[0]}.npz").unlink()
    with pytest.raises(SystemExit, match="missing generated motion"):
        G.main(["--real-speech", str(rs), "--generated-real", str(good)])
    with pytest.raises(SystemExit, match="no motion for the real set"):
        G.main(["--real-speech", str(rs)])


def test_corpus_real_train_clips_and_extra_voices(tmp_path):
    """The corpus generator adds the real-speech TRAIN split (each channel of a stereo file separately,
    variants pitch/tempo-changed, motion from the audio) and never a VALIDATION recording."""
    import shutil
    from scipy.io import wavfile
    from livegesture.data.beat2 import read_split_csv, load_motion, load_audio

    rs = tmp_path / "real"
    rs.mkdir()
    for k, cid in enumerate(real_speech.TRAIN + real_speech.VALIDATION):
        a = speechlike(300 + k, 2.5)
        data = np.stack([a, a[::-1]], 1) if cid == "librispeech_stereo_2utt" else a
        wavfile.write(rs / f"{cid}.wav", 16000, (data * 20000).astype(np.int16))
    plans = synth.plan_real_clips(rs, 2, 5, 100)
    assert {Path(p.source).stem for p in plans} == set(real_speech.TRAIN)
    assert len(plans) == 2 * (len(real_speech.TRAIN) + 1)          # the stereo file gives two clips
    assert len({p.id for p in plans}) == len(plans) and all(p.split == "train" for p in plans)
    engines = ((synth_speech.ESPEAK, synth_speech.FLITE) if shutil.which(synth_speech.FLITE)
               else (synth_speech.ESPEAK,))
    out = tmp_path / "corpus"
    plans = synth.generate_corpus(out, minutes=0.15, seed=5, clip_seconds=(4.0, 5.0), progress=False,
                                  engines=engines, real_train=rs, real_variants=2)
    table = read_split_csv(out / "train_test_split.csv")
    real = [p for p in plans if p.source]
    assert all(table[p.id] == "train" for p in real)
    for p in real:
        m = load_motion(out / "smplxflame_30" / f"{p.id}.npz")
        x = load_audio(out / "wave16k" / f"{p.id}.wav")
        assert len(m["poses"]) == len(x) * FPS // SAMPLE_RATE
        if p.variant == 0 and p.channel is None:
            src = load_audio(p.source)
            assert np.abs(x - src).max() < 1e-3                    # as recorded
    with pytest.raises(ValueError, match="engines"):
        synth.generate_corpus(tmp_path / "x", minutes=0.1, seed=1, engines=("festival",))


# ----------------------------------------------------------------------------- the two mismatch designs, BC power

def bursts(seed: int, seconds: float, rate: float, sr: int = SAMPLE_RATE) -> np.ndarray:
    """Syllable-like bursts (80 ms, harmonic, Hann envelope), ``rate`` per second, each interval 1/rate
    +-30 % at random (at least 0.15 s): an onset track of a chosen density."""
    rng = np.random.default_rng(seed)
    n = int(seconds * sr)
    x = rng.normal(0, 1e-3, n)
    t = 0.2 + rng.uniform(0, 1 / rate)
    d = int(0.08 * sr)
    while t < seconds - 0.3:
        p = int(t * sr)
        tt = np.arange(d) / sr
        f0 = rng.uniform(110, 200)
        x[p:p + d] += 0.5 * np.hanning(d) * sum(np.sin(2 * np.pi * f0 * h * tt) / h for h in range(1, 6))
        t += max(0.15, rng.uniform(0.7, 1.3) / rate)
    return np.clip(x, -1, 1)


def test_chance_bc_and_shifted_bc():
    W = 300                                          # 10 s at 30 fps, 0.5 s trimmed at each end
    assert G.bc_window(W) == (15, 285)
    assert G.chance_bc(np.arange(0, 10, 0.1), W) > 0.99           # onsets every 0.1 s: any beat is on one
    assert G.chance_bc(np.zeros(0), W) == 0.0
    one = G.chance_bc(np.array([5.0]), W)                          # one onset in a 9 s window
    assert one == pytest.approx(np.sqrt(2 * np.pi) * 0.3 / 9.0, rel=0.02)
    assert math.isnan(G.chance_bc(np.array([1.0]), 31))            # shorter than the trims
    sparse, dense = bursts(1, 10, 0.5), bursts(2, 10, 5.0)
    ca_s, ca_d = G.ClipAudio(sparse), G.ClipAudio(dense)
    assert 0.1 < len(ca_s.onsets) / 10 < 1.2 and len(ca_d.onsets) / 10 > 3
    assert G.chance_bc(ca_d.onsets, W) > G.chance_bc(ca_s.onsets, W) + 0.3
    m = G.ClipMotion(follow(speechlike(3, 10.0), 0))
    sh = G.shifted_bc(m, ca_d)
    assert abs(sh - G.chance_bc(ca_d.onsets, W)) < 0.1             # at chance alignment, BC ~ its chance level


@pytest.fixture(scope="module")
def density_clips():
    """Five 10 s clips whose onset density falls from 5/s to 0.4/s, and motion made from UNRELATED audio."""
    rates = [5.0, 3.0, 1.5, 0.8, 0.4]
    audios = [bursts(40 + i, 10.0, r) for i, r in enumerate(rates)]
    unrelated = [follow(speechlike(900 + i, 10.0), i) for i in range(5)]
    return [f"d{i}" for i in range(5)], audios, unrelated


def test_audio_swap_bc_gap_is_onset_density_motion_swap_is_not(density_clips):
    """Motion that ignores its audio: with the audio swap, every clip whose partner (clip i+1) has sparser
    onsets shows a BC gap - 4 of 5 clips "win", the BC target passes - and the per-clip gap is the chance
    gap; with the motion swap the onsets are the same on both sides and the BC gaps vanish."""
    ids, audios, motions = density_clips
    ca = [G.ClipAudio(a) for a in audios]
    cm = [[G.ClipMotion(m)] for m in motions]
    a = G.evaluate_set(ids, cm, ca, n_boot=300, design="audio_swap")
    m = G.evaluate_set(ids, cm, ca, n_boot=300, design="motion_swap")
    gaps_a = np.array([r["bc"]["gap"] for r in a["per_clip"]])
    gaps_m = np.array([r["bc"]["gap"] for r in m["per_clip"]])
    assert (gaps_a[:4] > 0.02).all() and gaps_a[4] < -0.3           # spurious: density ordering decides
    assert G.targets_met(a)["bc_gap_positive_on_most_clips"]
    assert np.abs(gaps_m).max() < 0.08 and abs(m["summary"]["bc"]["gap"]) < 0.03
    p = G.onset_power(ids, cm, ca, a, m)
    assert p["summary"]["gap_vs_chance_gap_r"] > 0.9
    assert 0.7 < p["summary"]["gap_vs_chance_gap_slope"] < 1.3
    rates = [r["onsets_per_s"] for r in p["per_clip"]]
    assert rates == sorted(rates, reverse=True)
    for s in (a["summary"], m["summary"]):                          # the envelope measures ignore density
        assert abs(s["jaw_env"]["gap"]) < 0.3 and abs(s["speed_env"]["gap"]) < 0.2


def test_motion_swap_following_and_ignoring(clips):
    ids, audios, motions = clips
    r = G.evaluate_set(ids, [[mo] for mo in motions], audios, n_boot=500, design="motion_swap")
    s = r["summary"]
    assert r["design"] == "motion_swap" and r["per_clip"][0]["other_motions"] == 5
    assert s["jaw_env"]["gap"] > 0.6 and s["jaw_env"]["wins"] == 1.0
    assert s["speed_env"]["gap"] > 0.15
    assert s["bc"]["gap"] > 0 and s["bc"]["wins"] > 0.5
    assert G.targets_met(r)["all"]
    unrelated = [follow(speechlike(700 + i, 8.0), i) for i in range(6)]
    rev = [{k: v[::-1].copy() for k, v in mo.items()} for mo in motions]
    for bad in (unrelated, rev):
        s = G.evaluate_set(ids, [[mo] for mo in bad], audios, n_boot=500, design="motion_swap")["summary"]
        assert abs(s["jaw_env"]["gap"]) < 0.2 and abs(s["speed_env"]["gap"]) < 0.15 and abs(s["bc"]["gap"]) < 0.05
    with pytest.raises(ValueError, match="unknown design"):
        G.evaluate_set(ids, [[mo] for mo in motions], audios, design="shuffle")

"""The generalisation check (livegesture.eval.generalise): motion that follows its audio shows positive
own-minus-other gaps; motion that does not (another clip's motion, time-reversed motion) shows none, and
the check's targets then fail."""
import json

import numpy as np
import pytest

from livegesture.data import real_speech, synth
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
    assert G.main(["--real-speech", str(rs), "--generated-real", str(bad), "--bootstrap", "200",
                   "--require-targets"]) == 1
    (good / f"{ids[0]}.npz").unlink()
    with pytest.raises(SystemExit, match="missing generated motion"):
        G.main(["--real-speech", str(rs), "--generated-real", str(good)])
    with pytest.raises(SystemExit, match="no motion for the real set"):
        G.main(["--real-speech", str(rs)])

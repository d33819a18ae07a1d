"""livegesture.data.augment: deterministic per rng, length-preserving (unless tempo), each effect does what
it says (band limits remove energy above the band, noise reaches its SNR, pitch moves the pitch, tempo
changes the length)."""
import numpy as np
import pytest

from livegesture.data import augment as A

SR = 16000


def tone_speech(seconds=2.0, f0=150.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * SR)) / SR
    x = sum(np.sin(2 * np.pi * f0 * h * t) / h for h in range(1, 30))
    env = (np.sin(2 * np.pi * 3 * t) > 0).astype(float)       # 3 Hz syllables
    return 0.3 * x * env / 3 + 1e-4 * rng.normal(size=len(t))


def band_energy(x, lo, hi):
    f = np.fft.rfftfreq(len(x), 1 / SR)
    p = np.abs(np.fft.rfft(x)) ** 2
    return p[(f >= lo) & (f < hi)].sum() / p.sum()


def f0_estimate(x):
    seg = x[: 4096] * np.hanning(4096)
    r = np.correlate(seg, seg, "full")[4095:]
    lo, hi = SR // 400, SR // 60
    return SR / (lo + np.argmax(r[lo:hi]))


def test_deterministic_and_length():
    x = tone_speech()
    for seed in range(8):
        y1, log1 = A.augment(x, SR, np.random.default_rng(seed), return_log=True)
        y2 = A.augment(x, SR, np.random.default_rng(seed))
        assert np.array_equal(y1, y2)
        assert y1.shape == x.shape and y1.dtype == np.float32
        assert np.abs(y1).max() <= 1.0 and np.isfinite(y1).all()
    outs = [A.augment(x, SR, np.random.default_rng(s)) for s in range(4)]
    assert not np.array_equal(outs[0], outs[1])


def test_every_effect_is_drawn():
    x = tone_speech(1.0)
    seen = set()
    for s in range(60):
        _, log = A.augment(x, SR, np.random.default_rng(s), tempo=True, return_log=True)
        seen |= {e[0] for e in log}
    assert seen == set(A.EFFECTS)


def test_telephone_band_removes_high_and_low():
    x = tone_speech()
    hi0, lo0 = band_energy(x, 3800, 8000), band_energy(x, 0, 200)
    assert hi0 > 1e-3 and lo0 > 0.1
    y = A.band_limit(x, SR, np.random.default_rng(0), "telephone")
    assert len(y) == len(x)
    assert band_energy(y, 3800, 8000) < hi0 / 100
    assert band_energy(y, 0, 200) < lo0 / 3
    with pytest.raises(ValueError, match="unknown kind"):
        A.band_limit(x, SR, np.random.default_rng(0), "radio")


@pytest.mark.parametrize("snr", [0.0, 10.0, 20.0])
def test_noise_snr(snr):
    x = tone_speech()
    y = A.add_noise(x, SR, np.random.default_rng(1), snr, "white")
    n = y - x
    measured = 10 * np.log10(A._active_power(x, SR) / np.mean(n * n))
    assert abs(measured - snr) < 0.5


def test_pitch_shift_keeps_length_and_moves_pitch():
    x = tone_speech(f0=150.0)
    x = np.sin(2 * np.pi * 150 * np.arange(len(x)) / SR)
    y = A.pitch_shift(x, 4.0, SR)
    assert len(y) == len(x)
    assert f0_estimate(x) == pytest.approx(150, rel=0.03)
    assert f0_estimate(y) == pytest.approx(150 * 2 ** (4 / 12), rel=0.04)


def test_time_stretch_changes_length_keeps_pitch():
    x = np.sin(2 * np.pi * 200 * np.arange(SR) / SR)
    y = A.time_stretch(x, 1.25, SR)
    assert len(y) == int(round(SR / 1.25))
    assert f0_estimate(y) == pytest.approx(200, rel=0.03)


def test_codecs_and_reverb_change_the_wave():
    x = tone_speech()
    rng = np.random.default_rng(3)
    for k in ("mulaw", "pcm", "transform"):
        y = A.codec(x, SR, rng, k)
        assert len(y) == len(x)
        assert 0 < np.mean((y - x) ** 2) < np.mean(x ** 2)
    y = A.reverb(x, SR, rng, rt60=0.6, wet=1.0)
    gap = (np.sin(2 * np.pi * 3 * np.arange(len(x)) / SR) <= 0)     # the silent half-periods
    assert np.mean(y[gap] ** 2) > 100 * np.mean(x[gap] ** 2)         # the tail fills the pauses


def test_bad_input():
    with pytest.raises(ValueError, match="non-empty 1-D"):
        A.augment(np.zeros(0), SR, np.random.default_rng(0))
    with pytest.raises(ValueError, match="NaN"):
        A.augment(np.array([0.0, np.nan]), SR, np.random.default_rng(0))

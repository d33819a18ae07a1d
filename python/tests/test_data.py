"""BEAT2 loader on a generated tree and on broken trees; synthetic corpus determinism and audio-driven
motion; region features round trip; foot contact. The corpus tests need espeak-ng (apt-get install -y espeak-ng)."""
import hashlib
import shutil

import numpy as np
import pytest

from livegesture.data.beat2 import Beat2Corpus, Beat2Error, Beat2Windows
from livegesture.data.features import features_to_motion, foot_contact, motion_to_features
from livegesture.data.synth import generate_corpus, onset_times
from livegesture.eval.metrics import beat_constancy_from_motion
from livegesture.frontend import FrontendConfig
from livegesture.regions import REGIONS


def test_loader_reads_the_generated_tree(tiny_corpus):
    corpus = Beat2Corpus(tiny_corpus)
    ids = corpus.ids()
    assert ids and set(corpus.split_table.values()) <= {"train", "val", "test", "additional"}
    stats = corpus.stats("train", None)
    for r in REGIONS:
        assert stats.mean[r.name].shape == (r.dim,) and np.isfinite(stats.std[r.name]).all()
        assert (stats.std[r.name] > 0).all()
    ds = Beat2Windows(tiny_corpus, split="train", speakers=None, n_tokens=8, stride=4, stats=stats,
                      return_audio=True)
    assert len(ds) > 0
    item = ds[0]
    n_mels = FrontendConfig().n_mels
    assert tuple(item["mel"].shape) == (64, n_mels)                   # 8 mel frames per token
    for r in REGIONS:
        assert tuple(item["motion"][r.name].shape) == (32, r.dim)      # 4 frames per token
        assert item["motion"][r.name].dtype.is_floating_point
    cfg = FrontendConfig()
    s = item["start"]
    assert len(item["audio"]) == cfg.token_end(s + 7) - (4 * s * 16000 // 30) or \
        len(item["audio"]) == (4 * (s + 8)) * 16000 // 30 - (4 * s) * 16000 // 30


def test_speaker_two_benchmark_split(tiny_corpus):
    corpus = Beat2Corpus(tiny_corpus)
    for i in corpus.ids(speakers=2):
        assert i.startswith("2_")
    assert set(corpus.ids("test", 2)) <= set(corpus.ids(speakers=2))


def _copy(src, dst):
    shutil.copytree(src, dst)
    return dst


def test_missing_wav_is_named(tiny_corpus, tmp_path):
    root = _copy(tiny_corpus, tmp_path / "c")
    victim = Beat2Corpus(root).ids()[0]
    (root / "wave16k" / f"{victim}.wav").unlink()
    with pytest.raises(Beat2Error, match=rf"{victim}\.wav"):
        Beat2Corpus(root).clip(victim)


def test_wrong_npz_keys_are_named(tiny_corpus, tmp_path):
    root = _copy(tiny_corpus, tmp_path / "c")
    victim = Beat2Corpus(root).ids()[0]
    p = root / "smplxflame_30" / f"{victim}.npz"
    d = dict(np.load(p))
    d["pose"] = d.pop("poses")
    np.savez(p, **d)
    with pytest.raises(Beat2Error, match=rf"{victim}\.npz.*poses"):
        Beat2Corpus(root).clip(victim)


def test_frame_count_mismatch_is_named(tiny_corpus, tmp_path):
    root = _copy(tiny_corpus, tmp_path / "c")
    victim = Beat2Corpus(root).ids()[0]
    p = root / "smplxflame_30" / f"{victim}.npz"
    d = dict(np.load(p))
    d["trans"] = d["trans"][:-5]
    np.savez(p, **d)
    with pytest.raises(Beat2Error, match=rf"{victim}\.npz"):
        Beat2Corpus(root).clip(victim)


def test_bad_csv_is_named(tiny_corpus, tmp_path):
    root = _copy(tiny_corpus, tmp_path / "c")
    (root / "train_test_split.csv").write_text("name,kind\nx,train\n")
    with pytest.raises(Beat2Error, match="train_test_split.csv"):
        Beat2Corpus(root)


def test_corpus_is_deterministic_for_a_seed(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for d in (a, b):
        generate_corpus(d, minutes=0.2, seed=11, jobs=1, clip_seconds=(6.0, 7.0), progress=False)
    ida = sorted(p.name for p in (a / "smplxflame_30").iterdir())
    assert ida == sorted(p.name for p in (b / "smplxflame_30").iterdir())
    for sub in ("smplxflame_30", "wave16k"):
        for name in sorted(p.name for p in (a / sub).iterdir()):
            ha = hashlib.sha256((a / sub / name).read_bytes()).hexdigest()
            hb = hashlib.sha256((b / sub / name).read_bytes()).hexdigest()
            assert ha == hb, f"{sub}/{name} differs between two runs with the same seed"


def test_features_round_trip(tiny_corpus):
    corpus = Beat2Corpus(tiny_corpus)
    m = corpus.motion(corpus.ids()[0])
    f = motion_to_features(m["poses"][:120], m["trans"][:120], m["expressions"][:120])
    back = features_to_motion(f)
    f2 = motion_to_features(back["poses"], back["trans"], back["expressions"])
    for r in REGIONS:
        assert np.abs(f[r.name] - f2[r.name]).max() < 1e-5, r.name


def test_foot_contact_on_hand_made_motion():
    T = 10
    poses = np.zeros((T, 165), np.float32)
    trans = np.zeros((T, 3), np.float32)
    trans[5:, 0] = np.arange(1, 6) * 0.05          # the body slides 5 cm per frame from frame 5 on
    c = foot_contact(poses, trans)
    assert c.shape == (T, 4)
    assert (c[:4] == 1).all() and (c[4:9] == 0).all()


def test_synthetic_motion_follows_its_audio(tiny_corpus):
    """Beat Constancy of the corpus motion with its own audio beats that with another clip's audio."""
    corpus = Beat2Corpus(tiny_corpus)
    ids = corpus.ids()
    own, other = [], []
    for i, j in zip(ids, ids[1:] + ids[:1]):
        m, ai, aj = corpus.motion(i), corpus.audio(i), corpus.audio(j)
        n = min(len(m["poses"]), len(ai) * 30 // 16000, len(aj) * 30 // 16000)
        own.append(beat_constancy_from_motion(m["poses"][:n], m["trans"][:n], ai[:n * 16000 // 30], 16000, 30, trim_s=0.5))
        other.append(beat_constancy_from_motion(m["poses"][:n], m["trans"][:n], aj[:n * 16000 // 30], 16000, 30, trim_s=0.5))
    assert np.mean(own) > np.mean(other) + 0.02, (own, other)
    assert len(onset_times(corpus.audio(ids[0]))) > 0


# ============================================================================= detailed checks
# Layout, alignment, determinism of single clips, skeleton/feature API and exact error messages, on the
# same session corpus (conftest ``tiny_corpus``: 0.6 min, seed 3, clips of 10-14 s scaled down).

from pathlib import Path  # noqa: E402

from livegesture.data import beat2, synth, synth_motion, synth_speech  # noqa: E402
from livegesture.data.features import NormStats, region_parts  # noqa: E402
from livegesture.frontend import logmel, logmel_frames  # noqa: E402
from livegesture.regions import FOOT_JOINTS, UPPER_JOINTS, frame_start_sample  # noqa: E402
from livegesture.rotation import np_axis_angle_to_rot6d  # noqa: E402
from livegesture.skeleton import (N_JOINTS, PARENTS, forward_kinematics, forward_kinematics_torch,  # noqa: E402
                                  rest_joints)

TINY = dict(minutes=0.6, seed=3, clip_seconds=(10.0, 14.0))   # must match conftest.tiny_corpus


@pytest.fixture
def corpus_dir(tiny_corpus) -> Path:
    return Path(tiny_corpus)


def _clone(corpus_dir: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "beat"
    shutil.copytree(corpus_dir, dst)
    return dst


# ----------------------------------------------------------------------------- skeleton / features

def test_skeleton_tree_and_rest():
    assert len(PARENTS) == N_JOINTS and PARENTS[0] == -1
    assert all(0 <= PARENTS[j] < j for j in range(1, N_JOINTS))
    J = rest_joints()
    assert J[15, 1] > 1.4 and abs(J[10, 1]) < 0.1            # head up, feet near the ground
    assert J[20, 0] > 0.5 and J[21, 0] < -0.5                 # T-pose: left hand at +x
    zero = np.zeros((2, 165))
    np.testing.assert_allclose(forward_kinematics(zero, np.zeros((2, 3)))[0], J)


def test_fk_numpy_matches_torch():
    import torch
    rng = np.random.default_rng(0)
    p, t = rng.normal(0, 0.4, (5, 165)), rng.normal(0, 0.1, (5, 3))
    np.testing.assert_allclose(forward_kinematics_torch(torch.tensor(p), torch.tensor(t)).numpy(),
                               forward_kinematics(p, t), atol=1e-10)


def test_feature_layout_and_random_round_trip():
    rng = np.random.default_rng(1)
    T = 40
    poses = rng.normal(0, 0.5, (T, 165)).astype(np.float32)
    trans = rng.normal(0, 0.05, (T, 3)).astype(np.float32)
    expr = rng.normal(0, 1, (T, 100)).astype(np.float32)
    f = motion_to_features(poses, trans, expr)
    for r in REGIONS:
        assert f[r.name].shape == (T, r.dim) and f[r.name].dtype == np.float32
    up = region_parts("upper", f["upper"])["rot6d"]
    np.testing.assert_allclose(up, np_axis_angle_to_rot6d(poses.reshape(T, 55, 3)[:, list(UPPER_JOINTS)]), atol=1e-6)
    low = region_parts("lower", f["lower"])
    np.testing.assert_allclose(low["trans"], trans)
    np.testing.assert_allclose(region_parts("face", f["face"])["expressions"], expr)
    m = features_to_motion(f)
    assert m["poses"].shape == (T, 165) and m["trans"].shape == (T, 3) and m["expressions"].shape == (T, 100)
    assert np.all(m["poses"].reshape(T, 55, 3)[:, 23:25] == 0)          # eyes at rest
    f2 = motion_to_features(**m)
    for k in f:
        np.testing.assert_allclose(f2[k], f[k], atol=1e-5, err_msg=k)
    # the rotations themselves agree (axis-angle may differ by 2 pi near pi)
    keep = [j for j in range(55) if j not in (23, 24)]
    np.testing.assert_allclose(np_axis_angle_to_rot6d(m["poses"].reshape(T, 55, 3)[:, keep]),
                               np_axis_angle_to_rot6d(poses.reshape(T, 55, 3)[:, keep]), atol=1e-5)


def test_features_to_motion_subset_and_batch():
    rng = np.random.default_rng(2)
    up = np_axis_angle_to_rot6d(rng.normal(0, 0.3, (2, 7, 13, 3))).reshape(2, 7, 78)
    m = features_to_motion({"upper": up})
    assert m["poses"].shape == (2, 7, 165)
    assert np.all(m["trans"] == 0) and np.all(m["expressions"] == 0)
    with pytest.raises(ValueError, match="unknown regions"):
        features_to_motion({"arms": up})


def test_foot_contact_per_foot():
    T = 20
    poses = np.zeros((T, 165))
    trans = np.zeros((T, 3))
    trans[:10, 0] = np.arange(10) * 0.005        # slow drift: 5 mm per frame -> contact
    trans[10:, 0] = trans[9, 0] + np.arange(1, 11) * 0.03   # 3 cm per frame -> no contact
    c = foot_contact(poses, trans)
    assert c.shape == (T, 4) and c.dtype == np.float32
    assert np.all(c[:9] == 1) and np.all(c[9:] == 0)
    # bend the left knee: left ankle/foot move, the right foot stays planted
    poses = np.zeros((T, 165))
    poses[:, 4 * 3] = np.linspace(0, 1.5, T)    # left knee flexion
    c = foot_contact(poses, np.zeros((T, 3)))
    assert list(FOOT_JOINTS) == [7, 8, 10, 11]
    assert np.all(c[:, [1, 3]] == 1) and np.all(c[:, [0, 2]] == 0)
    # a single frame counts as contact; contact dims are in the lower features
    assert foot_contact(np.zeros((1, 165)), np.zeros((1, 3))).tolist() == [[1, 1, 1, 1]]
    f = motion_to_features(poses, np.zeros((T, 3)), np.zeros((T, 100)))
    np.testing.assert_array_equal(region_parts("lower", f["lower"])["contact"], c)


def test_norm_stats_json_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    feats = [{r.name: rng.normal(size=(30, r.dim)).astype(np.float32) for r in REGIONS} for _ in range(3)]
    feats[0]["lower"][:, 0] = 0.5
    from livegesture.data.features import compute_norm_stats
    st = compute_norm_stats(feats + [{k: v[:, :] * 1.0 for k, v in feats[0].items()}])
    all_up = np.concatenate([f["upper"] for f in feats] + [feats[0]["upper"]])
    np.testing.assert_allclose(st.mean["upper"], all_up.mean(0), atol=1e-5)
    np.testing.assert_allclose(st.std["upper"], all_up.std(0), atol=1e-5)
    st.save(tmp_path / "s.json")
    st2 = NormStats.load(tmp_path / "s.json")
    for k in st.mean:
        np.testing.assert_array_equal(st2.mean[k], st.mean[k])
        np.testing.assert_array_equal(st2.std[k], st.std[k])
    x = st2.denormalize(st2.normalize(feats[1]))
    np.testing.assert_allclose(x["face"], feats[1]["face"], atol=1e-5)


# ----------------------------------------------------------------------------- synthetic corpus + loader

def test_corpus_layout_and_npz_format(corpus_dir):
    assert sorted(p.name for p in corpus_dir.iterdir()) == [
        "smplxflame_30", "textgrid", "train_test_split.csv", "wave16k"]
    table = beat2.read_split_csv(corpus_dir / "train_test_split.csv")
    assert (corpus_dir / "train_test_split.csv").read_text().splitlines()[0] == "id,type"
    assert len(table) >= 8
    total = 0
    for cid in table:
        assert cid.split("_")[0].isdigit() and len(cid.split("_")) == 5
        z = np.load(corpus_dir / "smplxflame_30" / f"{cid}.npz")
        assert set(z.files) == {"betas", "poses", "trans", "expressions", "model", "gender", "mocap_frame_rate"}
        T = z["poses"].shape[0]
        assert z["poses"].shape == (T, 165) and z["poses"].dtype == np.float32
        assert z["trans"].shape == (T, 3) and z["expressions"].shape == (T, 100)
        assert z["betas"].shape == (300,)
        assert str(z["model"]) == "smplx2020" and str(z["gender"]) == "neutral"
        assert int(z["mocap_frame_rate"]) == 30
        assert np.all(z["poses"].reshape(T, 55, 3)[:, 23:25] == 0)
        from scipy.io import wavfile
        sr, a = wavfile.read(corpus_dir / "wave16k" / f"{cid}.wav")
        assert sr == 16000 and a.dtype == np.int16 and a.ndim == 1
        assert T == len(a) * 30 // 16000
        total += len(a)
        tg = (corpus_dir / "textgrid" / f"{cid}.TextGrid").read_text()
        assert tg.startswith('File type = "ooTextFile"') and 'name = "words"' in tg
    assert abs(total / 16000 - 60 * TINY["minutes"]) < 0.01   # --minutes is the total audio duration


def test_split_selection_by_split_and_speaker(corpus_dir, tmp_path):
    named = tmp_path / "beat_english_v2.0.0"
    shutil.copytree(corpus_dir, named)
    assert Beat2Corpus(tmp_path).root == named            # the parent of beat_english_v2.0.0 works too
    c = Beat2Corpus(corpus_dir)
    for split in ("train", "val", "test"):
        ids = c.ids(split, speakers=2)
        assert ids, split
        assert all(i.startswith("2_") and c.split_table[i] == split for i in ids)
    assert len(c.ids(speakers=None)) == len(c.split_table)
    assert len({beat2.speaker_of(i) for i in c.ids()}) >= 3
    assert set(c.ids("train")) >= set(c.ids("train", 2))
    with pytest.raises(ValueError, match="unknown split"):
        c.ids("training")


def test_loader_windows_aligned(corpus_dir):
    cfg = FrontendConfig()
    corpus = Beat2Corpus(corpus_dir, cfg)
    st = corpus.stats("train", (2,))
    for r in REGIONS:
        assert st.mean[r.name].shape == (r.dim,) and np.isfinite(st.mean[r.name]).all()
        assert np.isfinite(st.std[r.name]).all() and (st.std[r.name] >= 1e-3 - 1e-9).all()
    N = 8
    ds = Beat2Windows(corpus_dir, "train", (2,), N, 3, st, cfg, corpus=corpus, return_audio=True)
    assert len(ds) > 0
    item = ds[len(ds) - 1]
    assert item["mel"].shape == (8 * N, cfg.n_mels) and str(item["mel"].dtype) == "torch.float32"
    for r in REGIONS:
        assert tuple(item["motion"][r.name].shape) == (4 * N, r.dim)
        assert str(item["motion"][r.name].dtype) == "torch.float32"
    assert item["mel"].shape[0] == 2 * item["motion"]["upper"].shape[0]
    # the window is the whole-clip streaming frontend, sliced; motion is the normalised clip features
    s, cid = item["start"], item["id"]
    audio = corpus.audio(cid)
    mel_all = logmel(audio, cfg)
    np.testing.assert_array_equal(item["mel"].numpy(), mel_all[8 * s:8 * (s + N)])
    np.testing.assert_allclose(item["mel"].numpy(), logmel_frames(audio, 8 * s, 8 * N, cfg), atol=1e-5)
    a0, a1 = frame_start_sample(4 * s), frame_start_sample(4 * (s + N))
    np.testing.assert_array_equal(item["audio"].numpy(), audio[a0:a1])
    m = corpus.motion(cid)
    raw = motion_to_features(m["poses"], m["trans"], m["expressions"])
    np.testing.assert_allclose(item["motion"]["upper"].numpy(),
                               st.normalize({"upper": raw["upper"][4 * s:4 * (s + N)]})["upper"], atol=1e-5)
    clip = corpus.clip(cid)
    assert clip.n_tokens == min(len(m["poses"]) // 4, cfg.n_tokens(len(audio)))
    # normalised training windows are roughly standardised
    import torch
    up = torch.cat([ds[i]["motion"]["upper"] for i in range(len(ds))])
    assert abs(float(up.mean())) < 1.0
    # a DataLoader batches the items
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=2)))
    assert batch["mel"].shape == (2, 8 * N, cfg.n_mels) and len(batch["id"]) == 2


def test_regenerating_one_clip_is_byte_identical(corpus_dir, tmp_path):
    plans = synth.plan_corpus(TINY["minutes"], TINY["seed"], TINY["clip_seconds"])
    assert [p.id for p in plans] == list(beat2.read_split_csv(corpus_dir / "train_test_split.csv"))
    plan = plans[1]
    for d in ("smplxflame_30", "wave16k", "textgrid"):
        (tmp_path / d).mkdir()
    synth._clip_job((plan, str(tmp_path)))
    for sub, ext in (("smplxflame_30", "npz"), ("wave16k", "wav"), ("textgrid", "TextGrid")):
        a = (corpus_dir / sub / f"{plan.id}.{ext}").read_bytes()
        assert (tmp_path / sub / f"{plan.id}.{ext}").read_bytes() == a, ext
    other = synth.plan_corpus(TINY["minutes"], TINY["seed"] + 1, TINY["clip_seconds"])[1]
    assert other.seed != plan.seed


def test_upper_body_speed_follows_onsets(corpus_dir):
    """Upper-body joint speed rises right after audio onsets (strokes start at onsets): the correlation
    between an onset pulse train and the speed 2 frames later is clearly higher with the clip's own onsets
    than with time-shifted ones."""
    from scipy.ndimage import gaussian_filter1d

    c = Beat2Corpus(corpus_dir)
    pulses = {"real": [], "+0.5s": [], "-0.5s": [], "circular": []}
    speeds = []
    for cid in c.ids():
        m = c.motion(cid)
        T = len(m["poses"])
        J = forward_kinematics(m["poses"], m["trans"])[:, list(UPPER_JOINTS)]
        v = np.zeros(T)
        v[1:] = np.linalg.norm(np.diff(J, axis=0), axis=-1).mean(1) * 30
        on = synth_motion.onset_times(c.audio(cid))
        assert len(on) > 0
        dur = T / 30
        for name, o in (("real", on), ("+0.5s", on + 0.5), ("-0.5s", on - 0.5), ("circular", (on + dur / 2) % dur)):
            x = np.zeros(T)
            k = np.round(o * 30).astype(int)
            np.add.at(x, k[(k >= 0) & (k < T)], 1.0)
            x = gaussian_filter1d(x, 1.5)
            pulses[name].append((x - x.mean())[:-2])
        speeds.append((v - v.mean())[2:])
    v = np.concatenate(speeds)
    corr = {k: float(np.corrcoef(np.concatenate(p), v)[0, 1]) for k, p in pulses.items()}
    assert corr["real"] > 0.3, corr
    assert corr["real"] > max(corr["+0.5s"], corr["-0.5s"], corr["circular"]) + 0.15, corr


def _loud_quiet_speech(seconds: float = 24.0):
    """Continuous syllable-like harmonic bursts at 5 Hz, no pauses; 2 s phrases alternate between loud and
    18 dB quieter. -> (16 kHz audio, per-frame 30 fps indicator of the loud phrases)."""
    sr, n = 16000, int(16000 * seconds)
    x = np.zeros(n)
    L = int(0.16 * sr)
    tt = np.arange(L) / sr
    for k, t0 in enumerate(np.arange(0.0, seconds - 0.2, 0.2)):
        f0 = 120 + 20 * np.sin(k)
        attack_decay = np.minimum(tt / 0.02, 1) * np.exp(-tt / 0.08)
        burst = sum(np.sin(2 * np.pi * f0 * h * tt) / h for h in range(1, 12)) * attack_decay
        gain = 1.0 if int(t0 // 2) % 2 == 0 else 10 ** (-18 / 20)
        i0 = int(t0 * sr)
        x[i0:i0 + L] += 0.3 * gain * burst
    x += 1e-3 * np.random.default_rng(0).standard_normal(n)
    T = int(seconds * 30)
    return x, (np.floor(np.arange(T) / 30 / 2) % 2 == 0).astype(float)


def test_loudness_drive_couples_strokes_to_loudness():
    """On continuous speech whose loudness changes by phrase, the ``loudness`` and ``syllable`` stroke drives make
    upper-body speed follow the loud phrases far more than the ``flux`` drive (the original corpus), whose spectral-flux
    onset strength barely sees an 18 dB level change."""
    from scipy.ndimage import gaussian_filter1d
    from livegesture.data import synth_motion, synth_speech
    from livegesture.regions import UPPER_JOINTS
    from livegesture.skeleton import forward_kinematics

    x, loud = _loud_quiet_speech()
    an = synth_motion.analyse_audio(x)
    T = len(loud)
    r = {}
    for drive in synth_motion.STROKE_DRIVES:
        cs = []
        for seed in range(4):
            p, tr, _ = synth_motion.generate_motion(an, T, synth_speech.STYLE_BY_SPEAKER[2],
                                                    np.random.default_rng(seed), drive)
            J = forward_kinematics(p, tr)[:, list(UPPER_JOINTS)]
            v = np.zeros(T)
            v[1:] = np.linalg.norm(np.diff(J, axis=0), axis=-1).mean(1) * 30
            cs.append(np.corrcoef(gaussian_filter1d(v, 6), loud)[0, 1])
        r[drive] = float(np.mean(cs))
    for drive in ("loudness", "syllable", "syllable-body"):
        assert r[drive] > 0.6, r
        assert r[drive] > r["flux"] + 0.15, r
    with pytest.raises(ValueError, match="stroke drive 'pitch'"):
        synth_motion.generate_motion(an, T, synth_speech.STYLE_BY_SPEAKER[2], np.random.default_rng(0), "pitch")


def test_syllable_loudness_is_the_window_mean():
    """``syllable_loudness``: the mean envelope over the 60 ms (6 analysis frames) from each onset's frame,
    shortened at the clip's end."""
    from livegesture.data import synth_motion

    n = 50
    env = np.linspace(0.0, 0.98, n)
    a = synth_motion.AudioAnalysis(times=np.arange(n) * 0.01, env=env, active=np.ones(n, bool), onset_env=env,
                                   f0=np.zeros(n), onsets=np.array([0.10, 0.47]),
                                   onset_strength=np.array([0.5, 0.5]), phrase_start=np.zeros(2, bool))
    got = synth_motion.syllable_loudness(a)
    np.testing.assert_allclose(got, [env[10:16].mean(), env[47:50].mean()], rtol=1e-12)
    np.testing.assert_allclose(synth_motion.onset_loudness(a), [env[10], env[47]], rtol=1e-12)


def test_one_audio_many_motions(corpus_dir):
    c = Beat2Corpus(corpus_dir)
    cid = c.ids("train", 2)[0]
    audio = c.audio(cid)
    an = synth_motion.analyse_audio(audio)
    T = len(audio) * 30 // 16000
    style = synth_speech.STYLE_BY_SPEAKER[2]
    p1, _, e1 = synth_motion.generate_motion(an, T, style, np.random.default_rng(1))
    p2, _, e2 = synth_motion.generate_motion(an, T, style, np.random.default_rng(2))
    assert np.abs(p1 - p2).mean() > 1e-3
    # the jaw follows the same audio in both
    assert np.corrcoef(p1[:, 66], p2[:, 66])[0, 1] > 0.9


# ----------------------------------------------------------------------------- broken trees

def test_missing_wav_message_and_skip_broken(corpus_dir, tmp_path):
    root = _clone(corpus_dir, tmp_path)
    cid = beat2.Beat2Corpus(root).ids("train", 2)[0]
    (root / "wave16k" / f"{cid}.wav").unlink()
    with pytest.raises(Beat2Error, match=rf"wave16k/{cid}\.wav: missing audio file"):
        Beat2Windows(root, "train", (2,), 4, corpus=Beat2Corpus(root))
    # skip_broken is explicit and reports what it skipped
    with pytest.warns(UserWarning, match=rf"{cid}\.wav"):
        ds = Beat2Windows(root, "train", (2,), 4, corpus=Beat2Corpus(root, skip_broken=True))
    assert cid not in {c.id for c in ds.clips}


def test_wrong_npz_keys_message(corpus_dir, tmp_path):
    root = _clone(corpus_dir, tmp_path)
    c = Beat2Corpus(root)
    cid = c.ids("train", 2)[0]
    path = root / "smplxflame_30" / f"{cid}.npz"
    z = dict(np.load(path))
    z["pose"] = z.pop("poses")
    np.savez(path, **z)
    with pytest.raises(Beat2Error, match=rf"{cid}\.npz: missing key\(s\) \['poses'\]"):
        c.clip(cid)


def test_frame_count_and_shape_messages(corpus_dir, tmp_path):
    root = _clone(corpus_dir, tmp_path)
    c = Beat2Corpus(root)
    cid = c.ids("train", 2)[0]
    path = root / "smplxflame_30" / f"{cid}.npz"
    z = dict(np.load(path))
    z["trans"] = z["trans"][:-5]
    np.savez(path, **z)
    with pytest.raises(Beat2Error, match=rf"{cid}\.npz: frame count mismatch"):
        c.clip(cid)
    z = dict(np.load(path))
    z["trans"] = np.zeros((len(z["poses"]), 2), dtype=np.float32)
    np.savez(path, **z)
    with pytest.raises(Beat2Error, match=r"'trans' has shape"):
        c.clip(cid)


def test_audio_far_shorter_than_motion(corpus_dir, tmp_path):
    from scipy.io import wavfile
    root = _clone(corpus_dir, tmp_path)
    c = Beat2Corpus(root)
    cid = c.ids("train", 2)[0]
    path = root / "wave16k" / f"{cid}.wav"
    sr, a = wavfile.read(path)
    wavfile.write(path, sr, a[:len(a) - int(1.5 * sr)])
    with pytest.raises(Beat2Error, match=rf"{cid}\.wav: audio is .* shorter"):
        c.clip(cid)


def test_audio_other_rate_is_resampled(corpus_dir, tmp_path):
    from scipy.io import wavfile
    root = _clone(corpus_dir, tmp_path)
    cid = Beat2Corpus(root).ids("train", 2)[0]
    path = root / "wave16k" / f"{cid}.wav"
    sr, a = wavfile.read(path)
    a48 = np.repeat(a[:, None], 3, axis=0).reshape(-1)          # 48 kHz, stereo
    wavfile.write(path, 48000, np.stack([a48, a48], 1))
    x = beat2.load_audio(path)
    assert abs(len(x) - len(a)) <= 1
    assert Beat2Corpus(root).clip(cid).n_tokens > 0


def test_bad_csv_messages(corpus_dir, tmp_path):
    root = _clone(corpus_dir, tmp_path)
    csv = root / "train_test_split.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("name,split\n" + "\n".join(lines[1:]) + "\n")
    with pytest.raises(Beat2Error, match=r"train_test_split\.csv: bad header"):
        Beat2Corpus(root)
    csv.write_text("id,type\n" + lines[1].split(",")[0] + ",holdout\n")
    with pytest.raises(Beat2Error, match=r"train_test_split\.csv: line 2: unknown type 'holdout'"):
        Beat2Corpus(root)
    csv.unlink()
    with pytest.raises(Beat2Error, match=r"train_test_split\.csv: missing"):
        Beat2Corpus(root)


def test_missing_npz_for_csv_id(corpus_dir, tmp_path):
    root = _clone(corpus_dir, tmp_path)
    c = Beat2Corpus(root)
    cid = c.ids("test", 2)[0]
    (root / "smplxflame_30" / f"{cid}.npz").unlink()
    with pytest.raises(Beat2Error, match=rf"smplxflame_30/{cid}\.npz: missing motion file"):
        Beat2Windows(root, "test", 2, 4, corpus=c)

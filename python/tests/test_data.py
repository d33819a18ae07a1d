"""BEAT2 loader on a generated tree and on broken trees; synthetic corpus determinism and audio-driven
motion; region features round trip; foot contact."""
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

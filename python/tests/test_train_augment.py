"""Training with audio augmentation (livegesture.train --augment N): every clip gets N augmented mel copies
of the same shape; windows draw from the clean mel and the copies; mel statistics cover all of them."""
import numpy as np
import torch

from livegesture.config import get_config
from livegesture.train import TrainData


def test_train_data_augmented_copies(tiny_corpus):
    cfg = get_config("tiny")
    plain = TrainData(tiny_corpus, cfg, None)
    aug = TrainData(tiny_corpus, cfg, None, augment=2, seed=3)
    assert all(len(v) == 3 for v in aug.mel_variants)
    for c, vs in enumerate(aug.mel_variants):
        assert np.array_equal(vs[0], plain.mel[c])
        assert all(v.shape == vs[0].shape for v in vs)
        assert not np.allclose(vs[1], vs[0]) and not np.allclose(vs[2], vs[1])
    again = TrainData(tiny_corpus, cfg, None, augment=2, seed=3)
    assert all(np.array_equal(a, b) for va, vb in zip(aug.mel_variants, again.mel_variants) for a, b in zip(va, vb))
    assert not np.allclose(aug.mel_std, plain.mel_std)
    aug.tokens = [np.zeros((n, 4), np.int64) for n in aug.n_tok]
    seen = set()
    rng = np.random.default_rng(0)
    for _ in range(6):
        mel, tok = aug.ar_batch(rng, 4, 8, "cpu")
        assert mel.shape == (8, 32, cfg.frontend.n_mels) and tok.shape == (8, 4, 4)
        for b in range(8):
            for c, vs in enumerate(aug.mel_variants):
                for k, v in enumerate(vs):
                    for s in range(aug.n_tok[c] - 3):
                        if np.array_equal(v[8 * s:8 * s + 32], mel[b].numpy()):
                            seen.add(k)
    assert seen == {0, 1, 2}


def test_svq_from_reuses_the_motion_tokenizer(tiny_corpus, tmp_path):
    """--svq-from: svq1/svq2 come from another checkpoint (weights and motion statistics), the audio-side
    stages are trained, the mel statistics are this run's."""
    from livegesture import checkpoint as ckpt
    from livegesture.train import train
    ov = dict(steps_svq1=4, steps_svq2=4, steps_experts=3, steps_fuse=3, save_every=100, speakers=None)
    src = train("tiny", str(tiny_corpus), str(tmp_path / "a"), overrides=ov)
    final = train("tiny", str(tiny_corpus), str(tmp_path / "b"), overrides={**ov, "augment": 1, "seed": 1},
                  svq_from=str(src))
    a, b = ckpt.load(src), ckpt.load(final)
    for r in a.svq:
        for k, v in a.svq[r].state_dict().items():
            assert torch.equal(v, b.svq[r].state_dict()[k]), (r, k)
    assert not torch.equal(a.audio_encoder.mel_std, b.audio_encoder.mel_std)
    assert b.provenance["svq_from"] == str(src) and b.provenance["augment"] == 1

"""Fine-tuning (livegesture.train --init-from CKPT [--extra-data DIR]): every weight and statistic starts from
the checkpoint, the motion tokenizer (svq1/svq2) and all normalisation statistics stay as they are, the
experts and fuse stages continue from the checkpoint's weights, and the stages resume across sittings."""
import pytest
import torch

from livegesture import checkpoint as ckpt
from livegesture.train import STAGES, train

OV = dict(steps_svq1=4, steps_svq2=4, steps_experts=3, steps_fuse=3, save_every=100, speakers=None)


@pytest.fixture(scope="module")
def source(tiny_corpus, tmp_path_factory):
    return train("tiny", str(tiny_corpus), str(tmp_path_factory.mktemp("src")), overrides=OV)


def _same(a, b, prefix=""):
    sa, sb = a.state_dict(), b.state_dict()
    return {k for k in sa if k.startswith(prefix) and not torch.equal(sa[k], sb[k])}


def test_init_from_starts_from_every_weight(tiny_corpus, source, tmp_path):
    # with a zero learning rate the fine-tuned model IS the source model: nothing is re-initialised and the
    # mel statistics are the source's, not this (augmented, mixed) run's
    final = train("tiny", str(tiny_corpus), str(tmp_path / "ft0"), init_from=str(source),
                  extra_data=[str(tiny_corpus)], overrides={**OV, "lr_ar": 0.0, "augment": 1, "seed": 5})
    a, b = ckpt.load(source), ckpt.load(final)
    assert _same(a, b) == set()
    assert b.provenance["init_from"] == str(source)
    assert b.provenance["train_clips"] == 2 * a.provenance["train_clips"]     # the corpus mixed in twice


def test_init_from_fine_tunes_audio_stages_and_resumes(tiny_corpus, source, tmp_path):
    out = tmp_path / "ft"
    kw = dict(init_from=str(source), extra_data=[str(tiny_corpus)], overrides={**OV, "lr_ar": 1e-3, "augment": 1})
    train("tiny", str(tiny_corpus), str(out), stages=STAGES[:3], **kw)      # first sitting: up to experts
    assert (out / "experts.pt").exists() and not (out / "fuse.pt").exists()
    experts = ckpt.load(out / "experts.pt")
    kw2 = dict(kw, overrides={**OV, "lr_ar": 5e-4, "augment": 1})
    final = train("tiny", str(tiny_corpus), str(out), **kw2)                 # second sitting: fuse, another lr
    a, b = ckpt.load(source), ckpt.load(final)
    assert _same(a, b, "svq.") == set()                                      # tokenizer and motion stats kept
    assert torch.equal(a.audio_encoder.mel_mean, b.audio_encoder.mel_mean)
    assert torch.equal(a.audio_encoder.mel_std, b.audio_encoder.mel_std)
    assert _same(a, b, "audio_encoder.") and _same(a, b, "experts.") and _same(a, b, "fuse.")
    # fuse trains the (shared) region classifiers, nothing else of the eXperts or the audio encoder
    assert _same(experts, b, "audio_encoder.") == set()
    assert {k for k in _same(experts, b, "experts.") if ".classifier." not in k} == set()
    assert _same(experts, b, "fuse.")
    assert b.provenance["init_from"] == str(source) and b.provenance["stages_done"] == list(STAGES)
    # each stage's learning rate is the one of the sitting that trained it (train_config is the last sitting's)
    assert b.provenance["stages"]["experts"]["lr"] == 1e-3 and b.provenance["stages"]["fuse"]["lr"] == 5e-4
    assert b.provenance["stages"]["experts"]["steps"] == OV["steps_experts"]
    assert b.provenance["train_config"]["lr_ar"] == 5e-4


def test_init_from_rejects_another_config(tiny_corpus, source, tmp_path):
    with pytest.raises(SystemExit, match="config differs"):
        train("default", str(tiny_corpus), str(tmp_path / "bad"), init_from=str(source), overrides=OV)
    with pytest.raises(SystemExit, match="exclude each other"):
        train("tiny", str(tiny_corpus), str(tmp_path / "bad2"), init_from=str(source), svq_from=str(source),
              overrides=OV)


def test_train_command_line_fine_tunes(tiny_corpus, source, tmp_path, capsys):
    # the command users type, through the argument parser (a duplicated option once broke `python -m
    # livegesture.train` entirely while the function-level tests above passed)
    from livegesture.train import main
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0 and "--init-from" in capsys.readouterr().out
    out = tmp_path / "cli"
    main(["--config", "tiny", "--data", str(tiny_corpus), "--out", str(out), "--speakers", "all",
          "--init-from", str(source), "--lr-ar", "0", "--steps-experts", "2", "--steps-fuse", "2"])
    assert _same(ckpt.load(source), ckpt.load(out / "final.pt")) == set()

"""Every training stage runs a few steps on the tiny config and its loss goes down on a fixed batch."""
import numpy as np
import pytest
import torch

from livegesture import checkpoint as ckpt
from livegesture.config import get_config
from livegesture.models.model import LiveGesture
from livegesture.train import (STAGES, Logger, TrainConfig, TrainData, init_codebooks, run_stage, stage_experts,
                               stage_fuse, stage_svq1, stage_svq2, tokenize_clips, train)

BUILDERS = {"svq1": stage_svq1, "svq2": stage_svq2, "experts": stage_experts, "fuse": stage_fuse}


@pytest.fixture(scope="module")
def setup(tiny_corpus):
    cfg = get_config("tiny")
    tcfg = TrainConfig.for_model("tiny")
    torch.manual_seed(0)
    model = LiveGesture(cfg)
    data = TrainData(tiny_corpus, cfg, None)
    return model, data, tcfg


def fixed_loss(model, data, tcfg, name, step_fn):
    torch.manual_seed(123)
    with torch.no_grad():
        return float(step_fn(0, np.random.default_rng(123))[0])


def test_each_stage_reduces_its_loss(setup, tmp_path):
    model, data, tcfg = setup
    logger = Logger(tmp_path)
    for name in STAGES:
        if name == "svq2":
            init_codebooks(model, data, tcfg, "cpu", np.random.default_rng(0))
        if name == "experts":
            tokenize_clips(model, data, "cpu")
        model.train()
        params, step_fn, state_fn = BUILDERS[name](model, data, tcfg, "cpu")
        before = fixed_loss(model, data, tcfg, name, step_fn)
        run_stage(name, model, params, 40, step_fn, tcfg, tmp_path, logger, "cpu", state_fn)
        after = fixed_loss(model, data, tcfg, name, step_fn)
        for p in model.parameters():
            p.requires_grad_(True)
        assert after < before, f"stage {name}: loss on a fixed batch went from {before:.4f} to {after:.4f}"


def test_svq2_keeps_encoder_and_decoder_frozen(setup):
    model, data, tcfg = setup
    enc = {k: v.clone() for k, v in model.svq["upper"].encoder.state_dict().items()}
    dec = {k: v.clone() for k, v in model.svq["upper"].decoder.state_dict().items()}
    params, step_fn, state_fn = stage_svq2(model, data, tcfg, "cpu")
    assert not any(p is q for p in params for q in model.svq["upper"].decoder.parameters())
    opt = torch.optim.Adam(params, lr=1e-2)
    loss, _ = step_fn(0, np.random.default_rng(0))
    loss.backward()
    opt.step()
    for k, v in model.svq["upper"].encoder.state_dict().items():
        assert torch.equal(v, enc[k])
    for k, v in model.svq["upper"].decoder.state_dict().items():
        assert torch.equal(v, dec[k])
    for p in model.parameters():
        p.requires_grad_(True)


def test_train_command_resumes_and_writes_final(tiny_corpus, tmp_path):
    ov = dict(steps_svq1=6, steps_svq2=4, steps_experts=4, steps_fuse=4, save_every=2, speakers=None)
    final = train("tiny", str(tiny_corpus), str(tmp_path), stages=STAGES[:2], overrides=ov)
    assert (tmp_path / "svq1.pt").exists() and (tmp_path / "svq2.pt").exists()
    assert not (tmp_path / "experts.pt").exists() and not final.exists()
    final = train("tiny", str(tiny_corpus), str(tmp_path), overrides=ov)     # reuses svq1/svq2
    model = ckpt.load(final)
    assert model.provenance["stages_done"] == list(STAGES)
    assert (tmp_path / "train_log.jsonl").read_text().count('"stage": "svq1"') >= 2

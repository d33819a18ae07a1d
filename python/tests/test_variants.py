"""The papers' variants as configuration (livegesture.variants): listed, refused when unknown, and each one changes
the model or the training the way its paper reference says (and nothing else). The end-to-end proof (train a few
steps, export, parity on both backends, generate) is scripts/variants.sh, run by the test command."""
import dataclasses

import numpy as np
import pytest
import torch

from livegesture import checkpoint as ckpt
from livegesture import families, variants
from livegesture.config import get_config
from livegesture.diffsheg.config import get_config as get_diffsheg_config
from livegesture.diffsheg.denoiser import EXP_DIM, GES_DIM, MOTION_DIM, concat_width
from livegesture.regions import REGION_NAMES
from livegesture.train import TrainConfig, TrainData, main as train_main, stage_fuse, stage_svq2, tokenize_clips

LG, DS = families.LIVEGESTURE.name, families.DIFFSHEG.name


def lg_model(variant, seed=0):
    return ckpt.random_model(variants.apply(get_config("tiny"), LG, variant), seed)


def ds_model(variant, seed=0):
    return ckpt.random_model(variants.apply(get_diffsheg_config("tiny"), DS, variant), seed, family=DS)


def test_list_variants_prints_the_names_one_a_line_for_both_families(capsys):
    for fam in (LG, DS):
        assert train_main(["--family", fam, "--list-variants"]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert lines == list(variants.variants_of(fam)) and lines[0] == "full" and len(lines) >= 5


def test_an_unknown_variant_is_refused_naming_the_choices(capsys):
    with pytest.raises(SystemExit):
        train_main(["--variant", "no-such", "--data", "x", "--out", "y"])
    err = capsys.readouterr().err
    assert "--variant no-such" in err and "no-pilor" in err
    with pytest.raises(ValueError, match="unknown diffsheg variant 'no-pilor'"):
        variants.apply(get_diffsheg_config("tiny"), DS, "no-pilor")     # a LiveGesture variant is not DiffSHEG's


def test_every_variant_names_its_paper_reference_and_only_known_fields():
    for v in variants.VARIANTS:
        assert v.paper and v.summary, v.name
        base = get_config("tiny") if v.family == LG else get_diffsheg_config("tiny")
        cfg = variants.apply(base, v.family, v.name)           # raises on a field the config lacks
        assert cfg.variant == v.name
        tfields = {f.name for f in dataclasses.fields(TrainConfig)} if v.family == LG else None
        if tfields is not None:
            assert set(v.train) <= tfields, v.name


def test_full_is_the_unchanged_model():
    """The default variant is the model the shipped bundles were exported from: same weights from the same seed."""
    a, b = ckpt.random_model("tiny", 0), lg_model("full")
    assert a.state_dict().keys() == b.state_dict().keys()
    assert all(torch.equal(a.state_dict()[k], b.state_dict()[k]) for k in a.state_dict())
    # the fusion's parameters registered in the order of the shipped bundles' export (the ONNX initializer names
    # follow it: its own parameters, then the adapters, blocks and final norm)
    fuse = [k.split(".")[1] for k in b.state_dict() if k.startswith("fuse.") and not k.startswith("fuse.classifiers")]
    assert list(dict.fromkeys(fuse)) == ["region_embed", "null_audio", "pilor", "blocks", "norm"]
    c, d = ckpt.random_model("tiny", 0, family=DS), ds_model("full")
    assert all(torch.equal(c.state_dict()[k], d.state_dict()[k]) for k in c.state_dict())


def test_fusion_switches_remove_their_layers_and_caches():
    full = lg_model("full")
    keys = set(full.state_dict())
    assert any(".pilor." in k for k in keys)
    assert not any(".pilor." in k for k in lg_model("no-pilor").state_dict())
    names = {s.name for s in full.fuse.cache_specs()}
    assert any("tattn" in n for n in names) and any("xattn" in n for n in names)
    assert not any("tattn" in s.name for s in lg_model("no-temporal").fuse.cache_specs())
    no_audio = lg_model("no-fuse-audio").fuse
    assert not any("xattn" in s.name for s in no_audio.cache_specs()) and not no_audio.uses_audio
    assert not any(".spatial." in k for k in lg_model("no-spatial").state_dict())
    assert lg_model("codebook-half").cfg.codebook_size == get_config("tiny").codebook_size // 2
    assert lg_model("codebook-double").cfg.codebook_size == get_config("tiny").codebook_size * 2


@torch.no_grad()
def test_additive_audio_replaces_the_cross_attention_and_still_follows_the_audio():
    m = lg_model("additive-audio")
    e = m.experts["upper"]
    assert not any(layer.is_cross for layer in e.layers) and e.additive
    assert not any("xattn" in s.name for s in e.cache_specs() + m.fuse.cache_specs())
    assert m.fuse.uses_audio and m.fuse.additive
    g = torch.Generator().manual_seed(0)
    B = 2
    prev = torch.full((B,), m.cfg.bos_token)
    a1, a2 = torch.randn(B, m.cfg.audio_dim, generator=g), torch.randn(B, m.cfg.audio_dim, generator=g)
    h1, _ = e.step(prev, a1, torch.ones(B), e.init_cache(B))
    h2, _ = e.step(prev, a2, torch.ones(B), e.init_cache(B))
    assert not torch.allclose(h1["hidden"], h2["hidden"])            # the audio reaches the eXpert
    full = lg_model("full")
    assert any(layer.is_cross for layer in full.experts["upper"].layers)    # must-fail side: full cross-attends


@torch.no_grad()
def test_experts_only_predicts_with_the_experts_own_classifiers():
    m = lg_model("experts-only")
    g = torch.Generator().manual_seed(0)
    B = 3
    hidden = {r: torch.randn(B, m.cfg.d_model, generator=g) for r in REGION_NAMES}
    out, new = m.fuse.step(hidden, torch.randn(B, m.cfg.audio_dim, generator=g), torch.ones(B), m.fuse.init_cache(B))
    want = torch.stack([m.experts[r].logits(hidden[r]) for r in REGION_NAMES], 1)
    assert torch.equal(out["logits"], want)
    # must-fail: with xAR-Fuse the logits are not the eXperts'
    full = lg_model("full")
    out, _ = full.fuse.step(hidden, torch.randn(B, m.cfg.audio_dim, generator=g), torch.ones(B),
                            full.fuse.init_cache(B))
    assert not torch.allclose(out["logits"], torch.stack([full.experts[r].logits(hidden[r]) for r in REGION_NAMES], 1))


def _eps(model, x, t):
    B, n = x.shape[:2]
    audio = torch.randn(B, n, model.cfg.audio_dim, generator=torch.Generator().manual_seed(1))
    return model.denoiser(x, t, audio, torch.zeros(B, dtype=torch.int64), torch.ones(B))


@torch.no_grad()
def test_diffsheg_condition_flow_follows_the_variant():
    """uni: the expression's eps never depends on the gesture input; reverse: it does, and the gesture's eps no
    longer depends on the expression; no-x0: neither reads the other."""
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 12, MOTION_DIM, generator=g)
    t = torch.tensor([500, 20])
    x_g = x.clone()
    x_g[..., :GES_DIM] += 1.0          # the gesture part changed
    x_e = x.clone()
    x_e[..., GES_DIM:] += 1.0          # the expression part changed

    def moved(model, x2, part):
        a, b = _eps(model, x, t), _eps(model, x2, t)
        sl = slice(GES_DIM, None) if part == "exp" else slice(0, GES_DIM)
        return not torch.equal(a[..., sl], b[..., sl])
    full, rev, nox0 = ds_model("full"), ds_model("reverse"), ds_model("no-x0")
    assert not moved(full, x_g, "exp") and moved(full, x_e, "ges")
    assert moved(rev, x_g, "exp") and not moved(rev, x_e, "ges")
    assert not moved(nox0, x_g, "exp") and not moved(nox0, x_e, "ges")
    concat = ds_model("naive-concat")
    assert concat.denoiser.joint.inp.out_features == concat_width(concat.cfg) > concat.cfg.d_model
    assert moved(concat, x_g, "exp") and moved(concat, x_e, "ges")
    assert EXP_DIM == MOTION_DIM - GES_DIM


def test_no_detach_lets_the_gesture_loss_reach_the_expression_branch():
    x = torch.randn(2, 12, MOTION_DIM, generator=torch.Generator().manual_seed(0))
    t = torch.tensor([500, 20])
    grads = {}
    for v in ("full", "no-detach"):
        m = ds_model(v)          # eval mode: no dropout
        _eps(m, x, t)[..., :GES_DIM].square().sum().backward()          # the gesture's loss only
        grads[v] = sum(float(p.grad.abs().sum()) for p in m.denoiser.exp.parameters() if p.grad is not None)
    assert grads["full"] == 0.0 and grads["no-detach"] > 0.0


def _data(tiny_corpus, cfg, tcfg):
    data = TrainData(tiny_corpus, cfg, None)
    return data


def test_training_variants_change_the_fuse_stage(tiny_corpus):
    cfg = get_config("tiny")
    base = TrainConfig.for_model("tiny")
    model = ckpt.random_model("tiny", 0)
    data = _data(tiny_corpus, cfg, base)
    tokenize_clips(model, data, "cpu")

    def batch(variant, step=0, seed=5):
        tcfg = dataclasses.replace(base, **variants.train_overrides(LG, variant))
        _, fn, _ = stage_fuse(model, data, tcfg, "cpu")
        return fn.sample(step, np.random.default_rng(seed)), fn, tcfg
    # at step 0 the project's ramp allows no region drop; the paper's U(0, 0.2) does from the first step
    assert batch("full")[0]["p_drop"] == 0.0
    drops = [batch("paper-region-mask", 0, s)[0]["p_drop"] for s in range(20)]
    assert 0.0 < max(drops) <= 0.2
    late = [batch("no-region-mask", base.steps_fuse, s)[0] for s in range(5)]
    assert all(b["p_drop"] == 0.0 and not b["region_mask"].any() for b in late)
    assert all(batch("no-ugm", base.steps_fuse, s)[0]["ratio"] == 0.0 for s in range(5))
    assert max(batch("full", base.steps_fuse, s)[0]["ratio"] for s in range(5)) > 0.0     # must-fail side
    # masked-fuse-loss: with nothing masked (step 0: ratio and p_drop are 0) there is no fuse loss
    b, fn, _ = batch("masked-fuse-loss")
    from livegesture.trainkit import to_device
    with torch.no_grad():
        _, parts = fn.compute(0, to_device(b, "cpu"))
        _, parts_full = batch("full")[1].compute(0, to_device(b, "cpu"))
    assert float(parts["fuse"]) == 0.0 and float(parts_full["fuse"]) > 0.0


def test_one_stage_svq_trains_the_autoencoder_with_the_quantizer(tiny_corpus):
    cfg = get_config("tiny")
    base = TrainConfig.for_model("tiny")
    data = _data(tiny_corpus, cfg, base)
    for variant, joint in (("full", False), ("one-stage-svq", True)):
        model = ckpt.random_model("tiny", 0)
        tcfg = dataclasses.replace(base, **variants.train_overrides(LG, variant))
        params, _, _ = stage_svq2(model, data, tcfg, "cpu")
        dec = {id(p) for p in model.svq["upper"].decoder.parameters()}
        assert any(id(p) in dec for p in params) == joint, variant


def test_full_body_svq_has_one_region_of_every_joint(tiny_corpus):
    """Table 6: one SVQ, one eXpert and the fusion over one region whose features are the four regions' side by
    side; the region table covers the frame exactly as the four do, and the stream's frames come from it."""
    from livegesture.regions import BODY, REGION_BY_NAME, REGIONS, model_regions, region_layout, split
    from livegesture.stream import generate_clip
    m = lg_model("full-body-svq")
    assert m.region_names == ("body",) and list(m.components()) == ["audio_encoder", "expert_body", "fusion",
                                                                      "decoder_body"]
    assert m.svq["body"].d_in == BODY.dim == sum(r.dim for r in REGIONS) == 425
    assert m.fuse.R == 1 and len(m.fuse.classifiers) == 1
    # the layout: the four regions' parts, offsets shifted; every joint of theirs, the eyes in none
    four = region_layout()
    (body,) = region_layout(m.regions)
    assert sorted(body["joints"]) == sorted(j for r in four for j in r["joints"]) and 23 not in body["joints"]
    assert [p["name"] for p in body["parts"]] == [p["name"] for r in four for p in r["parts"]]
    assert body["parts"][-1]["offset"] + body["parts"][-1]["dim"] == 425
    # training data: the composite is the normalised members side by side; split inverts it
    data = TrainData(tiny_corpus, m.cfg, None)
    f = data.feats[0]
    assert np.array_equal(f["body"], np.concatenate([f[r] for r in REGION_NAMES], -1))
    assert all(np.array_equal(v, f[k]) for k, v in split({"body": f["body"]}).items())
    with pytest.raises(ValueError, match="region 'body': 424 features, expected 425"):
        split({"body": f["body"][:, :424]})     # must-fail: a vector of the wrong width
    # the statistics compose the same way (set from the four regions' stats)
    stats = data.stats.to_dict()["regions"]
    m.set_normalisation(stats)
    assert np.allclose(m.svq["body"].mean.numpy(), np.concatenate([stats[r]["mean"] for r in REGION_NAMES]))
    # one token per step, and frames assembled from the one region
    out = generate_clip(m, np.random.default_rng(0).standard_normal(16000).astype(np.float32) * 0.1, seed=1)
    assert out["tokens"].shape[1] == 1 and out["poses"].shape == (28, 165)
    assert np.abs(out["expressions"]).sum() > 0 and np.abs(out["trans"]).sum() > 0
    with pytest.raises(ValueError, match="form 'fused'"):
        generate_clip(m, np.zeros(16000, np.float32), form="fused")
    assert REGION_BY_NAME["upper"] in model_regions(get_config("tiny"))
    with pytest.raises(ValueError, match="regions 'three'"):
        model_regions(dataclasses.replace(get_config("tiny"), regions="three"))


def test_the_stages_before_a_variants_first_changed_stage_are_fulls(tiny_corpus, tmp_path):
    """scripts/ablation.sh takes the stages a variant does not change from the `full` run of the same budget
    (livegesture.train.first_changed_stage): they must be the same computation, bit for bit."""
    from livegesture.train import STAGES, first_changed_stage, train
    assert first_changed_stage("full") is None and first_changed_stage("no-local-loss") == "fuse"
    assert first_changed_stage("paper-expert-noise") == "experts" and first_changed_stage("additive-audio") == "experts"
    assert first_changed_stage("full-body-svq") == "svq1" and first_changed_stage("one-stage-svq") == "svq1"
    assert first_changed_stage("codebook-half") == "svq1" and first_changed_stage("no-pilor") == "fuse"
    tcfg = dataclasses.replace(TrainConfig.for_model("tiny"), steps_svq1=2, steps_svq2=2, steps_experts=2,
                               speakers=None)
    for v in ("full", "no-local-loss", "paper-expert-noise"):
        train("tiny", str(tiny_corpus), str(tmp_path / v), stages=STAGES[:3], tcfg=tcfg, variant=v)

    def same(a, b, stage):
        sa, sb = (ckpt.load_payload(tmp_path / v / f"{stage}.pt")["state_dict"] for v in (a, b))
        return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
    assert same("full", "no-local-loss", "experts") and same("full", "paper-expert-noise", "svq2")
    assert not same("full", "paper-expert-noise", "experts")     # must-fail side: the stage it changes differs


def test_the_manifest_records_the_variant():
    from export.bundle_writer import variant_record
    cfg = variants.apply(get_config("tiny"), LG, "codebook-half")
    rec = variant_record(LG, cfg)
    assert rec["name"] == "codebook-half" and rec["model_options"] == {"codebook_size": cfg.codebook_size}
    assert "Table 3" in rec["paper"]
    assert variant_record(LG, get_config("tiny"))["name"] == "full"


FAMILY_COMPARISON = r"""[!=]=\s*["'](?:livegesture|diffsheg)["']|["'](?:livegesture|diffsheg)["']\s*[!=]=|""" \
    r"""["'](?:livegesture|diffsheg)["']\s*(?:not\s+)?in\b|\bin\s*\(\s*["'](?:livegesture|diffsheg)["']"""


def test_no_family_string_comparison_outside_the_registry():
    """Issue 37: the family is picked through livegesture.families only (checkpoint, stream, eval, train, export,
    bench_train, quantize...); a comparison with a family name anywhere else fails here."""
    import re
    from pathlib import Path
    root = Path(__file__).resolve().parents[2]
    pat = re.compile(FAMILY_COMPARISON)
    assert pat.search('if fam == "diffsheg":') and pat.search("x = 'livegesture' != y")   # must-fail cases
    assert pat.search('if family in ("livegesture", "diffsheg"):')
    offenders = []
    for base in ("python/livegesture", "export", "bench"):
        for p in sorted((root / base).rglob("*.py")):
            if p.name == "families.py":
                continue
            for n, line in enumerate(p.read_text().splitlines(), 1):
                if pat.search(line.split("#")[0]):
                    offenders.append(f"{p.relative_to(root)}:{n}: {line.strip()}")
    assert not offenders, "family names compared outside livegesture.families:\n" + "\n".join(offenders)

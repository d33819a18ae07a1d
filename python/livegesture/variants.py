"""The papers' model variants as configuration (issue 43): a variant is a name, the paper's table or section it
comes from, the model-config fields it sets and the training-config fields it sets. The model code reads those
fields (``livegesture.models.fuse``, ``livegesture.diffsheg.denoiser``, ``livegesture.train``); nothing else
knows a variant.

    python -m livegesture.train --list-variants                       # the names, one a line (both families)
    python -m livegesture.train --config tiny --variant no-pilor --data DIR --out runs/x
    python -m livegesture.train --family diffsheg --config tiny --variant reverse --data DIR --out runs/y

The checkpoint's config records the variant (``variant`` and the switched fields), so ``export/export.py``
writes it into the bundle's manifest (``model.config`` and ``model.variant``: which graphs exist, which options
were set) and the runtime runs the graphs the manifest lists. docs/model.md and docs/diffsheg.md list every
variant and fidelity choice with its paper reference.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable


@dataclass(frozen=True)
class Variant:
    name: str
    family: str
    paper: str                  # where the paper describes it (table / section), or "project's choice"
    summary: str
    model: dict = field(default_factory=dict)     # model-config fields (or a function cfg -> dict)
    train: dict = field(default_factory=dict)     # training-config fields
    model_fn: Callable | None = None              # cfg -> model-config fields that depend on the base config

    @property
    def changes_graphs(self) -> bool:
        """Whether the variant changes the model (its exported graphs); otherwise only training differs and its
        bundle has the ``full`` model's graphs."""
        return bool(self.model) or self.model_fn is not None

    def model_fields(self, cfg) -> dict:
        out = dict(self.model)
        if self.model_fn is not None:
            out.update(self.model_fn(cfg))
        return out


_LG = "livegesture"
_DS = "diffsheg"

VARIANTS: tuple[Variant, ...] = (
    # ---------------------------------------------------------------- LiveGesture (seed 000)
    Variant("full", _LG, "the paper's model (sections 3.1-3.3, supp. B)", "every component on"),
    Variant("no-pilor", _LG, "Table 2a, w/o PILOR", "no PILOR adapters: h~ = h + region embedding",
            model={"pilor": False}),
    Variant("no-ugm", _LG, "Table 2a, w/o UGR (Table 2f: the ratio ranges)", "no uncertainty-guided token masking in the fuse stage",
            train={"ugm_max_ratio": 0.0}),
    Variant("no-region-mask", _LG, "Table 7, a = 0", "no random region masking in the fuse stage",
            train={"region_drop_max": 0.0}),
    Variant("no-spatial", _LG, "Table 2a, w/o spatial attn.", "fuse blocks without inter-region spatial attention",
            model={"fuse_spatial": False}),
    Variant("no-temporal", _LG, "Table 2a, w/o temporal attn.", "fuse blocks without causal temporal attention",
            model={"fuse_temporal": False}),
    Variant("no-fuse-audio", _LG, "section 3.2.2 (the fuse block's audio-motion cross-attention; no table)",
            "fuse blocks without audio-motion cross-attention", model={"fuse_audio": False}),
    Variant("additive-audio", _LG, "Table 4, supp. G: causal self-attention with audio added",
            "the audio token projected and added to the motion embedding (eXperts) and to the fused states (fuse "
            "blocks) instead of audio-motion cross-attention", model={"audio_fusion": "additive"}),
    Variant("experts-only", _LG, "Table 2b, region-eXperts alone",
            "no xAR-Fuse: the eXperts' own classifiers predict; the fuse stage is skipped",
            model={"fusion": "none"}, train={"steps_fuse": 0}),
    Variant("one-stage-svq", _LG, "Table 2c, 1-stage",
            "SVQ trained in one stage: encoder, decoder and quantizer together (svq1 skipped)",
            train={"svq_stages": 1}),
    Variant("full-body-svq", _LG, "Table 6, supp. I: full-body SVQ (1 tokenizer)",
            "one region for the whole body: one SVQ over every joint, translation, foot contact and expressions "
            "(the four regions' features side by side), one eXpert, the fusion over one region",
            model={"regions": "full-body"}),
    Variant("codebook-half", _LG, "Table 3, supp. F (codebook size 512 / 1024 / 2048)", "half the config's codebook size",
            model_fn=lambda cfg: {"codebook_size": max(2, cfg.codebook_size // 2)}),
    Variant("codebook-double", _LG, "Table 3, supp. F (codebook size 512 / 1024 / 2048)", "twice the config's codebook size",
            model_fn=lambda cfg: {"codebook_size": cfg.codebook_size * 2}),
    Variant("no-local-loss", _LG, "Table 2e, lambda_local = 0", "the fuse stage without the local eXpert loss",
            train={"local_weight": 0.0}),
    # fidelity options: the paper's value where the project's default differs (docs/model.md)
    Variant("paper-region-mask", _LG, "Table 7: p_drop ~ U(0, a), a = 0.2 the reported best",
            "region masking p_drop ~ U(0, 0.2) from the first step (default: top ramped to 0.5, supp. B)",
            train={"region_drop_max": 0.2, "region_drop_ramp": False}),
    Variant("paper-expert-noise", _LG, "Table 8: p_noise ~ U(0, a), a = 0.2 the reported best",
            "eXpert history noise with p_noise ~ U(0, 0.2) per batch (default: p_noise = 0.2, supp. B)",
            train={"noise_p_uniform": True}),
    Variant("masked-fuse-loss", _LG, "project's reading of section 3.3 (the paper does not say which tokens)",
            "the fuse loss only on tokens whose history input was masked (default: every token)",
            train={"fuse_loss_masked": True}),
    # ---------------------------------------------------------------- DiffSHEG (seed 001)
    Variant("full", _DS, "the paper's UniEG (section 3.3)", "expression -> gesture, x0 detached"),
    Variant("naive-concat", _DS, "section 4.5 / Table 1, Ours Naive Concat",
            "one branch over expression and gesture together, 1.41x wider", model={"flow": "concat"}),
    Variant("no-detach", _DS, "section 4.5 / Table 1, Ours w/o Detach",
            "the gesture loss reaches the expression branch through x0^E", model={"detach": False}),
    Variant("no-x0", _DS, "section 4.5 / Table 1, Ours w/o x0^E",
            "the gesture branch does not read the predicted expression", model={"x0_condition": False}),
    Variant("reverse", _DS, "section 4.5 / Table 1, Ours Reverse Direction",
            "gesture first: the expression branch reads the predicted gesture", model={"flow": "reverse"}),
)


def variants_of(family: str) -> dict[str, Variant]:
    return {v.name: v for v in VARIANTS if v.family == family}


def get(family: str, name: str) -> Variant:
    found = variants_of(family)
    if name not in found:
        raise ValueError(f"unknown {family} variant {name!r}; choose one of {', '.join(found)} "
                         "(python -m livegesture.train --list-variants)")
    return found[name]


def apply(cfg, family: str, name: str | None):
    """``cfg`` with variant ``name``'s model fields set (and ``variant = name``); None or "full": unchanged."""
    if name is None:
        return cfg
    v = get(family, name)
    fields = {f.name for f in dataclasses.fields(cfg)}
    model = v.model_fields(cfg)
    unknown = set(model) - fields
    if unknown:      # a variant naming a field the config lacks is a bug of this table: fail loudly
        raise ValueError(f"variant {name}: unknown {family} config fields {sorted(unknown)}")
    return dataclasses.replace(cfg, variant=name, **model)


def train_overrides(family: str, name: str | None) -> dict:
    """The training-config fields variant ``name`` sets (empty for None)."""
    return {} if name is None else dict(get(family, name).train)

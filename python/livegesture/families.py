"""The one registry of model families: a checkpoint's or a bundle manifest's ``family`` -> its config, model,
trainer, reference sampler, exporter and variants.

Nothing outside this module compares family names: tools ask the registry (``get(name)``, ``of_model(model)``,
``of_payload(checkpoint)``, ``of_manifest(manifest)``) and call what the family entry names. Entries name
their parts as ``"module:attribute"`` strings resolved on first use, so importing the registry imports no
model code (and the exporter, which lives in the ``export`` package of the repository, not in this Python
package, is resolved only by the exporter itself).

A new family is one more :class:`Family` in ``FAMILIES``.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class Family:
    name: str              # the manifest's / checkpoint's ``family``
    title: str             # how messages name it
    config: str            # module with get_config(name), CONFIGS, and the config class (``config_class``)
    config_class: str      # "module:Class" with from_dict / to_dict
    model: str             # "module:Class" of the torch model (constructor takes the config)
    trainer: str           # "module:function" train_from_args(args, device, opts, speakers): ``livegesture.train``
    train_bench: str       # "module:function" of ``livegesture.bench_train``: that family's training-rate rows
    sampler: str           # "module:function" generate_clip(model, audio_16k, seed=, guidance=, chunk=, ...)
    batch_sampler: str | None   # "module:function" generate_clips(model, audios, seeds, guidance=) or None
    exporter: str          # "module:function" of the ``export`` package: the bundle builder
    export_options: tuple[str, ...]    # ``export/export.py`` options the exporter takes (others are refused)
    sampler_options: tuple[str, ...]   # generate_clip keyword options this family takes besides seed/guidance/chunk
    sampler_options_refused: tuple[str, ...]   # options of the other families that do not apply here
    perturb_zero_init: bool = False    # random weights: layers initialised to zero get noise (outputs would be 0)

    def resolve(self, ref: str):
        mod, _, attr = ref.partition(":")
        return getattr(importlib.import_module(mod), attr)

    def get_config(self, name_or_cfg):
        if not isinstance(name_or_cfg, str):
            return name_or_cfg
        return importlib.import_module(self.config).get_config(name_or_cfg)

    def config_from_dict(self, d: dict):
        return self.resolve(self.config_class).from_dict(d)

    def build_model(self, cfg):
        return self.resolve(self.model)(cfg)

    def variants(self) -> dict:
        """The family's variants (``livegesture.variants``): name -> Variant."""
        from .variants import variants_of
        return variants_of(self.name)


LIVEGESTURE = Family(
    name="livegesture", title="LiveGesture",
    config="livegesture.config", config_class="livegesture.config:LiveGestureConfig",
    model="livegesture.models.model:LiveGesture",
    trainer="livegesture.train:train_from_args",
    train_bench="livegesture.bench_train:bench_livegesture",
    sampler="livegesture.stream:generate_livegesture_clip",
    batch_sampler=None,
    exporter="export.export:_build",
    export_options=("forms", "backend_forms"),
    sampler_options=("temperature", "top_k", "finish", "form"),
    sampler_options_refused=(),
)

DIFFSHEG = Family(
    name="diffsheg", title="DiffSHEG",
    config="livegesture.diffsheg.config", config_class="livegesture.diffsheg.config:DiffSHEGConfig",
    model="livegesture.diffsheg.model:DiffSHEG",
    trainer="livegesture.diffsheg.train:train_from_args",
    train_bench="livegesture.bench_train:bench_diffsheg",
    sampler="livegesture.diffsheg.foppas:generate_clip",
    batch_sampler="livegesture.diffsheg.foppas:generate_clips",
    exporter="export.diffsheg_export:build",
    export_options=("rollout_windows", "guidance", "jumps"),
    sampler_options=(),
    sampler_options_refused=("temperature", "top_k"),
    perturb_zero_init=True,
)

FAMILIES = {f.name: f for f in (LIVEGESTURE, DIFFSHEG)}
DEFAULT = LIVEGESTURE        # checkpoints and manifests without a ``family`` key (written before DiffSHEG)
NAMES = tuple(FAMILIES)


def get(name: str | None) -> Family:
    """The family called ``name`` (None: the default); ValueError naming the choices otherwise."""
    if name is None:
        return DEFAULT
    try:
        return FAMILIES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown model family {name!r} (expected {' or '.join(NAMES)})") from None


def of_model(model) -> Family:
    """The family of a torch model (its class attribute ``family``; absent: the default)."""
    return get(getattr(model, "family", DEFAULT.name))


def of_payload(payload: dict) -> Family:
    """The family of a checkpoint payload (``family`` key; absent: the default)."""
    return get(payload.get("family", DEFAULT.name))


def of_manifest(manifest: dict) -> Family:
    """The family of a bundle manifest (``family`` key; absent: the default)."""
    return get(manifest.get("family", DEFAULT.name))

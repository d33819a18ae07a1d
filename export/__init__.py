"""The exporter: a trained (or random-weights) model -> a model bundle (docs/bundle.md).

Modules: ``export`` (the command, and the LiveGesture bundle builder), ``diffsheg_export`` (the DiffSHEG
bundle builder), ``graphs`` (step-graph wrappers), ``verify`` (export-time checks), ``bundle_writer``
(manifest, files, atomic staging), ``quantize`` (reduced-precision bundles), ``flops``. Which builder a
model's family uses is ``livegesture.families`` (the registry's ``exporter``).

Run from the repository root as ``python -m export.export ...`` or ``python export/export.py ...`` (the same);
the ``livegesture`` package must be importable (``source scripts/env.sh`` installs it).
"""

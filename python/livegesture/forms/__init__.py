"""Graph forms (docs/bundle.md#forms-and-precision): other arrangements of the canonical components' arithmetic,
each exported as its own graph and checked against the canonical torch steps.

- :mod:`.experts_fused`: ``experts_fused``, the four region eXperts as one step on a region axis (form ``fused``);
- :mod:`.decoders_fused`: ``decoders_fused``, the four region SVQ decoders as one step (form ``fused``);
- :mod:`.fusion_attention`: ``fusion_attention``, the fusion with the opset-23 Attention op (form ``attention``).
- :mod:`.ring`: ring caches with a cohort phase, the torch reference of a cache layout not exported yet (issue 42;
  the steps read their caches in place and return only the new entries).

Not to be confused with :mod:`livegesture.models.fuse`, the model's xAR-Fuse component (the ``fusion`` graph).
"""

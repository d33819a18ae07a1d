"""LiveGesture: streaming zero-look-ahead co-speech full-body gesture generation (PyTorch reference).

The package is the single source of truth for numerics. Components (paper names):

- ``frontend``: the log-mel frontend (owned numerics, reproduced exactly in Rust).
- ``models.audio_encoder``: the streamable audio encoder.
- ``models.svq``: the per-region Streamable Vector-Quantized motion tokenizer (SVQ).
- ``models.expert``: the region-eXpert autoregressive transformer (xAR).
- ``models.fuse``: the causal spatial-temporal fusion transformer (xAR-Fuse).
- ``sampling``: classifier-free guidance on logits and the portable seeded sampler.
- ``stream``: the streaming reference loop chaining the step functions.
"""

__version__ = "0.1.0"

import torch

from livegesture.checkpoint import random_model


def scrambled_model(config: str, seed: int = 0):
    """Random weights where every parameter (null audio, PILOR adapters, region embeddings included) is
    non-trivial, so that the equality tests exercise every path."""
    m = random_model(config, seed)
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for name, p in m.named_parameters():
            if "pilor" in name or "null_audio" in name or "region_embed" in name:
                p.add_(0.1 * torch.randn(p.shape, generator=g))
        for r, svq in m.svq.items():
            svq.mean.copy_(torch.randn(svq.mean.shape, generator=g))
            svq.std.copy_(torch.rand(svq.std.shape, generator=g) + 0.5)
        m.audio_encoder.mel_mean.copy_(torch.randn(m.audio_encoder.mel_mean.shape, generator=g) - 5)
        m.audio_encoder.mel_std.copy_(torch.rand(m.audio_encoder.mel_std.shape, generator=g) + 1)
    return m.eval()

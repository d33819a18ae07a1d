"""DiffSHEG (seed 001): diffusion-based joint expression and gesture generation, the toolchain's second model
family. Components: ``config`` (tiny/default/paper), ``audio`` (speech encoders), ``layers`` (linear
self-attention, AdaIN, style-aware Transformer block, fusion residual block), ``denoiser`` (UniEG),
``model`` (the whole model), ``schedule`` (betas, alpha_bar, DDIM timesteps), ``noise`` (portable Gaussian
noise), ``foppas`` (DDIM + guidance + FOPPAS, the stream), ``train`` (training loop)."""

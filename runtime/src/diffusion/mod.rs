//! The DiffSHEG sampler's settings ([`SamplerOptions`], [`MOTION_DIM`]) and its noise schedule
//! ([`schedule`]): what a bundle's manifest fixes (its `diffusion` and `foppas` sections, read by the
//! bundle module) and what the DiffSHEG model samples with. A leaf module (it imports no other module
//! of the crate), so that the bundle reader does not depend on the model.

use anyhow::{bail, Result};

pub mod schedule;

pub use schedule::Schedule;

/// Motion features per frame (`motion.dim`).
pub const MOTION_DIM: usize = 425;

/// The sampler's settings (defaults: the manifest's `diffusion` and `foppas` sections).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplerOptions {
    /// DDIM steps S (must divide the training steps, 1000).
    pub steps: usize,
    /// Classifier-free guidance scale (1.0: only the conditional row runs).
    pub guidance: f64,
    /// Window length N in frames (<= `foppas.max_window`).
    pub window: usize,
    /// Overlap L in frames (< N).
    pub overlap: usize,
    /// RePaint jumps U per step (>= 1; 1 = no jump back).
    pub jumps: usize,
    /// The last `blend_steps` DDIM steps blend the known overlap linearly instead of replacing it.
    pub blend_steps: usize,
}

impl SamplerOptions {
    /// Checks every option; the error names the option and the valid range.
    pub fn validate(&self, schedule: &Schedule, max_window: usize) -> Result<()> {
        schedule.check_steps(self.steps)?;
        if self.window == 0 || self.window > max_window {
            bail!(
                "window must be in 1..={max_window} frames (the model's positional table, foppas.max_window), got {}",
                self.window
            );
        }
        if self.overlap >= self.window {
            bail!(
                "overlap must be smaller than the window ({} frames), got {}",
                self.window,
                self.overlap
            );
        }
        if self.jumps == 0 {
            bail!("jumps must be at least 1 (1 = no RePaint jump back), got 0");
        }
        if !self.guidance.is_finite() {
            bail!("guidance must be a finite number, got {}", self.guidance);
        }
        Ok(())
    }

    /// Denoiser rows per call: 2 with guidance (cond 1, cond 0), 1 without.
    pub fn rows(&self) -> usize {
        if self.guidance == 1.0 {
            1
        } else {
            2
        }
    }

    /// Denoiser calls of a window of `n` frames with (`outpaint`) or without known frames.
    pub fn calls_per_window(&self, outpaint: bool) -> usize {
        if outpaint && self.overlap > 0 {
            (self.steps - 1) * self.jumps + 1
        } else {
            self.steps
        }
    }

    /// Normals a window of `n` frames draws (docs/bundle.md: `nD` for the first window, else
    /// `nD + (S-1)(U L D + (U-1) n D)`).
    pub fn normals_per_window(&self, n: usize, outpaint: bool) -> u64 {
        let d = MOTION_DIM as u64;
        let n = n as u64;
        if outpaint && self.overlap > 0 {
            let (s, u, l) = (self.steps as u64, self.jumps as u64, self.overlap as u64);
            n * d + (s - 1) * (u * l * d + (u - 1) * n * d)
        } else {
            n * d
        }
    }
}

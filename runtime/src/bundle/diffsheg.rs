//! The manifest sections only a DiffSHEG bundle has (docs/bundle.md "DiffSHEG bundles"):
//! `diffusion`, `foppas`, `noise`, `motion`, `speakers`, and the `regions` and per-region
//! `normalisation` it shares in form with LiveGesture, parsed and checked against each other in
//! [`parse_manifest`](super::parse_manifest) when the manifest's `family` is `diffsheg`. Errors name the
//! manifest field and what was expected.

use std::collections::BTreeMap;

use anyhow::{bail, ensure, Context, Result};
use serde::Deserialize;
use serde_json::Value;

use super::RegionSpec;
use crate::diffusion::schedule::{alphas_cumprod, parse_f64_bits, Schedule};
use crate::diffusion::{SamplerOptions, MOTION_DIM};

/// `diffusion.ddim`.
#[derive(Debug, Clone, Deserialize)]
pub struct Ddim {
    /// Default DDIM steps (the paper's 25).
    pub steps: usize,
    /// Must be 0 (deterministic DDIM).
    #[serde(default)]
    pub eta: f64,
}

/// `diffusion.guidance`.
#[derive(Debug, Clone, Deserialize)]
pub struct Guidance {
    /// Default classifier-free guidance scale.
    pub scale: f64,
}

/// `diffusion`.
#[derive(Debug, Clone, Deserialize)]
pub struct Diffusion {
    /// Training steps (1000).
    pub train_steps: usize,
    /// `linear`.
    pub beta_schedule: String,
    pub beta_start: f64,
    pub beta_end: f64,
    /// `epsilon`.
    pub prediction: String,
    /// Exact table, 16 hex digits per value.
    pub alphas_cumprod_f64_bits: Vec<String>,
    pub ddim: Ddim,
    pub guidance: Guidance,
}

/// `foppas`.
#[derive(Debug, Clone, Deserialize)]
pub struct Foppas {
    pub window: usize,
    pub overlap: usize,
    pub jumps: usize,
    pub blend_steps: usize,
    /// Longest window the graphs take (their positional tables).
    pub max_window: usize,
}

/// `noise`.
#[derive(Debug, Clone, Deserialize)]
pub struct Noise {
    /// `splitmix64`.
    pub prng: String,
}

/// One entry of `motion.layout`.
#[derive(Debug, Clone, Deserialize)]
pub struct LayoutEntry {
    pub region: String,
    pub offset: usize,
    pub dim: usize,
}

/// `motion`.
#[derive(Debug, Clone, Deserialize)]
pub struct Motion {
    pub dim: usize,
    pub layout: Vec<LayoutEntry>,
}

/// `speakers`.
#[derive(Debug, Clone, Deserialize)]
pub struct Speakers {
    pub count: usize,
    pub default: usize,
}

#[derive(Debug, Clone, Deserialize)]
struct MeanStd {
    mean: Vec<f32>,
    std: Vec<f32>,
}

/// Every DiffSHEG section of a manifest, checked.
#[derive(Debug, Clone)]
pub struct DiffshegManifest {
    pub diffusion: Diffusion,
    pub foppas: Foppas,
    pub noise: Noise,
    pub motion: Motion,
    pub speakers: Speakers,
    /// Body regions and their feature layouts (as LiveGesture's).
    pub regions: Vec<RegionSpec>,
    /// Per motion feature (D = 425): `std` and `mean` from `normalisation[region]` at the region's
    /// offset.
    pub std: Vec<f32>,
    pub mean: Vec<f32>,
    /// The schedule from the exact bits (equal to the definition's recomputation).
    pub schedule: Schedule,
}

fn section<T: serde::de::DeserializeOwned>(m: &Value, name: &str) -> Result<T> {
    let v = m.get(name).with_context(|| {
        format!("manifest field '{name}' is missing (required for family diffsheg)")
    })?;
    serde_json::from_value(v.clone())
        .with_context(|| format!("manifest field '{name}' is malformed"))
}

impl DiffshegManifest {
    /// Parses and checks the sections of `manifest` (the whole manifest JSON).
    pub fn parse(manifest: &Value) -> Result<Self> {
        let diffusion: Diffusion = section(manifest, "diffusion")?;
        let foppas: Foppas = section(manifest, "foppas")?;
        let noise: Noise = section(manifest, "noise")?;
        let motion: Motion = section(manifest, "motion")?;
        let speakers: Speakers = section(manifest, "speakers")?;
        let regions: Vec<RegionSpec> = section(manifest, "regions")?;
        let norm: BTreeMap<String, MeanStd> = section(manifest, "normalisation")?;
        super::livegesture::check_coverage(&regions)
            .map_err(|e| anyhow::anyhow!("manifest regions: {e}"))?;

        ensure!(
            diffusion.beta_schedule == "linear" && diffusion.prediction == "epsilon",
            "manifest diffusion: beta_schedule '{}' / prediction '{}', this runtime implements 'linear' / 'epsilon'",
            diffusion.beta_schedule,
            diffusion.prediction
        );
        ensure!(
            diffusion.ddim.eta == 0.0,
            "manifest diffusion.ddim.eta: expected 0 (deterministic DDIM), got {}",
            diffusion.ddim.eta
        );
        ensure!(
            noise.prng == "splitmix64",
            "manifest noise.prng: expected 'splitmix64', got '{}'",
            noise.prng
        );
        ensure!(
            diffusion.train_steps >= 2
                && diffusion.alphas_cumprod_f64_bits.len() == diffusion.train_steps,
            "manifest diffusion.alphas_cumprod_f64_bits: {} values, expected train_steps = {}",
            diffusion.alphas_cumprod_f64_bits.len(),
            diffusion.train_steps
        );
        let table = parse_f64_bits(&diffusion.alphas_cumprod_f64_bits)
            .context("manifest diffusion.alphas_cumprod_f64_bits")?;
        let recomputed = alphas_cumprod(
            diffusion.train_steps,
            diffusion.beta_start,
            diffusion.beta_end,
        );
        if let Some(i) = (0..table.len()).find(|&i| table[i].to_bits() != recomputed[i].to_bits()) {
            bail!(
                "manifest diffusion.alphas_cumprod_f64_bits[{i}] = {} differs from the linear schedule \
                 ({} .. {}, {} steps) it states: expected {}",
                table[i],
                diffusion.beta_start,
                diffusion.beta_end,
                diffusion.train_steps,
                recomputed[i]
            );
        }
        let schedule = Schedule {
            alphas_cumprod: table,
        };
        ensure!(
            motion.dim == MOTION_DIM,
            "manifest motion.dim: expected {MOTION_DIM}, got {}",
            motion.dim
        );
        let mut std = vec![f32::NAN; MOTION_DIM];
        let mut mean = vec![f32::NAN; MOTION_DIM];
        let mut covered = 0;
        for e in &motion.layout {
            ensure!(
                e.offset + e.dim <= MOTION_DIM,
                "manifest motion.layout: region '{}' [{}, {}) exceeds {MOTION_DIM}",
                e.region,
                e.offset,
                e.offset + e.dim
            );
            let ms = norm.get(&e.region).with_context(|| {
                format!(
                    "manifest normalisation.{}: missing (named by motion.layout)",
                    e.region
                )
            })?;
            ensure!(
                ms.mean.len() == e.dim && ms.std.len() == e.dim,
                "manifest normalisation.{}: mean/std have {}/{} values, expected {}",
                e.region,
                ms.mean.len(),
                ms.std.len(),
                e.dim
            );
            std[e.offset..e.offset + e.dim].copy_from_slice(&ms.std);
            mean[e.offset..e.offset + e.dim].copy_from_slice(&ms.mean);
            covered += e.dim;
        }
        ensure!(
            covered == MOTION_DIM && std.iter().chain(&mean).all(|v| v.is_finite()),
            "manifest motion.layout must cover all {MOTION_DIM} features once with finite normalisation"
        );
        ensure!(
            speakers.count >= 1 && speakers.default < speakers.count,
            "manifest speakers: default {} outside 0..{}",
            speakers.default,
            speakers.count
        );
        let s = Self {
            diffusion,
            foppas,
            noise,
            motion,
            speakers,
            regions,
            std,
            mean,
            schedule,
        };
        s.default_options()
            .validate(&s.schedule, s.foppas.max_window)
            .context("manifest foppas/diffusion defaults")?;
        Ok(s)
    }

    /// The sampler options the bundle states (the paper's defaults for a paper-config bundle).
    pub fn default_options(&self) -> SamplerOptions {
        SamplerOptions {
            steps: self.diffusion.ddim.steps,
            guidance: self.diffusion.guidance.scale,
            window: self.foppas.window,
            overlap: self.foppas.overlap,
            jumps: self.foppas.jumps,
            blend_steps: self.foppas.blend_steps,
        }
    }

    /// De-normalises rows (frames x D) in place: `x * std + mean`, one f32 multiply then one f32 add.
    pub fn denormalise(&self, rows: &mut [f32]) {
        for row in rows.chunks_exact_mut(MOTION_DIM) {
            for ((v, &s), &m) in row.iter_mut().zip(&self.std).zip(&self.mean) {
                let p = *v * s;
                *v = p + m;
            }
        }
    }
}

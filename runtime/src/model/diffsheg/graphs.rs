//! The window's graph chain on a backend: `speech_encoder` then `denoiser`, as [`WindowGraphs`].
//!
//! The guidance rows (cond 1, cond 0) of a call are rows of one denoiser run on the batch axis.

use anyhow::{ensure, Context, Result};

use super::foppas::MOTION_DIM;
use super::stream::WindowGraphs;
use crate::backend::{GraphRunner, Tensor};

/// The two loaded graphs of a DiffSHEG bundle, shared by the streams of every thread (runs take
/// `&self`, each with a run state or session of its own).
pub struct DiffshegGraphs {
    /// `speech_encoder`.
    pub encoder: Box<dyn GraphRunner>,
    /// `denoiser`.
    pub denoiser: Box<dyn GraphRunner>,
    /// Mel bands of the encoder's input.
    pub n_mels: usize,
    /// Features per frame of the encoder's output (`audio_dim`).
    pub audio_dim: usize,
}

impl std::fmt::Debug for DiffshegGraphs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DiffshegGraphs")
            .field("n_mels", &self.n_mels)
            .field("audio_dim", &self.audio_dim)
            .finish_non_exhaustive()
    }
}

impl DiffshegGraphs {
    /// `speech_encoder` on a batch of windows of `n` frames: mel (B, 2n, n_mels) -> (B, n, audio_dim).
    pub fn encode_batch(&self, mel: Vec<f32>, batch: usize, n: usize) -> Result<Vec<f32>> {
        let t = Tensor::f32(vec![batch, 2 * n, self.n_mels], mel)?;
        let out = self.encoder.run(&[t])?;
        let a = out
            .into_iter()
            .next()
            .context("speech_encoder returned no output")?;
        ensure!(
            a.shape == [batch, n, self.audio_dim],
            "speech_encoder: output 'audio' has shape {:?}, expected [{batch}, {n}, {}]",
            a.shape,
            self.audio_dim
        );
        Ok(a.as_f32("speech_encoder output 'audio'")?.to_vec())
    }

    /// `denoiser` on B rows: x (B, n, D), t (B), audio (B, n, audio_dim), speaker (B), cond (B).
    #[allow(clippy::too_many_arguments)]
    pub fn denoise_batch(
        &self,
        x: Vec<f32>,
        t: Vec<i64>,
        audio: Vec<f32>,
        speaker: Vec<i64>,
        cond: Vec<f32>,
        n: usize,
    ) -> Result<Vec<f32>> {
        let b = t.len();
        let inputs = [
            Tensor::f32(vec![b, n, MOTION_DIM], x)?,
            Tensor::i64(vec![b], t)?,
            Tensor::f32(vec![b, n, self.audio_dim], audio)?,
            Tensor::i64(vec![b], speaker)?,
            Tensor::f32(vec![b], cond)?,
        ];
        let names: Vec<&str> = ["x_t", "t", "audio", "speaker", "cond"].to_vec();
        let named: Vec<(&str, &Tensor)> = names.iter().copied().zip(inputs.iter()).collect();
        let out = self.denoiser.run_named(&named)?;
        let (_, eps) = out
            .into_iter()
            .next()
            .context("denoiser returned no output")?;
        ensure!(
            eps.shape == [b, n, MOTION_DIM],
            "denoiser: output 'eps' has shape {:?}, expected [{b}, {n}, {MOTION_DIM}]",
            eps.shape
        );
        Ok(eps.as_f32("denoiser output 'eps'")?.to_vec())
    }
}

impl WindowGraphs for DiffshegGraphs {
    fn encode(&self, mel: &[f32], n: usize) -> Result<Vec<f32>> {
        self.encode_batch(mel.to_vec(), 1, n)
    }

    fn denoise(
        &self,
        x: &[f32],
        n: usize,
        t: i64,
        audio: &[f32],
        speaker: i64,
        conds: &[f32],
    ) -> Result<Vec<f32>> {
        let b = conds.len();
        let mut xs = Vec::with_capacity(b * x.len());
        let mut au = Vec::with_capacity(b * audio.len());
        for _ in 0..b {
            xs.extend_from_slice(x);
            au.extend_from_slice(audio);
        }
        self.denoise_batch(xs, vec![t; b], au, vec![speaker; b], conds.to_vec(), n)
    }
}

//! One LiveGesture stream's state, and the results of one token step.

use anyhow::{ensure, Result};
use ndarray::Array2;

use super::caches::Caches;
use super::StreamOptions;
use crate::audio::AudioSpan;
use crate::frontend::StreamingLogMel;
use crate::output::Frame;
use crate::sampling::SplitMix64;

/// Logits of one token step, `(regions, codebook_size)` row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct StepLogits {
    /// Conditional branch.
    pub cond: Vec<f32>,
    /// Unconditional branch (absent without guidance).
    pub uncond: Option<Vec<f32>>,
}

/// The result of one token step of one stream.
#[derive(Debug, Clone, PartialEq)]
pub struct TokenStep {
    /// Token index `t` (from 0).
    pub token_index: u64,
    /// Sampled token per region, in region order.
    pub tokens: Vec<i64>,
    /// The fusion logits (only with [`StreamOptions::record_logits`]).
    pub logits: Option<StepLogits>,
    /// Frames `4t .. 4t + 3`.
    pub frames: Vec<Frame>,
}

/// Everything of one stream except its caches.
#[derive(Debug)]
pub(super) struct StreamState {
    pub(super) opts: StreamOptions,
    pub(super) gamma: f64,
    pub(super) temperature: f64,
    pub(super) top_k: usize,
    pub(super) frontend: StreamingLogMel,
    pub(super) prev: Vec<i64>,
    pub(super) rng: SplitMix64,
    /// Tokens stepped.
    pub(super) t: u64,
    /// Set by [`StreamState::finish_audio`]: (frames covering the input, silence samples added).
    pub(super) end: Option<(u64, u64)>,
}

impl StreamState {
    pub(super) fn new(
        opts: &StreamOptions,
        gamma: f64,
        temperature: f64,
        top_k: usize,
        frontend: StreamingLogMel,
        bos: i64,
        n_regions: usize,
    ) -> Self {
        StreamState {
            opts: opts.clone(),
            gamma,
            temperature,
            top_k,
            frontend,
            prev: vec![bos; n_regions],
            rng: SplitMix64::new(opts.seed),
            t: 0,
            end: None,
        }
    }

    pub(super) fn branch_rows(&self) -> usize {
        if self.gamma != 1.0 {
            2
        } else {
            1
        }
    }

    /// Errors once the stream has been finished.
    pub(super) fn check_open(&self) -> Result<()> {
        ensure!(
            self.end.is_none(),
            "the stream was finished (its audio ended); reset it to start a new one"
        );
        Ok(())
    }

    /// Feeds audio to the frontend; returns the mel blocks of the tokens it completes.
    pub(super) fn push_audio(&mut self, chunk: &[f32]) -> Result<Vec<Array2<f32>>> {
        self.check_open()?;
        self.frontend.push(chunk)
    }

    /// Ends the stream's audio (docs/output.md): pushes the silence that completes its last partial token and
    /// returns the mel blocks of the tokens still to step, and the number of frames that covers
    /// `input` ([`AudioSpan::frames`]); the caller steps the blocks and keeps the frames whose index
    /// is below that number. Errors (changing nothing) when `input` claims more than one token of
    /// audio beyond what was pushed, or fewer frames than the tokens already produced.
    pub(super) fn finish_audio(&mut self, input: AudioSpan) -> Result<(Vec<Array2<f32>>, u64)> {
        self.check_open()?;
        let cfg = self.frontend.config().clone();
        let total = input.frames(cfg.fps);
        let fpt = cfg.frames_per_token;
        let produced = self.frontend.tokens_emitted();
        let received = self.frontend.samples_received();
        let describe = || {
            format!(
                "the input is {} samples at {} Hz ({:.3} s, {total} frames) but {received} samples at {} Hz were pushed ({produced} tokens, {} frames)",
                input.samples,
                input.sample_rate,
                input.seconds(),
                cfg.sample_rate,
                produced * fpt
            )
        };
        ensure!(
            produced * fpt <= total,
            "finish: {}: fewer frames than already produced",
            describe()
        );
        let needed = total.div_ceil(fpt);
        ensure!(
            needed <= produced + 1,
            "finish: {}: more than one token of audio is missing",
            describe()
        );
        let mut pad = 0;
        let mels = if needed > produced {
            pad = cfg.token_end(needed - 1) - received;
            self.frontend.push(&vec![0.0; pad as usize])?
        } else {
            Vec::new()
        };
        ensure!(
            self.frontend.tokens_emitted() == needed,
            "finish: the silence completed {} tokens, expected {needed}",
            self.frontend.tokens_emitted()
        );
        self.end = Some((total, pad));
        Ok((mels, total))
    }

    /// Frames produced so far (cut at the end of the audio once finished).
    pub(super) fn frames_done(&self) -> u64 {
        let n = self.t * self.frontend.config().frames_per_token;
        match self.end {
            Some((total, _)) => n.min(total),
            None => n,
        }
    }

    /// Samples received (in all) at which the next token's audio is complete; `u64::MAX` once
    /// finished.
    pub(super) fn next_token_samples(&self) -> u64 {
        if self.end.is_some() {
            return u64::MAX;
        }
        self.frontend
            .config()
            .token_end(self.frontend.tokens_emitted())
    }

    /// Samples received, without the silence added by `finish`.
    pub(super) fn samples_received(&self) -> u64 {
        self.frontend.samples_received() - self.end.map_or(0, |e| e.1)
    }
}

/// One stream's state (see the module docs).
#[derive(Debug)]
pub struct Stream {
    pub(super) state: StreamState,
    pub(super) caches: Caches,
    pub(super) poisoned: bool,
}

impl Stream {
    /// True when classifier-free guidance is on (gamma != 1).
    pub fn guided(&self) -> bool {
        self.state.gamma != 1.0
    }

    /// Rows this stream occupies in the expert and fusion batches (2 with guidance, else 1).
    pub fn branch_rows(&self) -> usize {
        self.state.branch_rows()
    }

    /// Guidance scale in use.
    pub fn guidance(&self) -> f64 {
        self.state.gamma
    }

    /// Temperature in use.
    pub fn temperature(&self) -> f64 {
        self.state.temperature
    }

    /// Top-k in use.
    pub fn top_k(&self) -> usize {
        self.state.top_k
    }

    /// The options the stream was created with.
    pub fn options(&self) -> &StreamOptions {
        &self.state.opts
    }

    /// Tokens stepped so far.
    pub fn tokens_done(&self) -> u64 {
        self.state.t
    }

    /// Frames emitted so far (`frames_per_token` per token; once finished, cut at the audio's end).
    pub fn frames_done(&self) -> u64 {
        self.state.frames_done()
    }

    /// Audio samples received so far (not counting the silence added by [`LiveGestureGraphs::finish`](super::LiveGestureGraphs::finish)).
    pub fn samples_received(&self) -> u64 {
        self.state.samples_received()
    }

    /// Samples received (in all) at which the next token's audio is complete (`u64::MAX` once
    /// finished).
    pub fn next_token_samples(&self) -> u64 {
        self.state.next_token_samples()
    }

    /// True once [`LiveGestureGraphs::finish`](super::LiveGestureGraphs::finish) (or [`Stream::finish_audio`]) ended the stream.
    pub fn is_finished(&self) -> bool {
        self.state.end.is_some()
    }

    /// The previous token of every region (BOS before the first step).
    pub fn prev_tokens(&self) -> &[i64] {
        &self.state.prev
    }

    /// True after a failed step: the stream refuses further work until [`LiveGestureGraphs::reset`](super::LiveGestureGraphs::reset).
    pub fn is_poisoned(&self) -> bool {
        self.poisoned
    }

    /// Feeds audio to the stream's frontend only, returning the mel frames of each completed token.
    /// Use with [`LiveGestureGraphs::step_batch`](super::LiveGestureGraphs::step_batch) to step many streams together.
    pub fn push_audio(&mut self, chunk: &[f32]) -> Result<Vec<Array2<f32>>> {
        self.state.push_audio(chunk)
    }

    /// Ends the stream's audio for stepping with [`LiveGestureGraphs::step_batch`](super::LiveGestureGraphs::step_batch) (docs/output.md): the mel blocks of
    /// the silence-completed last token (none when the audio ended on a token boundary) and the
    /// number of frames that covers `input`; keep only frames whose index is below it
    /// ([`cut_frames`]). [`LiveGestureGraphs::finish`](super::LiveGestureGraphs::finish) does all of this for one stream.
    pub fn finish_audio(&mut self, input: AudioSpan) -> Result<(Vec<Array2<f32>>, u64)> {
        self.state.finish_audio(input)
    }
}

/// Drops the frames of `steps` whose index is `total` or more (the end of the audio, docs/output.md).
pub fn cut_frames(steps: &mut [TokenStep], total: u64) {
    for s in steps {
        s.frames.retain(|f| f.index < total);
    }
}

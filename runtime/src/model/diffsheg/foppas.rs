//! DDIM, classifier-free guidance and FOPPAS, operation by operation as
//! `python/livegesture/diffsheg/foppas.py` defines them (the manifest's `foppas.definition`).
//!
//! Graph outputs are float32; everything the sampler computes is IEEE float64 per element in the
//! written order (Rust never fuses a multiply and an add on its own), rounded to float32 only where the
//! definition says so. Given the same graph outputs the sampler is therefore exact: the per-call trace
//! of the reference rollout is reproduced bit for bit (tests below).
//!
//! - [`SamplerOptions`]: steps, guidance, window N, overlap L, jumps U, blend steps.
//! - [`plan_windows`]: the windows of a stream of T frames.
//! - [`WindowSampler`]: one window, as a state machine that asks for one guided `eps` at a time
//!   ([`WindowSampler::next_call`], [`WindowSampler::feed`]); [`sample_window`] drives it with a closure.
//! - [`guided_eps`]: `u + gamma * (c - u)` in float64 from the denoiser's two rows.

use anyhow::{ensure, Result};

use super::noise::NoiseStream;
use super::schedule::Schedule;
pub use crate::diffusion::{SamplerOptions, MOTION_DIM};

/// `(start, n)` of every window of a stream of `t` frames (window N, overlap L): starts 0, N-L, ...,
/// `n = min(N, t - start)`; the last window is the first with `start + N >= t`.
pub fn plan_windows(t: usize, window: usize, overlap: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    if t == 0 {
        return out;
    }
    let mut s = 0;
    loop {
        let n = window.min(t - s);
        out.push((s, n));
        if s + window >= t {
            break;
        }
        s += window - overlap;
    }
    out
}

/// Classifier-free guidance in float64: `u + gamma * (c - u)` from the conditional row `c` and the
/// unconditional row `u` (float32 graph outputs); `c` alone when `u` is `None` (gamma 1).
pub fn guided_eps(c: &[f32], u: Option<&[f32]>, gamma: f64) -> Vec<f64> {
    match u {
        None => c.iter().map(|&v| v as f64).collect(),
        Some(u) => c
            .iter()
            .zip(u)
            .map(|(&c, &u)| {
                let (c, u) = (c as f64, u as f64);
                u + gamma * (c - u)
            })
            .collect(),
    }
}

/// One denoiser call a window asks for: the noisy motion `x` (n, D) and the DDIM timestep `t`.
#[derive(Debug, Clone, Copy)]
pub struct Call<'a> {
    /// The window's current x, float32 (n x D row-major).
    pub x: &'a [f32],
    /// DDIM timestep `tau_j` (not the step index).
    pub t: i64,
}

/// One FOPPAS window as a state machine (see the module docs and `foppas.py`'s `sample_window`).
#[derive(Debug, Clone)]
pub struct WindowSampler {
    n: usize,
    l: usize,
    known: Option<Vec<f64>>,
    xk: Vec<f64>,
    x: Vec<f32>,
    taus: Vec<usize>,
    /// Current step j (counts down) and pass u.
    j: usize,
    u: usize,
    done: bool,
    calls: usize,
    noise: NoiseStream,
    opts: SamplerOptions,
    w: Vec<f64>,
    schedule: std::sync::Arc<Schedule>,
    /// Scratch buffers reused by every pass (the window's x_{t-1} in float64 and its noise draw).
    xp: Vec<f64>,
    nz: Vec<f32>,
}

impl WindowSampler {
    /// Starts a window of `n` frames: draws `x_T` (n x D) from `noise` (the stream's noise, moved in and
    /// given back by [`WindowSampler::finish`]), and the first pass's known part. `known` is the held
    /// overlap (L x D, float32) of the previous window, `None` for the first window (plain DDIM).
    pub fn new(
        n: usize,
        known: Option<&[f32]>,
        opts: SamplerOptions,
        schedule: std::sync::Arc<Schedule>,
        mut noise: NoiseStream,
    ) -> Result<Self> {
        let d = MOTION_DIM;
        let taus = schedule.ddim_timesteps(opts.steps)?;
        let l = known.map_or(0, |k| k.len() / d);
        if let Some(k) = known {
            ensure!(
                k.len() == l * d && l > 0 && l <= n,
                "FOPPAS: known frames have {} values, expected L x {d} with 1 <= L <= n = {n}",
                k.len()
            );
        }
        let x = noise.take(n * d);
        let w = (0..l)
            .map(|i| {
                if l > 1 {
                    i as f64 / (l - 1) as f64
                } else {
                    0.0
                }
            })
            .collect();
        let mut s = Self {
            n,
            l,
            known: known.map(|k| k.iter().map(|&v| v as f64).collect()),
            xk: Vec::new(),
            x,
            j: opts.steps - 1,
            u: 0,
            taus,
            done: false,
            calls: 0,
            noise,
            opts,
            w,
            schedule,
            xp: vec![0.0; n * d],
            nz: vec![0.0; n * d],
        };
        s.begin_pass();
        Ok(s)
    }

    fn passes(&self) -> usize {
        if self.l > 0 && self.j > 0 {
            self.opts.jumps
        } else {
            1
        }
    }

    /// The known part of this pass, drawn before the denoiser call.
    fn begin_pass(&mut self) {
        let Some(known) = &self.known else { return };
        let (_, a_p) = self.schedule.step_alphas(&self.taus, self.j);
        let m = self.l * MOTION_DIM;
        if self.j > 0 {
            let nz = &mut self.nz[..m];
            self.noise.take_into(nz);
            let (ca, cb) = (a_p.sqrt(), (1.0 - a_p).sqrt());
            self.xk.clear();
            self.xk.extend(
                known
                    .iter()
                    .zip(nz.iter())
                    .map(|(&k, &z)| ca * k + cb * z as f64),
            );
        } else {
            self.xk.clear();
            self.xk.extend_from_slice(known);
        }
    }

    /// The next denoiser call, or `None` when the window is complete.
    pub fn next_call(&self) -> Option<Call<'_>> {
        (!self.done).then(|| Call {
            x: &self.x,
            t: self.taus[self.j] as i64,
        })
    }

    /// Frames of the window.
    pub fn frames(&self) -> usize {
        self.n
    }

    /// Denoiser calls fed so far.
    pub fn calls(&self) -> usize {
        self.calls
    }

    /// The stream's noise position now.
    pub fn noise_position(&self) -> u64 {
        self.noise.position
    }

    /// Applies one pass with the guided `eps` (n x D, float64) of [`WindowSampler::next_call`].
    pub fn feed(&mut self, eps: &[f64]) -> Result<()> {
        ensure!(
            !self.done,
            "FOPPAS: the window is complete; no call was pending"
        );
        let d = MOTION_DIM;
        ensure!(
            eps.len() == self.n * d,
            "FOPPAS: eps has {} values, expected {} x {d}",
            eps.len(),
            self.n
        );
        let (a_t, a_p) = self.schedule.step_alphas(&self.taus, self.j);
        let (c1, c2) = ((1.0 - a_t).sqrt(), a_t.sqrt());
        let (c3, c4) = (a_p.sqrt(), (1.0 - a_p).sqrt());
        let xp = &mut self.xp;
        for ((p, &x), &e) in xp.iter_mut().zip(&self.x).zip(eps) {
            let x0 = (x as f64 - c1 * e) / c2;
            *p = c3 * x0 + c4 * e;
        }
        if self.l > 0 {
            let head = &mut xp[..self.l * d];
            if self.j >= self.opts.blend_steps {
                head.copy_from_slice(&self.xk);
            } else {
                for (i, row) in head.chunks_exact_mut(d).enumerate() {
                    let w = self.w[i];
                    let xk = &self.xk[i * d..(i + 1) * d];
                    for (p, &k) in row.iter_mut().zip(xk) {
                        *p = (1.0 - w) * k + w * *p;
                    }
                }
            }
        }
        self.calls += 1;
        let passes = self.passes();
        if self.u + 1 < passes {
            // RePaint jump back from step j-1 to step j
            let r = a_t / a_p;
            let (ra, rb) = (r.sqrt(), (1.0 - r).sqrt());
            self.noise.take_into(&mut self.nz);
            for ((x, &p), &z) in self.x.iter_mut().zip(self.xp.iter()).zip(&self.nz) {
                *x = (ra * p + rb * z as f64) as f32;
            }
            self.u += 1;
        } else {
            for (x, &p) in self.x.iter_mut().zip(self.xp.iter()) {
                *x = p as f32;
            }
            if self.j == 0 {
                self.done = true;
                return Ok(());
            }
            self.j -= 1;
            self.u = 0;
        }
        self.begin_pass();
        Ok(())
    }

    /// Skips to the last DDIM step (j = 0, which draws no noise) with `x` as its input: for checking
    /// the last pass against a recorded call (parity tools, tests).
    pub fn resume_at_last_step(mut self, x: &[f32]) -> Result<Self> {
        ensure!(
            x.len() == self.x.len(),
            "FOPPAS: x has {} values, expected {}",
            x.len(),
            self.x.len()
        );
        self.x.copy_from_slice(x);
        self.j = 0;
        self.u = 0;
        self.done = false;
        self.begin_pass();
        Ok(self)
    }

    /// The window's clean motion (n x D, float32) and the stream's noise, once every call was fed.
    pub fn finish(self) -> Result<(Vec<f32>, NoiseStream)> {
        ensure!(
            self.done,
            "FOPPAS: window finished after {} of {} denoiser calls",
            self.calls,
            self.opts.calls_per_window(self.l > 0)
        );
        Ok((self.x, self.noise))
    }
}

/// Runs one window with `eps(x, t)` returning the guided eps (n x D, float64) of each call.
pub fn sample_window(
    n: usize,
    known: Option<&[f32]>,
    opts: SamplerOptions,
    schedule: std::sync::Arc<Schedule>,
    noise: &mut NoiseStream,
    mut eps: impl FnMut(&[f32], i64) -> Result<Vec<f64>>,
) -> Result<Vec<f32>> {
    let mut w = WindowSampler::new(n, known, opts, schedule, *noise)?;
    while let Some(c) = w.next_call() {
        let e = eps(c.x, c.t)?;
        w.feed(&e)?;
    }
    let (x, nz) = w.finish()?;
    *noise = nz;
    Ok(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::diffsheg::schedule::alphas_cumprod;
    use std::sync::Arc;

    fn schedule() -> Arc<Schedule> {
        Arc::new(Schedule {
            alphas_cumprod: alphas_cumprod(1000, 1e-4, 0.02),
        })
    }

    fn opts() -> SamplerOptions {
        SamplerOptions {
            steps: 5,
            guidance: 1.25,
            window: 24,
            overlap: 4,
            jumps: 2,
            blend_steps: 2,
        }
    }

    #[test]
    fn windows_cover_the_stream() {
        assert_eq!(plan_windows(0, 24, 4), vec![]);
        assert_eq!(plan_windows(10, 24, 4), vec![(0, 10)]);
        assert_eq!(plan_windows(24, 24, 4), vec![(0, 24)]);
        assert_eq!(
            plan_windows(98, 24, 4),
            vec![(0, 24), (20, 24), (40, 24), (60, 24), (80, 18)]
        );
        assert_eq!(plan_windows(44, 24, 4), vec![(0, 24), (20, 24)]);
        assert_eq!(plan_windows(45, 24, 4), vec![(0, 24), (20, 24), (40, 5)]);
    }

    #[test]
    fn options_are_validated_with_clear_messages() {
        let s = schedule();
        assert!(opts().validate(&s, 24).is_ok());
        let msg = |o: SamplerOptions| o.validate(&s, 24).unwrap_err().to_string();
        assert!(msg(SamplerOptions { steps: 7, ..opts() }).contains("must divide 1000"));
        assert!(msg(SamplerOptions {
            window: 25,
            ..opts()
        })
        .contains("1..=24"));
        assert!(msg(SamplerOptions {
            window: 0,
            ..opts()
        })
        .contains("window"));
        assert!(msg(SamplerOptions {
            overlap: 24,
            ..opts()
        })
        .contains("overlap"));
        assert!(msg(SamplerOptions { jumps: 0, ..opts() }).contains("jumps"));
        assert!(msg(SamplerOptions {
            guidance: f64::NAN,
            ..opts()
        })
        .contains("guidance"));
    }

    #[test]
    fn draws_and_calls_follow_the_contract_counts() {
        let s = schedule();
        for (known, n) in [(false, 24), (true, 24), (true, 18)] {
            let o = opts();
            let kn = vec![0.5f32; o.overlap * MOTION_DIM];
            let mut noise = NoiseStream::new(3);
            let mut calls = 0;
            let x = sample_window(
                n,
                known.then_some(&kn[..]),
                o,
                s.clone(),
                &mut noise,
                |x, _| {
                    calls += 1;
                    Ok(x.iter().map(|&v| v as f64 * 0.1).collect())
                },
            )
            .unwrap();
            assert_eq!(x.len(), n * MOTION_DIM);
            assert_eq!(calls, o.calls_per_window(known));
            assert_eq!(noise.position, o.normals_per_window(n, known));
            if known {
                // blended at j = 0 with w_0 = 0: the first overlap frame is the known frame exactly
                assert!(x[..MOTION_DIM].iter().all(|&v| v == 0.5));
            }
        }
    }

    #[test]
    fn guidance_is_float64_and_one_row_without_it() {
        let c = [1.0f32, 2.0];
        let u = [0.5f32, 4.0];
        assert_eq!(guided_eps(&c, Some(&u), 1.25), vec![1.125, 1.5]);
        assert_eq!(guided_eps(&c, None, 1.0), vec![1.0, 2.0]);
        assert_eq!(opts().rows(), 2);
        assert_eq!(
            SamplerOptions {
                guidance: 1.0,
                ..opts()
            }
            .rows(),
            1
        );
    }

    #[test]
    fn feeding_a_finished_window_or_wrong_sizes_fails() {
        let mut w = WindowSampler::new(3, None, opts(), schedule(), NoiseStream::new(0)).unwrap();
        assert!(w.feed(&[0.0; 5]).is_err());
        assert!(
            WindowSampler::new(3, None, opts(), schedule(), NoiseStream::new(0))
                .unwrap()
                .finish()
                .is_err()
        );
        for _ in 0..5 {
            w.feed(&vec![0.0; 3 * MOTION_DIM]).unwrap();
        }
        assert!(w.next_call().is_none());
        assert!(w.feed(&vec![0.0; 3 * MOTION_DIM]).is_err());
    }
}

//! Resampling any input rate to 16 kHz (see the [module docs](super) for the filter and its alignment).

use rubato::{
    calculate_cutoff, Resampler, SincFixedIn, SincInterpolationParameters, SincInterpolationType,
    WindowFunction,
};

use super::{AudioError, AudioSpan, RESAMPLE_BLOCK, TARGET_RATE};

struct SincState {
    rs: SincFixedIn<f64>,
    /// Input not yet processed (fewer than `RESAMPLE_BLOCK` frames between calls).
    pending: Vec<f64>,
    out_buf: Vec<Vec<f64>>,
    /// Leading outputs still to drop (those before stream time 0).
    to_skip: usize,
    /// Real input frames received (the alignment zeros not counted).
    n_in: u64,
    /// Outputs delivered.
    n_out: u64,
}

impl SincState {
    /// Processes one block (`None`: a block of zeros; shorter blocks are zero-padded) and appends
    /// the outputs that are not skipped to `out`.
    fn run_block(
        &mut self,
        block: Option<&[f64]>,
        out: &mut Vec<f32>,
    ) -> Result<(), rubato::ResampleError> {
        let (_, n) = match block {
            Some(b) if b.len() == RESAMPLE_BLOCK => {
                self.rs.process_into_buffer(&[b], &mut self.out_buf, None)?
            }
            Some(b) => self
                .rs
                .process_partial_into_buffer(Some(&[b]), &mut self.out_buf, None)?,
            None => {
                self.rs
                    .process_partial_into_buffer(None::<&[&[f64]]>, &mut self.out_buf, None)?
            }
        };
        let skip = self.to_skip.min(n);
        self.to_skip -= skip;
        out.extend(self.out_buf[0][skip..n].iter().map(|&x| x as f32));
        self.n_out += (n - skip) as u64;
        Ok(())
    }

    /// Appends input, processing every complete block.
    fn feed(
        &mut self,
        input: impl IntoIterator<Item = f64>,
        out: &mut Vec<f32>,
    ) -> Result<(), rubato::ResampleError> {
        for x in input {
            self.pending.push(x);
            if self.pending.len() == RESAMPLE_BLOCK {
                let block = std::mem::take(&mut self.pending);
                self.run_block(Some(&block), out)?;
                self.pending = block;
                self.pending.clear();
            }
        }
        Ok(())
    }
}

fn gcd(a: u64, b: u64) -> u64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// Converts a mono stream at any rate to 16 kHz. See the module docs: pass-through at 16 kHz, otherwise
/// a windowed-sinc resampler fed in fixed blocks, so the output is independent of input chunking.
///
/// Alignment: `rubato::SincFixedIn` (0.16) emits output `k` at input time `(k + 1) * t - 1`, with
/// `t = rate_in / 16000 = p / q` in lowest terms. Prepending `p - 1` zeros and dropping the first
/// `q - 1` outputs makes output `j` sample input time exactly `j * t`; a unit test pins this down.
pub struct Resampler16k {
    rate: u32,
    origin: String,
    sinc: Option<SincState>,
    /// Input samples pushed since creation (kept across `finish`).
    received: u64,
}

impl std::fmt::Debug for Resampler16k {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Resampler16k")
            .field("rate", &self.rate)
            .field("origin", &self.origin)
            .finish_non_exhaustive()
    }
}

impl Resampler16k {
    /// A resampler from `input_rate` Hz to 16 kHz; `origin` names the source in error messages.
    pub fn new(input_rate: u32, origin: impl Into<String>) -> Result<Self, AudioError> {
        let origin = origin.into();
        if input_rate == 0 {
            return Err(AudioError::InvalidSetting {
                origin,
                detail: "sample rate 0 Hz; expected a positive rate".into(),
            });
        }
        let mut r = Self {
            rate: input_rate,
            origin,
            sinc: None,
            received: 0,
        };
        if input_rate != TARGET_RATE {
            r.sinc = Some(r.make_state()?);
        }
        Ok(r)
    }

    fn err(&self, detail: impl std::fmt::Display) -> AudioError {
        AudioError::Resample {
            origin: self.origin.clone(),
            rate: self.rate,
            detail: detail.to_string(),
        }
    }

    fn make_state(&self) -> Result<SincState, AudioError> {
        let sinc_len = 128;
        let window = WindowFunction::BlackmanHarris2;
        let params = SincInterpolationParameters {
            sinc_len,
            f_cutoff: calculate_cutoff(sinc_len, window),
            oversampling_factor: 256,
            interpolation: SincInterpolationType::Cubic,
            window,
        };
        let ratio = TARGET_RATE as f64 / self.rate as f64;
        let rs = SincFixedIn::<f64>::new(ratio, 1.0, params, RESAMPLE_BLOCK, 1)
            .map_err(|e| self.err(e))?;
        let g = gcd(self.rate as u64, TARGET_RATE as u64);
        let (p, q) = (self.rate as u64 / g, TARGET_RATE as u64 / g);
        let out_buf = rs.output_buffer_allocate(true);
        let mut st = SincState {
            rs,
            pending: Vec::with_capacity(RESAMPLE_BLOCK),
            out_buf,
            to_skip: (q - 1) as usize,
            n_in: 0,
            n_out: 0,
        };
        let mut out = Vec::new();
        st.feed(std::iter::repeat_n(0.0, (p - 1) as usize), &mut out)
            .map_err(|e| self.err(e))?;
        debug_assert!(out.is_empty());
        Ok(st)
    }

    /// The input sample rate.
    pub fn input_rate(&self) -> u32 {
        self.rate
    }

    /// The input received since creation, at the input rate (not reset by `finish`).
    pub fn input_span(&self) -> AudioSpan {
        AudioSpan::new(self.received, self.rate)
    }

    /// Pushes input samples; returns the 16 kHz samples now available (possibly none).
    pub fn push(&mut self, input: &[f32]) -> Result<Vec<f32>, AudioError> {
        self.received += input.len() as u64;
        let Some(st) = self.sinc.as_mut() else {
            return Ok(input.to_vec());
        };
        st.n_in += input.len() as u64;
        let mut out =
            Vec::with_capacity(input.len() * TARGET_RATE as usize / self.rate as usize + 16);
        let res = st.feed(input.iter().map(|&x| x as f64), &mut out);
        res.map_err(|e| self.err(e))?;
        Ok(out)
    }

    /// Ends the stream: flushes the filter tail so that exactly `floor(n_in * 16000 / rate)` samples
    /// have come out in total, returns the remaining ones, and resets for a new stream.
    pub fn finish(&mut self) -> Result<Vec<f32>, AudioError> {
        let Some(mut st) = self.sinc.take() else {
            return Ok(Vec::new());
        };
        let target = st.n_in * TARGET_RATE as u64 / self.rate as u64;
        let mut out = Vec::new();
        let pending = std::mem::take(&mut st.pending);
        if !pending.is_empty() {
            st.run_block(Some(&pending), &mut out)
                .map_err(|e| self.err(e))?;
        }
        let mut guard = 0;
        while st.n_out < target {
            st.run_block(None, &mut out).map_err(|e| self.err(e))?;
            guard += 1;
            if guard > 10_000 {
                return Err(self.err("the resampler did not flush its tail"));
            }
        }
        let excess = (st.n_out - target) as usize;
        out.truncate(out.len().saturating_sub(excess));
        self.sinc = Some(self.make_state()?);
        Ok(out)
    }
}

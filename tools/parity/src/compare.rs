//! The worst of many comparisons of one output (over steps, frames or calls), each judged by the
//! project's one comparison, [`livegesture::compare::diff`] (docs/parity.md: `max|a - b| <= bound x
//! max(1, max|ref|)` per graph, output and step; NaN or Inf on either side fails).

use super::*;
use livegesture::compare::{diff, Diff};

/// The worst comparison of one output over several steps, with where it happened.
///
/// Each step's tensors are compared on their own scale (`max(1, max|reference|)` of that step's
/// reference tensor); the worst step is the one with the largest error relative to its scale, and a
/// step that no bound passes (NaN or Inf, shapes or lengths that differ) is worse than any finite error.
#[derive(Debug, Clone)]
pub(super) struct MaxAbs {
    /// The largest absolute difference of the worst step (infinite when a step cannot pass).
    pub(super) err: f64,
    /// The scale the worst step is judged at: `max(1, max|reference|)` of its reference tensor.
    pub(super) scale: f64,
    pub(super) step: Option<u64>,
    pub(super) location: Option<String>,
    pub(super) count: u64,
    pub(super) problem: Option<String>,
    /// Judge at scale 1 (an absolute bound, e.g. the log-mel frontend's).
    pub(super) absolute: bool,
}

impl Default for MaxAbs {
    fn default() -> Self {
        Self {
            err: 0.0,
            scale: 1.0,
            step: None,
            location: None,
            count: 0,
            problem: None,
            absolute: false,
        }
    }
}

pub(super) fn unravel(mut i: usize, shape: &[usize]) -> Vec<usize> {
    let mut idx = vec![0; shape.len()];
    for (k, &d) in shape.iter().enumerate().rev() {
        if d > 0 {
            idx[k] = i % d;
            i /= d;
        }
    }
    idx
}

impl MaxAbs {
    /// A comparison judged at scale 1 (absolute bound).
    pub(super) fn absolute() -> Self {
        Self {
            absolute: true,
            ..Default::default()
        }
    }

    /// The error relative to the scale it is judged at (what is compared with the bound).
    pub(super) fn scaled(&self) -> f64 {
        self.err / self.scale
    }

    /// Whether every folded step passes `bound` (scaled), something was compared and no step had a
    /// problem.
    pub(super) fn within(&self, bound: f64) -> bool {
        self.problem.is_none() && self.count > 0 && self.err <= bound * self.scale
    }

    /// Folds one step's comparison in: `d` compared `got` with the reference; `locate(i)` names flat
    /// index `i` for the report.
    pub(super) fn fold(&mut self, step: u64, d: &Diff, locate: impl Fn(usize) -> String) {
        self.count += d.compared as u64;
        let scale = if self.absolute { 1.0 } else { d.scale };
        let problem = d.problem();
        let worse = match (&self.problem, &problem) {
            (Some(_), _) => false,
            (None, Some(_)) => true,
            (None, None) => self.step.is_none() || d.max_abs / scale > self.err / self.scale,
        };
        if !worse {
            return;
        }
        self.err = d.max_abs;
        self.scale = scale;
        self.step = Some(step);
        let at = d.index.map(&locate);
        match problem {
            Some(p) => {
                self.problem = Some(match at {
                    Some(at) => format!("step {step}, {at}: {p}"),
                    None => format!("step {step}: {p}"),
                });
                self.location = None;
            }
            None => {
                self.location = match (at, d.values) {
                    (Some(at), Some((g, r))) => Some(format!(
                        "largest at step {step}, {at}: {g} vs {r} (scale {})",
                        fmt_scale(scale)
                    )),
                    _ => None,
                }
            }
        }
    }

    /// Folds another running comparison in (keeps the worse, adds the counts).
    pub(super) fn merge(&mut self, other: MaxAbs) {
        self.count += other.count;
        let worse = match (&self.problem, &other.problem) {
            (Some(_), _) => false,
            (None, Some(_)) => true,
            (None, None) => {
                other.step.is_some() && (self.step.is_none() || other.scaled() > self.scaled())
            }
        };
        if worse {
            self.err = other.err;
            self.scale = other.scale;
            self.step = other.step;
            self.location = other.location;
            self.problem = other.problem;
        }
    }

    /// Compares two slices at `step` ([`livegesture::compare::diff`]) and folds the result in.
    pub(super) fn add_slices(
        &mut self,
        step: u64,
        got: &[f32],
        want: &[f32],
        locate: impl Fn(usize) -> String,
    ) {
        let d = diff(got, want);
        self.fold(step, &d, locate);
    }

    /// Folds the comparison of two tensors at `step` in (float32: [`livegesture::compare::diff`]; int64:
    /// exact, at scale 1).
    pub(super) fn add(&mut self, step: u64, got: &Tensor, want: &Tensor) {
        if got.shape != want.shape || got.dtype() != want.dtype() {
            if self.problem.is_none() {
                self.problem = Some(format!(
                    "step {step}: {} {:?} vs {} {:?} (shapes or types differ)",
                    got.dtype(),
                    got.shape,
                    want.dtype(),
                    want.shape
                ));
                self.err = f64::INFINITY;
                self.scale = 1.0;
                self.step = Some(step);
                self.location = None;
            }
            return;
        }
        let shape = got.shape.clone();
        let locate = |i: usize| format!("index {:?}", unravel(i, &shape));
        match (&got.data, &want.data) {
            (TensorData::F32(a), TensorData::F32(b)) => self.add_slices(step, a, b, locate),
            (TensorData::I64(a), TensorData::I64(b)) => {
                // integers (step counters, tokens): exact, at scale 1
                let d = livegesture::compare::diff_i64(a, b);
                let abs = std::mem::replace(&mut self.absolute, true);
                self.fold(step, &d, locate);
                self.absolute = abs;
            }
            _ => unreachable!("dtypes checked above"),
        }
    }
}

/// A scale as the report prints it (`1` below magnitude 1, else 4 significant digits).
pub fn fmt_scale(scale: f64) -> String {
    if scale == 1.0 {
        "1".into()
    } else {
        format!("{scale:.4}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string()
    }
}

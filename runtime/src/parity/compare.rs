//! Running maximum absolute differences, with where the largest one is.

use super::*;

/// A running max abs difference with where it happened.
#[derive(Debug, Clone, Default)]
pub(super) struct MaxAbs {
    pub(super) err: f64,
    pub(super) step: Option<u64>,
    pub(super) location: Option<String>,
    pub(super) count: u64,
    pub(super) problem: Option<String>,
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
    /// Folds the comparison of two tensors at `step` in. NaN anywhere counts as an infinite error.
    pub(super) fn add(&mut self, step: u64, got: &Tensor, want: &Tensor) {
        if got.shape != want.shape || got.dtype() != want.dtype() {
            self.problem.get_or_insert_with(|| {
                format!(
                    "step {step}: {} {:?} vs {} {:?} (shapes or types differ)",
                    got.dtype(),
                    got.shape,
                    want.dtype(),
                    want.shape
                )
            });
            self.err = f64::INFINITY;
            self.step.get_or_insert(step);
            return;
        }
        let diffs: Box<dyn Iterator<Item = (f64, f64)>> = match (&got.data, &want.data) {
            (TensorData::F32(a), TensorData::F32(b)) => {
                Box::new(a.iter().zip(b).map(|(&x, &y)| (x as f64, y as f64)))
            }
            (TensorData::I64(a), TensorData::I64(b)) => {
                Box::new(a.iter().zip(b).map(|(&x, &y)| (x as f64, y as f64)))
            }
            _ => unreachable!("dtypes checked above"),
        };
        let mut worst: Option<(usize, f64, f64, f64)> = None;
        for (i, (x, y)) in diffs.enumerate() {
            let d = if x.is_nan() || y.is_nan() {
                f64::INFINITY
            } else {
                (x - y).abs()
            };
            if worst.is_none_or(|w| d > w.1) {
                worst = Some((i, d, x, y));
            }
        }
        self.count += got.len() as u64;
        if let Some((i, d, x, y)) = worst {
            if self.step.is_none() || d > self.err {
                self.err = d;
                self.step = Some(step);
                self.location = Some(format!(
                    "largest at step {step}, index {:?}: {x} vs {y}",
                    unravel(i, &got.shape)
                ));
            }
        }
    }

    pub(super) fn add_f32(&mut self, step: u64, index: String, got: f32, want: f32) {
        let d = if got.is_nan() || want.is_nan() {
            f64::INFINITY
        } else {
            (got as f64 - want as f64).abs()
        };
        self.count += 1;
        if self.step.is_none() || d > self.err {
            self.err = d;
            self.step = Some(step);
            self.location = Some(format!("largest at {index}: {got} vs {want}"));
        }
    }
}

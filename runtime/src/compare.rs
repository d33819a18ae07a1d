//! The one comparison of two float tensors used by the parity suite and every test (docs/parity.md).
//!
//! A bound is on the largest absolute difference over one tensor, scaled by the reference tensor's
//! magnitude: `max|got - reference| <= bound * max(1, max|reference|)`. Below magnitude 1 the bound is
//! absolute; above it, relative.
//!
//! A comparison fails, whatever the bound, when
//! - a value on either side is NaN or infinite ([`Diff::nonfinite`] says which side and where: Rust's
//!   `f32::max` returns the other argument when one is NaN, so a hand-written `fold(0.0, f32::max)`
//!   counts a NaN output as agreement; this helper never does);
//! - nothing was compared (two empty tensors prove nothing);
//! - the lengths differ ([`Diff::length_mismatch`]).
//!
//! ```
//! use livegesture::compare::diff;
//! let reference = [40.0_f32, -3.0];
//! let got = [40.0_f32 + 4.0 * f32::EPSILON * 40.0, -3.0];
//! assert!(diff(&got, &reference).within(1e-5)); // a few ulps near 40: passes the scaled bound
//! assert!(!diff(&[f32::NAN, -3.0], &reference).within(1e-5)); // NaN: fails
//! assert!(!diff(&[], &[]).within(1e-5)); // nothing compared: fails
//! ```

use std::fmt;

/// The result of comparing `got` with `reference` (see [`diff`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Diff {
    /// The largest `|got - reference|` over the compared values; infinite when the comparison cannot
    /// pass (a non-finite value, nothing compared, lengths that differ), so a caller that reads only
    /// this field still fails.
    pub max_abs: f64,
    /// The (flat) index of the largest difference, or of the first non-finite value.
    pub index: Option<usize>,
    /// The scale the bound is multiplied by: `max(1, max|reference|)` over the finite reference values.
    pub scale: f64,
    /// How many value pairs were compared (the shorter length when the lengths differ).
    pub compared: usize,
    /// A NaN or infinite value on either side: which side(s) and where, e.g. `got[17] = NaN`.
    pub nonfinite: Option<String>,
    /// `(got.len(), reference.len())` when they differ.
    pub length_mismatch: Option<(usize, usize)>,
    /// The value pair `(got, reference)` at [`Diff::index`].
    pub values: Option<(f32, f32)>,
    /// Tensors of different shapes or element types ([`diff_tensors`]): both, named.
    pub shape_mismatch: Option<String>,
}

/// Compares `got` with `reference` element by element (see the module documentation).
pub fn diff(got: &[f32], reference: &[f32]) -> Diff {
    let n = got.len().min(reference.len());
    let mut scale = 1.0_f64;
    let mut max_abs = 0.0_f64;
    let mut index = None;
    let mut nonfinite: Option<String> = None;
    let mut nonfinite_at = None;
    for (i, (&g, &r)) in got.iter().zip(reference).enumerate() {
        let (gf, rf) = (g.is_finite(), r.is_finite());
        if !(gf && rf) {
            if nonfinite.is_none() {
                nonfinite = Some(match (gf, rf) {
                    (false, true) => format!("got[{i}] = {g} (reference {r})"),
                    (true, false) => format!("reference[{i}] = {r} (got {g})"),
                    _ => format!("both sides at [{i}]: got {g}, reference {r}"),
                });
                nonfinite_at = Some(i);
            }
            continue;
        }
        scale = scale.max((r as f64).abs());
        let d = (g as f64 - r as f64).abs();
        if index.is_none() || d > max_abs {
            max_abs = d;
            index = Some(i);
        }
    }
    let length_mismatch = (got.len() != reference.len()).then_some((got.len(), reference.len()));
    if nonfinite.is_some() {
        index = nonfinite_at;
    }
    if nonfinite.is_some() || length_mismatch.is_some() || n == 0 {
        max_abs = f64::INFINITY;
    }
    let values = index.map(|i| (got[i], reference[i]));
    Diff {
        max_abs,
        index,
        scale,
        compared: n,
        nonfinite,
        length_mismatch,
        values,
        shape_mismatch: None,
    }
}

/// Compares two tensors ([`crate::backend::Tensor`]): shapes and element types must match (else the
/// comparison fails, naming both); float32 through [`diff`]; int64 (tokens, step counters) exactly,
/// in integers, at scale 1 (any difference is >= 1, over every bound the project uses).
pub fn diff_tensors(got: &crate::backend::Tensor, reference: &crate::backend::Tensor) -> Diff {
    use crate::backend::TensorData;
    if got.shape != reference.shape || got.dtype() != reference.dtype() {
        let mut d = diff(&[], &[]);
        d.shape_mismatch = Some(format!(
            "got {} {:?}, reference {} {:?}",
            got.dtype(),
            got.shape,
            reference.dtype(),
            reference.shape
        ));
        return d;
    }
    match (&got.data, &reference.data) {
        (TensorData::F32(a), TensorData::F32(b)) => diff(a, b),
        (TensorData::I64(a), TensorData::I64(b)) => diff_i64(a, b),
        _ => unreachable!("element types checked above"),
    }
}

/// Integers (step counters, tokens) compared exactly: the largest difference, at scale 1, so any
/// difference fails every bound below 1. Nothing compared, or unequal lengths, fails as in [`diff`].
pub fn diff_i64(got: &[i64], reference: &[i64]) -> Diff {
    let mut d = diff(&[], &[]);
    d.compared = got.len().min(reference.len());
    d.max_abs = 0.0;
    d.length_mismatch = (got.len() != reference.len()).then_some((got.len(), reference.len()));
    for (i, (x, y)) in got.iter().zip(reference).enumerate() {
        let e = x.abs_diff(*y) as f64;
        if d.index.is_none() || e > d.max_abs {
            d.max_abs = e;
            d.index = Some(i);
            d.values = Some((*x as f32, *y as f32));
        }
    }
    if d.compared == 0 {
        d.max_abs = f64::INFINITY;
    }
    d
}

impl Diff {
    /// Whether the comparison passes `bound` (scaled): every value finite on both sides, something
    /// compared, equal lengths, and `max_abs <= bound * scale`.
    pub fn within(&self, bound: f64) -> bool {
        self.nonfinite.is_none()
            && self.length_mismatch.is_none()
            && self.shape_mismatch.is_none()
            && self.compared > 0
            && self.max_abs <= bound * self.scale
    }

    /// The error in units of the scale (`max_abs / scale`): what is compared with the bound.
    pub fn scaled_error(&self) -> f64 {
        self.max_abs / self.scale
    }

    /// Why this comparison cannot pass any bound, if it cannot (non-finite value, nothing compared,
    /// lengths that differ).
    pub fn problem(&self) -> Option<String> {
        if let Some(m) = &self.shape_mismatch {
            return Some(format!("shapes or element types differ: {m}"));
        }
        if let Some((g, r)) = self.length_mismatch {
            return Some(format!("lengths differ: got {g} values, reference {r}"));
        }
        if let Some(nf) = &self.nonfinite {
            return Some(format!("non-finite value: {nf}"));
        }
        if self.compared == 0 {
            return Some("nothing compared (both sides empty)".into());
        }
        None
    }

    /// Keeps the worse of `self` and `other` (a failure that no bound passes first, then the larger
    /// [`Diff::scaled_error`]); folds the comparisons of several steps or tensors into one.
    pub fn worst(self, other: Diff) -> Diff {
        match (self.problem().is_some(), other.problem().is_some()) {
            (true, _) => self,
            (false, true) => other,
            _ if other.scaled_error() > self.scaled_error() => other,
            _ => self,
        }
    }

    /// One line for a failure message: the error, the scale, where, and the value pair.
    pub fn describe(&self) -> String {
        self.to_string()
    }

    /// `Ok(self)` when [`Diff::within`] `bound`, else an error naming `what`, the error, the bound and
    /// the scale it was judged at, and where.
    pub fn ensure(self, bound: f64, what: impl fmt::Display) -> Result<Diff, String> {
        if self.within(bound) {
            Ok(self)
        } else {
            Err(format!(
                "{what}: {self}; bound {bound:e} x scale {:.4} = {:e}",
                self.scale,
                bound * self.scale
            ))
        }
    }
}

impl fmt::Display for Diff {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(p) = self.problem() {
            write!(f, "{p} ({} compared)", self.compared)
        } else {
            write!(
                f,
                "max |got - reference| = {:.3e} (scaled {:.3e}, scale {:.4}, {} compared)",
                self.max_abs,
                self.scaled_error(),
                self.scale,
                self.compared
            )?;
            if let (Some(i), Some((g, r))) = (self.index, self.values) {
                write!(f, " at index {i}: got {g}, reference {r}")?;
            }
            Ok(())
        }
    }
}

/// Panics with [`Diff::ensure`]'s message unless `got` is within `bound` (scaled) of `reference`;
/// returns the [`Diff`] otherwise. For tests.
#[track_caller]
pub fn assert_within(got: &[f32], reference: &[f32], bound: f64, what: impl fmt::Display) -> Diff {
    match diff(got, reference).ensure(bound, what) {
        Ok(d) => d,
        Err(e) => panic!("{e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_few_ulps_near_40_pass_the_scaled_bound() {
        let reference: Vec<f32> = (0..64).map(|i| 38.0 + i as f32 * 0.03).collect();
        let mut got = reference.clone();
        // four float32 ulps at ~40 (ulp = 2^-18 * 2 = 3.8e-6): 1.5e-5 absolute, above the absolute 1e-5
        let ulp = f32::EPSILON * 32.0;
        got[40] += 4.0 * ulp;
        let d = diff(&got, &reference);
        assert!(
            d.max_abs > 1e-5,
            "the test needs an absolute error above 1e-5: {d}"
        );
        assert!(d.within(1e-5), "{d}");
        assert_eq!(d.index, Some(40));
        assert!(d.scale > 39.0 && d.scale < 40.0, "{d}");
        assert_eq!(d.compared, 64);
    }

    #[test]
    fn below_magnitude_one_the_bound_is_absolute() {
        let d = diff(&[0.5 + 2e-5], &[0.5]);
        assert_eq!(d.scale, 1.0);
        assert!(!d.within(1e-5), "{d}");
        assert!(d.within(1e-4), "{d}");
    }

    #[test]
    fn a_real_difference_fails() {
        let reference = vec![40.0_f32; 8];
        let mut got = reference.clone();
        got[3] = 40.01;
        let d = diff(&got, &reference);
        assert!(!d.within(1e-5), "{d}");
        assert_eq!(d.index, Some(3));
        assert_eq!(d.values, Some((40.01, 40.0)));
        let e = d.ensure(1e-5, "expert_body logits").unwrap_err();
        assert!(
            e.contains("expert_body logits") && e.contains("index 3"),
            "{e}"
        );
    }

    #[test]
    fn nan_or_inf_on_either_side_fails_and_says_which() {
        let clean = [1.0_f32, 2.0, 3.0];
        for (side, at, bad) in [
            ("got", 1, f32::NAN),
            ("reference", 2, f32::NAN),
            ("got", 0, f32::INFINITY),
            ("reference", 0, f32::NEG_INFINITY),
        ] {
            let mut broken = clean;
            broken[at] = bad;
            let d = if side == "got" {
                diff(&broken, &clean)
            } else {
                diff(&clean, &broken)
            };
            assert!(!d.within(1e9), "{side} {bad}: {d}");
            assert!(d.max_abs.is_infinite());
            let nf = d.nonfinite.clone().expect("nonfinite must be reported");
            assert!(nf.starts_with(&format!("{side}[{at}]")), "{nf}");
            assert_eq!(d.index, Some(at));
        }
        let d = diff(&[f32::NAN], &[f32::NAN]);
        assert!(!d.within(1.0));
        assert!(d.nonfinite.unwrap().contains("both"));
    }

    #[test]
    fn nothing_compared_fails() {
        let d = diff(&[], &[]);
        assert_eq!(d.compared, 0);
        assert!(!d.within(f64::MAX), "{d}");
        assert!(d.to_string().contains("nothing compared"));
    }

    #[test]
    fn length_mismatch_fails() {
        let d = diff(&[1.0, 2.0], &[1.0, 2.0, 3.0]);
        assert_eq!(d.length_mismatch, Some((2, 3)));
        assert!(!d.within(f64::MAX), "{d}");
        assert!(d.to_string().contains("lengths differ"));
    }

    #[test]
    fn worst_keeps_the_failure_then_the_larger_scaled_error() {
        let ok_small = diff(&[1.0], &[1.0]);
        let ok_big = diff(&[41.0], &[40.0]); // scaled 0.025
        let bad = diff(&[f32::NAN], &[1.0]);
        assert_eq!(ok_small.clone().worst(ok_big.clone()), ok_big);
        assert_eq!(ok_big.clone().worst(ok_small), ok_big);
        assert!(ok_big.clone().worst(bad.clone()).nonfinite.is_some());
        assert!(bad.worst(ok_big).nonfinite.is_some());
    }

    #[test]
    #[should_panic(expected = "non-finite value: got[0]")]
    fn assert_within_panics_on_nan() {
        assert_within(&[f32::NAN], &[0.0], 1.0, "probe");
    }

    /// issue 38 item 2: tensors compared by their values as float32 (what the browser parity did)
    /// passed an int64 off by one at magnitude 1e5 (scaled 1e-5) and a transposed shape; compared as
    /// tensors both fail, as does another element type.
    #[test]
    fn tensors_are_compared_by_shape_type_and_integers_exactly() {
        use crate::backend::Tensor;
        let bound = 1e-4 + 1e-5;
        let (a, b) = (vec![100_000i64, 7], vec![100_001i64, 7]);
        let as_f32 = |v: &[i64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        assert!(
            diff(&as_f32(&a), &as_f32(&b)).within(bound),
            "premise: the old way passed it"
        );
        let (ta, tb) = (
            Tensor::i64(vec![2], a.clone()).unwrap(),
            Tensor::i64(vec![2], b).unwrap(),
        );
        let d = diff_tensors(&ta, &tb);
        assert!(
            !d.within(bound) && d.max_abs == 1.0 && d.scale == 1.0,
            "{d}"
        );
        assert!(diff_tensors(&ta, &ta).within(0.0));
        // 2^24 + 1 and 2^24 are one float32: exact in integers
        let big = |x| Tensor::i64(vec![1], vec![x]).unwrap();
        assert!(!diff_tensors(&big((1 << 24) + 1), &big(1 << 24)).within(0.5));
        // a transposed shape with the same values in order, and another element type, fail
        let v: Vec<f32> = (0..6).map(|x| x as f32).collect();
        let (s23, s32) = (
            Tensor::f32(vec![2, 3], v.clone()).unwrap(),
            Tensor::f32(vec![3, 2], v.clone()).unwrap(),
        );
        assert!(diff(&v, &v).within(bound), "premise: values alone agree");
        let d = diff_tensors(&s23, &s32);
        assert!(
            !d.within(f64::MAX) && d.to_string().contains("shapes or element types differ"),
            "{d}"
        );
        let d = diff_tensors(&ta, &Tensor::f32(vec![2], vec![100_000.0, 7.0]).unwrap());
        assert!(!d.within(f64::MAX), "{d}");
        // NaN and empty still fail
        let n = Tensor::f32(vec![1], vec![f32::NAN]).unwrap();
        assert!(!diff_tensors(&n, &n).within(f64::MAX));
        let e = Tensor::i64(vec![0], vec![]).unwrap();
        assert!(!diff_tensors(&e, &e).within(f64::MAX));
    }
}

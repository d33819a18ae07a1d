//! The one quantile definition of the project's figures: `livegesture bench` (BENCHMARKS.md) and
//! `livegesture loadtest` (docs/serve.md#load-test) both report their p50/p95/p99 with it.

/// The `q`-quantile (`q` in 0..=1) of `sorted` (ascending): linear interpolation between the closest
/// ranks, numpy's default (`numpy.quantile(x, q)`). `None` for no values.
pub fn quantile(sorted: &[f64], q: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let x = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let lo = x.floor() as usize;
    let hi = x.ceil() as usize;
    Some(sorted[lo] + (sorted[hi] - sorted[lo]) * (x - lo as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_numpy() {
        // numpy.quantile([1, 2, 3, 4, 5], [0, 0.5, 0.95, 0.99, 1]) = 1, 3, 4.8, 4.96, 5
        let s = [1.0, 2.0, 3.0, 4.0, 5.0];
        let got: Vec<f64> = [0.0, 0.5, 0.95, 0.99, 1.0]
            .iter()
            .map(|&q| quantile(&s, q).unwrap())
            .collect();
        for (g, w) in got.iter().zip([1.0, 3.0, 4.8, 4.96, 5.0]) {
            assert!((g - w).abs() < 1e-12, "{got:?}");
        }
        // not the nearest rank (which gives 5 for p99 here)
        assert!(quantile(&s, 0.99).unwrap() < 5.0);
        assert_eq!(quantile(&[], 0.5), None);
        assert_eq!(quantile(&[7.0], 0.99), Some(7.0));
    }
}

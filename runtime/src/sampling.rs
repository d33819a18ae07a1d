//! The portable seeded sampler, reproducing `python/livegesture/sampling.py` bit for bit.
//!
//! # PRNG: SplitMix64
//!
//! The state is one `u64`, initialised to the seed. `next_u64`:
//!
//! ```text
//! state = state + 0x9E3779B97F4A7C15            (mod 2^64)
//! z = state
//! z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9      (mod 2^64)
//! z = (z ^ (z >> 27)) * 0x94D049BB133111EB      (mod 2^64)
//! return z ^ (z >> 31)
//! ```
//!
//! `next_f64 = (next_u64 >> 11) * 2^-53`, uniform in `[0, 1)`.
//!
//! # Sampling one token
//!
//! From `f32` conditional logits `c` and optional unconditional logits `u`, all arithmetic in `f64` in
//! this order:
//!
//! 1. `g_i = u_i + gamma * (c_i - u_i)` (without `u`: `g_i = c_i`);
//! 2. `g_i = g_i / temperature`;
//! 3. order the indices by `g` descending, ties by index ascending; keep the first `top_k` (all when
//!    `top_k` is 0 or `>= K`);
//! 4. `w_j = exp(g_j - g_first)` for the kept indices in that order (`f64::exp`), `S = sum` accumulated
//!    in that order;
//! 5. `r = next_f64() * S`; walk the kept indices in order accumulating `w`; the token is the first
//!    whose running sum exceeds `r` (the last kept index if rounding leaves none).
//!
//! Exactly one `next_u64` is drawn per successful call; a call that fails validation draws nothing.
//! Each stream owns one generator; per token step one uniform is drawn per region, in region order
//! (upper, hands, lower, face).

use anyhow::{bail, ensure, Result};

const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// The SplitMix64 generator (see the module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator whose state is `seed`.
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// The current state (restoring it with [`SplitMix64::new`] resumes the sequence).
    pub fn state(&self) -> u64 {
        self.state
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`: `(next_u64 >> 11) * 2^-53`.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }
}

/// Classifier-free guidance on logits in `f64`: `u + gamma * (c - u)`, or `c` without `u`.
pub fn guide(cond: &[f32], uncond: Option<&[f32]>, gamma: f64) -> Result<Vec<f64>> {
    match uncond {
        None => Ok(cond.iter().map(|&c| c as f64).collect()),
        Some(u) => {
            ensure!(
                u.len() == cond.len(),
                "sampler: conditional and unconditional logits differ in length ({} vs {})",
                cond.len(),
                u.len()
            );
            Ok(cond
                .iter()
                .zip(u)
                .map(|(&c, &u)| {
                    let (c, u) = (c as f64, u as f64);
                    u + gamma * (c - u)
                })
                .collect())
        }
    }
}

/// The guided, tempered and top-k-truncated distribution of one region's token: steps 1-4 of the
/// module docs, built once and then drawn from ([`TokenDistribution::draw`], step 5). The sampler
/// ([`sample_token`]) and the parity report's sampling margins use this one definition.
#[derive(Debug, Clone, PartialEq)]
pub struct TokenDistribution {
    /// Guided logits divided by the temperature, by token index (all finite).
    pub logits: Vec<f64>,
    /// Token indices by logit descending, ties by index ascending: the first `max(kept, 2)` (at most
    /// K) in that order, the rest after them in no particular order.
    pub order: Vec<usize>,
    /// How many indices of `order` are kept (top-k; all when `top_k` is 0 or `>= K`).
    pub kept: usize,
    /// `exp(g_j - g_first)` of the kept indices, in `order`.
    pub weights: Vec<f64>,
    /// The sum of `weights`, accumulated in order.
    pub total: f64,
}

/// A draw from a [`TokenDistribution`]: the token and its interval `[lo, hi)` of cumulative weight
/// (in units of [`TokenDistribution::total`]) that contained `r = u * total`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Draw {
    pub token: usize,
    pub r: f64,
    pub lo: f64,
    pub hi: f64,
}

impl TokenDistribution {
    /// Steps 1-4 from one region's logits (length K). Errors when `temperature <= 0` or not finite,
    /// when the logits are empty or of different lengths, or when a guided logit is NaN or infinite.
    pub fn new(
        cond: &[f32],
        uncond: Option<&[f32]>,
        gamma: f64,
        temperature: f64,
        top_k: usize,
    ) -> Result<Self> {
        // NaN is rejected too (Python rejects it through the finiteness check of the scaled logits).
        if temperature.is_nan() || temperature <= 0.0 {
            bail!("sampler: temperature must be > 0, got {temperature}");
        }
        ensure!(!cond.is_empty(), "sampler: logits are empty");
        let mut g = guide(cond, uncond, gamma)?;
        for x in g.iter_mut() {
            *x /= temperature;
        }
        if let Some(i) = g.iter().position(|x| !x.is_finite()) {
            bail!(
                "sampler: logits contain NaN or Inf (guided logit {i} is {})",
                g[i]
            );
        }
        let k = g.len();
        let mut order: Vec<usize> = (0..k).collect();
        // g descending, index ascending. All values are finite, so partial_cmp is total here, and it
        // treats -0.0 == 0.0 as numpy's sort does. Ties broken by index make it a strict total
        // order, so the kept prefix is the same whether the rest is sorted or only partitioned off:
        // top-k partitions first (O(K)), then sorts the prefix it keeps.
        let by_logit = |&a: &usize, &b: &usize| {
            g[b].partial_cmp(&g[a])
                .unwrap_or(std::cmp::Ordering::Equal)
                .then(a.cmp(&b))
        };
        let kept = if top_k > 0 && top_k < k { top_k } else { k };
        // at least the first two in order (the margin between the first two: parity's divergence)
        let sorted = kept.max(2).min(k);
        if sorted < k {
            order.select_nth_unstable_by(sorted - 1, by_logit);
            order[..sorted].sort_unstable_by(by_logit);
        } else {
            order.sort_unstable_by(by_logit);
        }
        let g0 = g[order[0]];
        let weights: Vec<f64> = order[..kept].iter().map(|&i| (g[i] - g0).exp()).collect();
        let mut total = 0.0f64;
        for &x in &weights {
            total += x;
        }
        Ok(Self {
            logits: g,
            order,
            kept,
            weights,
            total,
        })
    }

    /// Step 5 for the uniform `u` in `[0, 1)`: `r = u * total`; walking the kept indices in order
    /// and accumulating their weights, the token is the first whose running sum exceeds `r` (the
    /// last kept index if rounding leaves none).
    pub fn draw(&self, u: f64) -> Draw {
        let r = u * self.total;
        let mut acc = 0.0f64;
        for (&i, &x) in self.order.iter().zip(&self.weights) {
            let lo = acc;
            acc += x;
            if acc > r {
                return Draw {
                    token: i,
                    r,
                    lo,
                    hi: acc,
                };
            }
        }
        Draw {
            token: self.order[self.kept - 1],
            r,
            lo: 0.0,
            hi: self.total,
        }
    }

    /// The probability of `token` (0 when top-k left it out or it is out of range).
    pub fn probability(&self, token: i64) -> f64 {
        self.order[..self.kept]
            .iter()
            .zip(&self.weights)
            .find(|(&i, _)| i as i64 == token)
            .map_or(0.0, |(_, &x)| x / self.total)
    }
}

/// Draws one token from one region's logits (length K). See the module docs for the exact definition.
///
/// Errors (without drawing from `rng`) when `temperature <= 0` or not finite, when the logits are
/// empty or of different lengths, or when a guided logit is NaN or infinite.
pub fn sample_token(
    cond: &[f32],
    uncond: Option<&[f32]>,
    rng: &mut SplitMix64,
    gamma: f64,
    temperature: f64,
    top_k: usize,
) -> Result<usize> {
    let d = TokenDistribution::new(cond, uncond, gamma, temperature, top_k)?;
    Ok(d.draw(rng.next_f64()).token)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix_reference_values() {
        // Reference outputs of SplitMix64 seeded with 0 (Vigna's splitmix64.c).
        let mut r = SplitMix64::new(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(r.next_u64(), 0x06C4_5D18_8009_454F);
        let mut r = SplitMix64::new(u64::MAX);
        let x = r.next_f64();
        assert!((0.0..1.0).contains(&x));
    }

    #[test]
    fn greedy_when_one_logit_dominates() {
        let mut rng = SplitMix64::new(1);
        let mut c = vec![0.0f32; 50];
        c[17] = 1000.0;
        for _ in 0..20 {
            assert_eq!(sample_token(&c, None, &mut rng, 1.25, 1.0, 0).unwrap(), 17);
        }
    }

    #[test]
    fn ties_break_by_index_and_top_k() {
        // All equal: top_k = 1 keeps index 0 only.
        let c = vec![0.5f32; 8];
        let mut rng = SplitMix64::new(3);
        for _ in 0..10 {
            assert_eq!(sample_token(&c, None, &mut rng, 1.0, 1.0, 1).unwrap(), 0);
        }
        // top_k = 3 of equal logits: only 0, 1, 2 ever come out, each about a third of the time.
        let mut counts = [0usize; 8];
        for _ in 0..3000 {
            counts[sample_token(&c, None, &mut rng, 1.0, 1.0, 3).unwrap()] += 1;
        }
        assert!(counts[3..].iter().all(|&n| n == 0));
        assert!(counts[..3].iter().all(|&n| n > 900), "{counts:?}");
    }

    #[test]
    fn top_k_keeps_what_a_full_sort_keeps() {
        // logits with many ties (a few distinct values), guided and not: the kept prefix, its
        // weights and their sum equal those of sorting every index (the definition's step 3)
        let mut rng = SplitMix64::new(42);
        for trial in 0..200 {
            let k = 1 + (rng.next_u64() % 300) as usize;
            let levels = 1 + rng.next_u64() % 12;
            let c: Vec<f32> = (0..k)
                .map(|_| (rng.next_u64() % levels) as f32 * 0.25 - 1.0)
                .collect();
            let u: Vec<f32> = c.iter().map(|x| x * 0.5).collect();
            let uncond = (trial % 2 == 0).then_some(u.as_slice());
            for top_k in [0, 1, 2, 3, 32, k.saturating_sub(1), k, k + 1] {
                let d = TokenDistribution::new(&c, uncond, 1.5, 0.8, top_k).unwrap();
                let mut full: Vec<usize> = (0..k).collect();
                full.sort_by(|&a, &b| {
                    d.logits[b]
                        .partial_cmp(&d.logits[a])
                        .unwrap()
                        .then(a.cmp(&b))
                });
                let kept = if top_k > 0 && top_k < k { top_k } else { k };
                assert_eq!(d.kept, kept);
                let sorted = kept.max(2).min(k);
                assert_eq!(d.order[..sorted], full[..sorted], "k {k} top_k {top_k}");
                let mut rest = d.order[sorted..].to_vec();
                rest.sort_unstable();
                let mut want = full[sorted..].to_vec();
                want.sort_unstable();
                assert_eq!(rest, want);
                let g0 = d.logits[full[0]];
                let w: Vec<f64> = full[..kept]
                    .iter()
                    .map(|&i| (d.logits[i] - g0).exp())
                    .collect();
                assert_eq!(d.weights, w);
                assert_eq!(d.total, w.iter().fold(0.0, |a, x| a + x));
            }
        }
    }

    #[test]
    fn guidance_formula() {
        let g = guide(&[1.0, 2.0], Some(&[0.5, 3.0]), 1.25).unwrap();
        assert_eq!(g, vec![0.5 + 1.25 * 0.5, 3.0 - 1.25]);
    }

    #[test]
    fn errors_do_not_draw() {
        let mut rng = SplitMix64::new(9);
        let before = rng.clone();
        assert!(sample_token(&[1.0], None, &mut rng, 1.0, 0.0, 0).is_err());
        assert!(sample_token(&[1.0], None, &mut rng, 1.0, f64::NAN, 0).is_err());
        assert!(sample_token(&[], None, &mut rng, 1.0, 1.0, 0).is_err());
        assert!(sample_token(&[1.0, f32::NAN], None, &mut rng, 1.0, 1.0, 0).is_err());
        assert!(sample_token(&[1.0, 2.0], Some(&[1.0]), &mut rng, 1.0, 1.0, 0).is_err());
        assert_eq!(rng, before);
    }
}

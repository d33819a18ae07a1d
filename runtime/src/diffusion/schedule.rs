//! The diffusion schedule and DDIM timesteps (`python/livegesture/diffsheg/schedule.py`; the manifest's
//! `diffusion` section).
//!
//! The runtime takes the cumulative-alpha table from the manifest's exact bit patterns
//! (`alphas_cumprod_f64_bits`) and checks it against its own recomputation of the definition (1000
//! linear betas, a sequential float64 product), so a manifest whose table does not follow the
//! definition is refused rather than sampled with silently.

use anyhow::{bail, ensure, Context, Result};

/// The cumulative products `alpha_bar_i` of a linear beta schedule (float64, sequential):
/// `beta_i = i * step + start` (`step = (end - start) / (T - 1)`), `beta_{T-1} = end`.
pub fn alphas_cumprod(train_steps: usize, start: f64, end: f64) -> Vec<f64> {
    let step = (end - start) / (train_steps as f64 - 1.0);
    let mut out = Vec::with_capacity(train_steps);
    let mut acc = 1.0f64;
    for i in 0..train_steps {
        let beta = if i + 1 == train_steps {
            end
        } else {
            i as f64 * step + start
        };
        let a = 1.0 - beta;
        acc = if i == 0 { a } else { acc * a };
        out.push(acc);
    }
    out
}

/// Parses the manifest's `alphas_cumprod_f64_bits` (16 hex digits each).
pub fn parse_f64_bits(bits: &[String]) -> Result<Vec<f64>> {
    bits.iter()
        .enumerate()
        .map(|(i, h)| {
            ensure!(
                h.len() == 16,
                "alphas_cumprod_f64_bits[{i}]: expected 16 hex digits, got '{h}'"
            );
            let v = u64::from_str_radix(h, 16)
                .with_context(|| format!("alphas_cumprod_f64_bits[{i}]: '{h}' is not hex"))?;
            Ok(f64::from_bits(v))
        })
        .collect()
}

/// The table a sampler uses: `alpha_bar` for every training step.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    /// `alpha_bar_i`, i = 0 .. train_steps - 1.
    pub alphas_cumprod: Vec<f64>,
}

impl Schedule {
    /// Training steps (1000).
    pub fn train_steps(&self) -> usize {
        self.alphas_cumprod.len()
    }

    /// Checks that `steps` DDIM steps are valid for this schedule: 1 <= steps <= T and steps
    /// divides T (the paper's spacing).
    pub fn check_steps(&self, steps: usize) -> Result<()> {
        let t = self.train_steps();
        if steps == 0 || steps > t || !t.is_multiple_of(steps) {
            bail!(
                "DDIM steps must divide {t} (1, 2, 4, 5, 8, 10, 20, 25, 40, 50, ...), got {steps}"
            );
        }
        Ok(())
    }

    /// The ascending DDIM timesteps `tau_j = j * (T / steps)`, j = 0 .. steps - 1.
    pub fn ddim_timesteps(&self, steps: usize) -> Result<Vec<usize>> {
        self.check_steps(steps)?;
        let stride = self.train_steps() / steps;
        Ok((0..steps).map(|j| j * stride).collect())
    }

    /// `(a_t, a_p)` of DDIM step j: `ab[tau_j]` and `ab[tau_{j-1}]` (1.0 for j = 0).
    pub fn step_alphas(&self, taus: &[usize], j: usize) -> (f64, f64) {
        let a_t = self.alphas_cumprod[taus[j]];
        let a_p = if j > 0 {
            self.alphas_cumprod[taus[j - 1]]
        } else {
            1.0
        };
        (a_t, a_p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_python_and_the_definition() {
        let ab = alphas_cumprod(1000, 1e-4, 0.02);
        // schedule.alphas_cumprod() in Python: ab[0] = 0x1.fff2e48e8a71ep-1, ab[999] = 0x1.528cc8c61621dp-15
        assert_eq!(ab[0].to_bits(), 0x3fefff2e48e8a71e);
        assert_eq!(ab[999].to_bits(), 0x3f0528cc8c61621d);
        let bits: Vec<String> = ab.iter().map(|v| format!("{:016x}", v.to_bits())).collect();
        assert_eq!(parse_f64_bits(&bits).unwrap(), ab);
        assert!(parse_f64_bits(&["3fefff2e48e8a71".into()]).is_err());
        assert!(parse_f64_bits(&["3fefff2e48e8a7zz".into()]).is_err());
    }

    #[test]
    fn ddim_timesteps_and_step_validation() {
        let s = Schedule {
            alphas_cumprod: alphas_cumprod(1000, 1e-4, 0.02),
        };
        let taus = s.ddim_timesteps(25).unwrap();
        assert_eq!(taus.len(), 25);
        assert_eq!((taus[0], taus[1], taus[24]), (0, 40, 960));
        assert_eq!(s.step_alphas(&taus, 0).1, 1.0);
        assert_eq!(
            s.step_alphas(&taus, 3),
            (s.alphas_cumprod[120], s.alphas_cumprod[80])
        );
        for bad in [0, 3, 7, 1001, 2000] {
            let e = s.ddim_timesteps(bad).unwrap_err().to_string();
            assert!(e.contains("must divide 1000"), "{e}");
        }
        assert_eq!(s.ddim_timesteps(1000).unwrap().len(), 1000);
    }
}

//! Token divergence: the first step where two rollouts differ and how close the draw was to a tie.

use super::*;

/// How close one side's draw was to picking the other token (see the module docs).
#[derive(Debug, Clone, Serialize)]
pub struct Margin {
    /// Whose logits (`ort`, `tract`).
    pub source: String,
    /// The token these logits give with the replayed uniform draw.
    pub sampled: i64,
    /// The replayed uniform draw in `[0, 1)`.
    pub uniform: f64,
    /// Distance (probability) from the draw to the nearest edge of the sampled token's interval.
    pub cdf_margin: f64,
    /// Guided logit (after temperature) of the first side's token minus that of the second side's.
    pub token_gap: f64,
    /// Guided logit gap between the two most likely tokens.
    pub top2_gap: f64,
    /// Probabilities of the two candidate tokens (after top-k).
    pub p_first: f64,
    pub p_second: f64,
}

impl Margin {
    /// See [`Divergence::near_tie`].
    pub fn is_near_tie(&self) -> bool {
        self.cdf_margin < NEAR_TIE || self.token_gap.abs() < NEAR_TIE_LOGIT
    }
}

/// The first step where two rollouts' tokens differ.
#[derive(Debug, Clone, Serialize)]
pub struct Divergence {
    /// The two sides, e.g. `ort` and `torch`.
    pub first: String,
    pub second: String,
    pub step: u64,
    pub region: String,
    pub region_index: usize,
    pub first_token: i64,
    pub second_token: i64,
    /// Steps with any differing token (from the first divergence on, states differ too).
    pub differing_steps: u64,
    /// Margins from each side's logits that are known.
    pub margins: Vec<Margin>,
    /// Largest guided-logit difference between the two sides at that step and region (when both
    /// logits are known).
    pub logit_difference: Option<f64>,
}

impl Divergence {
    /// True when, from every known side's logits, the draw was fragile: it sat within [`NEAR_TIE`]
    /// of an edge of the sampled token's CDF interval, or the two candidate tokens' guided logits
    /// are within [`NEAR_TIE_LOGIT`] (so a tiny logit change swaps their order and intervals).
    /// `None` when no logits are known.
    pub fn near_tie(&self) -> Option<bool> {
        if self.margins.is_empty() {
            None
        } else {
            Some(self.margins.iter().all(Margin::is_near_tie))
        }
    }
}

impl fmt::Display for Divergence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} vs {}: tokens first differ at step {}, region '{}': {} {} vs {} {} ({} differing steps)",
            self.first,
            self.second,
            self.step,
            self.region,
            self.first,
            self.first_token,
            self.second,
            self.second_token,
            self.differing_steps
        )?;
        for m in &self.margins {
            write!(
                f,
                "; {} logits: draw u={:.6} gives token {}, {:.2e} from its interval edge (p {}={:.4}, p {}={:.4}), guided-logit gap {:.3e}, top-2 gap {:.3e}",
                m.source,
                m.uniform,
                m.sampled,
                m.cdf_margin,
                self.first_token,
                m.p_first,
                self.second_token,
                m.p_second,
                m.token_gap,
                m.top2_gap
            )?;
        }
        if let Some(d) = self.logit_difference {
            write!(
                f,
                "; guided logits differ by up to {d:.3e} between the sides"
            )?;
        }
        match self.near_tie() {
            Some(true) => write!(
                f,
                "; verdict: numerical near-tie (draw within {NEAR_TIE:.0e} of an interval edge, or the two tokens' \
                 guided logits within {NEAR_TIE_LOGIT:.0e}): a tiny logit difference flips this draw, so if the \
                 graph checks pass this is numerical noise, not a bug"
            ),
            Some(false) => write!(
                f,
                "; verdict: NOT a near-tie (draw >= {NEAR_TIE:.0e} from the interval edges, logit gap >= \
                 {NEAR_TIE_LOGIT:.0e}): the logits really differ, look for a bug"
            ),
            None => write!(f, "; no logits known on either side, margin not computed"),
        }
    }
}

/// Sampling parameters of a rollout, to replay its draws.
#[derive(Debug, Clone)]
pub struct SamplingParams {
    pub seed: u64,
    pub guidance: f64,
    pub temperature: f64,
    pub top_k: usize,
    /// Region names in sampling order.
    pub regions: Vec<String>,
}

/// One side of a rollout comparison: its tokens per step (region order) and, if known, its logits.
#[derive(Debug, Clone)]
pub struct RolloutTrace {
    pub name: String,
    pub tokens: Vec<Vec<i64>>,
    pub logits: Option<Vec<StepLogits>>,
}

/// The uniform draw of `region` at `step` (one draw per region per step, in region order).
pub fn replay_uniform(seed: u64, n_regions: usize, step: u64, region: usize) -> f64 {
    let mut rng = SplitMix64::new(seed);
    for _ in 0..step * n_regions as u64 + region as u64 {
        rng.next_u64();
    }
    rng.next_f64()
}

/// The margin of one side's draw between tokens `first` and `second` (see [`Margin`]).
pub fn sampling_margin(
    source: &str,
    cond: &[f32],
    uncond: Option<&[f32]>,
    p: &SamplingParams,
    uniform: f64,
    first: i64,
    second: i64,
) -> Result<Margin> {
    let d = TokenDistribution::new(cond, uncond, p.guidance, p.temperature, p.top_k)?;
    let g = &d.logits;
    let top2_gap = if g.len() > 1 {
        g[d.order[0]] - g[d.order[1]]
    } else {
        f64::INFINITY
    };
    let Draw {
        token: sampled,
        r,
        lo,
        hi,
    } = d.draw(uniform);
    let s = d.total;
    let prob = |t: i64| d.probability(t);
    let at = |t: i64| g.get(t as usize).copied().unwrap_or(f64::NAN);
    Ok(Margin {
        source: source.to_string(),
        sampled: sampled as i64,
        uniform,
        cdf_margin: ((r - lo).min(hi - r) / s).max(0.0),
        token_gap: at(first) - at(second),
        top2_gap,
        p_first: prob(first),
        p_second: prob(second),
    })
}

/// The first step and region where `a` and `b` differ, with margins from whichever logits are known.
pub fn find_divergence(
    a: &RolloutTrace,
    b: &RolloutTrace,
    p: &SamplingParams,
) -> Result<Option<Divergence>> {
    let n = a.tokens.len().min(b.tokens.len());
    let differing = a
        .tokens
        .iter()
        .zip(&b.tokens)
        .filter(|(x, y)| x != y)
        .count() as u64;
    let Some(step) = (0..n).find(|&t| a.tokens[t] != b.tokens[t]) else {
        return Ok(None);
    };
    let region = (0..a.tokens[step].len())
        .find(|&r| a.tokens[step].get(r) != b.tokens[step].get(r))
        .unwrap_or(0);
    let (ta, tb) = (
        a.tokens[step][region],
        b.tokens[step].get(region).copied().unwrap_or(-1),
    );
    let nr = p.regions.len().max(a.tokens[step].len());
    let u = replay_uniform(p.seed, nr, step as u64, region);
    let mut margins = Vec::new();
    let mut guided = Vec::new();
    for side in [a, b] {
        let Some(l) = side.logits.as_ref().and_then(|l| l.get(step)) else {
            continue;
        };
        let k = l.cond.len() / nr;
        let c = &l.cond[region * k..(region + 1) * k];
        let un = l.uncond.as_ref().map(|u| &u[region * k..(region + 1) * k]);
        margins.push(sampling_margin(&side.name, c, un, p, u, ta, tb)?);
        guided.push(guide(c, un, p.guidance)?);
    }
    let logit_difference = (guided.len() == 2).then(|| {
        guided[0]
            .iter()
            .zip(&guided[1])
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    });
    Ok(Some(Divergence {
        first: a.name.clone(),
        second: b.name.clone(),
        step: step as u64,
        region: p
            .regions
            .get(region)
            .cloned()
            .unwrap_or_else(|| format!("#{region}")),
        region_index: region,
        first_token: ta,
        second_token: tb,
        differing_steps: differing + (a.tokens.len().max(b.tokens.len()) - n) as u64,
        margins,
        logit_difference,
    }))
}

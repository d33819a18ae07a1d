//! Divergence reporting: two logits sources sampled with the same seed; the report must name the
//! first diverging step and region, the two tokens and the sampling margin, and tell a numerical
//! near-tie from a real difference.

use livegesture::model::livegesture::StepLogits;
use livegesture::sampling::{sample_token, SplitMix64};
use livegesture_parity::{find_divergence, replay_uniform, RolloutTrace, SamplingParams};

const K: usize = 16;
const REGIONS: [&str; 4] = ["upper", "hands", "lower", "face"];
const STEPS: usize = 30;

fn params() -> SamplingParams {
    SamplingParams {
        seed: 1234,
        guidance: 1.25,
        temperature: 1.0,
        top_k: 8,
        regions: REGIONS.iter().map(|s| s.to_string()).collect(),
    }
}

/// Pseudo-random guided logit pairs for every step and region.
fn random_logits() -> Vec<StepLogits> {
    let mut g = SplitMix64::new(99);
    (0..STEPS)
        .map(|_| {
            let mut v = || (g.next_f64() * 4.0 - 2.0) as f32;
            let cond: Vec<f32> = (0..REGIONS.len() * K).map(|_| v()).collect();
            let uncond: Vec<f32> = (0..REGIONS.len() * K).map(|_| v()).collect();
            StepLogits {
                cond,
                uncond: Some(uncond),
            }
        })
        .collect()
}

/// Samples a rollout from `logits` exactly as the pipeline does (one draw per region per step).
fn sample(name: &str, logits: Vec<StepLogits>, p: &SamplingParams) -> RolloutTrace {
    let mut rng = SplitMix64::new(p.seed);
    let tokens = logits
        .iter()
        .map(|l| {
            (0..REGIONS.len())
                .map(|r| {
                    let c = &l.cond[r * K..(r + 1) * K];
                    let u = l.uncond.as_ref().map(|u| &u[r * K..(r + 1) * K]);
                    sample_token(c, u, &mut rng, p.guidance, p.temperature, p.top_k).unwrap() as i64
                })
                .collect()
        })
        .collect();
    RolloutTrace {
        name: name.into(),
        tokens,
        logits: Some(logits),
    }
}

/// Sets the region's logits so that token 0 has probability `p0`, token 1 the rest, every other
/// token ~0 (cond == uncond, so the guided logits equal them).
fn two_token_logits(l: &mut StepLogits, region: usize, p0: f64) {
    let logit0 = (p0 / (1.0 - p0)).ln() as f32;
    for (k, x) in l.cond[region * K..(region + 1) * K].iter_mut().enumerate() {
        *x = match k {
            0 => logit0,
            1 => 0.0,
            _ => -60.0,
        };
    }
    let c = l.cond.clone();
    l.uncond = Some(c);
}

#[test]
fn identical_sources_do_not_diverge() {
    let p = params();
    let a = sample("a", random_logits(), &p);
    let b = sample("b", random_logits(), &p);
    assert!(find_divergence(&a, &b, &p).unwrap().is_none());
}

#[test]
fn real_difference_is_named_with_step_region_and_margin() {
    let p = params();
    let base = random_logits();
    let a = sample("a", base.clone(), &p);
    // source b: at step 12, region lower, a token outside a's choice dominates
    let (step, region) = (12, 2);
    let mut other = base.clone();
    let chosen = a.tokens[step][region] as usize;
    let boost = (chosen + 5) % K;
    other[step].cond[region * K + boost] += 20.0;
    let b = sample("b", other, &p);
    let d = find_divergence(&a, &b, &p)
        .unwrap()
        .expect("the sources diverge");
    eprintln!("{d}");
    assert_eq!(d.step, step as u64);
    assert_eq!(d.region, "lower");
    assert_eq!(d.region_index, region);
    assert_eq!(d.first_token, a.tokens[step][region]);
    assert_eq!(d.second_token, boost as i64);
    assert_eq!(d.margins.len(), 2);
    // each side's margin replays its own draw: it reproduces its own token
    assert_eq!(d.margins[0].sampled, d.first_token);
    assert_eq!(d.margins[1].sampled, d.second_token);
    assert_eq!(d.near_tie(), Some(false));
    assert!(d.logit_difference.unwrap() > 20.0);
    let text = d.to_string();
    assert!(
        text.contains("step 12") && text.contains("'lower'") && text.contains("NOT a near-tie"),
        "{text}"
    );
}

#[test]
fn near_tie_is_told_apart() {
    let p = params();
    // a step whose draw for region hands lies in (0.55, 0.95), so that token 0 (probability ~u) is
    // the first in the sampler's order and the draw sits on the edge between tokens 0 and 1
    let region = 1;
    let step = (3..STEPS)
        .find(|&t| (0.55..0.95).contains(&replay_uniform(p.seed, REGIONS.len(), t as u64, region)))
        .expect("a step with a suitable draw");
    let u = replay_uniform(p.seed, REGIONS.len(), step as u64, region);
    // a: token 0 gets u + 2e-6 of the mass (the draw falls just inside it); b: u - 2e-6 (just outside)
    let mut la = random_logits();
    two_token_logits(&mut la[step], region, u + 2e-6);
    let mut lb = random_logits();
    two_token_logits(&mut lb[step], region, u - 2e-6);
    let a = sample("a", la, &p);
    let b = sample("b", lb, &p);
    let d = find_divergence(&a, &b, &p)
        .unwrap()
        .expect("the near-tie flips the draw");
    eprintln!("{d}");
    assert_eq!((d.step, d.region.as_str()), (step as u64, "hands"));
    assert_eq!((d.first_token, d.second_token), (0, 1));
    for m in &d.margins {
        assert!(m.cdf_margin < 1e-5, "{}: margin {}", m.source, m.cdf_margin);
    }
    assert_eq!(d.near_tie(), Some(true));
    assert!(d.to_string().contains("near-tie"), "{d}");
}

#[test]
fn torch_side_without_logits_uses_the_backend_margin() {
    let p = params();
    let base = random_logits();
    let a = sample("ort", base.clone(), &p);
    let mut tokens = a.tokens.clone();
    tokens[20][3] = (tokens[20][3] + 1) % K as i64;
    let torch = RolloutTrace {
        name: "torch".into(),
        tokens,
        logits: None,
    };
    let d = find_divergence(&a, &torch, &p).unwrap().expect("diverges");
    assert_eq!((d.step, d.region.as_str()), (20, "face"));
    assert_eq!(d.margins.len(), 1);
    assert_eq!(d.margins[0].source, "ort");
    assert!(d.logit_difference.is_none());
}

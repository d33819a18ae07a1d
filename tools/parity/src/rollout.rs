//! The rollout check: the whole seeded rollout on each backend against torch and each other.

use super::*;

/// The frame fields compared by the rollout, chunk and batch checks.
pub(super) const FRAME_FIELDS: [&str; 4] = ["poses", "trans", "expressions", "foot_contact"];

pub(super) fn field(f: &Frame, k: usize) -> &[f32] {
    match k {
        0 => &f.poses,
        1 => &f.trans,
        2 => &f.expressions,
        _ => &f.foot_contact,
    }
}

/// Runs one stream over `audio` in chunks of `chunk` samples; with `finish`, ends it as `generate`
/// does (docs/output.md: the last partial token completed with silence, frames cut at the audio's end).
pub(super) fn run_stream(
    p: &LiveGestureGraphs,
    opts: &StreamOptions,
    audio: &[f32],
    chunk: usize,
    finish: bool,
) -> Result<Vec<TokenStep>> {
    let mut s = p.new_stream(opts)?;
    let mut steps = Vec::new();
    for c in audio.chunks(chunk.max(1)) {
        steps.extend(p.push_steps(&mut s, c)?);
    }
    if finish {
        steps.extend(p.finish_steps(&mut s, AudioSpan::at_16k(audio.len() as u64))?);
    }
    Ok(steps)
}

/// Compares the frames of token steps pairwise: `pairs` are (label naming the stream in the report,
/// got, want).
pub(super) fn frame_rows_steps(
    check: Check,
    what: &str,
    comparison: &str,
    pairs: &[(String, &[TokenStep], &[TokenStep])],
    bound: f64,
    rows: &mut Vec<Row>,
) {
    for (k, name) in FRAME_FIELDS.iter().enumerate() {
        let mut m = MaxAbs::default();
        for (label, got, want) in pairs {
            // one comparison per token step: the step's frames of this field, judged at their scale
            for (a, b) in got.iter().zip(want.iter()) {
                let (g, w, at) = step_field(a, b, k);
                m.add_slices(a.token_index, &g, &w, |i| {
                    let (f, j) = at[i];
                    format!("{label}frame {f}, {name}[{j}]")
                });
            }
        }
        rows.push(Row::max_abs(check, what, comparison, *name, &m, bound));
    }
}

/// The values of field `k` over the frames of two token steps (frames paired in order), and for each
/// value its (frame index, position in the field). Frames or values one side lacks make the lengths
/// differ, which the comparison reports.
fn step_field(a: &TokenStep, b: &TokenStep, k: usize) -> (Vec<f32>, Vec<f32>, Vec<(u64, usize)>) {
    let (mut g, mut w, mut at) = (Vec::new(), Vec::new(), Vec::new());
    for (fa, fb) in a.frames.iter().zip(&b.frames) {
        g.extend_from_slice(field(fa, k));
        w.extend_from_slice(field(fb, k));
        at.extend((0..field(fa, k).len()).map(|j| (fa.index, j)));
    }
    if a.frames.len() != b.frames.len() {
        g.push(f32::NAN);
    }
    (g, w, at)
}

pub(super) fn token_row(
    check: Check,
    what: &str,
    comparison: &str,
    got: &[Vec<i64>],
    want: &[Vec<i64>],
    detail: Option<String>,
) -> Row {
    let n = got.len().min(want.len());
    let mut differing = got.iter().zip(want).filter(|(a, b)| a != b).count() as u64;
    differing += (got.len().max(want.len()) - n) as u64;
    let first = (0..n)
        .find(|&t| got[t] != want[t])
        .or((got.len() != want.len()).then_some(n));
    let detail = detail.or_else(|| {
        (got.len() != want.len()).then(|| format!("{} steps vs {}", got.len(), want.len()))
    });
    Row {
        check,
        what: what.into(),
        comparison: comparison.into(),
        output: "tokens".into(),
        step: first.map(|s| s as u64),
        metric: Metric::DifferingSteps,
        error: differing as f64,
        compared: got.len().max(want.len()) as u64,
        bound: 0.0,
        scale: 1.0,
        // nothing compared proves nothing
        pass: differing == 0 && got.len().max(want.len()) > 0,
        detail: detail.or_else(|| got.is_empty().then(|| "nothing compared (0 steps)".into())),
    }
}

/// docs/targets.md ([`ParityOptions::target`]): a token row that failed only because the two
/// rollouts diverge passes when the first divergence is a near-tie from every side whose logits are
/// known (the frames before it are compared by their own rows). A divergence of unknown margin, one
/// that is not a near-tie, or rollouts of different lengths still fail.
pub(super) fn target_token_row(
    mut row: Row,
    div: Option<&Divergence>,
    same_length: bool,
    target: bool,
) -> Row {
    if !target || row.pass || row.compared == 0 {
        return row;
    }
    if let Some(d) = div {
        if same_length && d.near_tie() == Some(true) {
            row.pass = true;
            row.detail = Some(format!(
                "{}; passes as a target (docs/targets.md): the first divergence is a near-tie",
                row.detail.unwrap_or_default()
            ));
        }
    }
    row
}

pub(super) struct BackendRollout {
    kind: BackendKind,
    steps: Vec<TokenStep>,
}

impl BackendRollout {
    fn trace(&self) -> RolloutTrace {
        RolloutTrace {
            name: self.kind.to_string(),
            tokens: self.steps.iter().map(|s| s.tokens.clone()).collect(),
            logits: Some(
                self.steps
                    .iter()
                    .map(|s| {
                        s.logits.clone().unwrap_or(StepLogits {
                            cond: Vec::new(),
                            uncond: None,
                        })
                    })
                    .collect(),
            ),
        }
    }
}

#[allow(clippy::too_many_arguments)]
// long: the rollout compared token by token with its divergence analysis and the frame bounds; to split into replay and comparison
pub(super) fn rollout_rows(
    bundle: &Bundle,
    pipelines: &mut [(BackendKind, LiveGestureGraphs)],
    other_forms: &mut [(BackendKind, LiveGestureGraphs)],
    clip: &[f32],
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
    divergences: &mut Vec<Divergence>,
    target: bool,
    log: &mut dyn FnMut(&str),
) -> Result<(), ReferenceError> {
    let rel = bundle.reference_rollout();
    let path = bundle.path(&rel);
    let reference = ReferenceRollout::load(&path)?;
    let seed = bundle
        .reference()
        .and_then(|r| r.rollout_seed)
        .ok_or_else(|| ref_err(&bundle.manifest_path(), "reference.rollout_seed is missing"))?;
    let lg = bundle
        .livegesture()
        .map_err(|e| ref_err(&bundle.manifest_path(), e))?;
    let s = &lg.sampling;
    if let Some(g) = bundle.reference().and_then(|r| r.rollout_guidance) {
        if g != s.guidance {
            notes.push(format!(
                "the reference rollout was made with guidance {g}, the manifest's default is {}",
                s.guidance
            ));
        }
    }
    let params = SamplingParams {
        seed,
        guidance: s.guidance,
        temperature: s.temperature,
        top_k: s.top_k,
        regions: lg.region_names().iter().map(|r| r.to_string()).collect(),
    };
    let mut audio = Vec::with_capacity(clip.len() * reference.clip_repeats);
    for _ in 0..reference.clip_repeats {
        audio.extend_from_slice(clip);
    }
    notes.push(format!(
        "rollout: reference/clip.wav x {} ({:.1} s), seed {seed}, guidance {}, temperature {}, top_k {}, {} {} tokens",
        reference.clip_repeats,
        audio.len() as f64 / 16000.0,
        s.guidance,
        s.temperature,
        s.top_k,
        reference.tokens.len(),
        bundle.reference_name()
    ));
    let opts = StreamOptions {
        seed,
        record_logits: true,
        ..Default::default()
    };
    let torch_trace = RolloutTrace {
        name: bundle.reference_name().into(),
        tokens: reference.tokens.clone(),
        logits: None,
    };
    let mut runs: Vec<BackendRollout> = Vec::new();
    for (kind, p) in pipelines.iter_mut() {
        let t0 = Instant::now();
        match run_stream(p, &opts, &audio, 16000, false) {
            Ok(steps) => {
                log(&format!(
                    "rollout on {kind}: {} tokens in {:.1} s",
                    steps.len(),
                    t0.elapsed().as_secs_f64()
                ));
                runs.push(BackendRollout { kind: *kind, steps });
            }
            Err(e) => rows.push(Row::failed(
                Check::Rollout,
                "rollout",
                format!("{kind} vs {}", bundle.reference_name()),
                "tokens",
                0.0,
                format!("{kind} failed: {e:#}"),
            )),
        }
    }
    // the forms against each other (docs/bundle.md#forms-and-precision): the canonical form's rollout vs the form a backend runs,
    // on that backend: identical tokens, frames within the rollout bound
    for (kind, alt) in other_forms.iter_mut() {
        let Some(main) = runs.iter().find(|r| r.kind == *kind) else {
            continue;
        };
        let main_form = pipelines
            .iter()
            .find(|(k, _)| k == kind)
            .map(|(_, p)| p.form().to_string())
            .unwrap_or_default();
        let comparison = format!("{kind} {} vs {kind} {main_form}", alt.form());
        let what = format!("rollout ({main_form} form)");
        let t0 = Instant::now();
        let steps = match run_stream(alt, &opts, &audio, 16000, false) {
            Ok(s) => s,
            Err(e) => {
                rows.push(Row::failed(
                    Check::Rollout,
                    &what,
                    &comparison,
                    "tokens",
                    0.0,
                    format!("the {} form failed on {kind}: {e:#}", alt.form()),
                ));
                continue;
            }
        };
        log(&format!(
            "rollout on {kind}, {} form: {} tokens in {:.1} s",
            alt.form(),
            steps.len(),
            t0.elapsed().as_secs_f64()
        ));
        let alt_trace = RolloutTrace {
            name: format!("{kind} {}", alt.form()),
            tokens: steps.iter().map(|s| s.tokens.clone()).collect(),
            logits: None,
        };
        let mut main_trace = main.trace();
        main_trace.name = format!("{kind} {main_form}");
        let div =
            find_divergence(&alt_trace, &main_trace, &params).map_err(|e| ref_err(&path, e))?;
        let prefix = div.as_ref().map(|d| d.step as usize).unwrap_or(usize::MAX);
        rows.push(target_token_row(
            token_row(
                Check::Rollout,
                &what,
                &comparison,
                &alt_trace.tokens,
                &main_trace.tokens,
                div.as_ref().map(|d| d.to_string()),
            ),
            div.as_ref(),
            alt_trace.tokens.len() == main_trace.tokens.len(),
            target,
        ));
        let n = steps.len().min(main.steps.len()).min(prefix);
        frame_rows_steps(
            Check::Rollout,
            &what,
            &comparison,
            &[(String::new(), &steps[..n], &main.steps[..n])],
            ROLLOUT_FRAMES,
            rows,
        );
        if let Some(d) = div {
            divergences.push(d);
        }
    }
    // each backend vs torch
    for run in &runs {
        let comparison = format!("{} vs {}", run.kind, bundle.reference_name());
        let trace = run.trace();
        let other: Vec<RolloutTrace> = runs
            .iter()
            .filter(|r| r.kind != run.kind)
            .map(BackendRollout::trace)
            .collect();
        let div = find_divergence(&trace, &torch_trace, &params).map_err(|e| ref_err(&path, e))?;
        let div = div.map(|mut d| {
            // margins from the other backend's logits too (torch stored none)
            for o in &other {
                if let Some(l) = o.logits.as_ref().and_then(|l| l.get(d.step as usize)) {
                    let nr = params.regions.len();
                    let k = l.cond.len() / nr;
                    let r = d.region_index;
                    let c = &l.cond[r * k..(r + 1) * k];
                    let un = l.uncond.as_ref().map(|u| &u[r * k..(r + 1) * k]);
                    let u = replay_uniform(seed, nr, d.step, r);
                    if let Ok(m) =
                        sampling_margin(&o.name, c, un, &params, u, d.first_token, d.second_token)
                    {
                        d.margins.push(m);
                    }
                }
            }
            d
        });
        let prefix = div.as_ref().map(|d| d.step as usize).unwrap_or(usize::MAX);
        rows.push(target_token_row(
            token_row(
                Check::Rollout,
                "rollout",
                &comparison,
                &trace.tokens,
                &reference.tokens,
                div.as_ref().map(|d| d.to_string()),
            ),
            div.as_ref(),
            trace.tokens.len() == reference.tokens.len(),
            target,
        ));
        // frames (over the steps before any divergence)
        let n = run.steps.len().min(reference.tokens.len()).min(prefix);
        let fpt = run.steps.first().map(|s| s.frames.len()).unwrap_or(4);
        for (k, name) in FRAME_FIELDS.iter().enumerate() {
            let want = match k {
                0 => &reference.poses,
                1 => &reference.trans,
                2 => &reference.expressions,
                _ => &reference.foot_contact,
            };
            let mut m = MaxAbs::default();
            for st in &run.steps[..n] {
                // one comparison per token step: its frames of this field vs the reference's rows
                let (mut g, mut w, mut at) = (Vec::new(), Vec::new(), Vec::new());
                for fr in &st.frames {
                    let i = fr.index as usize;
                    if i >= want.nrows() {
                        m.problem.get_or_insert_with(|| {
                            format!(
                                "frame {i} is beyond the reference's {} frames",
                                want.nrows()
                            )
                        });
                        m.err = f64::INFINITY;
                        m.step.get_or_insert(st.token_index);
                        continue;
                    }
                    let row = want.row(i);
                    if row.len() != field(fr, k).len() {
                        m.problem.get_or_insert_with(|| {
                            format!(
                                "{name} has {} values per frame, reference {}",
                                field(fr, k).len(),
                                row.len()
                            )
                        });
                        m.err = f64::INFINITY;
                        m.step.get_or_insert(st.token_index);
                        continue;
                    }
                    g.extend_from_slice(field(fr, k));
                    w.extend(row.iter().copied());
                    at.extend((0..row.len()).map(|j| (i, j)));
                }
                if !g.is_empty() {
                    m.add_slices(st.token_index, &g, &w, |x| {
                        let (i, j) = at[x];
                        format!("frame {i}, {name}[{j}]")
                    });
                }
            }
            let mut row = Row::max_abs(
                Check::Rollout,
                "rollout",
                &comparison,
                *name,
                &m,
                ROLLOUT_FRAMES,
            );
            if n < run.steps.len().max(reference.tokens.len()) && m.problem.is_none() {
                let d = format!(
                    "frames compared over the first {} frames, before the token divergence",
                    n * fpt
                );
                row.detail = Some(match row.detail {
                    Some(x) => format!("{x}; {d}"),
                    None => d,
                });
            }
            rows.push(row);
        }
        if let Some(d) = div {
            divergences.push(d);
        }
    }
    // tract vs ort
    let ort = runs.iter().find(|r| r.kind == BackendKind::Ort);
    let tract = runs.iter().find(|r| r.kind == BackendKind::Tract);
    if let (Some(o), Some(t)) = (ort, tract) {
        let (to, tt) = (o.trace(), t.trace());
        let div = find_divergence(&tt, &to, &params).map_err(|e| ref_err(&path, e))?;
        let prefix = div.as_ref().map(|d| d.step as usize).unwrap_or(usize::MAX);
        rows.push(target_token_row(
            token_row(
                Check::Rollout,
                "rollout",
                "tract vs ort",
                &tt.tokens,
                &to.tokens,
                div.as_ref().map(|d| d.to_string()),
            ),
            div.as_ref(),
            tt.tokens.len() == to.tokens.len(),
            target,
        ));
        let n = t.steps.len().min(o.steps.len()).min(prefix);
        frame_rows_steps(
            Check::Rollout,
            "rollout",
            "tract vs ort",
            &[(String::new(), &t.steps[..n], &o.steps[..n])],
            ROLLOUT_FRAMES,
            rows,
        );
        // the fusion logits over the whole rollout (informative; same bound as the graphs)
        let mut m = MaxAbs::default();
        for (a, b) in t.steps[..n].iter().zip(&o.steps[..n]) {
            if let (Some(la), Some(lb)) = (&a.logits, &b.logits) {
                if let (Ok(x), Ok(y)) = (
                    Tensor::f32(vec![la.cond.len()], la.cond.clone()),
                    Tensor::f32(vec![lb.cond.len()], lb.cond.clone()),
                ) {
                    m.add(a.token_index, &x, &y);
                }
            }
        }
        rows.push(Row::max_abs(
            Check::Rollout,
            "rollout",
            "tract vs ort",
            "logits (cond)",
            &m,
            TRACT_VS_ORT,
        ));
        if let Some(d) = div {
            divergences.push(d);
        }
    }
    Ok(())
}

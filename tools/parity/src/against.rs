//! Export against export (`livegesture parity --against OLD`): a new export of a model checked
//! against a previous one, so that re-exporting a checkpoint with a new exporter, opset, precision or
//! runtime version cannot move the motion unnoticed.
//!
//! | check | what | bound |
//! |---|---|---|
//! | `graph` | every graph both bundles carry with the same inputs, outputs and caches: both run on the OLD bundle's reference inputs (chained steps from the zero caches, each chaining its own caches; DiffSHEG: every call), every output and cache at every step | [`AgainstOptions::graph_bound`] (scaled by the old output's magnitude) |
//! | `rollout` | LiveGesture: the whole seeded rollout of both bundles on the OLD bundle's reference audio and seed (each bundle's sampling defaults): token agreement, then every frame field per token step over the whole rollout | [`AgainstOptions::token_agreement`], [`AgainstOptions::frames_bound`] (scaled) |
//! | `rollout` | DiffSHEG: the seeded FOPPAS rollout of both bundles on the OLD bundle's reference audio, seed, speaker and sampler options: every frame field | [`AgainstOptions::frames_bound`] (scaled) |
//!
//! A graph only one bundle carries, or whose inputs, outputs or caches differ, is not compared and
//! is named in a note; two bundles of different families, or with no graph in common, are bad input.

use super::*;
use livegesture::model::diffsheg::model::DiffshegModel;

/// Bad input to [`against`]: bundles of different families, no graph in common, bounds out of
/// range (the CLI's exit code 2).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct AgainstInputError(pub String);

macro_rules! input_ensure {
    ($cond:expr, $($fmt:tt)+) => {
        if !$cond {
            return Err(AgainstInputError(format!($($fmt)+)).into());
        }
    };
}

/// Bounds of an export-against-export comparison (all user-settable on the command line).
#[derive(Debug, Clone, Copy)]
pub struct AgainstOptions {
    /// Graph outputs, new vs old on the same inputs: `max|new - old| <= bound x max(1, max|old|)`.
    pub graph_bound: f64,
    /// Rollout frames (per frame field and token step), scaled like the graph bound.
    pub frames_bound: f64,
    /// The fraction of rollout steps whose tokens must be identical (1 = every step).
    pub token_agreement: f64,
}

impl Default for AgainstOptions {
    /// docs/parity.md's bounds for another build of the same graphs: graphs 1e-4 (scaled), rollout
    /// frames 1e-4 (scaled), identical tokens.
    fn default() -> Self {
        Self {
            graph_bound: TRACT_VS_ORT,
            frames_bound: ROLLOUT_FRAMES,
            token_agreement: 1.0,
        }
    }
}

/// Runs one graph on a reference file's inputs: chained steps (`step{s}.input.*`, `n_steps`) from
/// the zero caches, or independent calls (`call{c}.input.*`, DiffSHEG). Returns every step's outputs
/// (graph order) and the step keys' prefix (`step` or `call`).
fn run_on_reference(
    backend: &dyn Backend,
    bundle: &Bundle,
    spec: &GraphSpec,
    refv: &ReferenceVectors,
) -> Result<(Vec<Vec<Tensor>>, &'static str)> {
    if let Ok(n) = refv.scalar("n_steps") {
        let n = usize::try_from(n).unwrap_or(0);
        return Ok((graphs::chain_graph(backend, bundle, spec, refv, n)?, "step"));
    }
    let runner = backend.load(spec, &bundle.graph_path(spec))?;
    let mut all = Vec::new();
    for c in 0.. {
        let key = |name: &str| format!("call{c}.input.{name}");
        if refv.get(&key(&spec.inputs[0].name)).is_err() {
            break;
        }
        let inputs: Vec<Tensor> = spec
            .inputs
            .iter()
            .map(|i| refv.get(&key(&i.name)).cloned())
            .collect::<Result<_, _>>()?;
        all.push(
            runner
                .run(&inputs)
                .with_context(|| format!("{} call {c}", backend.name()))?,
        );
    }
    Ok((all, "call"))
}

/// The `graph` rows: every graph the two bundles share with the same interface.
fn graph_rows_against(
    new: &Bundle,
    old: &Bundle,
    backend: &dyn Backend,
    cmp: &str,
    bound: f64,
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
) -> Result<usize> {
    let mut compared = 0;
    let mut skipped = Vec::new();
    for spec in old.graphs() {
        let Ok(new_spec) = new.graph(&spec.name) else {
            skipped.push(format!("{} (only in the old bundle)", spec.name));
            continue;
        };
        if (&new_spec.inputs, &new_spec.outputs, &new_spec.caches)
            != (&spec.inputs, &spec.outputs, &spec.caches)
        {
            skipped.push(format!("{} (inputs, outputs or caches differ)", spec.name));
            continue;
        }
        let (_, refv) = graphs::graph_reference(old, spec)?;
        let runs = (
            run_on_reference(backend, new, new_spec, &refv),
            run_on_reference(backend, old, spec, &refv),
        );
        let (got, want) = match runs {
            (Ok((g, _)), Ok((w, _))) => (g, w),
            (Err(e), _) | (_, Err(e)) => {
                rows.push(Row::failed(
                    Check::Graph,
                    &spec.name,
                    cmp,
                    "(all)",
                    bound,
                    format!("{e:#}"),
                ));
                continue;
            }
        };
        compared += 1;
        for (k, name) in spec.output_names().iter().enumerate() {
            let mut m = MaxAbs::default();
            if got.len() != want.len() {
                m.problem = Some(format!("{} steps vs {}", got.len(), want.len()));
                m.err = f64::INFINITY;
            }
            for (s, (g, w)) in got.iter().zip(&want).enumerate() {
                m.add(s as u64, &g[k], &w[k]);
            }
            rows.push(Row::max_abs(
                Check::Graph,
                &spec.name,
                cmp,
                *name,
                &m,
                bound,
            ));
        }
    }
    for spec in new.graphs() {
        if old.graph(&spec.name).is_err() {
            skipped.push(format!("{} (only in the new bundle)", spec.name));
        }
    }
    if !skipped.is_empty() {
        notes.push(format!(
            "against: graphs not compared: {}",
            skipped.join(", ")
        ));
    }
    Ok(compared)
}

/// The LiveGesture rollout rows: both bundles on the old bundle's reference audio and seed.
#[allow(clippy::too_many_arguments)]
/// The whole-rollout comparison of the family of the new bundle (through [`livegesture::model::for_family`],
/// the one place that maps a family to its code).
struct AgainstRollout<'a> {
    old: &'a Bundle,
    backend: &'a dyn Backend,
    cmp: &'a str,
    o: &'a AgainstOptions,
    rows: &'a mut Vec<Row>,
    notes: &'a mut Vec<String>,
    divergences: &'a mut Vec<Divergence>,
}

impl livegesture::model::FamilyTool for AgainstRollout<'_> {
    type Output = Result<()>;
    fn livegesture(self, new: &Bundle) -> Result<()> {
        livegesture_rollout(
            new,
            self.old,
            self.backend,
            self.cmp,
            self.o,
            self.rows,
            self.notes,
            self.divergences,
        )
    }
    fn diffsheg(self, new: &Bundle) -> Result<()> {
        diffsheg_rollout(
            new,
            self.old,
            self.backend,
            self.cmp,
            self.o,
            self.rows,
            self.notes,
        )
    }
}

// the report's three accumulators (rows, notes, divergences) as the other checks of this file take them
#[allow(clippy::too_many_arguments)]
fn livegesture_rollout(
    new: &Bundle,
    old: &Bundle,
    backend: &dyn Backend,
    cmp: &str,
    o: &AgainstOptions,
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
    divergences: &mut Vec<Divergence>,
) -> Result<()> {
    let clip_rel = old.reference_clip();
    let clip_path = old.path(&clip_rel);
    let clip = read_wav_16k_mono(&clip_path).map_err(|e| ref_err(&clip_path, e))?;
    let ro_rel = old.reference_rollout();
    let reference = ReferenceRollout::load(&old.path(&ro_rel))?;
    let seed = old
        .reference()
        .and_then(|r| r.rollout_seed)
        .ok_or_else(|| ref_err(&old.manifest_path(), "reference.rollout_seed is missing"))?;
    let mut audio = Vec::with_capacity(clip.len() * reference.clip_repeats);
    for _ in 0..reference.clip_repeats {
        audio.extend_from_slice(&clip);
    }
    let opts = StreamOptions {
        seed,
        record_logits: true,
        ..Default::default()
    };
    let run = |b: &Bundle| -> Result<(Vec<TokenStep>, String)> {
        let p = LiveGestureGraphs::with_form(b, backend, GraphForm::Auto)?;
        let form = p.form().to_string();
        Ok((run_stream(&p, &opts, &audio, 16000, false)?, form))
    };
    let (new_steps, new_form) = run(new).context("the new bundle's rollout")?;
    let (old_steps, old_form) = run(old).context("the old bundle's rollout")?;
    notes.push(format!(
        "against: rollout on the old bundle's reference/clip.wav x {} ({:.1} s), seed {seed}, each bundle's sampling defaults; new form {new_form}, old form {old_form}; {} vs {} tokens",
        reference.clip_repeats,
        audio.len() as f64 / 16000.0,
        new_steps.len(),
        old_steps.len()
    ));
    let new_tokens: Vec<Vec<i64>> = new_steps.iter().map(|s| s.tokens.clone()).collect();
    let old_tokens: Vec<Vec<i64>> = old_steps.iter().map(|s| s.tokens.clone()).collect();
    let lg = old.livegesture()?;
    let params = SamplingParams {
        seed,
        guidance: lg.sampling.guidance,
        temperature: lg.sampling.temperature,
        top_k: lg.sampling.top_k,
        regions: lg.region_names().iter().map(|r| r.to_string()).collect(),
    };
    let trace = |name: &str, steps: &[TokenStep], tokens: &[Vec<i64>]| RolloutTrace {
        name: name.into(),
        tokens: tokens.to_vec(),
        logits: Some(
            steps
                .iter()
                .map(|s| {
                    s.logits.clone().unwrap_or(StepLogits {
                        cond: Vec::new(),
                        uncond: None,
                    })
                })
                .collect(),
        ),
    };
    let div = find_divergence(
        &trace("new", &new_steps, &new_tokens),
        &trace("old", &old_steps, &old_tokens),
        &params,
    )?;
    let mut row = token_row(
        Check::Rollout,
        "rollout",
        cmp,
        &new_tokens,
        &old_tokens,
        div.as_ref().map(|d| d.to_string()),
    );
    // allowed differing steps: (1 - agreement) of the steps compared
    let allowed = ((1.0 - o.token_agreement.clamp(0.0, 1.0)) * row.compared as f64).floor();
    row.bound = allowed;
    row.pass = row.compared > 0 && row.error <= allowed;
    rows.push(row);
    // frames over the whole rollout, every token step (after a divergence they differ: that is what moved)
    let n = new_steps.len().min(old_steps.len());
    frame_rows_steps(
        Check::Rollout,
        "rollout",
        cmp,
        &[(String::new(), &new_steps[..n], &old_steps[..n])],
        o.frames_bound,
        rows,
    );
    if let Some(d) = div {
        divergences.push(d);
    }
    Ok(())
}

/// The DiffSHEG rollout rows: both bundles' FOPPAS rollouts on the old bundle's reference.
fn diffsheg_rollout(
    new: &Bundle,
    old: &Bundle,
    backend: &dyn Backend,
    cmp: &str,
    o: &AgainstOptions,
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
) -> Result<()> {
    use livegesture::model::diffsheg::reference::RolloutReference;
    let rel = old.reference_rollout();
    let path = old.path(&rel);
    let mut reference =
        RolloutReference::open(&path).map_err(|e| ref_err(&path, format!("{e:#}")))?;
    let audio = reference
        .f32("audio")
        .map_err(|e| ref_err(&path, format!("{e:#}")))?
        .data;
    let seed = reference
        .scalar("seed")
        .map_err(|e| ref_err(&path, format!("{e:#}")))?;
    let (so, speaker) = diffsheg::rollout_options(old, &path)?;
    let sopts = diffsheg::stream_options(&so, seed, speaker);
    let run = |b: &Bundle| -> Result<Vec<Frame>> {
        let m = DiffshegModel::load(b, backend)?;
        let mut s = m.stream(&sopts, false)?;
        diffsheg::run_chunked(&mut s, &audio, audio.len().max(1))
    };
    let new_frames = run(new).context("the new bundle's rollout")?;
    let old_frames = run(old).context("the old bundle's rollout")?;
    notes.push(format!(
        "against: FOPPAS rollout on the old bundle's reference/rollout.npz audio ({} samples), seed {seed}, speaker {speaker}, the old bundle's sampler options; {} vs {} frames",
        audio.len(),
        new_frames.len(),
        old_frames.len()
    ));
    if new_frames.len() != old_frames.len() {
        rows.push(Row::failed(
            Check::Rollout,
            "rollout",
            cmp,
            "frames",
            o.frames_bound,
            format!(
                "{} frames vs {} in the old bundle's rollout",
                new_frames.len(),
                old_frames.len()
            ),
        ));
    }
    for (k, name) in rollout::FRAME_FIELDS.iter().enumerate() {
        let mut m = MaxAbs::default();
        for (a, b) in new_frames.iter().zip(&old_frames) {
            m.add_slices(a.index, rollout::field(a, k), rollout::field(b, k), |j| {
                format!("frame {}, {name}[{j}]", a.index)
            });
        }
        rows.push(Row::max_abs(
            Check::Rollout,
            "rollout",
            cmp,
            *name,
            &m,
            o.frames_bound,
        ));
    }
    Ok(())
}

/// The checks `--against` runs; any other requested check is a failed row that says so.
pub const AGAINST_CHECKS: [Check; 2] = [Check::Graph, Check::Rollout];

/// Checks the bundle in `new` against the bundle in `old` (module docs) on the first of
/// `opts.backends` (ort when it runs). Errors on bad input: a bundle that does not load, bundles of
/// different families or with no graph in common, missing reference files of the old bundle.
// long: the checks of export against export in the order of the report's rows (load, graphs, rollout)
pub fn against(
    new_dir: &Path,
    old_dir: &Path,
    opts: &ParityOptions,
    o: &AgainstOptions,
    log: &mut dyn FnMut(&str),
) -> Result<Report> {
    let t0 = Instant::now();
    let new = Bundle::load(new_dir).context("the new bundle (--bundle)")?;
    let old = Bundle::load(old_dir).context("the old bundle (--against)")?;
    input_ensure!(
        new.family() == old.family(),
        "--against: the bundles are of different families ({} is {:?}, {} is {:?}); only exports of one model family can be compared",
        new_dir.display(),
        new.family(),
        old_dir.display(),
        old.family()
    );
    for (what, b) in [("graph", o.graph_bound), ("frames", o.frames_bound)] {
        input_ensure!(
            b.is_finite() && b >= 0.0,
            "--against: the {what} bound must be a number >= 0, got {b}"
        );
    }
    input_ensure!(
        (0.0..=1.0).contains(&o.token_agreement),
        "--against: the token agreement must be in 0..1, got {}",
        o.token_agreement
    );
    let kind = *opts
        .backends
        .iter()
        .min_by_key(|k| match k {
            BackendKind::Ort => 0,
            BackendKind::Tract => 1,
        })
        .ok_or_else(|| anyhow::anyhow!("no backend selected"))?;
    let bo = if kind == BackendKind::Ort {
        opts.ort.clone()
    } else {
        BackendOptions {
            kind,
            ..Default::default()
        }
    };
    let be = backend::create(&bo)
        .with_context(|| format!("starting the {kind} backend for --against"))?;
    let cmp = format!("new vs old ({kind})");
    let (mut rows, mut notes, mut divergences) = (Vec::new(), Vec::new(), Vec::new());
    notes.push(format!(
        "against: new {} vs old {}; bounds: graphs {:.1e} (scaled), rollout frames {:.1e} (scaled), token agreement {}",
        new.dir().display(),
        old.dir().display(),
        o.graph_bound,
        o.frames_bound,
        o.token_agreement
    ));
    // no check named: every check --against runs
    let checks = if opts.checks.is_empty() {
        AGAINST_CHECKS.to_vec()
    } else {
        opts.checks.clone()
    };
    let want = |c: Check| checks.contains(&c);
    if want(Check::Graph) {
        let t = Instant::now();
        let n = graph_rows_against(
            &new,
            &old,
            be.as_ref(),
            &cmp,
            o.graph_bound,
            &mut rows,
            &mut notes,
        )?;
        input_ensure!(
            n > 0 || rows.iter().any(|r| !r.pass),
            "--against: the bundles have no graph in common with the same inputs, outputs and caches"
        );
        log(&format!(
            "against: {n} graphs in {:.1} s",
            t.elapsed().as_secs_f64()
        ));
    }
    if want(Check::Rollout) {
        let t = Instant::now();
        let r = livegesture::model::for_family(
            &new,
            AgainstRollout {
                old: &old,
                backend: be.as_ref(),
                cmp: &cmp,
                o,
                rows: &mut rows,
                notes: &mut notes,
                divergences: &mut divergences,
            },
        );
        if let Err(e) = r {
            if e.chain().any(|c| c.is::<ReferenceError>()) {
                return Err(e);
            }
            rows.push(Row::failed(
                Check::Rollout,
                "rollout",
                &cmp,
                "(all)",
                o.frames_bound,
                format!("{e:#}"),
            ));
        }
        log(&format!(
            "against: rollout in {:.1} s",
            t.elapsed().as_secs_f64()
        ));
    }
    // a requested check --against does not run (logmel, chunks, batch) is a failed row saying so
    super::report::fail_checks_without_rows(
        &mut rows,
        &checks,
        super::why_no_rows(new.family(), Some(&AGAINST_CHECKS[..])),
    );
    Ok(Report {
        bundle: new.dir().to_path_buf(),
        backends: vec![kind.to_string()],
        rows,
        notes,
        divergences,
        runtimes: backend::runtime_versions(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

//! Parity in the browser (docs/wasm.md, bounds of docs/parity.md): tract compiled to WebAssembly
//! against the reference vectors that travel with the bundle.
//!
//! | check | what | bound |
//! |---|---|---|
//! | graph | every graph of the manifest over its reference steps (LiveGesture: `step{s}.*`, chained caches; DiffSHEG: `call{c}.*`), every data output at every step and every new cache at the last step, vs the reference | native tract's bound vs the reference: 1e-4 + 1e-5 (tract vs ort + ort vs torch), scaled by max(1, max|ref|) |
//! | rollout | LiveGesture: the whole seeded reference rollout (clip x repeats, the manifest's seed and sampling defaults): identical tokens, frames within the rollout bound; DiffSHEG: the seeded FOPPAS rollout over the reference audio with the manifest's rollout options: frames within the rollout bound | 1e-4 (scaled), as the native suite |
//!
//! Each line names the graph (or rollout), the output, the step, the error and the scale it was
//! judged at; a failed comparison is a `FAIL` line. The native suite (`livegesture parity`) also
//! compares against onnxruntime, which a browser does not have.

use std::collections::HashMap;
use std::io::Cursor;

use anyhow::{anyhow, bail, Context, Result};
use livegesture::audio::AudioSpan;
use livegesture::backend::tract::TractBackend;
use livegesture::backend::{Backend, Tensor, TensorData};
use livegesture::bundle::{Bundle, GraphSpec};
use livegesture::compare::{diff, diff_tensors, Diff};
use livegesture::model::livegesture::LiveGestureGraphs;
use livegesture::model::{self, StreamOptions};
use ndarray::{ArrayD, IxDyn};
use ndarray_npy::NpzReader;

/// tract vs the reference (torch; onnxruntime for a reduced-precision bundle): native tract's bound,
/// tract vs onnxruntime 1e-4 plus onnxruntime vs torch 1e-5 (docs/parity.md).
pub const GRAPH_BOUND: f64 = 1e-4 + 1e-5;
/// LiveGesture's rollout frames vs the reference (docs/parity.md).
pub const LIVEGESTURE_ROLLOUT_FRAMES: f64 = 1e-4;
/// DiffSHEG's rollout frames vs the reference (docs/parity.md: 1e-4 scaled, as the native suite).
pub const DIFFSHEG_ROLLOUT_FRAMES: f64 = 1e-4;

/// The outcome: one line per comparison.
#[derive(Debug, Default)]
pub struct Report {
    pub passed: usize,
    pub failed: usize,
    pub lines: Vec<String>,
}

impl Report {
    fn line(&mut self, pass: bool, text: String) {
        if pass {
            self.passed += 1;
        } else {
            self.failed += 1;
        }
        self.lines
            .push(format!("{} {text}", if pass { "PASS" } else { "FAIL" }));
    }

    fn compare(&mut self, what: &str, d: &Diff, bound: f64) {
        let pass = d.within(bound);
        self.line(
            pass,
            format!("{what}: {} (bound {bound:e} x scale)", d.describe()),
        );
    }

    pub fn to_json(&self) -> String {
        serde_json::json!({
            "passed": self.passed,
            "failed": self.failed,
            "lines": self.lines,
        })
        .to_string()
    }
}

/// The arrays of a reference npz, as tensors (float32 and int64).
struct Npz {
    name: String,
    arrays: HashMap<String, Tensor>,
}

impl Npz {
    fn read(bundle: &Bundle, rel: &str) -> Result<Self> {
        let name = bundle.path(rel).display().to_string();
        let bytes = bundle.read(rel)?;
        let mut npz = NpzReader::new(Cursor::new(&bytes[..]))
            .with_context(|| format!("{name}: not a valid npz"))?;
        let names = npz
            .names()
            .with_context(|| format!("{name}: not a valid npz"))?;
        let mut arrays = HashMap::new();
        for n in names {
            let t = if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<f32> = a;
                Tensor::f32(a.shape().to_vec(), a.iter().copied().collect())?
            } else if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<i64> = a;
                Tensor::i64(a.shape().to_vec(), a.iter().copied().collect())?
            } else if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<u64> = a;
                Tensor::i64(a.shape().to_vec(), a.iter().map(|&v| v as i64).collect())?
            } else {
                // other dtypes (float64 traces) are not read here
                continue;
            };
            arrays.insert(n.trim_end_matches(".npy").to_string(), t);
        }
        Ok(Self {
            name: name.clone(),
            arrays,
        })
    }

    fn get(&self, key: &str) -> Result<&Tensor> {
        self.arrays
            .get(key)
            .ok_or_else(|| anyhow!("{}: no array '{key}'", self.name))
    }

    fn f32(&self, key: &str) -> Result<&[f32]> {
        self.get(key)?.as_f32(key)
    }

    fn int(&self, key: &str) -> Result<i64> {
        match &self.get(key)?.data {
            TensorData::I64(v) if v.len() == 1 => Ok(v[0]),
            _ => bail!("{}: '{key}' is not an integer scalar", self.name),
        }
    }
}

/// Runs every check on `bundle` (see the module docs).
pub fn run(bundle: &Bundle) -> Result<Report> {
    let mut report = Report::default();
    let backend = TractBackend::new();
    for spec in bundle.graphs() {
        if let Err(e) = graph(bundle, &backend, spec, &mut report) {
            report.line(false, format!("graph {}: {e:#}", spec.name));
        }
    }
    let res = model::for_family(
        bundle,
        Rollout {
            backend: &backend,
            report: &mut report,
        },
    );
    if let Err(e) = res {
        report.line(false, format!("rollout: {e:#}"));
    }
    Ok(report)
}

/// The whole reference rollout of the bundle's family ([`model::for_family`]: the one place that maps
/// a family to its code).
struct Rollout<'a> {
    backend: &'a dyn Backend,
    report: &'a mut Report,
}

impl model::FamilyTool for Rollout<'_> {
    type Output = Result<()>;
    fn livegesture(self, bundle: &Bundle) -> Result<()> {
        livegesture_rollout(bundle, self.backend, self.report)
    }
    fn diffsheg(self, bundle: &Bundle) -> Result<()> {
        diffsheg_rollout(bundle, self.backend, self.report)
    }
}

/// One graph over its reference steps (module docs).
fn graph(
    bundle: &Bundle,
    backend: &dyn Backend,
    spec: &GraphSpec,
    report: &mut Report,
) -> Result<()> {
    let rel = spec
        .reference
        .clone()
        .unwrap_or_else(|| format!("reference/{}.npz", spec.name));
    let refv = Npz::read(bundle, &rel)?;
    let first = &spec.inputs[0].name;
    // LiveGesture: chained steps with caches; DiffSHEG: independent calls without caches
    let (prefix, n) = if refv.arrays.contains_key(&format!("step0.input.{first}")) {
        ("step", refv.int("n_steps")? as usize)
    } else {
        let mut n = 0;
        while refv.arrays.contains_key(&format!("call{n}.input.{first}")) {
            n += 1;
        }
        ("call", n)
    };
    anyhow::ensure!(n > 0, "{}: no reference steps", refv.name);
    let mut runner = backend.load_from(bundle, spec)?;
    let batch = refv.get(&format!("{prefix}0.input.{first}"))?.batch();
    let mut caches: Vec<Tensor> = spec.caches.iter().map(|c| c.zeros(batch)).collect();
    let mut worst: Vec<Option<(Diff, usize)>> = vec![None; spec.outputs.len()];
    for s in 0..n {
        let mut inputs: Vec<Tensor> = spec
            .inputs
            .iter()
            .map(|i| refv.get(&format!("{prefix}{s}.input.{}", i.name)).cloned())
            .collect::<Result<_>>()?;
        inputs.extend(caches);
        let out = runner
            .run(&inputs)
            .with_context(|| format!("wasm tract, {prefix} {s}"))?;
        for (k, o) in spec.outputs.iter().enumerate() {
            let want = refv.get(&format!("{prefix}{s}.output.{}", o.name))?;
            // shapes and element types checked, int64 exactly (livegesture::compare::diff_tensors)
            let d = diff_tensors(&out[k], want);
            worst[k] = Some(match worst[k].take() {
                None => (d, s),
                Some((w, ws)) => {
                    let w2 = w.clone().worst(d);
                    let at = if w2 == w { ws } else { s };
                    (w2, at)
                }
            });
        }
        caches = out[spec.outputs.len()..].to_vec();
        if s == n - 1 {
            for (k, c) in spec.caches.iter().enumerate() {
                let want = refv.get(&format!("{prefix}{s}.new_cache.{}", c.name))?;
                let d = diff_tensors(&caches[k], want);
                report.compare(
                    &format!(
                        "graph {} output {} {prefix} {s}: wasm tract vs {}",
                        spec.name,
                        c.output,
                        bundle.reference_name()
                    ),
                    &d,
                    GRAPH_BOUND,
                );
            }
        }
    }
    for (k, o) in spec.outputs.iter().enumerate() {
        if let Some((d, s)) = &worst[k] {
            report.compare(
                &format!(
                    "graph {} output {} (worst of {n} {prefix}s, at {prefix} {s}): wasm tract vs {}",
                    spec.name,
                    o.name,
                    bundle.reference_name()
                ),
                d,
                GRAPH_BOUND,
            );
        }
    }
    Ok(())
}

/// The frame fields of a rollout, in the reference file's names.
const FIELDS: [&str; 4] = ["poses", "trans", "expressions", "foot_contact"];

fn field(frames: &[livegesture::output::Frame], k: usize) -> Vec<f32> {
    frames
        .iter()
        .flat_map(|f| match k {
            0 => f.poses.to_vec(),
            1 => f.trans.to_vec(),
            2 => f.expressions.to_vec(),
            _ => f.foot_contact.to_vec(),
        })
        .collect()
}

fn clip_16k(bundle: &Bundle, rel: &str) -> Result<Vec<f32>> {
    let bytes = bundle.read(rel)?;
    let a =
        crate::wav::decode_mono(&bytes).with_context(|| bundle.path(rel).display().to_string())?;
    anyhow::ensure!(
        a.sample_rate == 16_000,
        "{}: the reference clip is at {} Hz; expected 16000",
        bundle.path(rel).display(),
        a.sample_rate
    );
    Ok(a.samples)
}

fn livegesture_rollout(bundle: &Bundle, backend: &dyn Backend, report: &mut Report) -> Result<()> {
    let r = bundle
        .reference()
        .ok_or_else(|| anyhow!("manifest.json has no `reference`"))?;
    let rel = bundle.reference_rollout();
    let refv = Npz::read(bundle, &rel)?;
    let seed = r
        .rollout_seed
        .ok_or_else(|| anyhow!("manifest.json: reference.rollout_seed is missing"))?;
    let clip_rel = bundle.reference_clip();
    let clip = clip_16k(bundle, &clip_rel)?;
    let repeats = refv.int("clip_repeats")?.max(1) as usize;
    let audio: Vec<f32> = std::iter::repeat_n(&clip[..], repeats)
        .flatten()
        .copied()
        .collect();
    let want_tokens = refv.get("tokens")?;
    let regions = want_tokens.shape.get(1).copied().unwrap_or(1);
    let want_tokens = want_tokens.as_i64("tokens")?.to_vec();
    let mut p = LiveGestureGraphs::new(bundle, backend)?;
    let opts = StreamOptions {
        seed,
        ..Default::default()
    };
    let mut s = p.new_stream(&opts)?;
    let mut steps = Vec::new();
    for c in audio.chunks(16_000) {
        steps.extend(p.push_steps(&mut s, c)?);
    }
    let got_tokens: Vec<i64> = steps
        .iter()
        .flat_map(|s| s.tokens.iter().copied())
        .collect();
    let what = format!(
        "rollout tokens ({} tokens, seed {seed}, clip x {repeats}): wasm tract vs {}",
        want_tokens.len() / regions.max(1),
        bundle.reference_name()
    );
    let first_diff = got_tokens
        .iter()
        .zip(&want_tokens)
        .position(|(a, b)| a != b);
    let prefix_tokens = match first_diff {
        // nothing compared proves nothing: an empty rollout fails below
        None if got_tokens.len() == want_tokens.len() && !want_tokens.is_empty() => {
            report.line(true, format!("{what}: identical"));
            steps.len()
        }
        None => {
            report.line(
                false,
                format!(
                    "{what}: {} token steps vs {} in the reference",
                    got_tokens.len() / regions.max(1),
                    want_tokens.len() / regions.max(1)
                ),
            );
            got_tokens.len().min(want_tokens.len()) / regions.max(1)
        }
        Some(i) => {
            report.line(
                false,
                format!(
                    "{what}: first differing token at step {}, region {}: {} vs {}",
                    i / regions,
                    i % regions,
                    got_tokens[i],
                    want_tokens[i]
                ),
            );
            i / regions
        }
    };
    let frames: Vec<livegesture::output::Frame> = steps[..prefix_tokens]
        .iter()
        .flat_map(|s| s.frames.iter().cloned())
        .collect();
    for (k, name) in FIELDS.iter().enumerate() {
        let want = refv.f32(name)?;
        let width = want.len() / refv.get(name)?.batch().max(1);
        let got = field(&frames, k);
        let n = got.len().min(want.len()) / width.max(1) * width;
        let d = diff(&got[..n], &want[..n]);
        report.compare(
            &format!(
                "rollout {name} ({} frames): wasm tract vs {}",
                n / width.max(1),
                bundle.reference_name()
            ),
            &d,
            LIVEGESTURE_ROLLOUT_FRAMES,
        );
    }
    Ok(())
}

fn diffsheg_rollout(bundle: &Bundle, backend: &dyn Backend, report: &mut Report) -> Result<()> {
    bundle
        .reference()
        .ok_or_else(|| anyhow!("manifest.json has no `reference`"))?;
    let rel = bundle.reference_rollout();
    let refv = Npz::read(bundle, &rel)?;
    let raw: serde_json::Value = serde_json::from_slice(&bundle.read("manifest.json")?)?;
    let ro = &raw["reference"]["rollout_options"];
    let get = |k: &str| -> Result<usize> {
        ro[k]
            .as_u64()
            .map(|v| v as usize)
            .ok_or_else(|| anyhow!("manifest.json: reference.rollout_options.{k} is missing"))
    };
    let opts = StreamOptions {
        seed: refv.int("seed")? as u64,
        guidance: Some(ro["guidance"].as_f64().ok_or_else(|| {
            anyhow!("manifest.json: reference.rollout_options.guidance is missing")
        })?),
        ddim_steps: Some(get("steps")?),
        window: Some(get("window")?),
        overlap: Some(get("overlap")?),
        jumps: Some(get("jumps")?),
        blend_steps: Some(get("blend_steps")?),
        speaker: Some(raw["reference"]["rollout_speaker"].as_u64().unwrap_or(0) as usize),
        ..Default::default()
    };
    let audio = refv.f32("audio")?.to_vec();
    let m = model::load(bundle, backend)?;
    let mut s = m.new_stream(&opts)?;
    let mut frames = s.push_audio(&audio)?;
    frames.extend(s.finish(AudioSpan::at_16k(audio.len() as u64))?);
    let t_frames = refv.int("frames")? as usize;
    report.line(
        frames.len() == t_frames,
        format!(
            "rollout frames (seed {}): {} frames, reference {t_frames}",
            opts.seed,
            frames.len()
        ),
    );
    for (k, name) in FIELDS.iter().enumerate() {
        let d = diff(&field(&frames, k), refv.f32(name)?);
        report.compare(
            &format!(
                "rollout {name} ({} frames): wasm tract vs {}",
                frames.len(),
                bundle.reference_name()
            ),
            &d,
            DIFFSHEG_ROLLOUT_FRAMES,
        );
    }
    Ok(())
}

//! The second browser engine (docs/wasm.md, "ONNX Runtime Web"): the same Rust runtime (bundle
//! verification, both families' streaming logic, resampling, the log-mel frontend, the sampler, frame
//! assembly, the parity checks) with the step graphs run by `onnxruntime-web` instead of tract.
//!
//! ONNX Runtime Web's `session.run` is asynchronous and the runtime's [`GraphRunner::run`] is not, so
//! the worker (`runtime/web/public/ort-worker.js`) joins them with WebAssembly JavaScript Promise
//! Integration (JSPI): the import `lgOrtRun` is wrapped in `WebAssembly.Suspending`, and the exports
//! below that reach it (`ortweb_stream`, `ortweb_push`, `ortweb_finish`, `ortweb_generate`,
//! `ortweb_parity`) are called through `WebAssembly.promising`. While a graph runs, this module's
//! stack is suspended; the worker sends one call at a time. Those exports take and return numbers
//! only (the worker calls them without wasm-bindgen's glue): their inputs are staged before
//! (`ortweb_stage_pcm`, `ortweb_stage_wav`), their result is taken after (`ortweb_take`), and they
//! return 0 on success, 1 on an error (whose message `ortweb_take` throws).
//!
//! Only the graphs change engine: the frontend and the sampler are this module's, bit for bit the
//! numerics of the tract engine.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, bail, ensure, Context, Result};
use js_sys::{Array, BigInt64Array, Float32Array};
use livegesture::backend::{check_inputs, Backend, GraphRunner, Tensor, TensorData};
use livegesture::bundle::{Bundle, GraphSpec};
use livegesture::model::{self, MotionModel};
use wasm_bindgen::prelude::*;
use wasm_bindgen::JsCast;

use livegesture::generate::{self, PcmStream};
use livegesture::portable_parity;

use crate::{seed_from, BundleFiles, Frames, Stream};

/// ONNX Runtime Web runs ONNX Runtime's CPU provider (compiled to WebAssembly): the bound of an
/// ONNX Runtime CPU provider against the torch references (docs/parity.md: 1e-5 scaled).
pub const ORT_WEB_GRAPH_BOUND: f64 = 1e-5;

#[wasm_bindgen]
extern "C" {
    /// `globalThis.lgOrtRun(graph, inputs)` (ort-worker.js): runs the ONNX Runtime Web session of
    /// `graph` on `inputs` (`[name, dtype, dims, data]` each, in the graph's input order); resolves
    /// to `[[dims, data], ...]` in the graph's output order, or to a string naming the error. Wrapped
    /// in `WebAssembly.Suspending`: from here it returns the resolved value.
    #[wasm_bindgen(js_name = lgOrtRun)]
    fn lg_ort_run(graph: &str, inputs: Array) -> JsValue;
}

/// The backend whose graph forms ONNX Runtime Web runs ([`Backend::forms_of`]): ONNX Runtime's CPU
/// kernels compiled to WebAssembly run the forms the bundle names for `ort` (`fused_ring` in the
/// shipped bundles), not the per-region canonical graphs.
pub(crate) const FORMS_OF: &str = "ort";

/// The graphs through `lgOrtRun` (the sessions live in the worker, one per graph file).
struct OrtWebBackend;

impl Backend for OrtWebBackend {
    fn name(&self) -> &str {
        "ort-web"
    }

    fn describe(&self) -> String {
        "ONNX Runtime Web (WebAssembly, CPU)".to_string()
    }

    /// [`FORMS_OF`].
    fn forms_of(&self) -> &str {
        FORMS_OF
    }

    fn load(&self, spec: &GraphSpec, path: &Path) -> Result<Box<dyn GraphRunner>> {
        let _ = path;
        Ok(Box::new(OrtWebRunner { spec: spec.clone() }))
    }

    fn load_bytes(
        &self,
        spec: &GraphSpec,
        path: &Path,
        _bytes: &[u8],
    ) -> Result<Box<dyn GraphRunner>> {
        // the worker made the session from the same (sha256-checked) bytes
        self.load(spec, path)
    }
}

struct OrtWebRunner {
    spec: GraphSpec,
}

fn to_js(name: &str, t: &Tensor) -> Array {
    let dims: Array = t.shape.iter().map(|&d| JsValue::from(d as f64)).collect();
    let (dtype, data): (&str, JsValue) = match &t.data {
        TensorData::F32(v) => ("float32", Float32Array::from(&v[..]).into()),
        TensorData::I64(v) => ("int64", BigInt64Array::from(&v[..]).into()),
    };
    Array::of4(&JsValue::from(name), &JsValue::from(dtype), &dims, &data)
}

fn from_js(graph: &str, name: &str, v: &JsValue) -> Result<Tensor> {
    let pair: &Array = v
        .dyn_ref()
        .ok_or_else(|| anyhow!("ort-web: graph '{graph}' output '{name}': not [dims, data]"))?;
    let shape = pair
        .get(0)
        .dyn_into::<Array>()
        .map_err(|_| anyhow!("ort-web: graph '{graph}' output '{name}': dims is not an array"))?
        .iter()
        .map(|d| {
            d.as_f64()
                .filter(|x| *x >= 0.0 && x.fract() == 0.0)
                .map(|x| x as usize)
                .ok_or_else(|| anyhow!("ort-web: graph '{graph}' output '{name}': bad dimension"))
        })
        .collect::<Result<Vec<_>>>()?;
    let data = pair.get(1);
    if let Some(a) = data.dyn_ref::<Float32Array>() {
        Tensor::f32(shape, a.to_vec())
    } else if let Some(a) = data.dyn_ref::<BigInt64Array>() {
        Tensor::i64(shape, a.to_vec())
    } else {
        bail!("ort-web: graph '{graph}' output '{name}': expected float32 or int64 data")
    }
}

impl GraphRunner for OrtWebRunner {
    fn spec(&self) -> &GraphSpec {
        &self.spec
    }

    fn run(&self, inputs: &[Tensor]) -> Result<Vec<Tensor>> {
        check_inputs(&self.spec, inputs)?;
        let names = self.spec.input_names();
        let args: Array = names
            .iter()
            .zip(inputs)
            .map(|(n, t)| JsValue::from(to_js(n, t)))
            .collect();
        let out = lg_ort_run(&self.spec.name, args);
        if let Some(msg) = out.as_string() {
            bail!("ort-web: graph '{}': {msg}", self.spec.name);
        }
        let out: Array = out.dyn_into().map_err(|_| {
            anyhow!(
                "ort-web: graph '{}': lgOrtRun did not return the outputs (is the worker using JSPI?)",
                self.spec.name
            )
        })?;
        let onames = self.spec.output_names();
        ensure!(
            out.length() as usize == onames.len(),
            "ort-web: graph '{}': {} outputs, expected {} ({onames:?})",
            self.spec.name,
            out.length(),
            onames.len()
        );
        onames
            .iter()
            .enumerate()
            .map(|(k, n)| from_js(&self.spec.name, n, &out.get(k as u32)))
            .collect()
    }
}

/// The engine's state: one model, its streams, the staged input and the last result.
#[derive(Default)]
struct Engine {
    bundle: Option<Bundle>,
    model: Option<Box<dyn MotionModel>>,
    streams: BTreeMap<u32, Stream>,
    next: u32,
    pcm: Vec<f32>,
    wav: Vec<u8>,
    result: Option<std::result::Result<JsValue, String>>,
}

thread_local! {
    static ENGINE: RefCell<Engine> = RefCell::new(Engine::default());
}

/// Runs `f` on the engine and keeps its result for [`ortweb_take`]: 0 on success, 1 on an error.
fn call(f: impl FnOnce(&mut Engine) -> Result<JsValue>) -> u32 {
    ENGINE.with(|e| {
        let mut e = e.borrow_mut();
        let r = f(&mut e).map_err(|err| format!("{err:#}"));
        let code = u32::from(r.is_err());
        e.result = Some(r);
        code
    })
}

fn model(e: &Engine) -> Result<&dyn MotionModel> {
    e.model
        .as_deref()
        .ok_or_else(|| anyhow!("ort-web: no model loaded"))
}

fn stream(e: &mut Engine, id: u32) -> Result<&mut Stream> {
    e.streams
        .get_mut(&id)
        .ok_or_else(|| anyhow!("ort-web: no stream {id}"))
}

/// A stream's options from JavaScript's arguments (`guidance` NaN: the bundle's default); the same
/// seed rule as the tract engine's [`seed_from`].
fn options(seed: f64, guidance: f64) -> Result<model::StreamOptions> {
    let seed = seed_from(seed)
        .map_err(|_| anyhow!("seed is {seed}; expected an integer from 0 to 2^53"))?;
    Ok(model::StreamOptions {
        seed,
        guidance: (!guidance.is_nan()).then_some(guidance),
        ..Default::default()
    })
}

/// `f` as Frames, with the face channel when the model has one.
fn frames(f: &[livegesture::output::Frame], face: bool) -> Result<JsValue> {
    Ok(Frames::of(f, face).map_err(|e| anyhow!(e))?.into())
}

/// Loads a bundle (sha256 of every file checked) for ONNX Runtime Web; runs no graph. With `complete`
/// false only the graphs it runs need be given (`filesToLoad(manifest, "ort-web", form)`): those of
/// ort's form, or of `form` where one is named. Returns `{family, fps, precision, graphs: [[name,
/// file], ...]}`: the graphs to make a session for (the worker makes one per file), every graph of
/// the bundle when `complete` (parity checks each), else the ones the model runs.
#[wasm_bindgen]
pub fn ortweb_load(
    name: String,
    files: BundleFiles,
    complete: bool,
    form: Option<String>,
) -> Result<JsValue, JsError> {
    let opts = crate::load_options(form.as_deref())?;
    let form = opts.form.to_string();
    let bundle = if complete {
        Bundle::from_files(name, files.files)
    } else {
        Bundle::from_files_run_by(name, files.files, FORMS_OF, Some(&form))
    }
    .map_err(|e| JsError::new(&e.to_string()))?;
    let m = model::load_with(&bundle, &OrtWebBackend, &opts)
        .map_err(|e| JsError::new(&format!("{e:#}")))?;
    let run = bundle.manifest().graph_files_run_by(FORMS_OF, Some(&form));
    let graphs: Array = bundle
        .graphs()
        .iter()
        .filter(|g| complete || run.contains(&g.file))
        .map(|g| JsValue::from(Array::of2(&g.name.as_str().into(), &g.file.as_str().into())))
        .collect();
    let info = js_sys::Object::new();
    let fields: [(&str, JsValue); 3] = [
        ("family", m.family().name().into()),
        ("fps", JsValue::from(m.fps() as f64)),
        ("precision", bundle.precision().to_string().into()),
    ];
    for (k, v) in fields {
        js_sys::Reflect::set(&info, &k.into(), &v).map_err(|_| JsError::new("info"))?;
    }
    js_sys::Reflect::set(&info, &"graphs".into(), &graphs).map_err(|_| JsError::new("info"))?;
    ENGINE.with(|e| {
        let mut e = e.borrow_mut();
        e.streams.clear();
        e.model = Some(m);
        e.bundle = Some(bundle);
    });
    Ok(info.into())
}

/// Stages the PCM of the next [`ortweb_push`].
#[wasm_bindgen]
pub fn ortweb_stage_pcm(pcm: Vec<f32>) {
    ENGINE.with(|e| e.borrow_mut().pcm = pcm);
}

/// Stages the WAV file of the next [`ortweb_generate`].
#[wasm_bindgen]
pub fn ortweb_stage_wav(wav: Vec<u8>) {
    ENGINE.with(|e| e.borrow_mut().wav = wav);
}

/// The result of the last asynchronous call: its value, or its error thrown.
#[wasm_bindgen]
pub fn ortweb_take() -> Result<JsValue, JsError> {
    ENGINE.with(|e| match e.borrow_mut().result.take() {
        Some(Ok(v)) => Ok(v),
        Some(Err(msg)) => Err(JsError::new(&msg)),
        None => Err(JsError::new("ort-web: no result to take")),
    })
}

/// A new stream (result: its id). `guidance` NaN: the bundle's default.
#[wasm_bindgen]
pub fn ortweb_stream(seed: f64, guidance: f64) -> u32 {
    call(|e| {
        let opts = options(seed, guidance)?;
        let inner = PcmStream::new(generate::new_stream(model(e)?, &opts)?, "stream");
        e.next += 1;
        let id = e.next;
        let face = model(e)?.has_face();
        e.streams.insert(id, Stream { inner, face });
        Ok(JsValue::from(id))
    })
}

/// Pushes the staged PCM at `rate` Hz into stream `id` (result: Frames).
#[wasm_bindgen]
pub fn ortweb_push(id: u32, rate: u32) -> u32 {
    call(|e| {
        let pcm = std::mem::take(&mut e.pcm);
        let s = stream(e, id)?;
        let f = s.inner.push(&pcm, rate)?;
        frames(&f, s.face)
    })
}

/// Finishes stream `id` (result: Frames).
#[wasm_bindgen]
pub fn ortweb_finish(id: u32) -> u32 {
    call(|e| {
        let s = stream(e, id)?;
        let f = s.inner.finish()?;
        frames(&f, s.face)
    })
}

/// Back to a cold start (runs no graph).
#[wasm_bindgen]
pub fn ortweb_reset(id: u32) -> Result<(), JsError> {
    ENGINE.with(|e| {
        let mut e = e.borrow_mut();
        let s = stream(&mut e, id).map_err(|err| JsError::new(&format!("{err:#}")))?;
        s.inner
            .reset()
            .map_err(|err| JsError::new(&format!("{err:#}")))
    })
}

/// Frees stream `id`.
#[wasm_bindgen]
pub fn ortweb_close(id: u32) {
    ENGINE.with(|e| {
        e.borrow_mut().streams.remove(&id);
    });
}

/// The staged WAV file through a fresh stream (result: Frames). `guidance` NaN: the bundle's.
#[wasm_bindgen]
pub fn ortweb_generate(seed: f64, guidance: f64) -> u32 {
    call(|e| {
        let wav = std::mem::take(&mut e.wav);
        let opts = options(seed, guidance)?;
        let g = generate::generate_wav_bytes(model(e)?, &opts, &wav, "wav")?;
        frames(&g.frames, model(e)?.has_face())
    })
}

/// Every graph against its reference vectors (ONNX Runtime's CPU bound vs torch,
/// [`ORT_WEB_GRAPH_BOUND`]) and the reference rollout (result: the report as JSON text).
#[wasm_bindgen]
pub fn ortweb_parity() -> u32 {
    call(|e| {
        let bundle = e.bundle.as_ref().context("ort-web: no model loaded")?;
        let report =
            portable_parity::run_with(bundle, &OrtWebBackend, "ort-web", ORT_WEB_GRAPH_BOUND);
        Ok(JsValue::from(report.to_json()))
    })
}

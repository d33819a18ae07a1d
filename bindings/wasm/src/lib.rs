//! The LiveGesture runtime in the browser: the runtime core (bundle verification, tract, both model
//! families, resampling, the log-mel frontend, the sampler, frame assembly) compiled to
//! `wasm32-unknown-unknown`, with a wasm-bindgen API that mirrors the Rust streaming API
//! (docs/wasm.md):
//!
//! ```js
//! const files = new BundleFiles();
//! files.add('manifest.json', bytes); files.add('audio_encoder.onnx', bytes); // ...
//! const model = Model.load('models/default', files, true); // sha256 of every listed file checked
//! const stream = model.stream(7, undefined);           // seed, guidance (undefined: the bundle's)
//! const f = stream.push(pcm, 48000);                   // Float32Array at any rate -> Frames
//! const last = stream.finish();                        // frames covering the whole input
//! stream.reset();
//! ```
//!
//! Errors come back as JS exceptions carrying the runtime's message. A panic cannot be caught on
//! wasm32 (it aborts the instance): [`last_panic`] returns its message so the worker can report it.
//!
//! Everything here is the library's: the bundle in memory ([`Bundle::from_some_files`]), the WAV
//! reader ([`generate::generate_wav_bytes`]), the stream at any sample rate ([`PcmStream`]), the
//! option checks ([`generate::new_stream`]), the parity checks ([`portable_parity::run`]) and the
//! skeleton ([`livegesture::skeleton::skeleton_json`]); this crate only converts to and from
//! JavaScript.

use std::cell::RefCell;
use std::collections::BTreeMap;

use livegesture::backend::tract::TractBackend;
use livegesture::bundle::Bundle;
use livegesture::generate::{self, PcmStream};
use livegesture::model::{self, MotionModel, StreamOptions};
use livegesture::output::Frame;
use livegesture::portable_parity;
use wasm_bindgen::prelude::*;

mod ortweb;

thread_local! {
    static PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Installs a panic hook that keeps the message for [`last_panic`] (wasm-bindgen's start function).
#[wasm_bindgen(start)]
pub fn start() {
    std::panic::set_hook(Box::new(|info| {
        let msg = info.to_string();
        PANIC.with(|p| *p.borrow_mut() = Some(msg));
    }));
}

/// The message of the panic that aborted this instance, if one did (the instance must then be
/// recreated).
#[wasm_bindgen(js_name = lastPanic)]
pub fn last_panic() -> Option<String> {
    PANIC.with(|p| p.borrow().clone())
}

/// True when this module was built with WebAssembly SIMD (`+simd128`, from `.cargo/config.toml`):
/// tract's and rustfft's 128-bit kernels.
#[wasm_bindgen]
pub fn simd() -> bool {
    cfg!(target_feature = "simd128")
}

/// The runtime's version (the `livegesture` crate).
#[wasm_bindgen]
pub fn version() -> String {
    env!("CARGO_PKG_VERSION").to_string()
}

/// The project's skeleton as JSON (`names`, `parents`, `offsets` in metres, `units`): what the page
/// poses, the same as `livegesture serve`'s `/skeleton.json`.
#[wasm_bindgen(js_name = skeletonJson)]
pub fn skeleton_json() -> String {
    livegesture::skeleton::skeleton_json()
}

fn js_err(e: impl std::fmt::Display) -> JsError {
    JsError::new(&e.to_string())
}

fn anyhow_err(e: anyhow::Error) -> JsError {
    JsError::new(&format!("{e:#}"))
}

/// A seed from JavaScript: a non-negative integer up to 2^53 (exactly representable).
fn seed_from(seed: f64) -> Result<u64, JsError> {
    if !(seed.is_finite() && seed >= 0.0 && seed.fract() == 0.0 && seed <= 9_007_199_254_740_992.0)
    {
        return Err(js_err(format!(
            "seed is {seed}; expected an integer from 0 to 2^53"
        )));
    }
    Ok(seed as u64)
}

/// The files of a bundle, gathered in memory before [`Model::load`] verifies them.
#[wasm_bindgen]
#[derive(Default)]
pub struct BundleFiles {
    files: BTreeMap<String, Vec<u8>>,
}

#[wasm_bindgen]
impl BundleFiles {
    #[wasm_bindgen(constructor)]
    pub fn new() -> BundleFiles {
        BundleFiles::default()
    }

    /// Adds the file `path` (relative to the bundle, as `manifest.json` lists it) with its bytes.
    pub fn add(&mut self, path: String, bytes: Vec<u8>) {
        self.files.insert(path, bytes);
    }

    /// Number of files added.
    #[wasm_bindgen(getter)]
    pub fn count(&self) -> usize {
        self.files.len()
    }
}

/// Frames out of a stream, row-major: `poses` (n x 165), `trans` (n x 3), `expressions` (n x 100),
/// `footContact` (n x 4), `index` (n); from a bundle with the face channel (docs/face.md) `arkit`
/// (n x 52) and `visemes` (n x 15), else both undefined.
#[wasm_bindgen]
#[derive(Default)]
pub struct Frames {
    index: Vec<f64>,
    poses: Vec<f32>,
    trans: Vec<f32>,
    expressions: Vec<f32>,
    foot_contact: Vec<f32>,
    face: Option<(Vec<f32>, Vec<f32>)>,
}

impl Frames {
    /// `frames` of a model with (`face`) or without the face channel.
    fn of(frames: &[Frame], face: bool) -> Result<Self, String> {
        let mut out = Frames {
            face: face.then(Default::default),
            ..Default::default()
        };
        for f in frames {
            out.index.push(f.index as f64);
            out.poses.extend_from_slice(&f.poses);
            out.trans.extend_from_slice(&f.trans);
            out.expressions.extend_from_slice(&f.expressions);
            out.foot_contact.extend_from_slice(&f.foot_contact);
            if let Some((arkit, visemes)) = &mut out.face {
                let v = f
                    .face
                    .as_ref()
                    .ok_or_else(|| format!("frame {} has no face values", f.index))?;
                arkit.extend_from_slice(&v.arkit);
                visemes.extend_from_slice(&v.visemes);
            }
        }
        Ok(out)
    }
}

#[wasm_bindgen]
impl Frames {
    /// Number of frames.
    #[wasm_bindgen(getter)]
    pub fn count(&self) -> usize {
        self.index.len()
    }
    /// Frame indices from the start of the stream.
    #[wasm_bindgen(getter)]
    pub fn index(&self) -> Vec<f64> {
        self.index.clone()
    }
    /// SMPL-X axis-angle, 55 joints x 3 per frame.
    #[wasm_bindgen(getter)]
    pub fn poses(&self) -> Vec<f32> {
        self.poses.clone()
    }
    /// Root translation in metres, 3 per frame.
    #[wasm_bindgen(getter)]
    pub fn trans(&self) -> Vec<f32> {
        self.trans.clone()
    }
    /// Expression coefficients, 100 per frame.
    #[wasm_bindgen(getter)]
    pub fn expressions(&self) -> Vec<f32> {
        self.expressions.clone()
    }
    /// Foot contact of joints 7, 8, 10, 11, 4 per frame.
    #[wasm_bindgen(getter, js_name = footContact)]
    pub fn foot_contact(&self) -> Vec<f32> {
        self.foot_contact.clone()
    }
    /// ARKit weights in [0, 1], 52 per frame ([`arkit_names`] order); undefined from a bundle
    /// without the face channel.
    #[wasm_bindgen(getter)]
    pub fn arkit(&self) -> Option<Vec<f32>> {
        self.face.as_ref().map(|f| f.0.clone())
    }
    /// Viseme probabilities (each frame's sum 1), 15 per frame ([`viseme_names`] order); undefined
    /// from a bundle without the face channel.
    #[wasm_bindgen(getter)]
    pub fn visemes(&self) -> Option<Vec<f32>> {
        self.face.as_ref().map(|f| f.1.clone())
    }
}

/// The 52 ARKit blendshape names of `Frames.arkit`, Apple's order (docs/face.md).
#[wasm_bindgen(js_name = arkitNames)]
pub fn arkit_names() -> Vec<String> {
    livegesture::face::ARKIT_NAMES
        .iter()
        .map(|s| s.to_string())
        .collect()
}

/// The 15 viseme names of `Frames.visemes`: `sil, PP, FF, TH, DD, kk, CH, SS, nn, RR, aa, E, ih, oh, ou`.
#[wasm_bindgen(js_name = visemeNames)]
pub fn viseme_names() -> Vec<String> {
    livegesture::face::VISEME_NAMES
        .iter()
        .map(|s| s.to_string())
        .collect()
}

/// The files a page downloads to run the bundle whose `manifest.json` is `manifest` with `engine`
/// (`wasm`, tract: the default; or `ort-web`, which runs the forms of `ort`) and the graph form
/// `form` (undefined or `auto`: the engine's form; [`Model::load`] with `complete` false): the graphs
/// of that form, the decoders run with it and the face channel (`Manifest::graph_files_run_by`), in
/// manifest order.
#[wasm_bindgen(js_name = filesToLoad)]
pub fn files_to_load(
    manifest: &[u8],
    engine: Option<String>,
    form: Option<String>,
) -> Result<Vec<String>, JsError> {
    let text = std::str::from_utf8(manifest)
        .map_err(|e| JsError::new(&format!("manifest.json: not UTF-8 text: {e}")))?;
    let m = livegesture::bundle::parse_manifest(text, std::path::Path::new("manifest.json"))
        .map_err(js_err)?;
    let form = load_options(form.as_deref())?.form.to_string();
    Ok(m.graph_files_run_by(forms_of(engine.as_deref())?, Some(&form)))
}

/// The backend whose forms `engine` runs (`Backend::forms_of`): `wasm` (tract) runs tract's,
/// `ort-web` runs ort's.
fn forms_of(engine: Option<&str>) -> Result<&'static str, JsError> {
    match engine.unwrap_or("wasm") {
        "wasm" | "tract" => Ok("tract"),
        "ort-web" => Ok(ortweb::FORMS_OF),
        other => Err(JsError::new(&format!(
            "engine '{other}': expected wasm or ort-web"
        ))),
    }
}

/// The load options of a page's `form` (undefined, `auto`, `canonical`, `fused`, `attention`,
/// `fused_ring`, `attention_ring`: docs/bundle.md#forms-and-precision).
pub(crate) fn load_options(form: Option<&str>) -> Result<model::LoadOptions, JsError> {
    let form = form
        .unwrap_or("auto")
        .parse::<model::GraphForm>()
        .map_err(|e| JsError::new(&format!("form: {e}")))?;
    Ok(model::LoadOptions { form })
}

/// A verified bundle loaded on tract: makes streams.
#[wasm_bindgen]
pub struct Model {
    bundle: Bundle,
    model: Box<dyn MotionModel>,
}

#[wasm_bindgen]
impl Model {
    /// Verifies the bundle's files (every file given, with the size and sha256 `manifest.json`
    /// lists) and loads its graphs on tract. `name` stands for the bundle in messages (e.g. its
    /// URL). With `complete` false, only the graphs tract runs need be given ([`files_to_load`]: a
    /// page that only runs the model need not download the other forms or the reference vectors;
    /// `parity` then fails naming what is missing); with `complete` true, every listed file. `form`
    /// (undefined: `auto`, tract's form) picks the LiveGesture graph form.
    pub fn load(
        name: String,
        files: BundleFiles,
        complete: bool,
        form: Option<String>,
    ) -> Result<Model, JsError> {
        let opts = load_options(form.as_deref())?;
        let bundle = if complete {
            Bundle::from_files(name, files.files)
        } else {
            let form = opts.form.to_string();
            Bundle::from_files_run_by(name, files.files, "tract", Some(&form))
        }
        .map_err(js_err)?;
        let model = model::load_with(&bundle, &TractBackend::new(), &opts).map_err(anyhow_err)?;
        Ok(Model { bundle, model })
    }

    /// The model family (`livegesture`, `diffsheg`).
    #[wasm_bindgen(getter)]
    pub fn family(&self) -> String {
        self.model.family().name().to_string()
    }

    /// Output frames per second (30).
    #[wasm_bindgen(getter)]
    pub fn fps(&self) -> f64 {
        self.model.fps() as f64
    }

    /// Whether frames carry the face channel (`Frames.arkit`, `Frames.visemes`): a bundle with a
    /// face graph.
    #[wasm_bindgen(getter, js_name = hasFace)]
    pub fn has_face(&self) -> bool {
        self.model.has_face()
    }

    /// The weights' precision (`float32`, `float16`, ...).
    #[wasm_bindgen(getter)]
    pub fn precision(&self) -> String {
        self.bundle.precision().to_string()
    }

    /// A fresh stream with `seed` and classifier-free guidance `guidance` (undefined: the bundle's
    /// default).
    pub fn stream(&self, seed: f64, guidance: Option<f64>) -> Result<Stream, JsError> {
        let opts = Self::options(seed, guidance)?;
        let inner = generate::new_stream(self.model.as_ref(), &opts).map_err(anyhow_err)?;
        Ok(Stream {
            inner: PcmStream::new(inner, "stream"),
            face: self.model.has_face(),
        })
    }

    fn options(seed: f64, guidance: Option<f64>) -> Result<StreamOptions, JsError> {
        Ok(StreamOptions {
            seed: seed_from(seed)?,
            guidance,
            ..Default::default()
        })
    }

    /// A whole WAV file (8/16/24/32-bit PCM or 32-bit float, any rate and channel count) through a
    /// fresh stream: `ceil(duration x fps)` frames.
    pub fn generate(
        &self,
        wav: &[u8],
        seed: f64,
        guidance: Option<f64>,
    ) -> Result<Frames, JsError> {
        let opts = Self::options(seed, guidance)?;
        let g = generate::generate_wav_bytes(self.model.as_ref(), &opts, wav, "wav")
            .map_err(anyhow_err)?;
        Frames::of(&g.frames, self.model.has_face()).map_err(js_err)
    }

    /// The parity checks of docs/wasm.md on this bundle (the library's
    /// [`portable_parity::run`]: every graph against its reference vectors, the whole reference
    /// rollout); a JSON string `{passed, failed, lines}`.
    pub fn parity(&self) -> Result<String, JsError> {
        let report = portable_parity::run(&self.bundle, &TractBackend::new(), "wasm tract");
        Ok(report.to_json())
    }
}

/// One stream: its own state (audio buffers, caches, random generator, resampler), the library's
/// [`PcmStream`].
#[wasm_bindgen]
pub struct Stream {
    inner: PcmStream,
    face: bool,
}

#[wasm_bindgen]
impl Stream {
    /// Pushes mono PCM in [-1, 1] at `sample_rate` Hz (any chunk size; one rate per stream until
    /// reset); returns the frames it completes.
    pub fn push(&mut self, pcm: &[f32], sample_rate: u32) -> Result<Frames, JsError> {
        let f = self.inner.push(pcm, sample_rate).map_err(anyhow_err)?;
        Frames::of(&f, self.face).map_err(js_err)
    }

    /// Ends the stream: the remaining frames, so that the stream has emitted
    /// `ceil(samples x fps / rate)` frames in total.
    pub fn finish(&mut self) -> Result<Frames, JsError> {
        let f = self.inner.finish().map_err(anyhow_err)?;
        Frames::of(&f, self.face).map_err(js_err)
    }

    /// Back to a cold start with the same seed and options (also after an error or finish).
    pub fn reset(&mut self) -> Result<(), JsError> {
        self.inner.reset().map_err(anyhow_err)
    }

    /// Frames emitted so far.
    #[wasm_bindgen(getter, js_name = framesEmitted)]
    pub fn frames_emitted(&self) -> f64 {
        self.inner.stream().frames_emitted() as f64
    }

    /// Frames emitted together (a token of 4 frames for LiveGesture, a window step for DiffSHEG).
    #[wasm_bindgen(getter, js_name = framesPerUnit)]
    pub fn frames_per_unit(&self) -> f64 {
        self.inner.stream().frames_per_unit() as f64
    }

    /// The guidance scale in use.
    #[wasm_bindgen(getter)]
    pub fn guidance(&self) -> f64 {
        self.inner.stream().guidance()
    }
}

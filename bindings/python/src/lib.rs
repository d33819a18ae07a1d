//! `livegesture_runtime`: the LiveGesture runtime as a Python module (docs/python.md).
//!
//! A thin door onto the library API: [`livegesture::generate::open_model`] loads a bundle,
//! [`livegesture::generate::PcmStream`] is a stream fed with PCM at any rate, and
//! [`livegesture::generate::generate_wav`] / [`livegesture::generate::generate_pcm`] are the
//! whole-input path of `livegesture generate`, so `Model.generate` equals the CLI bit for bit.
//!
//! Every computation runs with the GIL released ([`Python::detach`]) and inside
//! [`std::panic::catch_unwind`]: a panic becomes a `RuntimeError`, never a crash or a
//! `PanicException`. Errors carry the CLI's message; their Python type follows
//! [`livegesture::generate::classify`]: `FileNotFoundError` / `OSError` for files, `ValueError` for
//! bad input, `RuntimeError` otherwise.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};

use numpy::{PyArray1, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use livegesture::backend::{BackendKind, BackendOptions};
use livegesture::face::{ARKIT_DIM, ARKIT_NAMES, VISEME_DIM, VISEME_NAMES};
use livegesture::generate::{self, ErrorKind, PcmStream};
use livegesture::model::GraphForm;
use livegesture::model::{MotionModel, StreamOptions};
use livegesture::output::{Frame, EXPR_DIM, POSE_DIM, TRANS_DIM};

/// The Python exception for a library error, with the CLI's message (`{e:#}`: context, then causes).
fn to_py(e: anyhow::Error) -> PyErr {
    let msg = format!("{e:#}");
    match generate::classify(&e) {
        ErrorKind::NotFound => PyFileNotFoundError::new_err(msg),
        ErrorKind::Io => PyOSError::new_err(msg),
        ErrorKind::Input => PyValueError::new_err(msg),
        ErrorKind::Runtime => PyRuntimeError::new_err(msg),
    }
}

/// Runs `f` with the GIL released; a panic inside becomes a `RuntimeError`.
fn compute<T: Send>(
    py: Python<'_>,
    what: &str,
    f: impl FnOnce() -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    py.detach(|| match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r.map_err(to_py),
        Err(p) => Err(PyRuntimeError::new_err(generate::panic_message(
            what,
            p.as_ref(),
        ))),
    })
}

/// Frames as the result dict: `poses` (n, 165) float32, `trans` (n, 3), `expressions` (n, 100),
/// `index` (n,) int64; with `face` (a bundle with the face channel) `arkit` (n, 52) and `visemes`
/// (n, 15) float32, else both None.
fn frames_dict<'py>(py: Python<'py>, frames: &[Frame], face: bool) -> PyResult<Bound<'py, PyDict>> {
    let n = frames.len();
    let mut poses = Vec::with_capacity(n * POSE_DIM);
    let mut trans = Vec::with_capacity(n * TRANS_DIM);
    let mut expressions = Vec::with_capacity(n * EXPR_DIM);
    let mut index = Vec::with_capacity(n);
    for f in frames {
        poses.extend_from_slice(&f.poses);
        trans.extend_from_slice(&f.trans);
        expressions.extend_from_slice(&f.expressions);
        index.push(f.index as i64);
    }
    let d = PyDict::new(py);
    d.set_item(
        "poses",
        PyArray1::from_vec(py, poses).reshape([n, POSE_DIM])?,
    )?;
    d.set_item(
        "trans",
        PyArray1::from_vec(py, trans).reshape([n, TRANS_DIM])?,
    )?;
    d.set_item(
        "expressions",
        PyArray1::from_vec(py, expressions).reshape([n, EXPR_DIM])?,
    )?;
    d.set_item("index", PyArray1::from_vec(py, index))?;
    if face {
        let mut arkit = Vec::with_capacity(n * ARKIT_DIM);
        let mut visemes = Vec::with_capacity(n * VISEME_DIM);
        for f in frames {
            let v = f.face.as_ref().ok_or_else(|| {
                PyRuntimeError::new_err(format!("frame {} has no face values", f.index))
            })?;
            arkit.extend_from_slice(&v.arkit);
            visemes.extend_from_slice(&v.visemes);
        }
        d.set_item(
            "arkit",
            PyArray1::from_vec(py, arkit).reshape([n, ARKIT_DIM])?,
        )?;
        d.set_item(
            "visemes",
            PyArray1::from_vec(py, visemes).reshape([n, VISEME_DIM])?,
        )?;
    } else {
        d.set_item("arkit", py.None())?;
        d.set_item("visemes", py.None())?;
    }
    Ok(d)
}

/// Mono samples of a 1-D numpy array: float32 as is, int16 as `x / 32768` (as the WAV reader),
/// float64 cast to float32. Copied, so the computation can run without the GIL.
fn samples_of(pcm: &Bound<'_, PyAny>) -> PyResult<Vec<f32>> {
    let Ok(arr) = pcm.cast::<PyUntypedArray>() else {
        return Err(PyTypeError::new_err(format!(
            "pcm: expected a 1-D numpy array of float32 or int16 samples, got {}",
            pcm.get_type().name()?
        )));
    };
    if arr.ndim() != 1 {
        return Err(PyValueError::new_err(format!(
            "pcm: expected a 1-D (mono) array, got {} dimensions with shape {:?}; mix the channels first, e.g. x.mean(axis=1)",
            arr.ndim(),
            arr.shape()
        )));
    }
    let py = pcm.py();
    let dt = arr.dtype();
    if dt.is_equiv_to(&numpy::dtype::<f32>(py)) {
        let a = pcm.cast::<PyArray1<f32>>()?.readonly();
        return Ok(a.as_array().iter().copied().collect());
    }
    if dt.is_equiv_to(&numpy::dtype::<i16>(py)) {
        let a = pcm.cast::<PyArray1<i16>>()?.readonly();
        let v: Vec<i16> = a.as_array().iter().copied().collect();
        return Ok(generate::i16_to_f32(&v));
    }
    if dt.is_equiv_to(&numpy::dtype::<f64>(py)) {
        let a = pcm.cast::<PyArray1<f64>>()?.readonly();
        return Ok(a.as_array().iter().map(|&x| x as f32).collect());
    }
    Err(PyValueError::new_err(format!(
        "pcm: dtype {} is not supported; expected float32 in [-1, 1] or int16 (float64 is cast to float32)",
        dt.str()?
    )))
}

/// Stream options from the keyword arguments (None = the bundle's default).
#[allow(clippy::too_many_arguments)]
fn options(
    seed: u64,
    guidance: Option<f64>,
    temperature: Option<f64>,
    top_k: Option<usize>,
    ddim_steps: Option<usize>,
    jumps: Option<usize>,
    window: Option<usize>,
    overlap: Option<usize>,
    blend_steps: Option<usize>,
    speaker: Option<usize>,
) -> StreamOptions {
    StreamOptions {
        seed,
        guidance,
        temperature,
        top_k,
        record_logits: false,
        ddim_steps,
        jumps,
        window,
        overlap,
        blend_steps,
        speaker,
    }
}

/// The bundle of `Model()` without a path (docs/python.md#the-default-bundle): `$LIVEGESTURE_BUNDLE`,
/// else the `models/default` of the checkout the module was built from. Unlike the CLI's
/// [`livegesture::bundle::default_bundle_dir`], no bundle beside the executable: that is the Python
/// interpreter here.
fn default_bundle() -> PathBuf {
    match std::env::var_os(livegesture::bundle::BUNDLE_ENV).filter(|v| !v.is_empty()) {
        Some(v) => PathBuf::from(v),
        None => livegesture::bundle::repo_default_bundle(),
    }
}

/// A loaded and verified model bundle on one backend; thread-safe, makes any number of streams.
///
/// path: the bundle folder (None: $LIVEGESTURE_BUNDLE, else the models/default of the checkout the
/// module was built from). backend: "tract" (pure Rust, CPU) or "ort" (ONNX Runtime from ort_lib,
/// $ORT_DYLIB_PATH or an installed onnxruntime package; ep its execution provider, threads its
/// intra-op threads). form: a LiveGesture bundle's graph form (auto, canonical, fused, attention).
/// Raises FileNotFoundError / ValueError with the CLI's message for a missing or broken bundle.
#[pyclass(module = "livegesture_runtime", frozen)]
struct Model {
    inner: Arc<dyn MotionModel>,
    path: PathBuf,
}

#[pymethods]
impl Model {
    #[new]
    #[pyo3(signature = (path=None, backend="tract", *, ep="cpu", threads=1, ort_lib=None, form="auto"))]
    fn new(
        py: Python<'_>,
        path: Option<PathBuf>,
        backend: &str,
        ep: &str,
        threads: usize,
        ort_lib: Option<PathBuf>,
        form: &str,
    ) -> PyResult<Self> {
        let kind: BackendKind = backend.parse().map_err(PyValueError::new_err)?;
        let form: GraphForm = form.parse().map_err(PyValueError::new_err)?;
        if kind == BackendKind::Tract && !ep.eq_ignore_ascii_case("cpu") {
            return Err(PyValueError::new_err(format!(
                "ep={ep} needs backend=\"ort\" (tract runs on the CPU only)"
            )));
        }
        let opts = BackendOptions {
            kind,
            execution_provider: ep.to_string(),
            intra_threads: threads.max(1),
            ort_library: ort_lib,
        };
        let dir = path.unwrap_or_else(default_bundle);
        let model = compute(py, "loading the model", || {
            generate::open_model(Some(&dir), &opts, form)
        })?;
        Ok(Self {
            inner: Arc::from(model),
            path: dir,
        })
    }

    /// The bundle folder.
    #[getter]
    fn path(&self) -> String {
        self.path.display().to_string()
    }

    /// The bundle's family: "livegesture" or "diffsheg".
    #[getter]
    fn family(&self) -> String {
        self.inner.family().to_string()
    }

    /// The backend the graphs run on: "tract" or "ort".
    #[getter]
    fn backend(&self) -> String {
        self.inner.backend_name().to_string()
    }

    /// Output frames per second (30).
    #[getter]
    fn fps(&self) -> u64 {
        self.inner.fps()
    }

    /// Whether results carry the face channel (`arkit`, `visemes`; docs/face.md): a bundle with a
    /// face graph. Without one, results have `arkit` and `visemes` None.
    #[getter]
    fn has_face(&self) -> bool {
        self.inner.has_face()
    }

    /// A new stream (cold start) with these options; None takes the bundle's default.
    #[pyo3(signature = (seed=0, guidance=None, *, temperature=None, top_k=None, ddim_steps=None, jumps=None, window=None, overlap=None, blend_steps=None, speaker=None))]
    #[allow(clippy::too_many_arguments)]
    fn stream(
        &self,
        py: Python<'_>,
        seed: u64,
        guidance: Option<f64>,
        temperature: Option<f64>,
        top_k: Option<usize>,
        ddim_steps: Option<usize>,
        jumps: Option<usize>,
        window: Option<usize>,
        overlap: Option<usize>,
        blend_steps: Option<usize>,
        speaker: Option<usize>,
    ) -> PyResult<Stream> {
        let opts = options(
            seed,
            guidance,
            temperature,
            top_k,
            ddim_steps,
            jumps,
            window,
            overlap,
            blend_steps,
            speaker,
        );
        let model = self.inner.as_ref();
        let inner = compute(py, "stream", || generate::new_stream(model, &opts))?;
        Ok(Stream {
            inner: Mutex::new(PcmStream::new(inner, "stream")),
            face: model.has_face(),
        })
    }

    /// Motion for a whole input: a WAV path (str or os.PathLike; sample_rate must be None) or a 1-D
    /// array with its sample_rate. Equals `livegesture generate` with the same bundle, backend and
    /// options, bit for bit.
    #[pyo3(signature = (audio, sample_rate=None, seed=0, guidance=None, *, temperature=None, top_k=None, ddim_steps=None, jumps=None, window=None, overlap=None, blend_steps=None, speaker=None))]
    #[allow(clippy::too_many_arguments)]
    fn generate<'py>(
        &self,
        py: Python<'py>,
        audio: &Bound<'py, PyAny>,
        sample_rate: Option<u32>,
        seed: u64,
        guidance: Option<f64>,
        temperature: Option<f64>,
        top_k: Option<usize>,
        ddim_steps: Option<usize>,
        jumps: Option<usize>,
        window: Option<usize>,
        overlap: Option<usize>,
        blend_steps: Option<usize>,
        speaker: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let opts = options(
            seed,
            guidance,
            temperature,
            top_k,
            ddim_steps,
            jumps,
            window,
            overlap,
            blend_steps,
            speaker,
        );
        let model = self.inner.as_ref();
        let out = if audio.cast::<PyUntypedArray>().is_ok() {
            let Some(rate) = sample_rate else {
                return Err(PyValueError::new_err(
                    "sample_rate is required with an array of samples (the rate of the array, in Hz)",
                ));
            };
            let samples = samples_of(audio)?;
            compute(py, "generate", || {
                generate::generate_pcm(model, &opts, &samples, rate, "audio")
            })?
        } else {
            let path: PathBuf = audio.extract().map_err(|_| {
                PyTypeError::new_err(
                    "audio: expected a WAV file path (str or os.PathLike) or a 1-D numpy array of samples",
                )
            })?;
            if let Some(rate) = sample_rate {
                return Err(PyValueError::new_err(format!(
                    "sample_rate={rate} was given with a WAV file, whose header gives the rate; pass sample_rate only with an array"
                )));
            }
            compute(py, "generate", || {
                generate::generate_wav(model, &opts, &path)
            })?
        };
        frames_dict(py, &out.frames, model.has_face())
    }

    fn __repr__(&self) -> String {
        format!(
            "Model(path={:?}, family={:?}, backend={:?})",
            self.path.display().to_string(),
            self.inner.family().to_string(),
            self.inner.backend_name()
        )
    }
}

/// One stream: all its state. Push audio in chunks of any size; finish at the end of the input.
///
/// A stream may be used from any thread (calls on one stream are serialised); several streams run in
/// parallel, each call releasing the GIL.
#[pyclass(module = "livegesture_runtime", frozen)]
struct Stream {
    inner: Mutex<PcmStream>,
    /// Whether the frames carry the face channel.
    face: bool,
}

impl Stream {
    /// Reads a property of the stream (waiting, without the GIL, for a call on another thread).
    fn read<T: Send>(&self, py: Python<'_>, f: impl FnOnce(&PcmStream) -> T + Send) -> PyResult<T> {
        compute(py, "stream", || Ok(f(&*self.lock()?)))
    }

    /// `push`, with the seconds `PcmStream::push` took.
    fn push_timed<'py>(
        &self,
        py: Python<'py>,
        pcm: &Bound<'py, PyAny>,
        sample_rate: u32,
    ) -> PyResult<(Bound<'py, PyDict>, f64)> {
        let samples = samples_of(pcm)?;
        let (frames, core) = compute(py, "stream.push", || {
            let mut stream = self.lock()?;
            let t0 = std::time::Instant::now();
            let frames = stream.push(&samples, sample_rate)?;
            Ok((frames, t0.elapsed().as_secs_f64()))
        })?;
        Ok((frames_dict(py, &frames, self.face)?, core))
    }

    /// The stream, or an error if an earlier call panicked (then only reset() recovers it).
    fn lock(&self) -> anyhow::Result<MutexGuard<'_, PcmStream>> {
        self.inner.lock().map_err(|_| {
            anyhow::anyhow!(
                "stream: an earlier call failed with an internal error; reset() the stream to use it again"
            )
        })
    }
}

#[pymethods]
impl Stream {
    /// Pushes mono samples (1-D float32 in [-1, 1] or int16) at sample_rate Hz; returns the frames
    /// they complete. The first push fixes the stream's rate.
    #[pyo3(signature = (pcm, sample_rate=16000))]
    fn push<'py>(
        &self,
        py: Python<'py>,
        pcm: &Bound<'py, PyAny>,
        sample_rate: u32,
    ) -> PyResult<Bound<'py, PyDict>> {
        Ok(self.push_timed(py, pcm, sample_rate)?.0)
    }

    /// Benchmark hook (bindings/python/bench_overhead.py): `push`, and the seconds its Rust core
    /// (`PcmStream::push`) took inside it, so that the binding's own cost per call is measured on the
    /// same call.
    #[pyo3(signature = (pcm, sample_rate=16000))]
    fn _push_timed<'py>(
        &self,
        py: Python<'py>,
        pcm: &Bound<'py, PyAny>,
        sample_rate: u32,
    ) -> PyResult<(Bound<'py, PyDict>, f64)> {
        self.push_timed(py, pcm, sample_rate)
    }

    /// Ends the input: the remaining frames, so that the stream's frames cover everything pushed
    /// (ceil(n * 30 / rate) frames in all).
    fn finish<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let frames = compute(py, "stream.finish", || self.lock()?.finish())?;
        frames_dict(py, &frames, self.face)
    }

    /// Back to a cold start with the same options and seed (also after an error or finish()).
    fn reset(&self, py: Python<'_>) -> PyResult<()> {
        compute(py, "stream.reset", || {
            let mut g = match self.inner.lock() {
                Ok(g) => g,
                Err(poisoned) => {
                    self.inner.clear_poison();
                    poisoned.into_inner()
                }
            };
            g.reset()
        })
    }

    /// Frames emitted so far.
    #[getter]
    fn frames_emitted(&self, py: Python<'_>) -> PyResult<u64> {
        self.read(py, |s| s.stream().frames_emitted())
    }

    /// The sample rate fixed by the first push (None before it).
    #[getter]
    fn sample_rate(&self, py: Python<'_>) -> PyResult<Option<u32>> {
        self.read(py, PcmStream::sample_rate)
    }

    /// The classifier-free guidance scale in use.
    #[getter]
    fn guidance(&self, py: Python<'_>) -> PyResult<f64> {
        self.read(py, |s| s.stream().guidance())
    }

    /// Frames emitted together (4 for LiveGesture's tokens; a window step for DiffSHEG).
    #[getter]
    fn frames_per_unit(&self, py: Python<'_>) -> PyResult<u64> {
        self.read(py, |s| s.stream().frames_per_unit())
    }

    /// How far past a unit, in frames, the audio must reach before it is emitted (0 for LiveGesture).
    #[getter]
    fn lookahead_frames(&self, py: Python<'_>) -> PyResult<u64> {
        self.read(py, |s| s.stream().lookahead_frames())
    }
}

/// Benchmark hook (bindings/python/bench_overhead.py): pushes 16 kHz `pcm` in chunks of `chunk`
/// samples through a new stream of `model` with `MotionStream::push_audio`, all in Rust, and returns
/// the seconds the pushes took and the frames they made: the Rust core's cost of the loop that
/// `Stream.push` runs from Python.
#[pyfunction]
fn _bench_push_audio(
    py: Python<'_>,
    model: &Model,
    pcm: &Bound<'_, PyAny>,
    chunk: usize,
    seed: u64,
) -> PyResult<(f64, usize)> {
    let samples = samples_of(pcm)?;
    let opts = StreamOptions {
        seed,
        ..Default::default()
    };
    let m = model.inner.as_ref();
    compute(py, "_bench_push_audio", || {
        let mut stream = generate::new_stream(m, &opts)?;
        let t0 = std::time::Instant::now();
        let mut frames = 0;
        for c in samples.chunks(chunk.max(1)) {
            frames += stream.push_audio(c)?.len();
        }
        Ok((t0.elapsed().as_secs_f64(), frames))
    })
}

/// Test hook (bindings/tests/test_python.py): panics inside a computation, as a bug in the runtime
/// would; with a stream, while that stream's call holds its state. Shows that a panic becomes a
/// `RuntimeError` and that the stream refuses work until `reset()`.
#[pyfunction]
#[pyo3(signature = (stream=None))]
fn _panic_for_test(py: Python<'_>, stream: Option<&Stream>) -> PyResult<()> {
    compute(py, "_panic_for_test", || match stream {
        Some(s) => {
            let _guard = s.lock()?;
            panic!("a deliberate panic inside a stream call")
        }
        None => panic!("a deliberate panic"),
    })
}

/// The LiveGesture runtime: speech audio in, SMPL-X motion frames out (docs/python.md).
#[pymodule]
fn livegesture_runtime(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Model>()?;
    m.add_class::<Stream>()?;
    m.add_function(wrap_pyfunction!(_bench_push_audio, m)?)?;
    m.add_function(wrap_pyfunction!(_panic_for_test, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("FPS", livegesture::output::FPS)?;
    m.add("POSE_DIM", POSE_DIM)?;
    m.add("TRANS_DIM", TRANS_DIM)?;
    m.add("EXPR_DIM", EXPR_DIM)?;
    m.add("ARKIT_DIM", ARKIT_DIM)?;
    m.add("VISEME_DIM", VISEME_DIM)?;
    m.add("ARKIT_NAMES", ARKIT_NAMES.to_vec())?;
    m.add("VISEME_NAMES", VISEME_NAMES.to_vec())?;
    Ok(())
}

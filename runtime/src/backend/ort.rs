//! The ONNX Runtime backend (`ort` 2.0.0-rc.15, loaded dynamically).
//!
//! Nothing is downloaded or linked at build time. The shared library is found at run time, in order:
//!
//! 1. an explicit path ([`BackendOptions::ort_library`], the CLI's `--ort-lib`);
//! 2. the environment variable `ORT_DYLIB_PATH` (`scripts/env.sh` sets it);
//! 3. a library installed beside the executable (the release archives, docs/install.md):
//!    `<exe dir>/../lib/libonnxruntime.so*` or `<exe dir>/libonnxruntime.so*`;
//! 4. the `onnxruntime` Python package of the project's virtual environment (`$LIVEGESTURE_VENV`,
//!    `$VIRTUAL_ENV`, `~/.cache/livegesture/venv-*`), then of common system and user
//!    `site-packages` / `dist-packages` folders: `onnxruntime/capi/libonnxruntime.so*`.
//!
//! One ONNX Runtime environment exists per process; the first backend created fixes the library.
//!
//! Execution providers: `cpu` (the default) needs nothing. `cuda`, `openvino`, `xnnpack`, `qnn` and
//! `webgpu` are ort's typed providers (`ort::ep`), registered on each session with
//! `error_on_failure` when the loaded library was built with them; otherwise the backend refuses to
//! start, naming the library and the providers it does have. Sessions use one intra-op thread unless
//! told otherwise (the step graphs are small; parallelism comes from running streams side by side).
//!
//! Runs use ONNX Runtime's C `Run` directly ([`OrtGraph`]) rather than ort's `Session::run`: it is
//! the one call that takes **preallocated outputs that borrow the caller's buffers**, so a step
//! writes its new caches straight into last step's cache buffers (zero copies, zero allocations in
//! a steady stream batch). ort's `OutputSelector::preallocate` only accepts values that own their
//! data, which would cost a copy per output per step.

use std::ffi::{c_char, c_int, CStr, CString};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::{anyhow, bail, ensure, Context, Result};
use ort::environment::Environment;
use ort::ep::{self, ExecutionProvider, ExecutionProviderDispatch};
use ort::session::builder::GraphOptimizationLevel;
use ort::session::Session;
use ort::value::{DynValueRef, DynValueRefMut, TensorRef, TensorRefMut};
use ort::AsPointer;

use super::pool::Pool;
use super::{
    check_inputs, check_outputs, Backend, BackendOptions, DType, GraphRunner, Tensor, TensorData,
};
use crate::bundle::{concrete_shape, has_named_axis, GraphSpec};

/// Environment variable naming the ONNX Runtime shared library.
pub const ORT_DYLIB_ENV: &str = "ORT_DYLIB_PATH";

struct OrtEnv {
    env: Environment,
    library: PathBuf,
}

static ENV: OnceLock<std::result::Result<OrtEnv, String>> = OnceLock::new();

fn lib_name_matches(name: &str) -> bool {
    (name.starts_with("libonnxruntime.so")
        || (name.starts_with("libonnxruntime.") && name.ends_with(".dylib")))
        || name.eq_ignore_ascii_case("onnxruntime.dll")
}

/// Looks for the ONNX Runtime library inside `site` (a `site-packages` folder).
fn in_site_packages(site: &Path) -> Option<PathBuf> {
    let capi = site.join("onnxruntime").join("capi");
    let mut found: Vec<PathBuf> = std::fs::read_dir(&capi)
        .ok()?
        .filter_map(|e| e.ok())
        .filter(|e| lib_name_matches(&e.file_name().to_string_lossy()))
        .map(|e| e.path())
        .collect();
    found.sort();
    // the most specific name (libonnxruntime.so.1.31.1 over libonnxruntime.so)
    found.into_iter().max_by_key(|p| p.as_os_str().len())
}

/// `site-packages` folders of a Python prefix (`<prefix>/lib/python3*/site-packages`, `dist-packages`).
fn site_dirs(prefix: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for lib in ["lib", "lib64"] {
        let Ok(rd) = std::fs::read_dir(prefix.join(lib)) else {
            continue;
        };
        let mut pys: Vec<PathBuf> = rd
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with("python3"))
            .map(|e| e.path())
            .collect();
        pys.sort();
        for py in pys {
            out.push(py.join("site-packages"));
            out.push(py.join("dist-packages"));
        }
    }
    out.push(prefix.join("Lib").join("site-packages")); // Windows venv layout
    out
}

/// `libonnxruntime.so*` in `<exe dir>/../lib` or `<exe dir>` (how the release archives ship it).
fn beside_executable() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    // through symlinks (a link in /usr/local/bin to an unpacked archive); not on Windows, whose canonical
    // form (`\\?\C:\...`) takes neither `..` nor `/` in the paths joined to it
    #[cfg(not(windows))]
    let exe = exe.canonicalize().ok()?;
    let dir = exe.parent()?;
    [dir.join("../lib"), dir.to_path_buf()]
        .into_iter()
        .find_map(|d| {
            let mut libs: Vec<PathBuf> = std::fs::read_dir(&d)
                .ok()?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    p.file_name()
                        .and_then(|n| n.to_str())
                        .is_some_and(|n| n.starts_with("libonnxruntime.so"))
                })
                .collect();
            libs.sort();
            libs.pop()
        })
}

/// Finds the ONNX Runtime shared library (see the module docs for the search order).
pub fn find_library(explicit: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = explicit {
        ensure!(
            p.is_file(),
            "ort: ONNX Runtime library {} does not exist",
            p.display()
        );
        return Ok(p.to_path_buf());
    }
    if let Some(v) = std::env::var_os(ORT_DYLIB_ENV).filter(|v| !v.is_empty()) {
        let p = PathBuf::from(v);
        ensure!(
            p.is_file(),
            "ort: {ORT_DYLIB_ENV}={} does not exist; point it at libonnxruntime.so (e.g. `source scripts/env.sh`)",
            p.display()
        );
        return Ok(p);
    }
    if let Some(p) = beside_executable() {
        return Ok(p);
    }
    let mut prefixes: Vec<PathBuf> = Vec::new();
    for var in ["LIVEGESTURE_VENV", "VIRTUAL_ENV", "CONDA_PREFIX"] {
        if let Some(v) = std::env::var_os(var).filter(|v| !v.is_empty()) {
            prefixes.push(PathBuf::from(v));
        }
    }
    let home = std::env::var_os("HOME").map(PathBuf::from);
    if let Some(h) = &home {
        if let Ok(rd) = std::fs::read_dir(h.join(".cache").join("livegesture")) {
            let mut venvs: Vec<PathBuf> = rd
                .filter_map(|e| e.ok())
                .filter(|e| e.file_name().to_string_lossy().starts_with("venv"))
                .map(|e| e.path())
                .collect();
            venvs.sort();
            prefixes.extend(venvs);
        }
        prefixes.push(h.join(".local"));
    }
    prefixes.push(PathBuf::from("/usr/local"));
    prefixes.push(PathBuf::from("/usr"));
    for prefix in &prefixes {
        for site in site_dirs(prefix) {
            if let Some(p) = in_site_packages(&site) {
                return Ok(p);
            }
        }
    }
    bail!(
        "ort: ONNX Runtime library not found: set {ORT_DYLIB_ENV} to libonnxruntime.so (`source scripts/env.sh` does), \
         or install the onnxruntime Python package (searched $LIVEGESTURE_VENV, $VIRTUAL_ENV, ~/.cache/livegesture/venv-*, \
         ~/.local, /usr/local, /usr); or use --backend tract"
    )
}

fn environment(explicit: Option<&Path>) -> Result<&'static OrtEnv> {
    let r = ENV.get_or_init(|| {
        let library = find_library(explicit).map_err(|e| format!("{e:#}"))?;
        let builder = ort::init_from(&library).map_err(|e| {
            format!(
                "ort: cannot load ONNX Runtime from {}: {e}",
                library.display()
            )
        })?;
        let env = builder
            .with_name("livegesture")
            .with_telemetry(false)
            .build()
            .map_err(|e| {
                format!(
                    "ort: cannot create the ONNX Runtime environment ({}): {e}",
                    library.display()
                )
            })?;
        Ok(OrtEnv { env, library })
    });
    let env = r.as_ref().map_err(|e| anyhow!("{e}"))?;
    if let Some(p) = explicit {
        ensure!(
            same_file(p, &env.library),
            "ort: ONNX Runtime is already loaded from {} in this process; cannot switch to {}",
            env.library.display(),
            p.display()
        );
    }
    Ok(env)
}

/// The ONNX Runtime this process loaded: its version as the library itself reports it
/// (`OrtGetApiBase()->GetVersionString()`) and its path; `None` before an ort backend was created
/// (or when it could not start).
pub fn loaded_runtime() -> Option<(String, PathBuf)> {
    let env = ENV.get()?.as_ref().ok()?;
    let path = CString::new(env.library.as_os_str().as_encoded_bytes()).ok()?;
    // SAFETY: RTLD_NOLOAD only returns a handle to the library already loaded by `ort::init_from`
    // (no constructor runs again); OrtGetApiBase and GetVersionString are the C API's stable entry
    // points, the string is static in the library, which stays loaded for the whole process.
    unsafe {
        let handle = libc::dlopen(path.as_ptr(), libc::RTLD_NOW | libc::RTLD_NOLOAD);
        if handle.is_null() {
            return None;
        }
        let sym = libc::dlsym(handle, c"OrtGetApiBase".as_ptr());
        let version = if sym.is_null() {
            None
        } else {
            let get: unsafe extern "system" fn() -> *const ort::sys::OrtApiBase =
                std::mem::transmute(sym);
            let base = get();
            if base.is_null() {
                None
            } else {
                let v = ((*base).GetVersionString)();
                (!v.is_null()).then(|| CStr::from_ptr(v).to_string_lossy().into_owned())
            }
        };
        libc::dlclose(handle);
        version.map(|v| (v, env.library.clone()))
    }
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

/// Converts a C API status into a result (releasing the status).
fn check_status(status: ort::sys::OrtStatusPtr, what: &str) -> Result<()> {
    if status.0.is_null() {
        return Ok(());
    }
    let api = ort::api();
    // SAFETY: a non-null status from the C API; its message is a NUL-terminated string owned by the
    // status, copied before the status is released.
    let msg = unsafe {
        let p = (api.GetErrorMessage)(status.0);
        let m = if p.is_null() {
            "unknown error".to_string()
        } else {
            CStr::from_ptr(p).to_string_lossy().into_owned()
        };
        (api.ReleaseStatus)(status.0);
        m
    };
    bail!("ort: {what}: {msg}")
}

/// Execution providers compiled into the loaded library (`CPUExecutionProvider`, ...), for error
/// messages (ort checks one provider at a time, `ExecutionProvider::is_available`, but does not list
/// them, so this one call goes through the C API).
pub fn available_providers() -> Result<Vec<String>> {
    let api = ort::api();
    let mut ptr: *mut *mut c_char = std::ptr::null_mut();
    let mut n: c_int = 0;
    // SAFETY: standard C API out-parameters; the list is released below.
    check_status(
        unsafe { (api.GetAvailableProviders)(&mut ptr, &mut n) },
        "listing execution providers",
    )?;
    let mut out = Vec::new();
    if !ptr.is_null() {
        for i in 0..n.max(0) as usize {
            // SAFETY: `ptr` holds `n` NUL-terminated strings.
            let s = unsafe { CStr::from_ptr(*ptr.add(i)) };
            out.push(s.to_string_lossy().into_owned());
        }
        // SAFETY: releasing the list returned above.
        check_status(
            unsafe { (api.ReleaseAvailableProviders)(ptr, n) },
            "releasing the provider list",
        )?;
    }
    Ok(out)
}

/// An execution provider the backend can append: the `--ep` name, ONNX Runtime's provider name, and
/// ort's typed provider (registered with `error_on_failure`, so a provider that cannot start fails
/// the session instead of silently falling back to the CPU).
struct Provider {
    name: &'static str,
    ort_name: &'static str,
    dispatch: fn() -> ExecutionProviderDispatch,
}

const PROVIDERS: &[Provider] = &[
    Provider {
        name: "cuda",
        ort_name: <ep::CUDA as ExecutionProvider>::NAME,
        dispatch: || ep::CUDA::default().build(),
    },
    Provider {
        name: "openvino",
        ort_name: <ep::OpenVINO as ExecutionProvider>::NAME,
        dispatch: || ep::OpenVINO::default().build(),
    },
    Provider {
        name: "xnnpack",
        ort_name: <ep::XNNPACK as ExecutionProvider>::NAME,
        dispatch: || ep::XNNPACK::default().build(),
    },
    Provider {
        name: "qnn",
        ort_name: <ep::QNN as ExecutionProvider>::NAME,
        dispatch: || ep::QNN::default().build(),
    },
    Provider {
        name: "webgpu",
        ort_name: <ep::WebGPU as ExecutionProvider>::NAME,
        dispatch: || ep::WebGPU::default().build(),
    },
];

/// The ONNX Runtime backend.
pub struct OrtBackend {
    ep: String,
    /// The typed provider for `ep` (`None` for the CPU).
    provider: Option<&'static Provider>,
    intra_threads: usize,
    env: &'static OrtEnv,
}

impl std::fmt::Debug for OrtBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OrtBackend")
            .field("library", &self.env.library)
            .field("ep", &self.ep)
            .finish()
    }
}

impl OrtBackend {
    /// Loads ONNX Runtime (once per process) and checks the execution provider is available.
    pub fn new(opts: &BackendOptions) -> Result<Self> {
        let env = environment(opts.ort_library.as_deref())?;
        let ep = opts.execution_provider.to_ascii_lowercase();
        let mut provider = None;
        if ep != "cpu" {
            let Some(p) = PROVIDERS.iter().find(|p| p.name == ep) else {
                let names: Vec<&str> = std::iter::once("cpu")
                    .chain(PROVIDERS.iter().map(|p| p.name))
                    .collect();
                bail!(
                    "ort: unknown execution provider '{ep}'; expected one of {}",
                    names.join(", ")
                );
            };
            let have = available_providers()?;
            ensure!(
                have.iter().any(|h| h == p.ort_name),
                "ort: execution provider '{ep}' ({}) is not available in {} (it has: {}); \
                 use a build of ONNX Runtime with it (e.g. the onnxruntime-gpu package for cuda) or --ep cpu",
                p.ort_name,
                env.library.display(),
                have.join(", ")
            );
            provider = Some(p);
        }
        Ok(Self {
            ep,
            provider,
            intra_threads: opts.intra_threads.max(1),
            env,
        })
    }

    /// The library in use.
    pub fn library(&self) -> &Path {
        &self.env.library
    }
}

impl Backend for OrtBackend {
    fn name(&self) -> &str {
        "ort"
    }

    fn describe(&self) -> String {
        format!(
            "ort (ONNX Runtime from {}, execution provider {}, {} intra-op thread(s))",
            self.env.library.display(),
            self.ep,
            self.intra_threads
        )
    }

    fn load(&self, spec: &GraphSpec, path: &Path) -> Result<Box<dyn GraphRunner>> {
        let maker = SessionMaker {
            env: self.env,
            provider: self.provider,
            intra_threads: self.intra_threads,
            path: path.to_path_buf(),
        };
        let session = maker.make(spec)?;
        let names: Vec<&str> = session.inputs().iter().map(|o| o.name()).collect();
        ensure!(
            names == spec.input_names(),
            "ort: graph '{}' has inputs {names:?}, the manifest lists {:?}",
            spec.name,
            spec.input_names()
        );
        Ok(Box::new(OrtGraph::new(spec, session, maker)?))
    }
}

/// How a graph's sessions are made (the first at load time, more when threads run it at once).
#[derive(Clone)]
struct SessionMaker {
    env: &'static OrtEnv,
    provider: Option<&'static Provider>,
    intra_threads: usize,
    path: PathBuf,
}

impl SessionMaker {
    fn make(&self, spec: &GraphSpec) -> Result<Session> {
        let path = &self.path;
        let what = || format!("ort: loading graph '{}' from {}", spec.name, path.display());
        let e = |err: ort::Error<ort::session::builder::SessionBuilder>| anyhow!("{err}");
        let mut builder = Session::builder(&self.env.env)
            .map_err(|err| anyhow!("{err}"))
            .with_context(what)?
            .with_optimization_level(GraphOptimizationLevel::All)
            .map_err(e)
            .with_context(what)?
            .with_intra_threads(self.intra_threads)
            .map_err(e)
            .with_context(what)?
            .with_inter_threads(1)
            .map_err(e)
            .with_context(what)?
            // subnormals flushed on pool threads too (the calling thread: `flush_denormals` in run)
            .with_flush_to_zero()
            .map_err(e)
            .with_context(what)?;
        if let Some(p) = self.provider {
            builder = builder
                .with_execution_providers([(p.dispatch)().error_on_failure()])
                .map_err(e)
                .with_context(what)?;
        }
        builder
            .commit_from_file(path)
            .map_err(|err| anyhow!("{err}"))
            .with_context(what)
    }
}

/// How many sessions a graph may have: one per run that can make progress at the same time, i.e.
/// the cores this process may use ([`std::thread::available_parallelism`]) divided by the intra-op
/// threads of each run (at least one). Sessions are made only when runs overlap, so a process that
/// steps one stream at a time keeps one session per graph.
pub fn sessions_cap(intra_threads: usize) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    (cores / intra_threads.max(1)).max(1)
}

/// A graph loaded into an ONNX Runtime session.
///
/// Runs go through the C API's `Run` with **preallocated outputs**: every output is an `OrtValue`
/// over the buffer of the caller's [`Tensor`] (reused when large enough), so ONNX Runtime writes the
/// results straight into it, with no output allocation by the session and no copy out of it. This
/// is the mechanism of ort's `OutputSelector::preallocate`, which only accepts values that own their
/// data. Inputs are borrowed the same way (`TensorRef`, no copy).
///
/// A session runs one call at a time (ort's `Session::run` takes `&mut self`: its authors hold
/// ONNX Runtime's concurrent `Run` on one session unsafe), so the graph keeps a small pool of
/// sessions: a run takes an idle one, or makes one while fewer than [`sessions_cap`] exist, or
/// waits. Each session holds its own copy of the graph's weights and kernels' prepacked buffers:
/// the memory of a loaded model grows by one copy per extra thread that ever stepped at the same
/// moment (docs/python.md gives the measured figure).
pub struct OrtGraph {
    spec: GraphSpec,
    input_names: Vec<CString>,
    output_names: Vec<CString>,
    sessions: Pool<Session>,
    maker: SessionMaker,
}

impl OrtGraph {
    fn new(spec: &GraphSpec, session: Session, maker: SessionMaker) -> Result<Self> {
        let c = |names: Vec<&str>| -> Result<Vec<CString>> {
            names
                .into_iter()
                .map(|n| {
                    CString::new(n).with_context(|| format!("graph '{}': name {n:?}", spec.name))
                })
                .collect()
        };
        Ok(OrtGraph {
            spec: spec.clone(),
            input_names: c(spec.input_names())?,
            output_names: c(spec.output_names())?,
            sessions: Pool::with_first(session, sessions_cap(maker.intra_threads)),
            maker,
        })
    }

    /// Sessions made so far (idle or running).
    pub fn sessions(&self) -> usize {
        self.sessions.live()
    }
}

impl OrtGraph {
    /// Runs with outputs allocated by ONNX Runtime (ort's safe `Session::run`) and copies them into
    /// `outputs`: the path for graphs whose output sizes are not known before the run.
    fn run_allocated(
        &self,
        values: Vec<DynValueRef<'_>>,
        outputs: &mut Vec<Tensor>,
        batch: usize,
    ) -> Result<()> {
        let name = self.spec.name.clone();
        let input_names = self.spec.input_names();
        let named: Vec<(&str, DynValueRef<'_>)> = input_names.into_iter().zip(values).collect();
        let specs: Vec<(String, DType)> = self
            .spec
            .all_outputs()
            .into_iter()
            .map(|(n, d, _)| (n.to_string(), d))
            .collect();
        self.sessions.with(
            || self.maker.make(&self.spec),
            |session| {
                let result = super::flush_denormals(|| session.run(named));
                let got = result.map_err(|err| anyhow!("ort: running graph '{name}': {err}"))?;
                copy_outputs(&name, &specs, &got, outputs)
            },
        )?;
        check_outputs(&self.spec, outputs, batch)
            .with_context(|| format!("ort: graph '{name}'"))?;
        Ok(())
    }
}

/// Copies the outputs `specs` of a run (allocated by ONNX Runtime) into `outputs`.
fn copy_outputs(
    name: &str,
    specs: &[(String, DType)],
    got: &ort::session::SessionOutputs<'_>,
    outputs: &mut Vec<Tensor>,
) -> Result<()> {
    {
        outputs.clear();
        for (out_name, dtype) in specs {
            let v = got
                .get(out_name.as_str())
                .with_context(|| format!("ort: graph '{name}' returned no output '{out_name}'"))?;
            let t = match dtype {
                DType::F32 => {
                    let (shape, data) = v.try_extract_tensor::<f32>().map_err(|err| {
                        anyhow!("ort: graph '{name}', output '{out_name}': {err}")
                    })?;
                    Tensor::f32(shape.iter().map(|&d| d as usize).collect(), data.to_vec())?
                }
                DType::I64 => {
                    let (shape, data) = v.try_extract_tensor::<i64>().map_err(|err| {
                        anyhow!("ort: graph '{name}', output '{out_name}': {err}")
                    })?;
                    Tensor::i64(shape.iter().map(|&d| d as usize).collect(), data.to_vec())?
                }
            };
            outputs.push(t);
        }
        Ok(())
    }
}

impl GraphRunner for OrtGraph {
    fn spec(&self) -> &GraphSpec {
        &self.spec
    }

    fn run(&self, inputs: &[Tensor]) -> Result<Vec<Tensor>> {
        let mut out = Vec::new();
        self.run_into(inputs, &mut out)?;
        Ok(out)
    }

    fn run_into(&self, inputs: &[Tensor], outputs: &mut Vec<Tensor>) -> Result<()> {
        let batch = check_inputs(&self.spec, inputs)?;
        let name = &self.spec.name;
        let mut values: Vec<DynValueRef<'_>> = Vec::with_capacity(inputs.len());
        for t in inputs {
            let v = match &t.data {
                TensorData::F32(d) => {
                    TensorRef::from_array_view((t.shape.as_slice(), d.as_slice()))?.into_dyn()
                }
                TensorData::I64(d) => {
                    TensorRef::from_array_view((t.shape.as_slice(), d.as_slice()))?.into_dyn()
                }
            };
            values.push(v);
        }
        let specs = self.spec.all_outputs();
        // Preallocation needs every output's size. An output with a named axis (DiffSHEG's window
        // length `frames`, which ONNX Runtime derives from the inputs) cannot be sized here: such a
        // graph runs with outputs allocated by ONNX Runtime and copied out (one copy per output).
        if specs.iter().any(|(_, _, s)| has_named_axis(s)) {
            return self.run_allocated(values, outputs, batch);
        }
        outputs.truncate(specs.len());
        outputs.resize_with(specs.len(), Tensor::default);
        for (t, (_, dtype, shape)) in outputs.iter_mut().zip(&specs) {
            t.prepare_output(*dtype, concrete_shape(shape, batch));
        }
        let mut out_values: Vec<DynValueRefMut<'_>> = Vec::with_capacity(outputs.len());
        for t in outputs.iter_mut() {
            let Tensor { shape, data } = t;
            let v = match data {
                TensorData::F32(d) => {
                    TensorRefMut::from_array_view_mut((shape.as_slice(), d.as_mut_slice()))?
                        .into_dyn()
                }
                TensorData::I64(d) => {
                    TensorRefMut::from_array_view_mut((shape.as_slice(), d.as_mut_slice()))?
                        .into_dyn()
                }
            };
            out_values.push(v);
        }
        let in_names: Vec<*const c_char> = self.input_names.iter().map(|n| n.as_ptr()).collect();
        let out_names: Vec<*const c_char> = self.output_names.iter().map(|n| n.as_ptr()).collect();
        let in_ptrs: Vec<*const ort::sys::OrtValue> = values.iter().map(|v| v.ptr()).collect();
        let mut out_ptrs: Vec<*mut ort::sys::OrtValue> =
            out_values.iter().map(|v| v.ptr().cast_mut()).collect();
        ensure!(
            in_ptrs.len() == in_names.len() && out_ptrs.len() == out_names.len(),
            "ort: graph '{name}': {} inputs and {} outputs for {} and {} names",
            in_ptrs.len(),
            out_ptrs.len(),
            in_names.len(),
            out_names.len()
        );
        self.sessions.with(
            || self.maker.make(&self.spec),
            |session| {
                // SAFETY: the session pointer is live and used by this thread only (taken out of
                // the pool for this run, `&mut`); the name arrays hold NUL-terminated strings owned
                // by `self`; every input and output pointer is a live OrtValue over a buffer that
                // outlives the call (`values` borrows `inputs`, `out_values` borrows `outputs`
                // mutably, both dropped after it). Non-null outputs are preallocated: ONNX Runtime
                // writes into them (shape mismatches are reported as errors) and does not replace
                // or release them.
                let status = super::flush_denormals(|| unsafe {
                    (ort::api().Run)(
                        session.ptr_mut(),
                        std::ptr::null(),
                        in_names.as_ptr(),
                        in_ptrs.as_ptr(),
                        in_ptrs.len(),
                        out_names.as_ptr(),
                        out_ptrs.len(),
                        out_ptrs.as_mut_ptr(),
                    )
                });
                check_status(status, &format!("running graph '{name}' (batch {batch})"))
            },
        )?;
        drop(out_values);
        drop(values);
        check_outputs(&self.spec, outputs, batch)
    }
}

//! Inference backends: run one step graph on named `f32` / `i64` tensors with a dynamic batch axis.
//!
//! A [`Backend`] loads a bundle graph ([`GraphSpec`] + ONNX file) into a [`GraphRunner`]. A runner
//! takes its inputs **in the graph's order** ([`GraphSpec::input_names`]: data inputs, then
//! `cache.<name>`) and returns its outputs in the graph's order ([`GraphSpec::output_names`]: data
//! outputs, then `new_cache.<name>`); the bundle loader has already checked that the ONNX file has
//! exactly these names in this order. [`GraphRunner::run_named`] takes the inputs by name instead.
//! Axis 0 of every tensor is the batch; one call may carry any batch size.
//!
//! Two implementations:
//!
//! - [`tract`] (default, pure Rust): one optimised plan per batch size, built on first
//!   use and cached;
//! - [`ort`] (feature `ort`): ONNX Runtime loaded at run time from `ORT_DYLIB_PATH` or an
//!   installed `onnxruntime` Python package, with a selectable execution provider.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use anyhow::{ensure, Result};

use crate::bundle::{shape_fits, shape_string, Bundle, GraphSpec};

#[cfg(feature = "ort")]
pub mod ort;
mod pool;
pub mod tract;

pub use crate::tensor::{DType, Tensor, TensorData};

/// A loaded step graph, ready to run.
///
/// Runs take `&self`: one runner is shared by every stream of a model, and streams on different
/// threads run it at the same time, each run with its own per-run state (tract: a plan state from a
/// pool per plan; ort: a session from a small pool per graph, `ort::OrtGraph`). A run's result
/// depends only on its inputs, never on which pooled state or session ran it.
pub trait GraphRunner: Send + Sync {
    /// The graph's manifest entry.
    fn spec(&self) -> &GraphSpec;

    /// Runs one step. `inputs` are in the graph's input order (data inputs, then caches); the
    /// outputs come back in the graph's output order (data outputs, then new caches).
    fn run(&self, inputs: &[Tensor]) -> Result<Vec<Tensor>>;

    /// Like [`GraphRunner::run`], writing the outputs into `outputs`: it is resized to the graph's
    /// output count and each tensor reshaped for this run, keeping its buffer when it is large
    /// enough, so a caller that passes the same tensors again (e.g. last step's input caches as this
    /// step's output caches) saves allocations. Backends that can write outputs in place (ort) also
    /// save a copy per output; the default runs [`GraphRunner::run`] and replaces `outputs`.
    fn run_into(&self, inputs: &[Tensor], outputs: &mut Vec<Tensor>) -> Result<()> {
        *outputs = self.run(inputs)?;
        Ok(())
    }

    /// Prepares runs of batch sizes `sizes` before the first of them, so that none pays for a
    /// one-time preparation later (a server calls it before its first session). tract builds the
    /// plans of these sizes and one with the batch left symbolic for every other size (no plan is
    /// optimised after this call). Default: nothing to prepare.
    fn prepare_batches(&self, sizes: &[usize]) -> Result<()> {
        let _ = sizes;
        Ok(())
    }

    /// Runs one step with inputs given by name (any order); returns `(name, tensor)` in graph order.
    fn run_named(&self, inputs: &[(&str, &Tensor)]) -> Result<Vec<(String, Tensor)>> {
        let names: Vec<String> = self
            .spec()
            .input_names()
            .iter()
            .map(|s| s.to_string())
            .collect();
        let mut ordered = Vec::with_capacity(names.len());
        for n in &names {
            let t = inputs
                .iter()
                .find(|(k, _)| k == n)
                .map(|(_, t)| (*t).clone())
                .ok_or_else(|| {
                    anyhow::anyhow!("graph '{}': input '{n}' not given", self.spec().name)
                })?;
            ordered.push(t);
        }
        for (k, _) in inputs {
            ensure!(
                names.iter().any(|n| n == k),
                "graph '{}' has no input '{k}' (inputs: {names:?})",
                self.spec().name
            );
        }
        let out = self.run(&ordered)?;
        let onames: Vec<String> = self
            .spec()
            .output_names()
            .iter()
            .map(|s| s.to_string())
            .collect();
        Ok(onames.into_iter().zip(out).collect())
    }
}

/// Runs `f` with subnormal ("denormal") floats flushed to zero on this thread: the x86-64 MXCSR
/// flush-to-zero and denormals-are-zero bits are set for the call and the previous mode is restored
/// after it (also on panic). Both backends run their graphs through this (ONNX Runtime with one
/// intra-op thread and tract compute on the calling thread; ort's own pool threads get the same mode
/// from the session option `session.set_denormal_as_zero`).
///
/// Why: attention probabilities of far-away window slots and GELU tails of large negative inputs fall
/// into the subnormal range (below 1.2e-38), where x86 arithmetic takes a slow microcode path; with
/// real streams this made graphs up to 1.5x slower. Flushing changes values only below 1.2e-38, far
/// under every parity bound (docs/parity.md). Other architectures run `f` unchanged.
pub fn flush_denormals<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        #[allow(deprecated)] // the intrinsics are the documented way to read and write MXCSR
        use std::arch::x86_64::{_mm_getcsr, _mm_setcsr};
        /// MXCSR bits: flush-to-zero (15) and denormals-are-zero (6).
        const FTZ_DAZ: u32 = (1 << 15) | (1 << 6);
        struct Restore(u32);
        impl Drop for Restore {
            fn drop(&mut self) {
                // SAFETY: writes back the MXCSR value read from this thread before the call.
                #[allow(deprecated)]
                unsafe {
                    _mm_setcsr(self.0)
                }
            }
        }
        // SAFETY: SSE is part of x86-64; only the FTZ/DAZ bits are changed, and restored by `Restore`.
        #[allow(deprecated)]
        let old = unsafe { _mm_getcsr() };
        let _restore = Restore(old);
        #[allow(deprecated)]
        unsafe {
            _mm_setcsr(old | FTZ_DAZ)
        };
        f()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        f()
    }
}

/// Checks inputs against the spec (count, dtypes, shapes with one shared batch size); returns the batch.
pub fn check_inputs(spec: &GraphSpec, inputs: &[Tensor]) -> Result<usize> {
    let expected = spec.all_inputs();
    ensure!(
        inputs.len() == expected.len(),
        "graph '{}': {} inputs given, the graph takes {} ({:?})",
        spec.name,
        inputs.len(),
        expected.len(),
        spec.input_names()
    );
    let batch = inputs.first().map(Tensor::batch).unwrap_or(1);
    for (t, (name, dtype, shape)) in inputs.iter().zip(expected) {
        ensure!(
            t.dtype() == dtype && shape_fits(shape, &t.shape, batch),
            "graph '{}': input '{name}' is {} {:?}, expected {} {} with batch {batch}",
            spec.name,
            t.dtype(),
            t.shape,
            dtype,
            shape_string(shape)
        );
    }
    Ok(batch)
}

/// Checks a run's outputs against the spec (count, dtypes, shapes for batch `batch`).
pub fn check_outputs(spec: &GraphSpec, outputs: &[Tensor], batch: usize) -> Result<()> {
    let expected = spec.all_outputs();
    ensure!(
        outputs.len() == expected.len(),
        "graph '{}' returned {} outputs, the manifest lists {} ({:?})",
        spec.name,
        outputs.len(),
        expected.len(),
        spec.output_names()
    );
    for (t, (name, dtype, shape)) in outputs.iter().zip(expected) {
        ensure!(
            t.dtype() == dtype && shape_fits(shape, &t.shape, batch),
            "graph '{}': output '{name}' is {} {:?}, the manifest says {} {} with batch {batch}",
            spec.name,
            t.dtype(),
            t.shape,
            dtype,
            shape_string(shape)
        );
    }
    Ok(())
}

/// Something that loads step graphs.
pub trait Backend: Send + Sync {
    /// Short name (`tract`, `ort`).
    fn name(&self) -> &str;

    /// A description for logs and `info` (library, execution provider).
    fn describe(&self) -> String {
        self.name().to_string()
    }

    /// The backend whose graph forms this one runs by default (`--form auto`, the manifest's
    /// `backend_forms`, [`crate::bundle::LiveGestureManifest::default_form`]): its own name, except
    /// for a build of the same kernels elsewhere (ONNX Runtime Web runs the forms of `ort`).
    fn forms_of(&self) -> &str {
        self.name()
    }

    /// Loads the graph `spec` from `path`.
    fn load(&self, spec: &GraphSpec, path: &Path) -> Result<Box<dyn GraphRunner>>;

    /// Loads the graph `spec` from the ONNX file's `bytes` (`path` names it in messages). Backends
    /// that cannot load from memory refuse.
    fn load_bytes(
        &self,
        spec: &GraphSpec,
        path: &Path,
        bytes: &[u8],
    ) -> Result<Box<dyn GraphRunner>> {
        let _ = bytes;
        anyhow::bail!(
            "{}: the {} backend cannot load a graph from memory (graph '{}')",
            path.display(),
            self.name(),
            spec.name
        )
    }

    /// Loads the graph `spec` of `bundle`: from memory for a bundle given as bytes
    /// ([`Bundle::from_files`]), else from its file.
    fn load_from(&self, bundle: &Bundle, spec: &GraphSpec) -> Result<Box<dyn GraphRunner>> {
        let path = bundle.graph_path(spec);
        match bundle.memory_file(&spec.file) {
            Some(bytes) => self.load_bytes(spec, &path, bytes),
            None => self.load(spec, &path),
        }
    }
}

/// Which backend to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BackendKind {
    /// tract (pure Rust).
    #[default]
    Tract,
    /// ONNX Runtime.
    Ort,
}

impl FromStr for BackendKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "tract" => Ok(BackendKind::Tract),
            "ort" | "onnxruntime" => Ok(BackendKind::Ort),
            other => Err(format!("unknown backend '{other}'; expected tract or ort")),
        }
    }
}

impl fmt::Display for BackendKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            BackendKind::Tract => "tract",
            BackendKind::Ort => "ort",
        })
    }
}

/// Backend settings.
#[derive(Debug, Clone)]
pub struct BackendOptions {
    pub kind: BackendKind,
    /// ort execution provider (`cpu`, `cuda`, ...).
    pub execution_provider: String,
    /// Intra-op threads (ort); 1 by default.
    pub intra_threads: usize,
    /// Explicit ONNX Runtime library (else `ORT_DYLIB_PATH`, else a search).
    pub ort_library: Option<std::path::PathBuf>,
}

impl Default for BackendOptions {
    fn default() -> Self {
        Self {
            kind: BackendKind::Tract,
            execution_provider: "cpu".into(),
            intra_threads: 1,
            ort_library: None,
        }
    }
}

/// Creates the backend described by `opts`.
pub fn create(opts: &BackendOptions) -> Result<Box<dyn Backend>> {
    match opts.kind {
        BackendKind::Tract => {
            ensure!(
                opts.execution_provider.eq_ignore_ascii_case("cpu"),
                "the tract backend runs on the CPU only; execution provider '{}' needs the ort backend",
                opts.execution_provider
            );
            Ok(Box::new(tract::TractBackend::new()))
        }
        #[cfg(feature = "ort")]
        BackendKind::Ort => Ok(Box::new(ort::OrtBackend::new(opts)?)),
        #[cfg(not(feature = "ort"))]
        BackendKind::Ort => {
            anyhow::bail!(
                "this build of livegesture has no ort backend (built without the `ort` feature)"
            )
        }
    }
}

/// The tract version this build runs: `tract-onnx`'s crate version, pinned exactly in
/// `runtime/Cargo.toml` (a test keeps the two equal).
pub const TRACT_VERSION: &str = "0.23.9";

/// The inference runtimes this process ran, one line each: `tract <version>` and, once an ort
/// backend was created, `ONNX Runtime <version, as the loaded library reports it> (<library>)`.
pub fn runtime_versions() -> Vec<String> {
    #[cfg_attr(not(feature = "ort"), allow(unused_mut))]
    let mut v = vec![format!("tract {TRACT_VERSION}")];
    #[cfg(feature = "ort")]
    if let Some((version, path)) = self::ort::loaded_runtime() {
        v.push(format!("ONNX Runtime {version} ({})", path.display()));
    }
    v
}

#[cfg(test)]
mod version_tests {
    #[test]
    fn tract_version_is_the_pinned_crate_version() {
        let cargo = include_str!("../../Cargo.toml");
        let pin = format!("tract-onnx = \"={}\"", super::TRACT_VERSION);
        assert!(
            cargo.lines().any(|l| l.trim() == pin),
            "runtime/Cargo.toml does not pin {pin}: update TRACT_VERSION"
        );
    }
}

// long: the manifest's types and their checks field by field (docs/bundle.md); the family sections are in livegesture.rs and diffsheg.rs, the ONNX reading in onnx.rs
//! Model bundles: `manifest.json`, the step ONNX graphs it lists, and their verification.
//!
//! A bundle is a folder written by `export/export.py` (format: `docs/bundle.md`). [`Bundle::load`]
//!
//! 1. reads `manifest.json` and refuses any `schema_version` other than [`SCHEMA_VERSION`];
//! 2. checks the sha256 and size of **every** file listed under `files` (a missing file, a changed
//!    byte, a wrong size: each refused with the file's name and the expected vs actual value), and
//!    that every graph file is among them;
//! 3. parses each graph's ONNX protobuf and checks its inputs and outputs against the manifest: the
//!    same names in the same order (data inputs, then `cache.<name>`; data outputs, then
//!    `new_cache.<name>`), the same element types and ranks, and the same fixed dimensions where the
//!    file states them (a symbolic dimension is accepted; backends check actual shapes on every run);
//! 4. checks the manifest is self-consistent ([`Manifest::check`]): the family-common part (frontend
//!    and rates agree, every tensor has the batch axis first and only there, every cache is fed as
//!    `cache.<name>` and returned as `new_cache.<name>` and starts as zeros), then the sections of its
//!    family.
//!
//! # Families
//!
//! The manifest's `family` (`livegesture` or `diffsheg`; a manifest without the field is
//! `livegesture`, as every bundle exported before the field existed) picks the model implementation
//! ([`crate::model`]). The **family-common part** ([`Manifest`]: `schema_version`, `format`,
//! `family`, `model`, `rates`, `frontend`, `graphs`, `files`, `provenance`, `reference`) is required
//! for every family. Each family adds its own sections, required only for that family and parsed in
//! [`parse_manifest`] into a field of [`Manifest`]:
//!
//! - `livegesture`: `regions`, `vocab`, `sampling` ([`LiveGestureManifest`], in [`livegesture`]);
//! - `diffsheg`: `diffusion`, `foppas`, `noise`, `motion`, `speakers`, `regions`, `normalisation`
//!   ([`DiffshegManifest`], in [`diffsheg`]; parsed and checked together in [`parse_manifest`]).
//!
//! Everything the runtime needs (frontend configuration, cache shapes, the family's sections) is then
//! read from the manifest: initial caches are zeros of the shapes listed there ([`CacheSpec::zeros`]),
//! never hard-coded.
//!
//! The default bundle is a bundle installed beside the executable, else the repository's
//! `models/default` (see [`default_bundle_dir`]); the environment variable `LIVEGESTURE_BUNDLE`
//! overrides it.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;
use sha2::{Digest, Sha256};

use crate::frontend::FrontendConfig;

pub mod diffsheg;
mod graph;
pub mod livegesture;
mod onnx;

pub use diffsheg::DiffshegManifest;
pub use graph::{
    concrete_shape, has_named_axis, ring_slot, shape_fits, shape_string, CacheSpec, Dim, GraphSpec,
    TensorSpec,
};
pub use livegesture::{
    check_coverage, FormGraphs, FormSpec, LiveGestureManifest, RegionPart, RegionSpec,
    SamplingDefaults, Vocab, FORMS,
};

/// The manifest schema version this runtime reads.
pub const SCHEMA_VERSION: u64 = 1;

/// Environment variable naming the bundle used when none is given on the command line.
pub const BUNDLE_ENV: &str = "LIVEGESTURE_BUNDLE";

/// The repository's default bundle, `<repo>/models/default` (resolved from this crate's source
/// location at build time).
pub fn repo_default_bundle() -> PathBuf {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    crate_dir
        .parent()
        .unwrap_or(crate_dir)
        .join("models")
        .join("default")
}

/// The bundle to use: `explicit` if given, else `$LIVEGESTURE_BUNDLE`, else a bundle installed beside
/// the executable ([`installed_default_bundle`]), else [`repo_default_bundle`] (the build-time path).
pub fn default_bundle_dir(explicit: Option<&Path>) -> PathBuf {
    if let Some(p) = explicit {
        return p.to_path_buf();
    }
    match std::env::var_os(BUNDLE_ENV) {
        Some(v) if !v.is_empty() => PathBuf::from(v),
        _ => installed_default_bundle().unwrap_or_else(repo_default_bundle),
    }
}

/// A default bundle installed beside the executable: `<exe_dir>/../share/livegesture/models/default`
/// or `<exe_dir>/models/default`, the first that holds a `manifest.json`.
pub fn installed_default_bundle() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    // through symlinks (a link in /usr/local/bin to an unpacked archive); not on Windows, whose canonical
    // form (`\\?\C:\...`) takes neither `..` nor `/` in the paths joined to it
    #[cfg(not(windows))]
    let exe = exe.canonicalize().ok()?;
    let dir = exe.parent()?;
    // the parent folder by name, not `..`: Windows' canonical paths (`\\?\C:\...`) do not resolve `..`
    [
        dir.parent().map(|p| {
            p.join("share")
                .join("livegesture")
                .join("models")
                .join("default")
        }),
        Some(dir.join("models").join("default")),
    ]
    .into_iter()
    .flatten()
    .find(|p| p.join("manifest.json").is_file())
}

/// Why a bundle was refused. Every variant names the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    #[error("{}: no bundle here (manifest.json not found); expected a folder written by export/export.py (give its path, or set {BUNDLE_ENV})", .dir.display())]
    NoManifest { dir: PathBuf },
    #[error("{}: cannot read: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: invalid manifest: {detail}", .path.display())]
    Manifest { path: PathBuf, detail: String },
    #[error("{}: unsupported schema_version {found}; this runtime reads schema_version {SCHEMA_VERSION} (re-export the bundle with a matching export/export.py)", .path.display())]
    SchemaVersion { path: PathBuf, found: String },
    #[error("{}: file listed in manifest.json is missing", .path.display())]
    MissingFile { path: PathBuf },
    #[error("{}: sha256 mismatch: manifest.json expects {expected}, the file has {actual} (the file is corrupt or was changed after export)", .path.display())]
    HashMismatch {
        path: PathBuf,
        expected: String,
        actual: String,
    },
    #[error("{}: size mismatch: manifest.json expects {expected} bytes, the file has {actual}", .path.display())]
    SizeMismatch {
        path: PathBuf,
        expected: u64,
        actual: u64,
    },
    #[error("{}: graph file is not listed under `files` in manifest.json, so it cannot be verified", .path.display())]
    Unlisted { path: PathBuf },
    #[error("{}: not a valid ONNX model: {detail}", .path.display())]
    BadOnnx { path: PathBuf, detail: String },
    #[error("{}: graph '{graph}' does not match manifest.json: {detail}", .path.display())]
    GraphMismatch {
        path: PathBuf,
        graph: String,
        detail: String,
    },
}
/// A model family: which implementation chains a bundle's graphs ([`crate::model`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
pub enum Family {
    /// LiveGesture: causal per-token chain of step graphs, zero look-ahead.
    #[default]
    #[serde(rename = "livegesture")]
    LiveGesture,
    /// DiffSHEG: windowed diffusion with outpainting (FOPPAS).
    #[serde(rename = "diffsheg")]
    DiffSheg,
}

impl Family {
    /// Every family the manifest may name.
    pub const ALL: [Family; 2] = [Family::LiveGesture, Family::DiffSheg];

    /// The name used in the manifest, Python and the CLI.
    pub fn name(self) -> &'static str {
        match self {
            Family::LiveGesture => "livegesture",
            Family::DiffSheg => "diffsheg",
        }
    }
}

impl fmt::Display for Family {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Family {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Family::ALL
            .into_iter()
            .find(|f| f.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Family::ALL.iter().map(|f| f.name()).collect();
                format!(
                    "unknown family '{s}'; this runtime knows {}",
                    names.join(", ")
                )
            })
    }
}

/// Rates of the token grid.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct Rates {
    pub sample_rate: u64,
    pub fps: u64,
    pub frames_per_token: u64,
    pub mel_frames_per_token: u64,
}

/// Model description.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct ModelInfo {
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub config_name: Option<String>,
    #[serde(default)]
    pub config: Value,
    /// Parameter count per graph.
    #[serde(default)]
    pub parameters: BTreeMap<String, u64>,
}

/// Reference vectors travelling with the bundle.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct ReferenceInfo {
    #[serde(default)]
    pub graphs: BTreeMap<String, String>,
    #[serde(default)]
    pub clip: Option<String>,
    #[serde(default)]
    pub clip_source: Option<String>,
    #[serde(default)]
    pub rollout: Option<String>,
    #[serde(default)]
    pub rollout_seed: Option<u64>,
    #[serde(default)]
    pub rollout_tokens: Option<u64>,
    #[serde(default)]
    pub rollout_guidance: Option<f64>,
    #[serde(default)]
    pub rollout_audio: Option<String>,
}

/// The weight precisions a bundle may declare in `precision.weights` (docs/bundle.md#forms-and-precision).
pub const PRECISIONS: [&str; 4] = ["float32", "float16", "bfloat16", "int8"];

/// `precision` of a reduced-precision bundle (docs/bundle.md#forms-and-precision, written by `export/quantize.py`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct Precision {
    /// `float32`, `float16`, `bfloat16` or `int8` ([`PRECISIONS`]).
    pub weights: String,
    /// How the quantized graphs were made.
    #[serde(default)]
    pub method: Option<String>,
    /// What produced the reference vectors and rollout of this bundle (a reduced bundle has no torch
    /// model in its precision: onnxruntime on the reduced graphs).
    #[serde(default)]
    pub reference: Option<String>,
    /// The measured error against the f32 model (per graph max abs, rollout token agreement).
    #[serde(default)]
    pub error_vs_f32: Value,
    /// The evaluation metrics of this bundle beside the f32 model's (`generated.<precision>` and
    /// `generated.float32`, the command that made them); null until recorded.
    #[serde(default)]
    pub metrics: Value,
}

/// A file entry of the manifest.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct FileEntry {
    pub sha256: String,
    #[serde(default)]
    pub bytes: Option<u64>,
}

/// `manifest.json`, as far as the runtime reads it: the family-common part, and the sections of the
/// manifest's family (see the module docs). Unknown fields are ignored. Build it with
/// [`parse_manifest`], which fills the family's sections.
#[derive(Debug, Clone, Deserialize, Serialize)]
pub struct Manifest {
    pub schema_version: u64,
    #[serde(default)]
    pub format: Option<String>,
    /// The model family (absent: `livegesture`).
    #[serde(default)]
    pub family: Family,
    pub model: ModelInfo,
    pub rates: Rates,
    pub frontend: FrontendConfig,
    pub graphs: Vec<GraphSpec>,
    #[serde(default)]
    pub reference: Option<ReferenceInfo>,
    #[serde(default)]
    pub checks: Value,
    pub files: BTreeMap<String, FileEntry>,
    #[serde(default)]
    pub provenance: Value,
    /// Reduced-precision bundles (docs/bundle.md#forms-and-precision): the weights' precision, how the reference vectors were made and
    /// the measured error against the f32 model. Absent: an f32 bundle.
    #[serde(default)]
    pub precision: Option<Precision>,
    /// The face channel (docs/face.md): absent in a bundle without one.
    #[serde(default)]
    pub face: Option<crate::face::FaceManifest>,
    /// The LiveGesture sections: `Some` exactly when `family` is `livegesture`.
    #[serde(skip)]
    pub livegesture: Option<LiveGestureManifest>,
    /// The DiffSHEG sections: `Some` exactly when `family` is `diffsheg`.
    #[serde(skip)]
    pub diffsheg: Option<DiffshegManifest>,
}

/// A verified bundle.
#[derive(Debug, Clone)]
pub struct Bundle {
    dir: PathBuf,
    manifest: Manifest,
    /// The files of a bundle given in memory ([`Bundle::from_files`]), by path relative to the
    /// bundle; `None` for a bundle read from its folder.
    memory: Option<Arc<BTreeMap<String, Vec<u8>>>>,
}

fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

impl Bundle {
    /// Loads and verifies the bundle in `dir` (see the module docs).
    pub fn load(dir: impl AsRef<Path>) -> Result<Self, BundleError> {
        let dir = dir.as_ref().to_path_buf();
        let mpath = dir.join("manifest.json");
        if !mpath.is_file() {
            return Err(BundleError::NoManifest { dir });
        }
        let text = std::fs::read_to_string(&mpath).map_err(|source| BundleError::Io {
            path: mpath.clone(),
            source,
        })?;
        let manifest = parse_manifest(&text, &mpath)?;
        let bundle = Bundle {
            dir,
            manifest,
            memory: None,
        };
        bundle.verify_files()?;
        bundle.check_consistency()?;
        Ok(bundle)
    }

    /// Loads and verifies a bundle given as its files in memory (a browser has no folder to read):
    /// `files` maps each path relative to the bundle (`manifest.json`, `fusion.onnx`, ...) to its
    /// bytes. `name` stands for the bundle's folder in messages (for example the URL the files came
    /// from). The same checks as [`Bundle::load`]: every file listed in the manifest must be among
    /// `files` with the listed size and sha256. Files not listed are kept but never read.
    pub fn from_files(
        name: impl Into<PathBuf>,
        files: BTreeMap<String, Vec<u8>>,
    ) -> Result<Self, BundleError> {
        Self::from_some_files(name, files, true)
    }

    /// Like [`Bundle::from_files`]; with `complete` false, a listed file that is not among `files`
    /// is allowed unless it is a graph (a page that only runs the model need not download the
    /// reference vectors): every file given is still checked, every graph must be given, and reading
    /// a file not given later fails as [`BundleError::MissingFile`].
    pub fn from_some_files(
        name: impl Into<PathBuf>,
        files: BTreeMap<String, Vec<u8>>,
        complete: bool,
    ) -> Result<Self, BundleError> {
        let required = if complete {
            Required::All
        } else {
            Required::Graphs
        };
        Self::from_files_required(name, files, required)
    }

    /// Like [`Bundle::from_some_files`], but the only graphs required are those `backend` runs with
    /// its default choices, or with the graph form `form` where one is named
    /// ([`Manifest::graph_files_run_by`]): a page downloads the ~30 MB that tract runs of the default
    /// bundle's 96 MB of forms. Every file given is still checked (size, sha256, graph I/O); loading
    /// a model that needs a graph not given fails naming the file ([`BundleError::MissingFile`]).
    pub fn from_files_run_by(
        name: impl Into<PathBuf>,
        files: BTreeMap<String, Vec<u8>>,
        backend: &str,
        form: Option<&str>,
    ) -> Result<Self, BundleError> {
        Self::from_files_required(name, files, Required::RunBy(backend, form))
    }

    fn from_files_required(
        name: impl Into<PathBuf>,
        files: BTreeMap<String, Vec<u8>>,
        required: Required<'_>,
    ) -> Result<Self, BundleError> {
        let dir = name.into();
        let mpath = dir.join("manifest.json");
        let Some(raw) = files.get("manifest.json") else {
            return Err(BundleError::NoManifest { dir });
        };
        let text = std::str::from_utf8(raw).map_err(|e| BundleError::Manifest {
            path: mpath.clone(),
            detail: format!("not UTF-8 text: {e}"),
        })?;
        let manifest = parse_manifest(text, &mpath)?;
        let bundle = Bundle {
            dir,
            manifest,
            memory: Some(Arc::new(files)),
        };
        bundle.verify_files_given(required)?;
        bundle.check_consistency()?;
        Ok(bundle)
    }

    /// The bytes of the file `rel` (a path relative to the bundle): from memory for a bundle made
    /// with [`Bundle::from_files`], else read from the folder. A missing file is
    /// [`BundleError::MissingFile`].
    pub fn read(&self, rel: &str) -> Result<Cow<'_, [u8]>, BundleError> {
        let path = self.dir.join(rel);
        match &self.memory {
            Some(files) => files
                .get(rel)
                .map(|b| Cow::Borrowed(b.as_slice()))
                .ok_or(BundleError::MissingFile { path }),
            None => match std::fs::read(&path) {
                Ok(b) => Ok(Cow::Owned(b)),
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    Err(BundleError::MissingFile { path })
                }
                Err(source) => Err(BundleError::Io { path, source }),
            },
        }
    }

    /// The bytes of `rel` when the bundle is held in memory ([`Bundle::from_files`]); `None` for a
    /// bundle read from a folder (its files are read where they are used) or a file not given.
    pub fn memory_file(&self, rel: &str) -> Option<&[u8]> {
        self.memory
            .as_ref()
            .and_then(|m| m.get(rel))
            .map(Vec::as_slice)
    }

    /// True for a bundle given in memory ([`Bundle::from_files`]).
    pub fn is_in_memory(&self) -> bool {
        self.memory.is_some()
    }

    /// The bundle folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The parsed manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The audio frontend configuration.
    pub fn frontend(&self) -> &FrontendConfig {
        &self.manifest.frontend
    }

    /// The model family.
    pub fn family(&self) -> Family {
        self.manifest.family
    }

    /// The LiveGesture sections (regions, vocabulary, sampling defaults), or an error naming the
    /// manifest when the bundle is of another family.
    pub fn livegesture(&self) -> Result<&LiveGestureManifest, BundleError> {
        self.manifest.livegesture.as_ref().ok_or_else(|| {
            self.manifest_err(format!(
                "family '{}' has no LiveGesture sections (regions, vocab, sampling)",
                self.manifest.family
            ))
        })
    }

    /// The DiffSHEG sections (diffusion, FOPPAS, noise, motion layout, speakers, normalisation), or
    /// an error naming the manifest when the bundle is of another family.
    pub fn diffsheg(&self) -> Result<&DiffshegManifest, BundleError> {
        self.manifest.diffsheg.as_ref().ok_or_else(|| {
            self.manifest_err(format!(
                "family '{}' has no DiffSHEG sections (diffusion, foppas, noise)",
                self.manifest.family
            ))
        })
    }

    /// All graphs.
    pub fn graphs(&self) -> &[GraphSpec] {
        &self.manifest.graphs
    }

    /// The graph called `name`.
    pub fn graph(&self, name: &str) -> Result<&GraphSpec, BundleError> {
        self.manifest
            .graphs
            .iter()
            .find(|g| g.name == name)
            .ok_or_else(|| BundleError::Manifest {
                path: self.manifest_path(),
                detail: format!("no graph named '{name}'"),
            })
    }

    /// Path of a graph's ONNX file.
    pub fn graph_path(&self, g: &GraphSpec) -> PathBuf {
        self.dir.join(&g.file)
    }

    /// Path of a file inside the bundle.
    pub fn path(&self, rel: &str) -> PathBuf {
        self.dir.join(rel)
    }

    /// Path of `manifest.json`.
    pub fn manifest_path(&self) -> PathBuf {
        self.dir.join("manifest.json")
    }

    /// The weights' precision (`precision.weights`; `float32` when the manifest has no `precision`).
    pub fn precision(&self) -> &str {
        self.manifest
            .precision
            .as_ref()
            .map_or("float32", |p| p.weights.as_str())
    }

    /// True for a reduced-precision bundle (docs/bundle.md#forms-and-precision): its reference vectors are not torch's.
    pub fn is_reduced_precision(&self) -> bool {
        self.precision() != "float32"
    }

    /// The producer of the bundle's reference vectors, as the parity rows name it: `torch` for an f32
    /// bundle, `reference` for a reduced-precision one (onnxruntime on the reduced graphs, see
    /// `precision.reference` in the manifest).
    pub fn reference_name(&self) -> &'static str {
        if self.is_reduced_precision() {
            "reference"
        } else {
            "torch"
        }
    }

    /// Provenance (training data, steps, export details) as written by the exporter.
    pub fn provenance(&self) -> &Value {
        &self.manifest.provenance
    }

    /// Reference vectors and rollout description, if the bundle has them.
    pub fn reference(&self) -> Option<&ReferenceInfo> {
        self.manifest.reference.as_ref()
    }

    /// The reference clip's name inside the bundle: `reference.clip`, else `reference/clip.wav`.
    pub fn reference_clip(&self) -> String {
        self.reference()
            .and_then(|r| r.clip.clone())
            .unwrap_or_else(|| "reference/clip.wav".into())
    }

    /// The reference rollout's name inside the bundle: `reference.rollout`, else
    /// `reference/rollout.npz`.
    pub fn reference_rollout(&self) -> String {
        self.reference()
            .and_then(|r| r.rollout.clone())
            .unwrap_or_else(|| "reference/rollout.npz".into())
    }

    fn manifest_err(&self, detail: impl Into<String>) -> BundleError {
        BundleError::Manifest {
            path: self.manifest_path(),
            detail: detail.into(),
        }
    }

    /// Checks size and sha256 of every listed file, that graph files are listed, and the ONNX I/O.
    fn verify_files(&self) -> Result<(), BundleError> {
        self.verify_files_given(Required::All)
    }

    /// [`Bundle::verify_files`]; listed files that `required` does not name may be absent from an
    /// in-memory bundle ([`Bundle::from_some_files`], [`Bundle::from_files_run_by`]).
    fn verify_files_given(&self, required: Required<'_>) -> Result<(), BundleError> {
        let mut graph_bytes: BTreeMap<&str, Cow<'_, [u8]>> = BTreeMap::new();
        let graph_files: Vec<&str> = self
            .manifest
            .graphs
            .iter()
            .map(|g| g.file.as_str())
            .collect();
        let run: Vec<String> = match required {
            Required::RunBy(backend, form) => self.manifest.graph_files_run_by(backend, form),
            _ => Vec::new(),
        };
        let is_required = |rel: &str| match required {
            Required::All => true,
            Required::Graphs => graph_files.contains(&rel),
            Required::RunBy(..) => run.iter().any(|f| f == rel),
        };
        let absent = |rel: &str| self.memory.as_ref().is_some_and(|m| !m.contains_key(rel));
        for (rel, entry) in &self.manifest.files {
            if rel.starts_with('/') || rel.split('/').any(|c| c == "..") {
                return Err(
                    self.manifest_err(format!("file entry '{rel}' points outside the bundle"))
                );
            }
            let path = self.dir.join(rel);
            if !is_required(rel) && absent(rel) {
                continue;
            }
            let bytes = self.read(rel)?;
            if let Some(expected) = entry.bytes {
                if expected != bytes.len() as u64 {
                    return Err(BundleError::SizeMismatch {
                        path,
                        expected,
                        actual: bytes.len() as u64,
                    });
                }
            }
            let actual = sha256_hex(&bytes);
            if !actual.eq_ignore_ascii_case(entry.sha256.trim()) {
                return Err(BundleError::HashMismatch {
                    path,
                    expected: entry.sha256.clone(),
                    actual,
                });
            }
            if graph_files.contains(&rel.as_str()) {
                graph_bytes.insert(rel.as_str(), bytes);
            }
        }
        for g in &self.manifest.graphs {
            let path = self.graph_path(g);
            let Some(bytes) = graph_bytes.get(g.file.as_str()) else {
                if !is_required(&g.file) && absent(&g.file) {
                    continue;
                }
                let exists = match &self.memory {
                    Some(files) => files.contains_key(&g.file),
                    None => path.exists(),
                };
                if !exists {
                    return Err(BundleError::MissingFile { path });
                }
                return Err(BundleError::Unlisted { path });
            };
            onnx::check_graph_io(g, &path, bytes)?;
        }
        Ok(())
    }

    fn check_consistency(&self) -> Result<(), BundleError> {
        self.manifest.check().map_err(|e| self.manifest_err(e))
    }
}

/// Which listed files an in-memory bundle must hold ([`Bundle::verify_files_given`]).
#[derive(Clone, Copy)]
enum Required<'a> {
    /// Every listed file.
    All,
    /// Every graph (other files may be left out).
    Graphs,
    /// The graphs this backend runs by default, or with the form named
    /// ([`Manifest::graph_files_run_by`]).
    RunBy(&'a str, Option<&'a str>),
}

impl Manifest {
    /// The files of the graphs `backend` (`tract`, `ort`; a backend that runs another's forms, such
    /// as ONNX Runtime Web, names that one: [`crate::backend::Backend::forms_of`]) runs with its
    /// default choices (`--form auto`, the bundle's face channel): for LiveGesture the audio encoder,
    /// the fusion and eXperts of the backend's form ([`LiveGestureManifest::default_form`]), the
    /// decoders it runs with it ([`LiveGestureManifest::default_decoders`]) and the face graph. With
    /// `form` named (`canonical`, `fused_ring`, ...), that form's graphs and its own decoders, as
    /// `--form` loads them. For DiffSHEG (one form), or a form the bundle does not carry (loading
    /// then names it), every graph. In manifest order.
    pub fn graph_files_run_by(&self, backend: &str, form: Option<&str>) -> Vec<String> {
        let names: Option<Vec<String>> = self.livegesture.as_ref().and_then(|lg| {
            let (_, graphs) = lg.graphs_run_by(backend, form)?;
            let mut n = vec!["audio_encoder".to_string(), graphs.fusion];
            n.extend(graphs.experts);
            n.extend(graphs.decoders);
            n.extend(self.face.iter().map(|f| f.graph.clone()));
            Some(n)
        });
        self.graphs
            .iter()
            .filter(|g| names.as_ref().is_none_or(|n| n.contains(&g.name)))
            .map(|g| g.file.clone())
            .collect()
    }

    /// Checks the manifest against itself, without reading any file: the family-common part, then the
    /// sections of its family (see the module docs). The error says what is wrong.
    pub fn check(&self) -> Result<(), String> {
        if let Some(p) = &self.precision {
            if !PRECISIONS.contains(&p.weights.as_str()) {
                return Err(format!(
                    "precision.weights is '{}'; expected one of {}",
                    p.weights,
                    PRECISIONS.join(", ")
                ));
            }
        }
        self.frontend
            .validate()
            .map_err(|e| format!("frontend: {e:#}"))?;
        let r = &self.rates;
        let f = &self.frontend;
        if r.sample_rate != f.sample_rate
            || r.fps != f.fps
            || r.frames_per_token != f.frames_per_token
            || r.mel_frames_per_token != f.mel_frames_per_token
        {
            return Err("`rates` and `frontend` disagree".into());
        }
        for g in &self.graphs {
            for c in &g.caches {
                if c.init != "zeros" {
                    return Err(format!(
                        "graph '{}': cache '{}' has init '{}'; this runtime supports only 'zeros'",
                        g.name, c.name, c.init
                    ));
                }
                if has_named_axis(&c.shape) {
                    return Err(format!(
                        "graph '{}': cache '{}' has shape {}; a cache's axes must be the batch and fixed sizes",
                        g.name,
                        c.name,
                        shape_string(&c.shape)
                    ));
                }
                if let Some(o) = &c.output_shape {
                    // a ring cache returns one slot of axis -2 (docs/bundle.md#ring-caches)
                    let r = c.shape.len();
                    let one_slot = r >= 3
                        && o.len() == r
                        && o[..r - 2] == c.shape[..r - 2]
                        && o[r - 2] == Dim::Fixed(1)
                        && o[r - 1] == c.shape[r - 1];
                    if !one_slot {
                        return Err(format!(
                            "graph '{}': cache '{}' has output_shape {}; a ring cache's entry is its shape {} with axis -2 of size 1",
                            g.name,
                            c.name,
                            shape_string(o),
                            shape_string(&c.shape)
                        ));
                    }
                }
                let (input, output) =
                    (format!("cache.{}", c.name), format!("new_cache.{}", c.name));
                if c.input != input || c.output != output {
                    return Err(format!(
                        "graph '{}': cache '{}' is fed as '{}' and returned as '{}'; expected '{input}' and '{output}'",
                        g.name, c.name, c.input, c.output
                    ));
                }
            }
            for (name, _, shape) in g.all_inputs().into_iter().chain(g.all_outputs()) {
                if shape.first() != Some(&Dim::Batch) || shape[1..].contains(&Dim::Batch) {
                    return Err(format!(
                        "graph '{}': tensor '{name}' has shape {}; expected the batch axis first and only there",
                        g.name,
                        shape_string(shape)
                    ));
                }
            }
        }
        crate::face::manifest_face(self)?;
        match self.family {
            Family::LiveGesture => match &self.livegesture {
                Some(lg) => lg.check(self),
                None => Err("family livegesture: the LiveGesture sections were not parsed".into()),
            },
            // parsed and checked together in `parse_manifest` (DiffshegManifest::parse)
            Family::DiffSheg => match &self.diffsheg {
                Some(_) => Ok(()),
                None => Err("family diffsheg: the DiffSHEG sections were not parsed".into()),
            },
        }
    }
}

/// Parses the manifest text: the schema version first (so a future schema is refused as such), then
/// the whole structure.
pub fn parse_manifest(text: &str, path: &Path) -> Result<Manifest, BundleError> {
    let value: Value = serde_json::from_str(text).map_err(|e| BundleError::Manifest {
        path: path.to_path_buf(),
        detail: format!("not valid JSON: {e}"),
    })?;
    match value.get("schema_version") {
        Some(Value::Number(n)) if n.as_u64() == Some(SCHEMA_VERSION) => {}
        Some(other) => {
            return Err(BundleError::SchemaVersion {
                path: path.to_path_buf(),
                found: other.to_string(),
            })
        }
        None => {
            return Err(BundleError::Manifest {
                path: path.to_path_buf(),
                detail: "no schema_version field".into(),
            })
        }
    }
    let err = |detail: String| BundleError::Manifest {
        path: path.to_path_buf(),
        detail,
    };
    // the family first, so an unknown one is refused as such
    if let Some(f) = value.get("family") {
        match f.as_str() {
            Some(name) => {
                name.parse::<Family>().map_err(err)?;
            }
            None => {
                return Err(err(format!(
                    "family is {f}; expected a string such as \"livegesture\""
                )))
            }
        }
    }
    let mut manifest: Manifest =
        serde_json::from_value(value.clone()).map_err(|e| err(e.to_string()))?;
    match manifest.family {
        Family::LiveGesture => {
            let lg: LiveGestureManifest = serde_json::from_value(value)
                .map_err(|e| err(format!("family livegesture: {e}")))?;
            manifest.livegesture = Some(lg);
        }
        Family::DiffSheg => {
            let d = DiffshegManifest::parse(&value)
                .map_err(|e| err(format!("family diffsheg: {e:#}")))?;
            manifest.diffsheg = Some(d);
        }
    }
    Ok(manifest)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dims_parse() {
        let d: Vec<Dim> = serde_json::from_str(r#"["batch", 4, 32]"#).unwrap();
        assert_eq!(d, vec![Dim::Batch, Dim::Fixed(4), Dim::Fixed(32)]);
        assert!(serde_json::from_str::<Vec<Dim>>(r#"[""]"#).is_err());
        assert!(serde_json::from_str::<Vec<Dim>>(r#"[-1]"#).is_err());
        assert_eq!(concrete_shape(&d, 3), vec![3, 4, 32]);
        // another named dynamic axis (DiffSHEG's window length)
        let d: Vec<Dim> = serde_json::from_str(r#"["batch", "frames", 425]"#).unwrap();
        assert_eq!(d[1], Dim::Named("frames".into()));
        assert!(shape_fits(&d, &[2, 88, 425], 2) && shape_fits(&d, &[2, 10, 425], 2));
        assert!(!shape_fits(&d, &[2, 88, 424], 2) && !shape_fits(&d, &[3, 88, 425], 2));
        assert_eq!(
            serde_json::to_string(&d).unwrap(),
            r#"["batch","frames",425]"#
        );
    }

    #[test]
    fn default_bundle_location() {
        let d = repo_default_bundle();
        assert!(d.ends_with("models/default"), "{}", d.display());
        assert!(!d.to_string_lossy().contains(".."));
        assert_eq!(
            default_bundle_dir(Some(Path::new("/x"))),
            PathBuf::from("/x")
        );
    }

    #[test]
    fn schema_version_refused() {
        let e = parse_manifest(r#"{"schema_version": 2}"#, Path::new("/b/manifest.json"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("schema_version 2") && e.contains("manifest.json"),
            "{e}"
        );
    }

    /// The shipped bundle's manifest, edited by `f`, parsed and checked.
    fn edited(f: impl FnOnce(&mut Value)) -> Result<Manifest, String> {
        let p = repo_default_bundle().join("manifest.json");
        let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        f(&mut v);
        let m = parse_manifest(&v.to_string(), &p).map_err(|e| e.to_string())?;
        m.check()?;
        Ok(m)
    }

    #[test]
    fn precision_is_read_checked_and_defaults_to_float32() {
        let m = edited(|_| {}).unwrap();
        assert!(m.precision.is_none());
        let m = edited(|v| {
            v["precision"] = serde_json::json!({"weights": "int8", "reference": "onnxruntime",
                                                "error_vs_f32": {"graphs_max_abs": {}, "rollout": {}}});
        })
        .unwrap();
        assert_eq!(m.precision.as_ref().unwrap().weights, "int8");
        for w in ["float16", "bfloat16", "float32"] {
            let m = edited(|v| v["precision"] = serde_json::json!({"weights": w})).unwrap();
            assert_eq!(m.precision.as_ref().unwrap().weights, w);
        }
        for bad in ["int3", "f16", "fp16", "FLOAT16", ""] {
            let e = edited(|v| v["precision"] = serde_json::json!({"weights": bad})).unwrap_err();
            assert!(
                e.contains("precision.weights") && e.contains(&format!("'{bad}'")),
                "{e}"
            );
        }
    }

    #[test]
    fn family_is_read_and_defaults_to_livegesture() {
        let m = edited(|_| {}).unwrap();
        assert_eq!(m.family, Family::LiveGesture);
        assert_eq!(m.livegesture.as_ref().unwrap().regions.len(), 4);
        let m = edited(|v| v["family"] = "livegesture".into()).unwrap();
        assert_eq!(m.family, Family::LiveGesture);
        let e = edited(|v| v["family"] = "gesturenet".into()).unwrap_err();
        assert!(
            e.contains("unknown family 'gesturenet'") && e.contains("diffsheg"),
            "{e}"
        );
        let e = edited(|v| v["family"] = 3.into()).unwrap_err();
        assert!(e.contains("family is 3"), "{e}");
    }

    #[test]
    fn livegesture_sections_are_required_only_for_livegesture() {
        let strip = |v: &mut Value| {
            let o = v.as_object_mut().unwrap();
            for k in ["regions", "vocab", "sampling", "pipeline"] {
                o.remove(k);
            }
        };
        let e = edited(strip).unwrap_err();
        assert!(
            e.contains("family livegesture") && e.contains("regions"),
            "{e}"
        );
        // a diffsheg manifest needs its own sections (diffusion, foppas, ...), not LiveGesture's
        let e = edited(|v| {
            strip(v);
            v["family"] = "diffsheg".into();
        })
        .unwrap_err();
        assert!(
            e.contains("family diffsheg") && e.contains("diffusion"),
            "{e}"
        );
        // the common part stays required for every family
        let e = edited(|v| {
            v["family"] = "diffsheg".into();
            v.as_object_mut().unwrap().remove("rates");
        })
        .unwrap_err();
        assert!(e.contains("rates"), "{e}");
    }

    #[test]
    fn named_axes_only_outside_caches_and_livegesture() {
        let e = edited(|v| v["graphs"][0]["inputs"][0]["shape"][1] = "frames".into()).unwrap_err();
        assert!(e.contains("named dynamic axis"), "{e}");
        let e = edited(|v| v["graphs"][0]["caches"][0]["shape"][1] = "frames".into()).unwrap_err();
        assert!(e.contains("a cache's axes"), "{e}");
    }

    #[test]
    fn cache_names_must_follow_the_convention() {
        let e =
            edited(|v| v["graphs"][0]["caches"][0]["input"] = "cache.other".into()).unwrap_err();
        assert!(
            e.contains("is fed as 'cache.other'") && e.contains("expected 'cache."),
            "{e}"
        );
        let e = edited(|v| v["graphs"][1]["caches"][0]["output"] = "next.x".into()).unwrap_err();
        assert!(e.contains("returned as 'next.x'"), "{e}");
    }
}

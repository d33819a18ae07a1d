//! Model bundles: `manifest.json`, the step ONNX graphs it lists, and their verification.
//!
//! A bundle is a folder written by `export/export.py` (format: `export/BUNDLE.md`). [`Bundle::load`]
//!
//! 1. reads `manifest.json` and refuses any `schema_version` other than [`SCHEMA_VERSION`];
//! 2. checks the sha256 and size of **every** file listed under `files` (a missing file, a changed
//!    byte, a wrong size: each refused with the file's name and the expected vs actual value), and
//!    that every graph file is among them;
//! 3. parses each graph's ONNX protobuf and checks its inputs and outputs against the manifest: the
//!    same names in the same order (data inputs, then `cache.<name>`; data outputs, then
//!    `new_cache.<name>`), the same element types and ranks, and the same fixed dimensions where the
//!    file states them (a symbolic dimension is accepted; backends check actual shapes on every run);
//! 4. checks the manifest is self-consistent (regions, graph names, vocabulary, frontend).
//!
//! Everything the runtime needs (frontend configuration, region layout, cache shapes, sampling
//! defaults, vocabulary) is then read from the manifest: initial caches are zeros of the shapes
//! listed there ([`CacheSpec::zeros`]), never hard-coded.
//!
//! The default bundle is the repository's `models/default` (see [`default_bundle_dir`]); the
//! environment variable `LIVEGESTURE_BUNDLE` overrides it.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Deserializer, Serialize};
use serde_json::Value;
use sha2::{Digest, Sha256};
use tract_onnx::pb;
use tract_onnx::prelude::Framework;

use crate::backend::{DType, Tensor};
use crate::frontend::FrontendConfig;

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
    let exe = std::env::current_exe().ok()?.canonicalize().ok()?;
    let dir = exe.parent()?;
    [
        dir.join("../share/livegesture/models/default"),
        dir.join("models/default"),
    ]
    .into_iter()
    .find(|p| p.join("manifest.json").is_file())
}

/// Why a bundle was refused. Every variant names the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    #[error("{}: no bundle here (manifest.json not found); expected a folder written by export/export.py (give one with --bundle or {BUNDLE_ENV})", .dir.display())]
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

/// One dimension of a tensor in the manifest: the dynamic batch axis or a fixed size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Dim {
    /// The dynamic batch axis (written `"batch"` in the manifest).
    Batch,
    /// A fixed size.
    Fixed(usize),
}

impl<'de> Deserialize<'de> for Dim {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        match Value::deserialize(d)? {
            Value::String(s) if s == "batch" => Ok(Dim::Batch),
            Value::Number(n) => n
                .as_u64()
                .map(|n| Dim::Fixed(n as usize))
                .ok_or_else(|| serde::de::Error::custom(format!("dimension {n} is not a size"))),
            other => Err(serde::de::Error::custom(format!(
                "dimension {other} is neither a size nor \"batch\""
            ))),
        }
    }
}

impl fmt::Display for Dim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Dim::Batch => f.write_str("batch"),
            Dim::Fixed(n) => write!(f, "{n}"),
        }
    }
}

fn shape_string(shape: &[Dim]) -> String {
    let v: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    format!("[{}]", v.join(", "))
}

/// A tensor's shape with the batch axis set to `batch`.
pub fn concrete_shape(shape: &[Dim], batch: usize) -> Vec<usize> {
    shape
        .iter()
        .map(|d| match d {
            Dim::Batch => batch,
            Dim::Fixed(n) => *n,
        })
        .collect()
}

/// A data input or output of a graph.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct TensorSpec {
    pub name: String,
    pub dtype: DType,
    pub shape: Vec<Dim>,
}

impl TensorSpec {
    /// Elements per batch row (product of the fixed dimensions).
    pub fn row_len(&self) -> usize {
        self.shape
            .iter()
            .map(|d| match d {
                Dim::Batch => 1,
                Dim::Fixed(n) => *n,
            })
            .product()
    }
}

/// A cache of a step graph: fed as `input`, returned updated as `output`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct CacheSpec {
    pub name: String,
    pub input: String,
    pub output: String,
    pub dtype: DType,
    pub shape: Vec<Dim>,
    #[serde(default = "zeros_init")]
    pub init: String,
}

fn zeros_init() -> String {
    "zeros".into()
}

impl CacheSpec {
    /// Elements per batch row.
    pub fn row_len(&self) -> usize {
        self.shape
            .iter()
            .map(|d| match d {
                Dim::Batch => 1,
                Dim::Fixed(n) => *n,
            })
            .product()
    }

    /// Bytes per batch row.
    pub fn row_bytes(&self) -> usize {
        self.row_len() * self.dtype.size()
    }

    /// The initial cache for `batch` rows: zeros of the manifest's shape and dtype.
    pub fn zeros(&self, batch: usize) -> Tensor {
        Tensor::zeros(self.dtype, concrete_shape(&self.shape, batch))
    }
}

/// One step graph of the bundle.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct GraphSpec {
    pub name: String,
    pub file: String,
    #[serde(default)]
    pub component: Option<String>,
    #[serde(default)]
    pub region: Option<String>,
    pub inputs: Vec<TensorSpec>,
    pub outputs: Vec<TensorSpec>,
    pub caches: Vec<CacheSpec>,
    #[serde(default)]
    pub reference: Option<String>,
}

impl GraphSpec {
    /// All input names in graph order: data inputs, then cache inputs.
    pub fn input_names(&self) -> Vec<&str> {
        self.inputs
            .iter()
            .map(|i| i.name.as_str())
            .chain(self.caches.iter().map(|c| c.input.as_str()))
            .collect()
    }

    /// All output names in graph order: data outputs, then cache outputs.
    pub fn output_names(&self) -> Vec<&str> {
        self.outputs
            .iter()
            .map(|o| o.name.as_str())
            .chain(self.caches.iter().map(|c| c.output.as_str()))
            .collect()
    }

    /// `(name, dtype, shape)` of every input in graph order.
    pub fn all_inputs(&self) -> Vec<(&str, DType, &[Dim])> {
        self.inputs
            .iter()
            .map(|i| (i.name.as_str(), i.dtype, i.shape.as_slice()))
            .chain(
                self.caches
                    .iter()
                    .map(|c| (c.input.as_str(), c.dtype, c.shape.as_slice())),
            )
            .collect()
    }

    /// `(name, dtype, shape)` of every output in graph order.
    pub fn all_outputs(&self) -> Vec<(&str, DType, &[Dim])> {
        self.outputs
            .iter()
            .map(|o| (o.name.as_str(), o.dtype, o.shape.as_slice()))
            .chain(
                self.caches
                    .iter()
                    .map(|c| (c.output.as_str(), c.dtype, c.shape.as_slice())),
            )
            .collect()
    }

    /// Cache bytes per batch row.
    pub fn cache_row_bytes(&self) -> usize {
        self.caches.iter().map(CacheSpec::row_bytes).sum()
    }

    /// Index of the data input `name`.
    pub fn input_index(&self, name: &str) -> Option<usize> {
        self.inputs.iter().position(|i| i.name == name)
    }

    /// Index of the data output `name`.
    pub fn output_index(&self, name: &str) -> Option<usize> {
        self.outputs.iter().position(|o| o.name == name)
    }
}

/// One part of a region's feature vector (`rot6d`, `trans`, `foot_contact`, `expressions`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct RegionPart {
    pub name: String,
    #[serde(default)]
    pub joints: Option<Vec<usize>>,
    pub offset: usize,
    pub dim: usize,
}

/// A body region and the layout of its feature vector.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct RegionSpec {
    pub name: String,
    pub dim: usize,
    pub joints: Vec<usize>,
    pub parts: Vec<RegionPart>,
}

impl RegionSpec {
    /// The part called `name`, if the region has it.
    pub fn part(&self, name: &str) -> Option<&RegionPart> {
        self.parts.iter().find(|p| p.name == name)
    }
}

/// Token vocabulary.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct Vocab {
    pub codebook_size: usize,
    pub bos_token: i64,
    #[serde(default)]
    pub mask_token: Option<i64>,
}

/// Sampling defaults of the bundle.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct SamplingDefaults {
    /// Classifier-free guidance scale gamma (1.0 disables guidance).
    pub guidance: f64,
    pub temperature: f64,
    /// Top-k (0 = all).
    pub top_k: usize,
    #[serde(default)]
    pub region_order: Vec<String>,
    #[serde(default)]
    pub prng: Option<String>,
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

/// A file entry of the manifest.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct FileEntry {
    pub sha256: String,
    #[serde(default)]
    pub bytes: Option<u64>,
}

/// `manifest.json`, as far as the runtime reads it. Unknown fields are ignored.
#[derive(Debug, Clone, Deserialize, Serialize)]
pub struct Manifest {
    pub schema_version: u64,
    #[serde(default)]
    pub format: Option<String>,
    pub model: ModelInfo,
    pub rates: Rates,
    pub frontend: FrontendConfig,
    pub regions: Vec<RegionSpec>,
    pub vocab: Vocab,
    pub graphs: Vec<GraphSpec>,
    pub sampling: SamplingDefaults,
    #[serde(default)]
    pub reference: Option<ReferenceInfo>,
    #[serde(default)]
    pub checks: Value,
    pub files: BTreeMap<String, FileEntry>,
    #[serde(default)]
    pub provenance: Value,
    #[serde(default)]
    pub pipeline: Value,
}

/// A verified bundle.
#[derive(Debug, Clone)]
pub struct Bundle {
    dir: PathBuf,
    manifest: Manifest,
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
        let bundle = Bundle { dir, manifest };
        bundle.verify_files()?;
        bundle.check_consistency()?;
        Ok(bundle)
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

    /// Regions in the pipeline's order.
    pub fn regions(&self) -> &[RegionSpec] {
        &self.manifest.regions
    }

    /// Region names in order.
    pub fn region_names(&self) -> Vec<&str> {
        self.manifest
            .regions
            .iter()
            .map(|r| r.name.as_str())
            .collect()
    }

    /// The vocabulary (BOS token, codebook size).
    pub fn vocab(&self) -> &Vocab {
        &self.manifest.vocab
    }

    /// Sampling defaults.
    pub fn sampling(&self) -> &SamplingDefaults {
        &self.manifest.sampling
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

    /// Provenance (training data, steps, export details) as written by the exporter.
    pub fn provenance(&self) -> &Value {
        &self.manifest.provenance
    }

    /// Reference vectors and rollout description, if the bundle has them.
    pub fn reference(&self) -> Option<&ReferenceInfo> {
        self.manifest.reference.as_ref()
    }

    fn manifest_err(&self, detail: impl Into<String>) -> BundleError {
        BundleError::Manifest {
            path: self.manifest_path(),
            detail: detail.into(),
        }
    }

    /// Checks size and sha256 of every listed file, that graph files are listed, and the ONNX I/O.
    fn verify_files(&self) -> Result<(), BundleError> {
        let mut graph_bytes: BTreeMap<&str, Vec<u8>> = BTreeMap::new();
        let graph_files: Vec<&str> = self
            .manifest
            .graphs
            .iter()
            .map(|g| g.file.as_str())
            .collect();
        for (rel, entry) in &self.manifest.files {
            if rel.starts_with('/') || rel.split('/').any(|c| c == "..") {
                return Err(
                    self.manifest_err(format!("file entry '{rel}' points outside the bundle"))
                );
            }
            let path = self.dir.join(rel);
            let bytes = match std::fs::read(&path) {
                Ok(b) => b,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                    return Err(BundleError::MissingFile { path })
                }
                Err(source) => return Err(BundleError::Io { path, source }),
            };
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
                if !path.exists() {
                    return Err(BundleError::MissingFile { path });
                }
                return Err(BundleError::Unlisted { path });
            };
            check_graph_io(g, &path, bytes)?;
        }
        Ok(())
    }

    fn check_consistency(&self) -> Result<(), BundleError> {
        let m = &self.manifest;
        m.frontend
            .validate()
            .map_err(|e| self.manifest_err(format!("frontend: {e:#}")))?;
        if m.rates.sample_rate != m.frontend.sample_rate
            || m.rates.fps != m.frontend.fps
            || m.rates.frames_per_token != m.frontend.frames_per_token
            || m.rates.mel_frames_per_token != m.frontend.mel_frames_per_token
        {
            return Err(self.manifest_err("`rates` and `frontend` disagree"));
        }
        if m.regions.is_empty() {
            return Err(self.manifest_err("no regions"));
        }
        let names = self.region_names();
        if !m.sampling.region_order.is_empty() && m.sampling.region_order != names {
            return Err(self.manifest_err(format!(
                "sampling.region_order {:?} differs from the regions {:?}",
                m.sampling.region_order, names
            )));
        }
        for r in &m.regions {
            for p in &r.parts {
                if p.offset + p.dim > r.dim {
                    return Err(self.manifest_err(format!(
                        "region '{}': part '{}' ends at {} beyond the region's {} dims",
                        r.name,
                        p.name,
                        p.offset + p.dim,
                        r.dim
                    )));
                }
            }
        }
        let mut wanted = vec!["audio_encoder".to_string(), "fusion".to_string()];
        for r in &names {
            wanted.push(format!("expert_{r}"));
            wanted.push(format!("decoder_{r}"));
        }
        for w in &wanted {
            self.graph(w)?;
        }
        if m.vocab.bos_token < 0 {
            return Err(self.manifest_err("vocab.bos_token is negative"));
        }
        if m.sampling.temperature.is_nan()
            || m.sampling.temperature <= 0.0
            || !m.sampling.guidance.is_finite()
        {
            return Err(self.manifest_err(format!(
                "sampling defaults out of range (guidance {}, temperature {})",
                m.sampling.guidance, m.sampling.temperature
            )));
        }
        for g in &m.graphs {
            for c in &g.caches {
                if c.init != "zeros" {
                    return Err(self.manifest_err(format!(
                        "graph '{}': cache '{}' has init '{}'; this runtime supports only 'zeros'",
                        g.name, c.name, c.init
                    )));
                }
            }
            for (name, _, shape) in g.all_inputs().into_iter().chain(g.all_outputs()) {
                if shape.first() != Some(&Dim::Batch) || shape[1..].contains(&Dim::Batch) {
                    return Err(self.manifest_err(format!(
                        "graph '{}': tensor '{name}' has shape {}; expected the batch axis first and only there",
                        g.name,
                        shape_string(shape)
                    )));
                }
            }
        }
        Ok(())
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
    serde_json::from_value(value).map_err(|e| BundleError::Manifest {
        path: path.to_path_buf(),
        detail: e.to_string(),
    })
}

fn onnx_dtype(elem_type: i32) -> Option<DType> {
    match elem_type {
        1 => Some(DType::F32),
        7 => Some(DType::I64),
        _ => None,
    }
}

fn onnx_dtype_name(elem_type: i32) -> String {
    match elem_type {
        1 => "float32".into(),
        7 => "int64".into(),
        6 => "int32".into(),
        10 => "float16".into(),
        11 => "float64".into(),
        9 => "bool".into(),
        other => format!("ONNX element type {other}"),
    }
}

/// Checks a graph's ONNX inputs/outputs (names, order, dtypes, ranks, fixed dims) against the manifest.
fn check_graph_io(g: &GraphSpec, path: &Path, bytes: &[u8]) -> Result<(), BundleError> {
    let proto: pb::ModelProto = tract_onnx::onnx()
        .proto_model_for_read(&mut &bytes[..])
        .map_err(|e| BundleError::BadOnnx {
            path: path.to_path_buf(),
            detail: format!("{e:#}"),
        })?;
    let graph = proto.graph.as_ref().ok_or_else(|| BundleError::BadOnnx {
        path: path.to_path_buf(),
        detail: "the model has no graph".into(),
    })?;
    let mismatch = |detail: String| BundleError::GraphMismatch {
        path: path.to_path_buf(),
        graph: g.name.clone(),
        detail,
    };
    let initializers: std::collections::HashSet<&str> =
        graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let actual_inputs: Vec<&pb::ValueInfoProto> = graph
        .input
        .iter()
        .filter(|v| !initializers.contains(v.name.as_str()))
        .collect();
    for (kind, actual, expected) in [
        ("inputs", actual_inputs, g.all_inputs()),
        ("outputs", graph.output.iter().collect(), g.all_outputs()),
    ] {
        let an: Vec<&str> = actual.iter().map(|v| v.name.as_str()).collect();
        let en: Vec<&str> = expected.iter().map(|e| e.0).collect();
        if an != en {
            return Err(mismatch(format!(
                "{kind} are {an:?} in the ONNX file, manifest.json lists {en:?}"
            )));
        }
        for (v, (name, dtype, shape)) in actual.iter().zip(&expected) {
            let Some(pb::type_proto::Value::TensorType(t)) =
                v.r#type.as_ref().and_then(|t| t.value.as_ref())
            else {
                return Err(mismatch(format!(
                    "'{name}' is not a tensor in the ONNX file"
                )));
            };
            if onnx_dtype(t.elem_type) != Some(*dtype) {
                return Err(mismatch(format!(
                    "'{name}' is {} in the ONNX file, manifest.json says {}",
                    onnx_dtype_name(t.elem_type),
                    dtype
                )));
            }
            let Some(s) = t.shape.as_ref() else {
                return Err(mismatch(format!("'{name}' has no shape in the ONNX file")));
            };
            if s.dim.len() != shape.len() {
                return Err(mismatch(format!(
                    "'{name}' has rank {} in the ONNX file, manifest.json says rank {} {}",
                    s.dim.len(),
                    shape.len(),
                    shape_string(shape)
                )));
            }
            for (axis, (d, e)) in s.dim.iter().zip(shape.iter()).enumerate() {
                use pb::tensor_shape_proto::dimension::Value as DV;
                match (d.value.as_ref(), e) {
                    (Some(DV::DimValue(a)), Dim::Fixed(b)) if *a == *b as i64 => {}
                    // symbolic in the file: the batch axis, or a size the exporter could not fold
                    // (checked on every run instead)
                    (Some(DV::DimParam(_)) | None, _) => {}
                    (actual, _) => {
                        let a = match actual {
                            Some(DV::DimValue(a)) => a.to_string(),
                            Some(DV::DimParam(p)) => format!("'{p}'"),
                            None => "?".into(),
                        };
                        return Err(mismatch(format!(
                            "'{name}' axis {axis} is {a} in the ONNX file, manifest.json says {e} (shape {})",
                            shape_string(shape)
                        )));
                    }
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dims_parse() {
        let d: Vec<Dim> = serde_json::from_str(r#"["batch", 4, 32]"#).unwrap();
        assert_eq!(d, vec![Dim::Batch, Dim::Fixed(4), Dim::Fixed(32)]);
        assert!(serde_json::from_str::<Vec<Dim>>(r#"["time"]"#).is_err());
        assert_eq!(concrete_shape(&d, 3), vec![3, 4, 32]);
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
}

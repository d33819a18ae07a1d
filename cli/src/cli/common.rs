//! Options shared by the subcommands, and error classification for exit codes.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::ValueEnum;

use livegesture::audio::AudioError;
use livegesture::backend::{self, BackendKind, BackendOptions};
use livegesture::bundle::{default_bundle_dir, Bundle, BundleError};
use livegesture::model::GraphForm;
use livegesture::model::{self, MotionModel, StreamOptions};

/// An error caused by the user's input or arguments (exit code 2): the library's one input error.
pub use livegesture::generate::InputError;

/// Exit code for an error: 2 for bad input (audio, bundle, arguments), 1 otherwise.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    let input = e
        .chain()
        .any(|c| c.is::<InputError>() || c.is::<AudioError>() || c.is::<BundleError>());
    if input {
        2
    } else {
        1
    }
}

/// Which inference backend runs the graphs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BackendArg {
    /// tract: pure Rust, CPU (default).
    Tract,
    /// ONNX Runtime, loaded from ORT_DYLIB_PATH or an installed onnxruntime Python package.
    Ort,
}

impl From<BackendArg> for BackendKind {
    fn from(b: BackendArg) -> Self {
        match b {
            BackendArg::Tract => BackendKind::Tract,
            BackendArg::Ort => BackendKind::Ort,
        }
    }
}

/// Bundle and backend selection.
#[derive(Debug, Clone, clap::Args)]
pub struct ModelArgs {
    /// Model bundle folder (default: $LIVEGESTURE_BUNDLE, else the repository's models/default).
    #[arg(long, value_name = "DIR")]
    pub bundle: Option<PathBuf>,
    /// Inference backend.
    #[arg(long, value_enum, default_value_t = BackendArg::Tract)]
    pub backend: BackendArg,
    /// Execution provider for --backend ort (cpu, cuda, openvino, xnnpack, ...).
    #[arg(long, value_name = "EP", default_value = "cpu")]
    pub ep: String,
    /// Intra-op threads for --backend ort.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub threads: usize,
    /// ONNX Runtime shared library for --backend ort (default: $ORT_DYLIB_PATH, else searched).
    #[arg(long, value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
}

/// DiffSHEG's sampling schedule and windows (`generate`, `stream`, `bench`).
#[derive(Debug, Clone, clap::Args)]
pub struct DiffshegArgs {
    /// DiffSHEG: DDIM steps, must divide 1000 (default: the bundle's; the paper's 25).
    #[arg(long, value_name = "S")]
    pub ddim_steps: Option<usize>,
    /// DiffSHEG: RePaint jumps per DDIM step, >= 1 (default: the bundle's, 2).
    #[arg(long, value_name = "U")]
    pub jumps: Option<usize>,
    /// DiffSHEG: window length in frames, <= the bundle's max window (default: the bundle's; 88 at 30 fps).
    #[arg(long, value_name = "N")]
    pub window: Option<usize>,
    /// DiffSHEG: overlap of consecutive windows in frames, < window (default: the bundle's; 10).
    #[arg(long, value_name = "L")]
    pub overlap: Option<usize>,
}

/// Generation settings.
#[derive(Debug, Clone, clap::Args)]
pub struct GenArgs {
    /// Seed of the sampler (one seed gives one motion on every backend).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Classifier-free guidance scale gamma (default: the bundle's; 1.0 disables guidance).
    #[arg(long, value_name = "G")]
    pub guidance: Option<f64>,
    /// Sampling temperature, > 0 (default: the bundle's).
    #[arg(long, value_name = "T")]
    pub temperature: Option<f64>,
    /// Keep the K most likely tokens, 0 = all (default: the bundle's).
    #[arg(long, value_name = "K")]
    pub top_k: Option<usize>,
    #[command(flatten)]
    pub diffsheg: DiffshegArgs,
    /// DiffSHEG: last DDIM steps that blend the overlap linearly (default: the bundle's, 2).
    #[arg(long, value_name = "B")]
    pub blend_steps: Option<usize>,
    /// DiffSHEG: style (speaker) id (default: the bundle's).
    #[arg(long, value_name = "ID")]
    pub speaker: Option<usize>,
}

impl GenArgs {
    /// Stream options (checked where every door's are: [`livegesture::generate::new_stream`]).
    pub fn stream_options(&self) -> Result<StreamOptions> {
        Ok(StreamOptions {
            seed: self.seed,
            guidance: self.guidance,
            temperature: self.temperature,
            top_k: self.top_k,
            record_logits: false,
            ddim_steps: self.diffsheg.ddim_steps,
            jumps: self.diffsheg.jumps,
            window: self.diffsheg.window,
            overlap: self.diffsheg.overlap,
            blend_steps: self.blend_steps,
            speaker: self.speaker,
        })
    }
}

impl ModelArgs {
    /// Loads and verifies the bundle.
    pub fn bundle(&self) -> Result<Bundle> {
        let dir = default_bundle_dir(self.bundle.as_deref());
        Ok(Bundle::load(&dir)?)
    }

    /// The backend settings of these arguments (a non-CPU execution provider without ort is an
    /// input error).
    pub fn backend_options(&self) -> Result<BackendOptions> {
        let opts = BackendOptions {
            kind: self.backend.into(),
            execution_provider: self.ep.clone(),
            intra_threads: self.threads.max(1),
            ort_library: self.ort_lib.clone(),
        };
        if opts.kind == BackendKind::Tract && !opts.execution_provider.eq_ignore_ascii_case("cpu") {
            return Err(InputError::new(format!(
                "--ep {} needs --backend ort (tract runs on the CPU only)",
                opts.execution_provider
            ))
            .into());
        }
        Ok(opts)
    }

    /// Creates the backend and loads the bundle's model (whichever its family), the region eXperts
    /// of a LiveGesture bundle in the form `form` (`--form`).
    pub fn model(&self, bundle: &Bundle, form: GraphForm) -> Result<Box<dyn MotionModel>> {
        check_form(bundle, form)?;
        let be = backend::create(&self.backend_options()?)?;
        model::load_with(bundle, be.as_ref(), &model::LoadOptions { form }).with_context(|| {
            format!(
                "loading the bundle {} with {}",
                bundle.dir().display(),
                be.describe()
            )
        })
    }
}

/// `--form` chooses among a LiveGesture bundle's forms; a bundle of a family with one form refuses
/// it (input error).
pub fn check_form(bundle: &Bundle, form: GraphForm) -> Result<()> {
    model::check_load_options(bundle, &model::LoadOptions { form })
        .map_err(|e| InputError::new(format!("--form {form}: {e:#}")).into())
}

/// A new stream of `model` ([`livegesture::generate::new_stream`], where every door's options are
/// checked); options refused (out of range, or of another family) are input errors (exit code 2).
pub fn new_stream(
    model: &dyn livegesture::model::MotionModel,
    opts: &StreamOptions,
) -> Result<Box<dyn livegesture::model::MotionStream>> {
    livegesture::generate::new_stream(model, opts)
}

/// The text of `e` as the CLI prints it: the causes joined by `: ` (as `{:#}` does), each input
/// error's fields spelled as this program's flags (`ddim_steps` -> `--ddim-steps`).
pub fn error_text(e: &anyhow::Error) -> String {
    e.chain()
        .map(|c| match c.downcast_ref::<InputError>() {
            Some(ie) => ie.render(flag),
            None => c.to_string(),
        })
        .collect::<Vec<_>>()
        .join(": ")
}

/// The flag of a [`StreamOptions`] field: `top_k` -> `--top-k`.
pub fn flag(field: &str) -> String {
    format!("--{}", field.replace('_', "-"))
}

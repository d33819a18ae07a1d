//! Command-line interface: argument definitions and dispatch.
//!
//! Adding a subcommand: write `src/cli/<name>.rs` with an `Args` struct (clap `Args` derive) and a
//! `run(args: Args) -> anyhow::Result<()>`, then add its line to [`Command`] and [`run`].
//!
//! No subcommand names a model family: `generate`, `stream` and `serve` run any bundle through
//! [`livegesture::model::load_with`] and the [`livegesture::model::MotionStream`] trait, `info` prints
//! the family-common manifest and [`livegesture::model::describe`], and `parity` / `bench` call the
//! library's `parity::run` / `bench::run_family`, which reach the family's code through
//! [`livegesture::model::for_family`].

use clap::{Parser, Subcommand};
use livegesture::model::GraphForm;

#[cfg(feature = "bench")]
pub mod bench;
pub mod common;
pub mod generate;
pub mod info;
#[cfg(feature = "loadtest")]
pub mod loadtest;
#[cfg(feature = "parity")]
pub mod parity;
#[cfg(feature = "serve")]
pub mod serve;
pub mod stream;

pub use common::{error_text, exit_code};

/// `livegesture --version`: the crate version, the commit it was built from and the target triple
/// (set by cli/build.rs), e.g. `0.1.0 (commit a6aad43f1c2e, x86_64-unknown-linux-musl)`.
pub const VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (commit ",
    env!("LIVEGESTURE_COMMIT"),
    ", ",
    env!("LIVEGESTURE_TARGET"),
    ")"
);

/// Streaming speech-driven full-body gesture generation (ONNX bundles, tract or ONNX Runtime).
///
/// Audio goes in (a WAV file or raw PCM on stdin); SMPL-X motion at 30 fps comes out, covering the
/// whole audio (ceil(duration x 30) frames). The bundle's family picks the model: livegesture emits
/// four frames per 133.3 ms motion token, with zero look-ahead. Without --bundle the bundle is $LIVEGESTURE_BUNDLE,
/// else one installed beside the executable (../share/livegesture/models/default or models/default),
/// else the repository's models/default.
#[derive(Debug, Parser)]
#[command(
    name = "livegesture",
    version = VERSION,
    about,
    long_about,
    propagate_version = true
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// LiveGesture: form of the region eXperts, fusion and decoders (docs/bundle.md#forms-and-precision): auto (the bundle's
    /// form for the backend, see `info`), canonical (one graph per region), fused (one graph for the
    /// four regions), attention (the fusion with the ONNX Attention op, `fusion_attention`), or
    /// fused_ring / attention_ring (those two on ring caches, docs/bundle.md#ring-caches).
    #[arg(
        long,
        global = true,
        value_name = "FORM",
        env = "LIVEGESTURE_FORM",
        default_value = "auto"
    )]
    pub form: GraphForm,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Generate motion for a WAV file and write a BEAT2 .npz.
    Generate(generate::Args),
    /// Generate motion live from raw PCM on stdin; frames on stdout as JSON lines or binary records.
    Stream(stream::Args),
    /// Describe a bundle: model, regions, graphs, state size, sampling defaults, provenance.
    Info(info::Args),
    #[cfg(feature = "parity")]
    /// Check a bundle's parity: every graph vs the torch reference vectors on ort and tract, the
    /// whole seeded rollout, the log-mel frontend, chunk-size and batch invariance (docs/parity.md).
    Parity(parity::Args),
    #[cfg(feature = "bench")]
    /// Benchmark a bundle on one core: step times per graph and whole chain, first-frame latency,
    /// state bytes, peak RSS, real-time streams per core with batched stepping.
    Bench(bench::Args),
    #[cfg(feature = "serve")]
    /// Serve live sessions over WebSocket (docs/serve.md), stepped together in batches; the browser page at /.
    Serve(serve::Args),
    #[cfg(feature = "loadtest")]
    /// Load-test a running server: real-time speech sessions ramped until p99 token latency crosses
    /// a bound; sessions held per core, latency and server CPU as a table, JSON and an SVG plot.
    Loadtest(loadtest::Args),
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let form = cli.form;
    match cli.command {
        Command::Generate(a) => generate::run(a, form),
        Command::Stream(a) => stream::run(a, form),
        Command::Info(a) => info::run(a),
        #[cfg(feature = "parity")]
        Command::Parity(a) => parity::run(a, form),
        #[cfg(feature = "bench")]
        Command::Bench(a) => bench::run(a, form),
        #[cfg(feature = "serve")]
        Command::Serve(a) => serve::run(a, form),
        #[cfg(feature = "loadtest")]
        Command::Loadtest(a) => loadtest::run(a),
    }
}

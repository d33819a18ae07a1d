//! Command-line interface: argument definitions and dispatch.
//!
//! Adding a subcommand: write `src/cli/<name>.rs` with an `Args` struct (clap `Args` derive) and a
//! `run(args: Args) -> anyhow::Result<()>`, then add its line to [`Command`] and [`run`].

use clap::{Parser, Subcommand};

pub mod bench;
pub mod common;
pub mod generate;
pub mod info;
pub mod parity;
pub mod serve;
pub mod stream;

pub use common::exit_code;

/// Streaming speech-driven full-body gesture generation (LiveGesture ONNX bundles, tract or ONNX Runtime).
///
/// Audio goes in (a WAV file or raw PCM on stdin); SMPL-X motion at 30 fps comes out, four frames per
/// 133.3 ms motion token, with zero look-ahead. Without --bundle the bundle is $LIVEGESTURE_BUNDLE,
/// else the repository's models/default.
#[derive(Debug, Parser)]
#[command(
    name = "livegesture",
    version,
    about,
    long_about,
    propagate_version = true
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Generate motion for a WAV file and write a BEAT2 .npz.
    Generate(generate::Args),
    /// Generate motion live from raw PCM on stdin; frames on stdout as JSON lines or binary records.
    Stream(stream::Args),
    /// Describe a bundle: model, regions, graphs, state size, sampling defaults, provenance.
    Info(info::Args),
    /// Check a bundle's parity: every graph vs the torch reference vectors on ort and tract, the
    /// whole seeded rollout, the log-mel frontend, chunk-size and batch invariance (SPEC section 7).
    Parity(parity::Args),
    /// Benchmark a bundle on one core: step times per graph and whole chain, first-frame latency,
    /// state bytes, peak RSS, real-time streams per core with batched stepping.
    Bench(bench::Args),
    /// Serve live sessions over WebSocket (SPEC 12), stepped together in batches; the browser page at /.
    Serve(serve::Args),
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Generate(a) => generate::run(a),
        Command::Stream(a) => stream::run(a),
        Command::Info(a) => info::run(a),
        Command::Parity(a) => parity::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Serve(a) => serve::run(a),
    }
}

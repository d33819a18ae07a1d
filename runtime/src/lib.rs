//! LiveGesture runtime: streaming speech-to-gesture generation from exported ONNX bundles.
//!
//! The library API, for running a bundle:
//!
//! - [`bundle`]: loading and verifying a model bundle (`manifest.json` with its `family`, sha256 of
//!   every file, graph I/O);
//! - [`tensor`]: the crate's [`tensor::Tensor`] and [`tensor::DType`] (a leaf: bundles describe graph
//!   I/O with them, backends run on them);
//! - [`backend`]: the `Backend` trait and its two implementations, tract (default) and ort
//!   (re-exports the tensor types);
//! - [`model`]: the family-independent streaming API every door uses ([`model::MotionModel`] with its
//!   batch step [`model::MotionModel::step_many`], [`model::MotionStream`], [`model::load`] picks the
//!   family's implementation) and the families ([`model::livegesture`], [`model::diffsheg`]);
//! - [`diffusion`]: DiffSHEG's sampler settings and noise schedule (read from the manifest, used by
//!   the model);
//! - [`error`]: [`error::InputError`] (bad input and the options it concerns) and the error kinds
//!   every door maps ([`error::classify`]);
//! - [`generate`]: the whole-input path (`livegesture generate` and every binding's `generate`) and
//!   [`generate::PcmStream`], a stream fed with PCM at any sample rate (the bindings' streams);
//! - [`audio`]: WAV and raw PCM input, converted to 16 kHz mono, and [`audio::AudioSpan`] (how many
//!   frames cover an input);
//! - [`portable_parity`]: the parity checks that need no files, no onnxruntime and no clock (every
//!   graph vs its reference vectors, the reference rollout; the browser's parity) and the graph and
//!   rollout bounds of docs/parity.md;
//! - [`compare`]: the one NaN-safe comparison of two tensors against a scaled bound (docs/parity.md),
//!   used by the parity suite and the tests;
//! - [`frontend`]: the log-mel audio frontend (the Python training frontend's definition, within 1e-4);
//! - [`stats`]: the one quantile definition of the benchmark and load-test figures;
//! - [`sampling`]: the portable seeded sampler (SplitMix64 + guided top-k sampling);
//! - [`rotation`]: rot6d / matrix / quaternion / axis-angle conversions;
//! - [`output`]: frames, BEAT2 `.npz` files and live records (JSON lines and binary);
//! - [`skeleton`] and [`bvh`]: the project's own skeleton (SMPL-X joint names and hierarchy) and BVH
//!   output on it.
//!
//! The tools are crates of their own on this library and on no other tool (README.md "Map of the tree"):
//! `livegesture-parity` (tools/parity: the parity suite of docs/parity.md), `livegesture-bench`
//! (tools/bench: the benchmarks of BENCHMARKS.md), `livegesture-serve` (tools/serve: live serving over
//! WebSocket, docs/serve.md, and its load test) and the `livegesture` program (cli/) on all of them. A
//! program that only runs bundles depends on this crate alone (package `livegesture-core`).

pub mod audio;
pub mod backend;
pub mod bundle;
pub mod bvh;
pub mod compare;
pub mod diffusion;
pub mod error;
pub mod face;
pub mod frontend;
pub mod generate;
pub mod model;
pub mod output;
pub mod portable_parity;
pub mod rotation;
pub mod sampling;
pub mod skeleton;
pub mod stats;
pub mod tensor;

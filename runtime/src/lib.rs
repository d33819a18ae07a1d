//! LiveGesture runtime: streaming speech-to-gesture generation from exported ONNX bundles.
//!
//! Graph-independent numerics and IO:
//!
//! - [`frontend`]: the log-mel audio frontend (the Python training frontend's definition, within 1e-4);
//! - [`sampling`]: the portable seeded sampler (SplitMix64 + guided top-k sampling);
//! - [`rotation`]: rot6d / matrix / quaternion / axis-angle conversions;
//! - [`audio`]: WAV and raw PCM input, converted to 16 kHz mono;
//! - [`output`]: BEAT2 `.npz` files and per-frame live records (JSON lines and binary).
//!
//! Bundles and inference:
//!
//! - [`bundle`]: loading and verifying a model bundle (`manifest.json`, sha256 of every file, graph I/O);
//! - [`backend`]: the `Backend` trait and its two implementations, tract (default) and ort;
//! - [`pipeline`]: the streaming pipeline (streams, batched token steps, frames).

pub mod audio;
pub mod backend;
pub mod bench;
pub mod bundle;
pub mod bvh;
pub mod frontend;
pub mod output;
pub mod parity;
pub mod pipeline;
pub mod rotation;
pub mod sampling;
pub mod serve;
pub mod skeleton;

//! DiffSHEG (docs/bundle.md "DiffSHEG bundles"): windowed diffusion with outpainting (FOPPAS).
//!
//! - [`noise`]: the portable Gaussian noise (bit-identical to Python);
//! - [`schedule`]: the linear-beta table (from the manifest's exact bits) and DDIM timesteps;
//! - [`foppas`]: DDIM + classifier-free guidance + FOPPAS for one window, operation by operation;
//! - [`stream`]: one stream's windowing, buffer and carried state (`foppas.state`);
//! - [`graphs`]: the window's graph chain on a backend;
//! - [`model`]: [`DiffshegModel`] and [`DiffshegStream`], the family behind the [`crate::model`] traits;
//!   its child `model::batch` runs the windows due in several streams together
//!   ([`crate::model::MotionModel::step_many`]).
//!
//! The manifest sections are [`crate::bundle::DiffshegManifest`].

pub mod foppas;
pub mod graphs;
pub mod model;
pub mod noise;
pub mod reference;
/// The schedule lives in [`crate::diffusion`] (the bundle reads it too); re-exported under its old path.
pub use crate::diffusion::schedule;
pub mod stream;
pub use model::{describe, DiffshegModel, DiffshegStream};

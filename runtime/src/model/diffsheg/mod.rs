//! DiffSHEG (export/BUNDLE.md "DiffSHEG bundles"): windowed diffusion with outpainting (FOPPAS).
//!
//! - [`noise`]: the portable Gaussian noise (bit-identical to Python);
//! - [`schedule`]: the linear-beta table (from the manifest's exact bits) and DDIM timesteps;
//! - [`foppas`]: DDIM + classifier-free guidance + FOPPAS for one window, operation by operation;
//! - [`stream`]: one stream's windowing, buffer and carried state (`foppas.state`);
//! - [`graphs`]: the window's graph chain on a backend;
//! - [`sections`]: the manifest's DiffSHEG sections.

pub mod foppas;
pub mod graphs;
pub mod noise;
pub mod reference;
pub mod schedule;
pub mod sections;
pub mod stream;

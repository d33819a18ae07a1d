//! The core library's integration tests, one module per area, in one test binary (one link of the
//! runtime instead of one per file). The shared helpers are the project's test fixture, the
//! `livegesture-parity-tests` crate (`common` in the modules).

mod bundle;
mod bundle_bytes;
mod coverage;
mod diffsheg_sampler;
mod face;
mod no_flags_in_core;
mod numerics;
mod pipeline;
mod portable_parity;
mod ring;
mod run_into;
mod step_many;
mod tract_plans;
mod tract_rows;
mod tract_softmax;

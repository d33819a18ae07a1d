//! The fuzz targets' shared entry points (see `harness.rs`, also compiled by the stable regression
//! test `cli/tests/it/fuzz_regressions.rs`). A module, not `include!`: the harness starts with inner
//! doc comments, which `include!` cannot take.

#[path = "../harness.rs"]
mod harness;

pub use harness::*;

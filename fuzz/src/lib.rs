//! The fuzz targets' shared entry points (see `harness.rs`, also compiled by the stable regression
//! test `runtime/tests/fuzz_regressions.rs`).

include!("../harness.rs");

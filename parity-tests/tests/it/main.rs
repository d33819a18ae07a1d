//! The parity suite's integration tests, one module per area, in one test binary (one link of the
//! runtime and the suite instead of one per file). The shared helpers are this crate's library
//! (`livegesture_parity_tests`: test bundles, breaking them, running parity and Python).

mod against;
mod broken_bundles;
mod bundles;
mod divergence;
mod must_fail;
mod reduced_precision;

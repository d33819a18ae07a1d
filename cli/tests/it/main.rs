//! The `livegesture` program's integration tests, one module per area, in one test binary (each
//! integration-test file used to be a binary of its own, linking the whole runtime again). The
//! helpers several modules share: [`support`] (the program's command) and [`serve_common`] (a
//! server, its clients, `generate` to compare with); the project's test fixture (bundles, Python,
//! the reference rollout) is the `livegesture-parity-tests` crate (`common` in the modules).

#[cfg(feature = "bench")]
mod bench;
mod cli;
mod diffsheg_cli;
#[cfg(feature = "parity")]
mod forms;
mod fuzz_regressions;
mod gltf_cli;
mod install;
#[cfg(feature = "loadtest")]
mod loadtest;
#[cfg(feature = "parity")]
mod parity_cli;
#[cfg(feature = "serve")]
mod serve;
#[cfg(feature = "serve")]
mod serve_access;
#[cfg(feature = "serve")]
mod serve_common;
#[cfg(feature = "serve")]
mod serve_diffsheg;
#[cfg(feature = "serve")]
mod serve_web_dir;
mod support;

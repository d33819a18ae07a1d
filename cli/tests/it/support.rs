//! What every module that runs the program shares: the `livegesture` binary as a command (without
//! the caller's `LIVEGESTURE_BUNDLE`, so that no test picks up a bundle from the environment), a
//! run of it, and its output as text.

use std::process::{Command, Output};

/// The `livegesture` binary built for these tests, `LIVEGESTURE_BUNDLE` removed.
pub fn livegesture() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_livegesture"));
    c.env_remove("LIVEGESTURE_BUNDLE");
    c
}

/// Runs `livegesture args...` to the end.
pub fn run(args: &[&str]) -> Output {
    livegesture().args(args).output().expect("run livegesture")
}

/// stdout, a newline, stderr.
pub fn text(o: &Output) -> String {
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

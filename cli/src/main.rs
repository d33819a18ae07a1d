//! `livegesture`: streaming speech-to-gesture generation from an exported LiveGesture bundle.
//!
//! Subcommands live in `src/cli/` (one file each). Exit codes: 0 success, 1 runtime error,
//! 2 usage error or bad input (unreadable audio, invalid bundle, bad arguments). Errors go to stderr,
//! data to stdout (or to the file named with `-o`).

mod cli;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    restore_sigpipe();
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("livegesture: error: {}", cli::error_text(&e));
            ExitCode::from(cli::exit_code(&e))
        }
    }
}

/// Behave like other Unix filters when the reader goes away (`livegesture info | head`): exit quietly
/// on SIGPIPE instead of panicking on a failed write to stdout. (Windows has no SIGPIPE.)
#[cfg(unix)]
fn restore_sigpipe() {
    // SAFETY: restoring the default disposition of one signal before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(unix))]
fn restore_sigpipe() {}

//! Replays the fuzz targets' inputs on stable (the fuzzers themselves need nightly: `fuzz/`): every
//! file under `fuzz/regressions/<target>/` (inputs that once crashed, hung or exhausted memory) and
//! the committed corpus `fuzz/corpus/<target>/` goes through the same entry points
//! (`fuzz/harness.rs`), which must return without panicking.

use std::path::{Path, PathBuf};

#[path = "../../../fuzz/harness.rs"]
mod harness;

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("fuzz")
}

/// Runs every input of `target` through `f`; returns how many there were.
fn replay(target: &str, f: fn(&[u8])) -> usize {
    let mut n = 0;
    for kind in ["regressions", "corpus"] {
        let dir = fuzz_dir().join(kind).join(target);
        let Ok(rd) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut files: Vec<PathBuf> = rd.filter_map(|e| e.ok()).map(|e| e.path()).collect();
        files.sort();
        for p in files {
            let data = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            eprintln!("{target}: {}", p.display());
            f(&data);
            n += 1;
        }
    }
    assert!(
        n > 0,
        "no inputs for the fuzz target {target} under {}",
        fuzz_dir().display()
    );
    n
}

#[test]
fn wav_inputs_are_refused_or_read() {
    replay("wav", harness::wav);
}

#[test]
fn raw_pcm_inputs_are_refused_or_read() {
    replay("raw_pcm", harness::raw_pcm);
}

#[test]
fn manifest_inputs_are_refused_or_read() {
    replay("manifest", harness::manifest);
}

#[cfg(feature = "serve")]
#[test]
fn serve_protocol_inputs_are_refused_or_handled() {
    replay("serve_protocol", harness::serve_protocol);
}

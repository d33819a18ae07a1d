//! Helpers of the parity suite's integration tests (`tests/*.rs`).
//!
//! The tests run [`livegesture::parity`] (the library behind `livegesture parity`) on
//!
//! - the shipped bundle `models/default` ([`default_bundle`]);
//! - a tiny random-weight bundle exported in the same run ([`tiny_bundle`]): the test command
//!   exports it and passes its folder in `LIVEGESTURE_TINY_BUNDLE`; without that variable the first
//!   test that needs it exports one with `$LIVEGESTURE_PY export/export.py --config tiny --out DIR`
//!   into `target/tmp/parity-tests/tiny-<hash of the exporter's sources>` (under a file lock, so
//!   parallel test processes export it once; a change to the exporter or the model re-exports);
//!   without either variable the tests fail saying so (they never skip);
//! - copies of a bundle with one graph broken by `tools/break_bundle.py` ([`break_bundle`]).
//!
//! Both backends run: ort needs ONNX Runtime (`ORT_DYLIB_PATH`, set by `source scripts/env.sh`).

use std::fs::File;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use livegesture::parity::{self, Check, ParityOptions, Report};

/// Environment variable naming a tiny bundle exported by the test command.
pub const TINY_BUNDLE_ENV: &str = "LIVEGESTURE_TINY_BUNDLE";

/// The repository root.
pub fn repo_root() -> PathBuf {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent().unwrap_or(here).to_path_buf()
}

/// The shipped bundle (read-only: tests never write into it).
pub fn default_bundle() -> PathBuf {
    repo_root().join("models").join("default")
}

/// The project's Python (`$LIVEGESTURE_PY`), or a panic saying how to get it.
pub fn python(why: &str) -> PathBuf {
    match std::env::var_os("LIVEGESTURE_PY").filter(|v| !v.is_empty()) {
        Some(p) if Path::new(&p).exists() => PathBuf::from(p),
        Some(p) => panic!(
            "LIVEGESTURE_PY={} does not exist; `source scripts/env.sh` sets it ({why})",
            Path::new(&p).display()
        ),
        None => panic!(
            "LIVEGESTURE_PY is not set: {why} needs the project's Python with torch and onnx \
             (`source scripts/env.sh` sets it)"
        ),
    }
}

fn hash_sources(h: &mut impl Hasher, dir: &Path) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = rd.filter_map(|e| e.ok()).map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if p.is_dir() {
            if !name.starts_with('_') && !name.starts_with('.') && name != "tests" {
                hash_sources(h, &p);
            }
        } else if name.ends_with(".py") {
            name.hash(h);
            std::fs::read(&p).unwrap_or_default().hash(h);
        }
    }
}

fn export_tiny() -> PathBuf {
    let root = repo_root();
    let mut h = std::collections::hash_map::DefaultHasher::new();
    hash_sources(&mut h, &root.join("export"));
    hash_sources(&mut h, &root.join("python").join("livegesture"));
    let base = root.join("target").join("tmp").join("parity-tests");
    std::fs::create_dir_all(&base)
        .unwrap_or_else(|e| panic!("cannot create {}: {e}", base.display()));
    let dir = base.join(format!("tiny-{:016x}", h.finish()));
    let lock = File::create(base.join(".lock")).expect("create the export lock file");
    lock.lock().expect("lock the export lock file");
    if !dir.join("manifest.json").exists() {
        let py = python(&format!(
            "exporting the tiny bundle (or set {TINY_BUNDLE_ENV} to one exported with \
             `$LIVEGESTURE_PY export/export.py --config tiny --out DIR`)"
        ));
        eprintln!("exporting a tiny bundle into {} ...", dir.display());
        let out = Command::new(&py)
            .arg(root.join("export").join("export.py"))
            .args(["--config", "tiny", "--out"])
            .arg(&dir)
            .current_dir(&root)
            .output()
            .unwrap_or_else(|e| panic!("cannot run {}: {e}", py.display()));
        assert!(
            out.status.success(),
            "exporting the tiny bundle failed ({}):\n{}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let _ = lock.unlock();
    dir
}

/// The tiny bundle of this run (see the crate docs).
pub fn tiny_bundle() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(
        || match std::env::var_os(TINY_BUNDLE_ENV).filter(|v| !v.is_empty()) {
            Some(p) => {
                let p = PathBuf::from(p);
                assert!(
                    p.join("manifest.json").is_file(),
                    "{TINY_BUNDLE_ENV}={} has no manifest.json (export one with \
                 `$LIVEGESTURE_PY export/export.py --config tiny --out DIR`)",
                    p.display()
                );
                p
            }
            None => export_tiny(),
        },
    )
    .clone()
}

/// How `tools/break_bundle.py` breaks the copy.
#[derive(Debug, Clone)]
pub enum Breakage {
    /// Add `delta` to one element of a MatMul/Gemm weight initializer.
    PerturbWeight { delta: f64 },
    /// Return the input cache `cache.<name>` unchanged as `new_cache.<name>`.
    FreezeCache { name: String },
}

/// Copies `src` to `dst` with `graph` broken as `how` says (manifest sha256 rewritten so the copy
/// loads); returns the script's JSON description of the change.
pub fn break_bundle(src: &Path, dst: &Path, graph: &str, how: &Breakage) -> serde_json::Value {
    let py = python("tools/break_bundle.py");
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tools")
        .join("break_bundle.py");
    let mut cmd = Command::new(&py);
    cmd.arg(&script).arg(src).arg(dst).args(["--graph", graph]);
    match how {
        Breakage::PerturbWeight { delta } => {
            cmd.arg("--perturb-weight").arg(format!("--delta={delta}"));
        }
        Breakage::FreezeCache { name } => {
            cmd.args(["--freeze-cache", name]);
        }
    }
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", py.display()));
    assert!(
        out.status.success(),
        "break_bundle.py failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.trim())
        .unwrap_or_else(|e| panic!("break_bundle.py printed no JSON ({e}): {text}"))
}

/// Runs the parity suite on `dir` with both backends and the given checks (all when empty),
/// printing progress and the table to stderr (shown by the test harness on failure or with
/// `--nocapture`).
pub fn run_parity(dir: &Path, checks: &[Check]) -> Report {
    let opts = ParityOptions {
        checks: if checks.is_empty() {
            Check::ALL.to_vec()
        } else {
            checks.to_vec()
        },
        ..Default::default()
    };
    let mut log = |m: &str| eprintln!("parity: {m}");
    let report = parity::run(dir, &opts, &mut log)
        .unwrap_or_else(|e| panic!("parity could not run on {}: {e:#}", dir.display()));
    eprintln!("{}\n{}", report.table(false), report.summary());
    report
}

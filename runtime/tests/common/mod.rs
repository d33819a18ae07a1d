//! Shared helpers of the bundle, pipeline and CLI tests.
//!
//! # The test bundle
//!
//! Tests run against a tiny random-weight bundle. Set `LIVEGESTURE_TEST_BUNDLE` to a bundle folder
//! to use one you exported, e.g.
//!
//! ```sh
//! source scripts/env.sh
//! $LIVEGESTURE_PY export/export.py --config tiny --out /tmp/lg-test-bundle --rollout-tokens 8 --reference-seconds 3
//! LIVEGESTURE_TEST_BUNDLE=/tmp/lg-test-bundle cargo test --release -p livegesture
//! ```
//!
//! Otherwise the first test that needs it exports one with `$LIVEGESTURE_PY` (set by
//! `scripts/env.sh`; `scripts/test.sh` sources it) into `target/tmp/test-bundles/tiny-<hash of the
//! export sources>`, under a file lock so parallel test processes (nextest) export it once; later
//! runs reuse it. Without either variable the tests fail with a message saying so.
#![allow(dead_code)]

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use ndarray::{Array0, Array2};
use ndarray_npy::NpzReader;
use sha2::{Digest, Sha256};

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .canonicalize()
        .expect("repo root")
}

fn tmp_root() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
}

/// The Python interpreter with torch/onnx (`LIVEGESTURE_PY`, else the project venv if one exists).
pub fn python() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("LIVEGESTURE_PY").filter(|v| !v.is_empty()) {
        return Some(PathBuf::from(p));
    }
    let venv = std::env::var_os("LIVEGESTURE_VENV")
        .map(PathBuf::from)
        .or_else(|| {
            let home = PathBuf::from(std::env::var_os("HOME")?);
            let mut v: Vec<PathBuf> = std::fs::read_dir(home.join(".cache/livegesture"))
                .ok()?
                .filter_map(|e| e.ok())
                .map(|e| e.path())
                .filter(|p| p.join(".complete").exists())
                .collect();
            v.sort();
            v.pop()
        })?;
    let py = venv.join("bin/python");
    py.exists().then_some(py)
}

fn hash_sources(h: &mut Sha256, dir: &Path) {
    let mut entries: Vec<PathBuf> = match std::fs::read_dir(dir) {
        Ok(rd) => rd.filter_map(|e| e.ok()).map(|e| e.path()).collect(),
        Err(_) => return,
    };
    entries.sort();
    for p in entries {
        if p.is_dir() {
            if !p
                .file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with('_') || n == "tests")
            {
                hash_sources(h, &p);
            }
        } else if p.extension().is_some_and(|e| e == "py") {
            h.update(p.to_string_lossy().as_bytes());
            h.update(std::fs::read(&p).unwrap_or_default());
        }
    }
}

const EXPORT_ARGS: &[&str] = &[
    "--config",
    "tiny",
    "--rollout-tokens",
    "8",
    "--reference-seconds",
    "3",
];

fn export_bundle() -> PathBuf {
    let root = repo_root();
    let mut h = Sha256::new();
    h.update(EXPORT_ARGS.join(" ").as_bytes());
    hash_sources(&mut h, &root.join("export"));
    hash_sources(&mut h, &root.join("python/livegesture"));
    let key = hex::encode(h.finalize());
    let base = tmp_root().join("test-bundles");
    std::fs::create_dir_all(&base).expect("create target/tmp/test-bundles");
    let dir = base.join(format!("tiny-{}", &key[..16]));
    let lock = File::create(base.join(".lock")).expect("create the export lock file");
    lock.lock().expect("lock the export lock file");
    if !dir.join("manifest.json").exists() {
        let py = python().unwrap_or_else(|| {
            panic!(
                "no test bundle: set LIVEGESTURE_TEST_BUNDLE to a bundle folder, or LIVEGESTURE_PY to the project's \
                 Python (`source scripts/env.sh`) so the tests can export a tiny one"
            )
        });
        eprintln!("exporting the tiny test bundle into {} ...", dir.display());
        let out = Command::new(&py)
            .arg(root.join("export/export.py"))
            .args(EXPORT_ARGS)
            .arg("--out")
            .arg(&dir)
            .current_dir(&root)
            .output()
            .unwrap_or_else(|e| panic!("cannot run {}: {e}", py.display()));
        assert!(
            out.status.success(),
            "exporting the test bundle failed ({}):\n{}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let _ = lock.unlock();
    dir
}

/// The test bundle folder (see the module docs).
pub fn bundle_dir() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        match std::env::var_os("LIVEGESTURE_TEST_BUNDLE").filter(|v| !v.is_empty()) {
            Some(p) => {
                let p = PathBuf::from(p);
                assert!(
                    p.join("manifest.json").exists(),
                    "LIVEGESTURE_TEST_BUNDLE={} has no manifest.json",
                    p.display()
                );
                p
            }
            None => export_bundle(),
        }
    })
    .clone()
}

/// Copies the test bundle into a fresh temporary folder (for corruption tests).
pub fn copy_bundle(to: &Path) -> PathBuf {
    fn copy_dir(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let e = e.unwrap();
            let p = e.path();
            if p.is_dir() {
                copy_dir(&p, &to.join(e.file_name()));
            } else {
                std::fs::copy(&p, to.join(e.file_name())).unwrap();
            }
        }
    }
    let dst = to.join("bundle");
    copy_dir(&bundle_dir(), &dst);
    dst
}

/// The bundle's reference rollout.
pub struct Rollout {
    pub tokens: Array2<i64>,
    pub poses: Array2<f32>,
    pub trans: Array2<f32>,
    pub expressions: Array2<f32>,
    pub foot_contact: Array2<f32>,
    pub seed: u64,
    pub clip_repeats: usize,
}

/// Reads `reference/rollout.npz` (written with `np.savez_compressed`).
pub fn rollout(bundle: &Path) -> Rollout {
    let src = bundle.join("reference/rollout.npz");
    let f = File::open(&src).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
    let mut npz = NpzReader::new(f).unwrap_or_else(|e| panic!("{}: {e}", src.display()));
    let seed: Array0<u64> = npz.by_name("seed").expect("rollout seed");
    let reps: Array0<i64> = npz.by_name("clip_repeats").expect("rollout clip_repeats");
    Rollout {
        tokens: npz.by_name("tokens").expect("rollout tokens"),
        poses: npz.by_name("poses").expect("rollout poses"),
        trans: npz.by_name("trans").expect("rollout trans"),
        expressions: npz.by_name("expressions").expect("rollout expressions"),
        foot_contact: npz.by_name("foot_contact").expect("rollout foot_contact"),
        seed: seed.into_scalar(),
        clip_repeats: reps.into_scalar() as usize,
    }
}

/// The ort library for tests: `ORT_DYLIB_PATH` must be set (`source scripts/env.sh`).
pub fn require_ort() {
    match std::env::var_os("ORT_DYLIB_PATH") {
        Some(p) if Path::new(&p).is_file() => {}
        Some(p) => panic!("ORT_DYLIB_PATH={} does not exist; `source scripts/env.sh`", Path::new(&p).display()),
        None => panic!("ORT_DYLIB_PATH is not set: the ort backend tests need ONNX Runtime (`source scripts/env.sh` sets it)"),
    }
}

/// Max abs difference of two equally shaped arrays.
pub fn max_abs(a: &Array2<f32>, b: &Array2<f32>) -> f32 {
    assert_eq!(a.dim(), b.dim(), "shapes differ");
    a.iter()
        .zip(b.iter())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

//! Build metadata for `livegesture --version`: the commit the binary was built from and the target
//! triple it was built for, as the compile-time variables `LIVEGESTURE_COMMIT` and `LIVEGESTURE_TARGET`.
//!
//! The commit is `git rev-parse --short=12 HEAD` of the checkout being built (followed by the ref
//! files, so a new commit rebuilds this crate), or `$LIVEGESTURE_COMMIT` when set (a build from a
//! source archive without `.git`), else `unknown`.

use std::path::PathBuf;
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let dir = std::env::var_os("CARGO_MANIFEST_DIR")?;
    let out = Command::new("git")
        .args(args)
        .current_dir(dir)
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let s = String::from_utf8(out.stdout).ok()?.trim().to_string();
    (!s.is_empty()).then_some(s)
}

fn main() {
    println!("cargo:rerun-if-env-changed=LIVEGESTURE_COMMIT");
    let commit = match std::env::var("LIVEGESTURE_COMMIT") {
        Ok(c) if !c.trim().is_empty() => c.trim().to_string(),
        _ => {
            // rebuild when HEAD moves: HEAD itself (a branch switch) and the file of the branch it names
            if let Some(git_dir) = git(&["rev-parse", "--absolute-git-dir"]) {
                let git_dir = PathBuf::from(git_dir);
                println!("cargo:rerun-if-changed={}", git_dir.join("HEAD").display());
                // HEAD's reflog grows with every commit, also where the branch's ref is still packed
                let reflog = git_dir.join("logs").join("HEAD");
                if reflog.exists() {
                    println!("cargo:rerun-if-changed={}", reflog.display());
                }
                if let (Some(r), Some(common)) = (
                    git(&["symbolic-ref", "-q", "HEAD"]),
                    git(&["rev-parse", "--git-common-dir"]),
                ) {
                    let common = PathBuf::from(common);
                    let common = if common.is_absolute() {
                        common
                    } else {
                        PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap()).join(common)
                    };
                    // only files that exist: cargo reruns a build script whose watched path is missing
                    // on every build (a fresh clone keeps its refs in packed-refs, a busy checkout in
                    // refs/heads), which would recompile this crate for every cargo command
                    for f in [common.join(&r), common.join("packed-refs")] {
                        if f.exists() {
                            println!("cargo:rerun-if-changed={}", f.display());
                        }
                    }
                }
            }
            git(&["rev-parse", "--short=12", "HEAD"]).unwrap_or_else(|| "unknown".into())
        }
    };
    println!("cargo:rustc-env=LIVEGESTURE_COMMIT={commit}");
    println!(
        "cargo:rustc-env=LIVEGESTURE_TARGET={}",
        std::env::var("TARGET").unwrap_or_else(|_| "unknown".into())
    );
}

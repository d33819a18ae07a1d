//! A binary outside the source tree finds its default bundle beside itself
//! (`<exe_dir>/../share/livegesture/models/default`, then `<exe_dir>/models/default`);
//! `$LIVEGESTURE_BUNDLE` and `--bundle` still win.

use livegesture_parity_tests as common;

use std::path::Path;
use std::process::Command;

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.path().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

fn info(bin: &Path, env_bundle: Option<&Path>) -> (bool, String) {
    let mut c = Command::new(bin);
    c.arg("info").env_remove("LIVEGESTURE_BUNDLE");
    if let Some(b) = env_bundle {
        c.env("LIVEGESTURE_BUNDLE", b);
    }
    let o = c.output().unwrap();
    (
        o.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        ),
    )
}

#[test]
fn a_copied_binary_finds_the_bundle_installed_beside_it() {
    let tmp = tempfile::tempdir().unwrap();
    let prefix = tmp.path().join("prefix");
    std::fs::create_dir_all(prefix.join("bin")).unwrap();
    let bin = prefix.join("bin/livegesture");
    std::fs::copy(env!("CARGO_BIN_EXE_livegesture"), &bin).unwrap();
    // <prefix>/share/livegesture/models/default
    let share = prefix.join("share/livegesture/models/default");
    copy_dir(&common::tiny_bundle(), &share);
    let (ok, out) = info(&bin, None);
    assert!(ok, "{out}");
    let shown = share.canonicalize().unwrap();
    assert!(
        out.contains("share/livegesture/models/default"),
        "{} not used:\n{out}",
        shown.display()
    );
    // $LIVEGESTURE_BUNDLE wins over the installed one
    let other = tmp.path().join("other");
    copy_dir(&common::tiny_bundle(), &other);
    let (ok, out) = info(&bin, Some(&other));
    assert!(ok && out.contains(&other.display().to_string()), "{out}");
    // <exe_dir>/models/default, for a binary unpacked next to its model
    std::fs::remove_dir_all(prefix.join("share")).unwrap();
    let flat = tmp.path().join("flat");
    std::fs::create_dir_all(&flat).unwrap();
    let bin2 = flat.join("livegesture");
    std::fs::copy(&bin, &bin2).unwrap();
    copy_dir(&common::tiny_bundle(), &flat.join("models/default"));
    let (ok, out) = info(&bin2, None);
    assert!(ok && out.contains("models/default"), "{out}");
    assert!(
        out.contains(&flat.canonicalize().unwrap().display().to_string()),
        "{out}"
    );
}

/// `livegesture --version` names the version, the commit it was built from and its target triple
/// (cli/build.rs), as the release archives' proof checks (scripts/prove_release.sh).
#[test]
fn version_names_the_commit_and_the_target() {
    let o = Command::new(env!("CARGO_BIN_EXE_livegesture"))
        .arg("--version")
        .output()
        .unwrap();
    assert!(o.status.success());
    let v = String::from_utf8_lossy(&o.stdout);
    let want_prefix = format!("livegesture {} (commit ", env!("CARGO_PKG_VERSION"));
    assert!(v.starts_with(&want_prefix), "{v}");
    // the commit: HEAD of this checkout when built from git (a new commit rebuilds the crate)
    if let Ok(g) = Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
    {
        if g.status.success() {
            let head = String::from_utf8_lossy(&g.stdout).trim().to_string();
            assert!(v.contains(&format!("commit {head},")), "HEAD {head}: {v}");
        }
    }
    // the target triple: this test's architecture and OS
    let triple = v.trim().rsplit(", ").next().unwrap().trim_end_matches(')');
    assert!(
        triple.starts_with(std::env::consts::ARCH) && triple.contains(std::env::consts::OS),
        "target '{triple}' in {v}"
    );
}

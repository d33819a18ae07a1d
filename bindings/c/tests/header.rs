//! The committed header `include/livegesture.h` is what cbindgen generates from `src/lib.rs` now.
//! After changing the API, regenerate it: `LIVEGESTURE_BLESS=1 cargo test -p livegesture-c --test header`
//! (which rewrites a stale header and fails; rerun without it to check the rewrite).

use std::path::Path;

fn fresh_header() -> String {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let bindings = cbindgen::Builder::new()
        .with_config(config)
        .with_src(dir.join("src/lib.rs"))
        .generate()
        .expect("cbindgen could not generate the header");
    let mut out = Vec::new();
    bindings.write(&mut out);
    String::from_utf8(out).expect("the header is UTF-8")
}

/// The first line where `committed` differs from `fresh`, or `None` when they are equal.
fn first_difference(committed: &str, fresh: &str) -> Option<String> {
    if committed == fresh {
        return None;
    }
    let (mut c, mut f) = (committed.lines(), fresh.lines());
    for line in 1.. {
        match (c.next(), f.next()) {
            (Some(a), Some(b)) if a == b => continue,
            (a, b) => {
                return Some(format!(
                    "line {line}: committed {:?}, generated {:?}",
                    a.unwrap_or("<end>"),
                    b.unwrap_or("<end>")
                ))
            }
        }
    }
    unreachable!()
}

/// With `bless`, a stale header is rewritten and the run still fails (so a test run with
/// LIVEGESTURE_BLESS set cannot pass a stale header; the next run without it checks the rewrite);
/// without, a difference fails naming the first differing line.
fn check_or_bless(path: &Path, fresh: &str, bless: bool) -> Result<(), String> {
    let committed = std::fs::read_to_string(path).unwrap_or_default();
    let Some(diff) = first_difference(&committed, fresh) else {
        return Ok(());
    };
    if bless {
        std::fs::write(path, fresh).map_err(|e| format!("writing {}: {e}", path.display()))?;
        return Err(format!(
            "{} was stale ({diff}) and has been rewritten (LIVEGESTURE_BLESS); review and commit it, \
             then rerun without LIVEGESTURE_BLESS",
            path.display()
        ));
    }
    Err(format!(
        "{} is not what cbindgen generates from src/lib.rs ({diff}); regenerate it with \
         LIVEGESTURE_BLESS=1 cargo test -p livegesture-c --test header",
        path.display()
    ))
}

/// issue 38 item 10: blessing a stale header used to return before any check (the test passed);
/// now it rewrites the file and fails. A current header passes either way.
#[test]
fn blessing_a_stale_header_fails() {
    let dir = std::env::temp_dir().join(format!("lg-header-bless-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("h.h");
    std::fs::write(&path, "old\n").unwrap();
    let e = check_or_bless(&path, "new\n", true).expect_err("a blessed stale header passed");
    assert!(e.contains("rewritten"), "{e}");
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "new\n");
    assert!(check_or_bless(&path, "new\n", true).is_ok());
    assert!(check_or_bless(&path, "newer\n", false).is_err());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn committed_header_equals_a_fresh_generation() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("include/livegesture.h");
    let fresh = fresh_header();
    if let Err(e) = check_or_bless(
        &path,
        &fresh,
        std::env::var_os("LIVEGESTURE_BLESS").is_some(),
    ) {
        panic!("{e}");
    }
    // the header declares every entry point
    for f in [
        "lg_model_load",
        "lg_stream_new",
        "lg_stream_push",
        "lg_stream_finish",
        "lg_stream_read",
        "lg_stream_read_face",
        "lg_model_has_face",
        "lg_arkit_name",
        "lg_viseme_name",
        "lg_stream_reset",
        "lg_last_error",
    ] {
        assert!(
            fresh.contains(&format!("{f}(")),
            "{f} missing from the header"
        );
    }
}

#[test]
fn a_changed_header_is_detected() {
    let fresh = fresh_header();
    let edited = fresh.replacen("lg_stream_push(", "lg_stream_push_renamed(", 1);
    let diff = first_difference(&edited, &fresh).expect("an edited header must differ");
    assert!(diff.contains("lg_stream_push_renamed"), "{diff}");
    assert!(first_difference(&format!("{fresh}// extra\n"), &fresh).is_some());
    assert!(first_difference(&fresh, &fresh).is_none());
}

//! The committed header `include/livegesture.h` is what cbindgen generates from `src/lib.rs` now.
//! After changing the API, regenerate it: `LIVEGESTURE_BLESS=1 cargo test -p livegesture-c --test header`.

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

#[test]
fn committed_header_equals_a_fresh_generation() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("include/livegesture.h");
    let fresh = fresh_header();
    if std::env::var_os("LIVEGESTURE_BLESS").is_some() {
        std::fs::write(&path, &fresh).expect("writing the header");
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    if let Some(diff) = first_difference(&committed, &fresh) {
        panic!(
            "{} is not what cbindgen generates from src/lib.rs ({diff}); regenerate it with \
             LIVEGESTURE_BLESS=1 cargo test -p livegesture-c --test header",
            path.display()
        );
    }
    // the header declares every entry point
    for f in [
        "lg_model_load",
        "lg_stream_new",
        "lg_stream_push",
        "lg_stream_finish",
        "lg_stream_read",
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

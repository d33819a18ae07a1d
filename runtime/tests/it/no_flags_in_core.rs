//! The core library (what every door runs: bundles, backends, models, audio, output, the whole-input
//! path) names no door's spelling of an option: no `--flag` text in its messages. The CLI spells the
//! options as flags (`generate::InputError::render`), Python as keyword arguments, C as struct fields.

use std::path::Path;

/// String literals (one per line, roughly) in `path` that contain `--` followed by a letter, outside
/// comments and tests.
fn flag_literals(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let code = text.split("#[cfg(test)]").next().unwrap_or("");
    let mut found = Vec::new();
    for (i, line) in code.lines().enumerate() {
        let t = line.trim_start();
        if t.starts_with("//") {
            continue;
        }
        let mut in_str = false;
        let mut prev = '\0';
        let chars: Vec<char> = line.chars().collect();
        for (k, &c) in chars.iter().enumerate() {
            if c == '"' && prev != '\\' {
                in_str = !in_str;
            } else if in_str
                && c == '-'
                && chars.get(k + 1) == Some(&'-')
                && chars.get(k + 2).is_some_and(|n| n.is_ascii_lowercase())
            {
                found.push(format!("{}:{}: {}", path.display(), i + 1, line.trim()));
                break;
            }
            prev = c;
        }
    }
    found
}

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") && !p.ends_with("tests.rs") {
            out.push(p);
        }
    }
}

#[test]
fn core_messages_carry_no_cli_flags() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    for d in ["model", "audio", "bundle", "backend", "output", "diffusion"] {
        rust_files(&src.join(d), &mut files);
    }
    for f in [
        "generate.rs",
        "portable_parity.rs",
        "frontend.rs",
        "sampling.rs",
        "skeleton.rs",
        "tensor.rs",
        "compare.rs",
    ] {
        files.push(src.join(f));
    }
    assert!(files.len() > 20, "{files:?}");
    let found: Vec<String> = files.iter().flat_map(|f| flag_literals(f)).collect();
    assert!(
        found.is_empty(),
        "flag text in core messages:\n{}",
        found.join("\n")
    );
}

#[test]
fn the_scan_finds_flag_text() {
    // must-fail: the scanner sees a flag in a message, not in a comment
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.rs");
    std::fs::write(
        &p,
        "// see --form\nfn f() -> String { format!(\"use --ddim-steps\") }\nconst A: &str = \"a -- b\";\n",
    )
    .unwrap();
    let found = flag_literals(&p);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].contains(":2:"), "{found:?}");
}

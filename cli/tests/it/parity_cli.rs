//! `livegesture parity` end to end: the JUnit report (`--junit`), the runtime versions it prints,
//! export against export (`--against`) and its exit codes. The library side of `--against` is
//! tested in `parity-tests/tests/it/against.rs`.

use livegesture_parity_tests as common;

use crate::support::text;

use std::path::Path;
use std::process::Output;

use quick_xml::events::Event;
use quick_xml::Reader;

fn run(args: &[&str]) -> Output {
    common::require_ort();
    crate::support::run(args)
}

/// (classname, name, failure message) of every testcase of a JUnit file, parsed back with quick-xml.
fn testcases(path: &Path) -> Vec<(String, String, Option<String>)> {
    let xml = std::fs::read_to_string(path).unwrap();
    let mut reader = Reader::from_str(&xml);
    let mut cases: Vec<(String, String, Option<String>)> = Vec::new();
    loop {
        match reader.read_event().expect("well-formed JUnit XML") {
            Event::Start(e) | Event::Empty(e) => {
                let attr = |k: &str| {
                    e.attributes()
                        .map(|a| a.unwrap())
                        .find(|a| a.key.as_ref() == k.as_bytes())
                        .map(|a| a.unescape_value().unwrap().into_owned())
                };
                match e.name().as_ref() {
                    b"testcase" => {
                        cases.push((attr("classname").unwrap(), attr("name").unwrap(), None))
                    }
                    b"failure" => {
                        cases.last_mut().expect("failure inside a testcase").2 = attr("message")
                    }
                    _ => {}
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    cases
}

#[test]
fn junit_has_one_testcase_per_comparison_and_names_the_failure() {
    let tmp = tempfile::tempdir().unwrap();
    let (xml, json) = (tmp.path().join("p.xml"), tmp.path().join("p.json"));
    let tiny = common::tiny_bundle();
    let o = run(&[
        "parity",
        "--bundle",
        tiny.to_str().unwrap(),
        "--backends",
        "ort,tract",
        "--checks",
        "graph,logmel",
        "--junit",
        xml.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    // the versions it ran
    let out = text(&o);
    assert!(
        out.contains(&format!("tract {}", livegesture::backend::TRACT_VERSION))
            && out.contains("ONNX Runtime 1."),
        "{out}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = report["rows"].as_array().unwrap();
    let cases = testcases(&xml);
    assert_eq!(cases.len(), rows.len(), "one testcase per comparison");
    assert!(cases.iter().all(|c| c.2.is_none()), "nothing failed");
    assert!(cases
        .iter()
        .any(|c| c.0 == "parity.graph.expert_hands" && c.1 == "ort vs torch: hidden"));

    // a perturbed weight: exit 1, the failure's message names graph, output, step, error and scale
    let broken = tmp.path().join("broken");
    common::break_bundle(
        &tiny,
        &broken,
        "expert_hands",
        &common::Breakage::PerturbWeight { delta: 0.01 },
    );
    let o = run(&[
        "parity",
        "--bundle",
        broken.to_str().unwrap(),
        "--backends",
        "ort,tract",
        "--checks",
        "graph",
        "--junit",
        xml.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let failed: Vec<_> = testcases(&xml)
        .into_iter()
        .filter(|c| c.2.is_some())
        .collect();
    assert!(!failed.is_empty());
    for (class, name, msg) in &failed {
        let msg = msg.as_deref().unwrap();
        assert_eq!(class, "parity.graph.expert_hands", "{msg}");
        let output = name.split(": ").nth(1).unwrap();
        for part in ["expert_hands", output, "step", "error", "x scale"] {
            assert!(msg.contains(part), "'{part}' not in: {msg}");
        }
    }
}

#[test]
fn junit_and_against_refuse_bad_paths() {
    let tiny = common::tiny_bundle();
    let o = run(&[
        "parity",
        "--bundle",
        tiny.to_str().unwrap(),
        "--junit",
        "/nonexistent-folder/p.xml",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--junit"), "{}", text(&o));
    let o = run(&[
        "parity",
        "--bundle",
        tiny.to_str().unwrap(),
        "--against",
        "/nonexistent-bundle",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--against"), "{}", text(&o));
    let o = run(&[
        "parity",
        "--bundle",
        tiny.to_str().unwrap(),
        "--against",
        tiny.to_str().unwrap(),
        "--against-token-agreement",
        "1.5",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    // the DiffSHEG bundle is another family
    let d = common::diffsheg_tiny_bundle();
    let o = run(&[
        "parity",
        "--bundle",
        tiny.to_str().unwrap(),
        "--against",
        d.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("different families"), "{}", text(&o));
}

#[test]
fn against_itself_passes_and_against_a_perturbed_copy_fails_with_exit_1() {
    let tmp = tempfile::tempdir().unwrap();
    let tiny = common::tiny_bundle();
    let xml = tmp.path().join("a.xml");
    let o = run(&[
        "parity",
        "--bundle",
        tiny.to_str().unwrap(),
        "--against",
        tiny.to_str().unwrap(),
        "--junit",
        xml.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(testcases(&xml)
        .iter()
        .any(|c| c.0 == "parity.rollout.rollout"));
    let broken = tmp.path().join("broken");
    common::break_bundle(
        &tiny,
        &broken,
        "fusion",
        &common::Breakage::PerturbWeight { delta: 0.05 },
    );
    let o = run(&[
        "parity",
        "--bundle",
        broken.to_str().unwrap(),
        "--against",
        tiny.to_str().unwrap(),
        "--checks",
        "graph",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        text(&o).contains("FAIL graph fusion (new vs old"),
        "{}",
        text(&o)
    );
}

#[test]
fn info_prints_the_runtime_versions() {
    let tiny = common::tiny_bundle();
    let o = run(&["info", "--bundle", tiny.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o));
    let out = text(&o);
    let line = out
        .lines()
        .find(|l| l.starts_with("runtimes"))
        .unwrap_or_else(|| panic!("no runtimes line: {out}"));
    assert!(
        line.contains(&format!("tract {}", livegesture::backend::TRACT_VERSION))
            && line.contains("ONNX Runtime 1."),
        "{line}"
    );
}

/// issue 38 item 1: a requested check that compares nothing fails, naming the check and why. Before,
/// `--checks batch` on a DiffSHEG bundle and `--against ... --checks logmel` printed "all 0
/// comparisons PASS", exited 0 and wrote a JUnit file with `tests="0"`.
#[test]
fn a_check_that_compares_nothing_fails_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let tiny = common::tiny_bundle();
    let d = common::diffsheg_tiny_bundle();
    let cases: [(Vec<&str>, &str, &str); 2] = [
        (
            vec!["--bundle", d.to_str().unwrap(), "--checks", "batch"],
            "batch",
            "does not apply to a diffsheg bundle",
        ),
        (
            vec![
                "--bundle",
                tiny.to_str().unwrap(),
                "--against",
                tiny.to_str().unwrap(),
                "--checks",
                "logmel",
            ],
            "logmel",
            "--against compares graph, rollout only",
        ),
    ];
    for (k, (args, check, why)) in cases.into_iter().enumerate() {
        let xml = tmp.path().join(format!("{k}.xml"));
        let mut all = vec!["parity", "--backends", "tract"];
        all.extend(args);
        all.extend(["--junit", xml.to_str().unwrap()]);
        let o = run(&all);
        let t = text(&o);
        assert_eq!(o.status.code(), Some(1), "{t}");
        assert!(!t.contains("all 0 comparisons PASS"), "{t}");
        assert!(
            t.contains(&format!("FAIL {check} "))
                && t.contains("compared nothing")
                && t.contains(why),
            "{t}"
        );
        let cases = testcases(&xml);
        assert_eq!(cases.len(), 1, "{cases:?}");
        assert!(
            cases[0].2.as_deref().unwrap_or("").contains(why),
            "{cases:?}"
        );
        assert!(!std::fs::read_to_string(&xml)
            .unwrap()
            .contains(r#"tests="0""#));
    }
}

//! The parity report as JUnit XML (`livegesture parity --junit FILE`), the format CI systems read:
//! one `<testsuite>` per check, one `<testcase>` per comparison (row), a `<failure>` on every
//! failed row whose message names the graph, the output, the step, the error and the bound with
//! the scale it was judged at ([`Row::failure_line`]). Written with quick-xml, which escapes every
//! attribute and text; characters XML 1.0 cannot carry at all (control characters) are replaced.

use std::io::Cursor;

use quick_xml::events::{BytesDecl, BytesEnd, BytesStart, BytesText, Event};
use quick_xml::Writer;

use super::*;

/// Text without the characters XML 1.0 forbids even escaped (C0 controls other than tab, line
/// feed and carriage return; U+FFFE, U+FFFF).
fn xml_safe(s: &str) -> String {
    s.chars()
        .map(|c| match c {
            '\t' | '\n' | '\r' => c,
            c if (c as u32) < 0x20 || c == '\u{FFFE}' || c == '\u{FFFF}' => '\u{FFFD}',
            c => c,
        })
        .collect()
}

/// The JUnit XML of `report` (see the module docs).
pub fn junit_xml(report: &Report) -> String {
    write(report).expect("writing XML into memory cannot fail")
}

// long: one XML document written element by element (suites, cases, failures, properties)
fn write(report: &Report) -> std::io::Result<String> {
    let mut w = Writer::new_with_indent(Cursor::new(Vec::new()), b' ', 2);
    let failures = report.failures().len();
    w.write_event(Event::Decl(BytesDecl::new("1.0", Some("UTF-8"), None)))?;
    // an empty report is written as one failed case (below), never as `tests="0"`
    let (tests, fails, secs) = (
        report.rows.len().max(1).to_string(),
        failures
            .max(usize::from(report.rows.is_empty()))
            .to_string(),
        format!("{:.3}", report.seconds),
    );
    let bundle = xml_safe(&report.bundle.display().to_string());
    w.write_event(Event::Start(BytesStart::new("testsuites").with_attributes(
        [
            ("name", "livegesture parity"),
            ("tests", tests.as_str()),
            ("failures", fails.as_str()),
            ("errors", "0"),
            ("time", secs.as_str()),
        ],
    )))?;
    if report.rows.is_empty() {
        // nothing compared proves nothing: one failed case says so (never `tests="0"`)
        w.write_event(Event::Start(BytesStart::new("testsuite").with_attributes(
            [
                ("name", "parity"),
                ("tests", "1"),
                ("failures", "1"),
                ("errors", "0"),
                ("skipped", "0"),
            ],
        )))?;
        w.write_event(Event::Start(BytesStart::new("testcase").with_attributes([
            ("classname", "parity"),
            ("name", "nothing compared"),
            ("time", "0"),
        ])))?;
        w.write_event(Event::Empty(BytesStart::new("failure").with_attributes([
            (
                "message",
                "the parity run compared nothing (0 rows): it proves nothing",
            ),
            ("type", "nothing compared"),
        ])))?;
        w.write_event(Event::End(BytesEnd::new("testcase")))?;
        w.write_event(Event::End(BytesEnd::new("testsuite")))?;
    }
    for check in Check::ALL {
        let rows: Vec<&Row> = report.rows.iter().filter(|r| r.check == check).collect();
        if rows.is_empty() {
            continue;
        }
        let n = rows.len().to_string();
        let f = rows.iter().filter(|r| !r.pass).count().to_string();
        let name = format!("parity.{check}");
        w.write_event(Event::Start(BytesStart::new("testsuite").with_attributes(
            [
                ("name", name.as_str()),
                ("tests", n.as_str()),
                ("failures", f.as_str()),
                ("errors", "0"),
                ("skipped", "0"),
            ],
        )))?;
        // properties: the bundle, the backends and the runtimes' versions
        w.write_event(Event::Start(BytesStart::new("properties")))?;
        let mut props = vec![
            ("bundle".to_string(), bundle.clone()),
            ("backends".to_string(), report.backends.join(", ")),
        ];
        props.extend(
            report
                .runtimes
                .iter()
                .enumerate()
                .map(|(i, r)| (format!("runtime.{i}"), xml_safe(r))),
        );
        for (k, v) in &props {
            w.write_event(Event::Empty(
                BytesStart::new("property")
                    .with_attributes([("name", k.as_str()), ("value", v.as_str())]),
            ))?;
        }
        w.write_event(Event::End(BytesEnd::new("properties")))?;
        for r in rows {
            let classname = xml_safe(&format!("parity.{}.{}", r.check, r.what));
            let case = xml_safe(&format!("{}: {}", r.comparison, r.output));
            let mut start = BytesStart::new("testcase");
            start.push_attribute(("classname", classname.as_str()));
            start.push_attribute(("name", case.as_str()));
            start.push_attribute(("time", "0"));
            if r.pass {
                w.write_event(Event::Empty(start))?;
                continue;
            }
            w.write_event(Event::Start(start))?;
            let message = xml_safe(&r.failure_line());
            let kind = match r.metric {
                Metric::MaxAbs => "bound exceeded",
                Metric::DifferingSteps => "tokens differ",
            };
            w.write_event(Event::Start(
                BytesStart::new("failure")
                    .with_attributes([("message", message.as_str()), ("type", kind)]),
            ))?;
            let body = xml_safe(&format!(
                "check {}\ngraph {}\ncomparison {}\noutput {}\nstep {}\nerror {}\nbound {}\nscale {}\ncompared {}\n{}",
                r.check,
                r.what,
                r.comparison,
                r.output,
                r.step.map(|s| s.to_string()).unwrap_or_else(|| "-".into()),
                r.error_text(),
                r.bound_text(),
                r.scale_text(),
                r.compared,
                r.detail.as_deref().unwrap_or("")
            ));
            w.write_event(Event::Text(BytesText::new(&body)))?;
            w.write_event(Event::End(BytesEnd::new("failure")))?;
            w.write_event(Event::End(BytesEnd::new("testcase")))?;
        }
        w.write_event(Event::End(BytesEnd::new("testsuite")))?;
    }
    w.write_event(Event::End(BytesEnd::new("testsuites")))?;
    let bytes = w.into_inner().into_inner();
    Ok(String::from_utf8(bytes).expect("quick-xml writes UTF-8") + "\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use quick_xml::events::Event;
    use quick_xml::Reader;

    fn row(what: &str, output: &str, pass: bool, detail: &str) -> Row {
        Row {
            check: Check::Graph,
            what: what.into(),
            comparison: "ort vs torch".into(),
            output: output.into(),
            step: Some(7),
            metric: Metric::MaxAbs,
            error: if pass { 1e-6 } else { 3.5e-4 },
            compared: 10,
            bound: 1e-5,
            scale: 38.5,
            pass,
            detail: Some(detail.into()),
        }
    }

    /// The XML parses back (quick-xml's reader) to one testcase per row, with a failure on the
    /// failed row only, whose message names the graph, output, step, error and scale, and markup in
    /// names and details (`<`, `&`, quotes, a control character) survives as text.
    #[test]
    fn junit_parses_back_with_one_testcase_per_row() {
        let report = Report {
            bundle: "models/a&b".into(),
            backends: vec!["ort".into()],
            rows: vec![
                row("expert_<hands>", "hidden", true, "fine"),
                row(
                    "fusion \"&\" 'x'",
                    "logits",
                    false,
                    "largest at <index [0, 1]>\u{1}&amp;",
                ),
            ],
            notes: vec![],
            divergences: vec![],
            runtimes: vec!["tract 0.23.9".into()],
            seconds: 1.5,
        };
        let xml = junit_xml(&report);
        let mut reader = Reader::from_str(&xml);
        let (mut cases, mut failures, mut suites) = (Vec::new(), Vec::new(), 0);
        let mut in_failure = false;
        let mut failure_text = String::new();
        loop {
            match reader.read_event().expect("well-formed XML") {
                Event::Start(e) | Event::Empty(e) => {
                    let attr = |k: &str| {
                        e.attributes()
                            .map(|a| a.unwrap())
                            .find(|a| a.key.as_ref() == k.as_bytes())
                            .map(|a| a.unescape_value().unwrap().into_owned())
                    };
                    match e.name().as_ref() {
                        b"testsuite" => {
                            suites += 1;
                            assert_eq!(attr("tests").as_deref(), Some("2"));
                            assert_eq!(attr("failures").as_deref(), Some("1"));
                        }
                        b"testcase" => cases.push(attr("classname").unwrap()),
                        b"failure" => {
                            failures.push(attr("message").unwrap());
                            in_failure = true;
                        }
                        _ => {}
                    }
                }
                Event::Text(t) if in_failure => failure_text.push_str(&t.unescape().unwrap()),
                Event::End(e) if e.name().as_ref() == b"failure" => in_failure = false,
                Event::Eof => break,
                _ => {}
            }
        }
        assert_eq!(suites, 1);
        assert_eq!(
            cases,
            [
                "parity.graph.expert_<hands>",
                "parity.graph.fusion \"&\" 'x'"
            ]
        );
        assert_eq!(failures.len(), 1);
        let m = &failures[0];
        for part in [
            "fusion \"&\" 'x'",
            "'logits'",
            "step 7",
            "3.500e-4",
            "x scale 38.5",
        ] {
            assert!(m.contains(part), "{part} not in {m}");
        }
        assert!(
            failure_text.contains("<index [0, 1]>\u{FFFD}&amp;"),
            "{failure_text}"
        );
        assert!(!xml.contains('\u{1}'));
    }

    /// A report with nothing in it is not `tests="0"` with no failure (what it was before): it is
    /// one failed case saying nothing was compared.
    #[test]
    fn an_empty_report_is_a_failed_case() {
        let report = Report {
            bundle: "b".into(),
            backends: vec!["ort".into()],
            rows: vec![],
            notes: vec![],
            divergences: vec![],
            runtimes: vec![],
            seconds: 0.0,
        };
        let xml = junit_xml(&report);
        assert!(!xml.contains(r#"tests="0""#), "{xml}");
        assert!(!xml.contains(r#"failures="0""#), "{xml}");
        assert!(
            xml.contains("<failure") && xml.contains("compared nothing"),
            "{xml}"
        );
    }
}

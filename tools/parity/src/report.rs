//! The parity report: one [`Row`] per comparison, rendered as a table and a summary.

use super::*;

/// What a row's error measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    /// Largest absolute difference of corresponding values.
    MaxAbs,
    /// Number of token steps that differ (of `total`).
    DifferingSteps,
}

/// One comparison of the report.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub check: Check,
    /// The graph, or what is compared (`rollout`, `clip.wav`, `chunk 160`, `batch 5`).
    pub what: String,
    /// `ort vs torch`, `tract vs ort`, `tract vs torch`, `rust vs python`, `tract` (self-consistency).
    pub comparison: String,
    /// The output (graph output name, `tokens`, `poses`, ...).
    pub output: String,
    /// The step (token) of the largest error, or the first diverging step.
    pub step: Option<u64>,
    pub metric: Metric,
    /// The error: a max abs difference, or a count of differing steps.
    pub error: f64,
    /// Steps compared (for [`Metric::DifferingSteps`]) or values compared.
    pub compared: u64,
    pub bound: f64,
    /// The scale the error was judged at (docs/parity.md): `max(1, max|reference|)` of the reference
    /// tensor at the row's step; the row passes when `error <= bound x scale`. 1 for absolute bounds
    /// and token counts.
    pub scale: f64,
    pub pass: bool,
    /// Where the largest error is, why the check could not run, or the divergence report.
    pub detail: Option<String>,
}

impl Row {
    pub(super) fn max_abs(
        check: Check,
        what: impl Into<String>,
        comparison: impl Into<String>,
        output: impl Into<String>,
        m: &MaxAbs,
        bound: f64,
    ) -> Row {
        Row {
            check,
            what: what.into(),
            comparison: comparison.into(),
            output: output.into(),
            step: m.step,
            metric: Metric::MaxAbs,
            error: m.err,
            compared: m.count,
            bound,
            scale: m.scale,
            pass: m.within(bound),
            detail: m
                .problem
                .clone()
                .or_else(|| m.location.clone())
                .or_else(|| {
                    (m.count == 0)
                        .then(|| "nothing compared (0 values): the check proves nothing".into())
                }),
        }
    }

    /// A row of an error measured elsewhere (by the exporter, recorded in the manifest's `checks`),
    /// judged at the scale recorded beside it.
    pub(super) fn recorded(
        check: Check,
        what: impl Into<String>,
        comparison: impl Into<String>,
        error: f64,
        scale: f64,
        bound: f64,
        detail: String,
    ) -> Row {
        let scale = if scale.is_finite() && scale >= 1.0 {
            scale
        } else {
            1.0
        };
        Row {
            check,
            what: what.into(),
            comparison: comparison.into(),
            output: "(all, recorded by export)".into(),
            step: None,
            metric: Metric::MaxAbs,
            error,
            compared: 1,
            bound,
            scale,
            pass: error.is_finite() && error <= bound * scale,
            detail: Some(detail),
        }
    }

    /// The error relative to the bound it was judged against (`error / (bound x scale)`; <= 1 passes).
    pub fn relative_error(&self) -> f64 {
        match self.metric {
            Metric::MaxAbs => self.error / (self.bound * self.scale).max(f64::MIN_POSITIVE),
            Metric::DifferingSteps => self.error,
        }
    }

    pub(super) fn failed(
        check: Check,
        what: impl Into<String>,
        comparison: impl Into<String>,
        output: impl Into<String>,
        bound: f64,
        why: String,
    ) -> Row {
        Row {
            check,
            what: what.into(),
            comparison: comparison.into(),
            output: output.into(),
            step: None,
            metric: Metric::MaxAbs,
            error: f64::INFINITY,
            compared: 0,
            bound,
            scale: 1.0,
            pass: false,
            detail: Some(why),
        }
    }

    /// The error as the table shows it.
    pub fn error_text(&self) -> String {
        match self.metric {
            Metric::MaxAbs if self.error.is_infinite() => "-".into(),
            Metric::MaxAbs if self.error == 0.0 => "0".into(),
            Metric::MaxAbs => format!("{:.3e}", self.error),
            Metric::DifferingSteps => format!("{} of {} steps", self.error, self.compared),
        }
    }

    /// The bound as the table shows it.
    pub fn bound_text(&self) -> String {
        match self.metric {
            Metric::MaxAbs if self.bound == 0.0 => "exact".into(),
            Metric::MaxAbs => format!("{:.1e}", self.bound),
            Metric::DifferingSteps if self.bound == 0.0 => "0 (identical)".into(),
            Metric::DifferingSteps => format!("{} steps", self.bound),
        }
    }

    /// The scale as the table shows it.
    pub fn scale_text(&self) -> String {
        match self.metric {
            Metric::MaxAbs => super::compare::fmt_scale(self.scale),
            Metric::DifferingSteps => "-".into(),
        }
    }

    /// One line naming everything about a failure (graph, output, step, error, the scale it was
    /// judged at).
    pub fn failure_line(&self) -> String {
        let step = self
            .step
            .map(|s| format!(" at step {s}"))
            .unwrap_or_default();
        let judged = match self.metric {
            Metric::MaxAbs => format!(
                "error {} > bound {} x scale {}",
                self.error_text(),
                self.bound_text(),
                self.scale_text()
            ),
            Metric::DifferingSteps => {
                format!("error {} > bound {}", self.error_text(), self.bound_text())
            }
        };
        let mut s = format!(
            "FAIL {} {} ({}): output '{}'{step}: {judged}",
            self.check, self.what, self.comparison, self.output,
        );
        if let Some(d) = &self.detail {
            s.push_str("; ");
            s.push_str(d);
        }
        s
    }
}

/// The report of a parity run.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub bundle: PathBuf,
    pub backends: Vec<String>,
    pub rows: Vec<Row>,
    /// Remarks (what was run on which data, skipped comparisons).
    pub notes: Vec<String>,
    /// Token divergences found in rollouts.
    pub divergences: Vec<Divergence>,
    /// The inference runtimes that ran, with their versions (`tract 0.23.9`, `ONNX Runtime 1.31.1
    /// (<library>)`).
    pub runtimes: Vec<String>,
    pub seconds: f64,
}

impl Report {
    /// True when there is at least one row and every row passed: a report with nothing compared
    /// proves nothing and fails.
    pub fn passed(&self) -> bool {
        !self.rows.is_empty() && self.rows.iter().all(|r| r.pass)
    }

    /// The rows that failed.
    pub fn failures(&self) -> Vec<&Row> {
        self.rows.iter().filter(|r| !r.pass).collect()
    }

    /// The rows of one check on one graph (or `what`).
    pub fn rows_for(&self, check: Check, what: &str) -> Vec<&Row> {
        self.rows
            .iter()
            .filter(|r| r.check == check && r.what == what)
            .collect()
    }

    /// The report as a text table. Without `all`, rows of one (check, what, comparison) that all
    /// pass are summarised by their worst output; failing rows are always shown one by one.
    pub fn table(&self, all: bool) -> String {
        let mut shown: Vec<(Row, usize)> = Vec::new();
        let mut i = 0;
        while i < self.rows.len() {
            let r = &self.rows[i];
            let mut j = i + 1;
            while j < self.rows.len()
                && self.rows[j].check == r.check
                && self.rows[j].what == r.what
                && self.rows[j].comparison == r.comparison
                && self.rows[j].metric == Metric::MaxAbs
                && r.metric == Metric::MaxAbs
            {
                j += 1;
            }
            let group = &self.rows[i..j];
            if all || group.len() == 1 || group.iter().any(|r| !r.pass) {
                shown.extend(group.iter().map(|r| (r.clone(), 1)));
            } else {
                // the worst relative to its bound; the first of equals
                let rel = |r: &Row| r.relative_error();
                let worst = group
                    .iter()
                    .fold(None::<&Row>, |w, r| match w {
                        Some(w) if rel(w) >= rel(r) => Some(w),
                        _ => Some(r),
                    })
                    .cloned()
                    .unwrap_or_else(|| r.clone());
                shown.push((worst, group.len()));
            }
            i = j;
        }
        let header = [
            "CHECK",
            "GRAPH/WHAT",
            "COMPARISON",
            "OUTPUT",
            "STEP",
            "MAX ABS ERROR",
            "BOUND",
            "SCALE",
            "RESULT",
        ];
        let cells: Vec<[String; 9]> = shown
            .iter()
            .map(|(r, n)| {
                let output = if *n > 1 {
                    format!("{} (worst of {n})", r.output)
                } else {
                    r.output.clone()
                };
                [
                    r.check.to_string(),
                    r.what.clone(),
                    r.comparison.clone(),
                    output,
                    r.step.map(|s| s.to_string()).unwrap_or_else(|| "-".into()),
                    r.error_text(),
                    r.bound_text(),
                    r.scale_text(),
                    if r.pass { "PASS" } else { "FAIL" }.to_string(),
                ]
            })
            .collect();
        let mut widths: Vec<usize> = header.iter().map(|h| h.len()).collect();
        for c in &cells {
            for (w, s) in widths.iter_mut().zip(c) {
                *w = (*w).max(s.chars().count());
            }
        }
        let line = |c: &[String]| -> String {
            let mut s = String::new();
            for (k, (cell, w)) in c.iter().zip(&widths).enumerate() {
                if k > 0 {
                    s.push_str("  ");
                }
                s.push_str(&format!("{cell:<w$}"));
            }
            s.trim_end().to_string() + "\n"
        };
        let mut out = line(&header.map(String::from));
        out.push_str(&line(
            &widths.iter().map(|w| "-".repeat(*w)).collect::<Vec<_>>(),
        ));
        for c in &cells {
            out.push_str(&line(c));
        }
        out
    }

    /// A human summary: notes, divergences, failures and the verdict.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        if !self.runtimes.is_empty() {
            s.push_str(&format!("runtimes: {}\n", self.runtimes.join("; ")));
        }
        for n in &self.notes {
            s.push_str(&format!("note: {n}\n"));
        }
        for d in &self.divergences {
            s.push_str(&format!("divergence: {d}\n"));
        }
        let failures = self.failures();
        for f in &failures {
            if f.check == Check::Rollout
                && f.metric == Metric::DifferingSteps
                && !self.divergences.is_empty()
            {
                // the divergence line above already says everything about it
                let mut short = (*f).clone();
                short.detail = Some("see the divergence above".into());
                s.push_str(&short.failure_line());
            } else {
                s.push_str(&f.failure_line());
            }
            s.push('\n');
        }
        if self.rows.is_empty() {
            s.push_str(&format!(
                "parity: FAIL: nothing compared (0 comparisons; {}; {:.1} s): the run proves nothing\n",
                self.backends.join(", "),
                self.seconds
            ));
        } else if failures.is_empty() {
            s.push_str(&format!(
                "parity: all {} comparisons PASS ({}; {:.1} s)\n",
                self.rows.len(),
                self.backends.join(", "),
                self.seconds
            ));
        } else {
            s.push_str(&format!(
                "parity: {} of {} comparisons FAIL ({}; {:.1} s)\n",
                failures.len(),
                self.rows.len(),
                self.backends.join(", "),
                self.seconds
            ));
        }
        s
    }
}

/// Appends a failed row for every check of `requested` that produced no row: a requested check that
/// compared nothing proves nothing, so it fails, naming the check and `why` it has nothing (a check
/// that does not apply to the bundle's family or to `--against`, or that ran nothing).
pub(super) fn fail_checks_without_rows(
    rows: &mut Vec<Row>,
    requested: &[Check],
    why: impl Fn(Check) -> String,
) {
    let mut seen = Vec::new();
    for &c in requested {
        if seen.contains(&c) || rows.iter().any(|r| r.check == c) {
            continue;
        }
        seen.push(c);
        rows.push(Row::failed(
            c,
            "(none)",
            "-",
            "(none)",
            0.0,
            format!("check '{c}' compared nothing: {}", why(c)),
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::super::rollout::token_row;
    use super::*;

    /// A row with nothing compared proves nothing: it fails, and says so.
    #[test]
    fn a_row_with_nothing_compared_fails() {
        let r = Row::max_abs(
            Check::Graph,
            "g",
            "ort vs torch",
            "out",
            &MaxAbs::default(),
            1e-5,
        );
        assert_eq!(r.compared, 0);
        assert!(!r.pass, "{r:?}");
        assert!(r.failure_line().contains("nothing compared"), "{r:?}");
        let t = token_row(Check::Rollout, "rollout", "ort vs torch", &[], &[], None);
        assert!(!t.pass, "an empty token comparison passed: {t:?}");
        // the same rows with something compared pass
        let mut m = MaxAbs::default();
        m.add_slices(0, &[1.0], &[1.0], |_| "x".into());
        assert!(Row::max_abs(Check::Graph, "g", "ort vs torch", "out", &m, 1e-5).pass);
        assert!(token_row(Check::Rollout, "r", "c", &[vec![1]], &[vec![1]], None).pass);
    }

    fn report(rows: Vec<Row>) -> Report {
        Report {
            bundle: "b".into(),
            backends: vec!["tract".into()],
            rows,
            notes: vec![],
            divergences: vec![],
            runtimes: vec![],
            seconds: 0.0,
        }
    }

    /// A report with nothing in it fails (before: `all` on no rows was true, "all 0 comparisons
    /// PASS"); a requested check without rows becomes a failed row naming the check and why.
    #[test]
    fn an_empty_report_and_a_check_without_rows_fail() {
        let empty = report(vec![]);
        assert!(
            empty.rows.iter().all(|r| r.pass),
            "premise: the old verdict passed it"
        );
        assert!(!empty.passed());
        assert!(
            empty.summary().contains("FAIL: nothing compared"),
            "{}",
            empty.summary()
        );
        let mut m = MaxAbs::default();
        m.add_slices(0, &[1.0], &[1.0], |_| "x".into());
        let mut rows = vec![Row::max_abs(
            Check::Graph,
            "g",
            "ort vs torch",
            "out",
            &m,
            1e-5,
        )];
        fail_checks_without_rows(
            &mut rows,
            &[Check::Graph, Check::Batch, Check::Batch],
            |c| format!("'{c}' does not apply here"),
        );
        let r = report(rows);
        assert_eq!(r.rows.len(), 2, "one failed row per check without rows");
        assert!(!r.passed());
        let line = r.failures()[0].failure_line();
        assert!(
            line.contains("batch")
                && line.contains("compared nothing")
                && line.contains("does not apply"),
            "{line}"
        );
        // a check with rows gets none added
        let mut rows = r.rows[..1].to_vec();
        fail_checks_without_rows(&mut rows, &[Check::Graph], |_| unreachable!());
        assert_eq!(rows.len(), 1);
        assert!(report(rows).passed());
    }
}

//! The chunk and batch checks fail on a deliberately broken run: the comparisons they use (tokens
//! with [`token_row`], frames with [`frame_rows_steps`] at the chunk check's exact bound and the
//! batch check's bound) on synthetic token steps with one value changed, a NaN on either side, a
//! step missing, or nothing at all.

use super::*;

fn steps(n: usize) -> Vec<TokenStep> {
    (0..n)
        .map(|t| TokenStep {
            token_index: t as u64,
            tokens: vec![t as i64 % 7, 3, 1, t as i64 % 5],
            logits: None,
            frames: (0..4)
                .map(|k| {
                    let i = (4 * t + k) as u64;
                    let v = |j: usize| ((i as f32) * 0.37 + j as f32 * 0.11).sin() * 2.0;
                    Frame {
                        index: i,
                        time_s: i as f64 / 30.0,
                        poses: std::array::from_fn(v),
                        trans: std::array::from_fn(|j| v(j + 200)),
                        expressions: std::array::from_fn(|j| v(j + 300)),
                        foot_contact: std::array::from_fn(|j| (j % 2) as f32),
                        face: None,
                    }
                })
                .collect(),
        })
        .collect()
}

/// The rows the chunk check (bound 0) or the batch check (`bound`) makes for `got` vs `want`.
fn rows_of(check: Check, got: &[TokenStep], want: &[TokenStep], bound: f64) -> Vec<Row> {
    let mut rows = Vec::new();
    let tg: Vec<Vec<i64>> = got.iter().map(|s| s.tokens.clone()).collect();
    let tw: Vec<Vec<i64>> = want.iter().map(|s| s.tokens.clone()).collect();
    rows.push(token_row(check, "probe", "c", &tg, &tw, None));
    let n = got.len().min(want.len());
    frame_rows_steps(
        check,
        "probe",
        "c",
        &[(String::new(), &got[..n], &want[..n])],
        bound,
        &mut rows,
    );
    rows
}

fn passes(rows: &[Row]) -> bool {
    rows.iter().all(|r| r.pass)
}

#[test]
fn the_chunk_and_batch_comparisons_fail_on_broken_runs() {
    let want = steps(6);
    for (check, bound) in [
        (Check::Chunks, 0.0),
        (Check::Batch, BATCH_FRAMES),
        (Check::Batch, TRACT_BATCH_FRAMES),
    ] {
        assert!(
            passes(&rows_of(check, &want, &want, bound)),
            "{check}: clean"
        );
        // one value moved by more than the bound (one ulp for the exact chunk check)
        let mut moved = want.clone();
        let x = &mut moved[3].frames[2].poses[40];
        *x = if bound == 0.0 {
            f32::from_bits(x.to_bits() + 1)
        } else {
            *x + 3.0 * bound as f32
        };
        assert!(
            !passes(&rows_of(check, &moved, &want, bound)),
            "{check}: moved value"
        );
        // a NaN on either side
        let mut nan = want.clone();
        nan[4].frames[1].expressions[9] = f32::NAN;
        assert!(
            !passes(&rows_of(check, &nan, &want, bound)),
            "{check}: NaN in the run checked"
        );
        assert!(
            !passes(&rows_of(check, &want, &nan, bound)),
            "{check}: NaN in the run it is checked against"
        );
        // a different token, a missing step, nothing at all
        let mut tok = want.clone();
        tok[2].tokens[1] += 1;
        assert!(
            !passes(&rows_of(check, &tok, &want, bound)),
            "{check}: token"
        );
        assert!(
            !passes(&rows_of(check, &want[..5], &want, bound)),
            "{check}: a step missing"
        );
        assert!(
            !passes(&rows_of(check, &[], &[], bound)),
            "{check}: nothing compared"
        );
    }
}

//! tract's prepared plans (`TRACT_ROW_BUCKETS`): once a server has prepared its batch sizes, a step
//! of a row count without a plan of its own runs padded on the plan of the next prepared count and
//! returns what a plan of its exact size returns, row for row.

use livegesture_parity_tests as common;

use livegesture::backend::tract::{row_bucket, TractGraph, TRACT_ROW_BUCKETS};
use livegesture::backend::{GraphRunner, Tensor, TensorData};
use livegesture::bundle::{concrete_shape, Bundle};

/// Inputs of `batch` rows, every row different: pseudo-random floats (data and caches), small
/// integers (tokens, step counts), and one phase for every row (ring graphs).
fn inputs(g: &TractGraph, batch: usize) -> Vec<Tensor> {
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        ((seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) as f32
    };
    g.spec()
        .all_inputs()
        .iter()
        .map(|(name, dt, shape)| {
            let mut t = Tensor::zeros(*dt, concrete_shape(shape, batch));
            match &mut t.data {
                TensorData::F32(v) => v.iter_mut().for_each(|x| *x = rnd()),
                TensorData::I64(v) if *name == "phase" => v.iter_mut().for_each(|x| *x = 3),
                TensorData::I64(v) => v.iter_mut().for_each(|x| *x = ((rnd() + 1.0) * 4.0) as i64),
            }
            t
        })
        .collect()
}

fn worst(a: &[Tensor], b: &[Tensor]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            assert_eq!(x.shape, y.shape, "output shapes differ");
            match (&x.data, &y.data) {
                (TensorData::F32(p), TensorData::F32(q)) => p
                    .iter()
                    .zip(q)
                    .map(|(u, v)| f64::from((u - v).abs()))
                    .fold(0.0, f64::max),
                (TensorData::I64(p), TensorData::I64(q)) if p == q => 0.0,
                _ => f64::INFINITY,
            }
        })
        .fold(0.0, f64::max)
}

#[test]
fn the_row_ladder_covers_every_step_and_pads_at_most_half() {
    assert_eq!(TRACT_ROW_BUCKETS.first(), Some(&1));
    assert!(TRACT_ROW_BUCKETS.windows(2).all(|w| w[0] < w[1]));
    for rows in 1..=*TRACT_ROW_BUCKETS.last().unwrap() {
        let b = row_bucket(rows).unwrap();
        assert!(
            b >= rows && 2 * b <= 3 * rows.max(2),
            "{rows} rows pad to {b}"
        );
    }
    // a step of MAX_STEP (32) guided streams is 64 rows
    assert_eq!(row_bucket(64), Some(64));
    assert_eq!(row_bucket(65), None);
}

#[test]
fn tract_padded_runs_return_what_a_plan_of_their_size_returns() {
    for (bundle, names) in [
        (
            common::tiny_bundle(),
            &["audio_encoder", "expert_upper", "fusion", "decoder_face"][..],
        ),
        (common::ring_bundle(), &["fusion_attention_ring"][..]),
    ] {
        let bundle = Bundle::load(&bundle).unwrap();
        for name in names {
            let spec = bundle.graph(name).unwrap().clone();
            let path = bundle.graph_path(&spec);
            let exact = TractGraph::load(&spec, &path).unwrap();
            let padded = TractGraph::load(&spec, &path).unwrap();
            for batch in [5usize, 7, 13] {
                let x = inputs(&exact, batch);
                padded.prepare_batches(&[batch]).unwrap();
                let want = exact.run(&x).unwrap();
                let got = padded.run(&x).unwrap();
                let rows = row_bucket(batch).unwrap();
                assert!(rows > batch);
                assert!(
                    padded.plan_sizes().contains(&vec![rows])
                        && !padded.plan_sizes().contains(&vec![batch]),
                    "{name}: plans {:?}, expected one of {rows} rows and none of {batch}",
                    padded.plan_sizes()
                );
                let err = worst(&got, &want);
                assert!(
                    err <= 1e-5,
                    "{name}: batch {batch} padded to {rows}: {err:.3e} from the exact plan"
                );
                // the rows are the stream's own: a run whose rows are swapped differs
                let mut swapped = x.clone();
                fn swap01<T>(v: &mut [T], batch: usize) {
                    let row = v.len() / batch;
                    let (a, b) = v.split_at_mut(row);
                    a.swap_with_slice(&mut b[..row]);
                }
                for t in swapped.iter_mut() {
                    match &mut t.data {
                        TensorData::F32(v) => swap01(v, batch),
                        TensorData::I64(v) => swap01(v, batch),
                    }
                }
                let other = padded.run(&swapped).unwrap();
                assert!(
                    worst(&other, &want) > 1e-3,
                    "{name}: swapped rows went unnoticed"
                );
            }
        }
    }
}

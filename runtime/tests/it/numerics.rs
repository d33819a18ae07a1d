//! Cross-language numerics checks: the Rust frontend, sampler and rotations against reference values
//! written by `python/tools/make_numerics_fixtures.py` into `tests/fixtures/numerics.npz`.
//!
//! Bounds (docs/parity.md): log-mel max abs error <= 1e-4; sampled tokens and SplitMix64 outputs
//! identical; rotations within 1e-5. Streaming with any chunk size must equal offline exactly.

use std::fmt::Debug;
use std::fs::File;
use std::path::PathBuf;

use livegesture::compare;
use livegesture::frontend::{logmel, FrontendConfig, StreamingLogMel};
use livegesture::rotation::{axis_angle_to_rot6d, rot6d_to_axis_angle};
use livegesture::sampling::{sample_token, SplitMix64};
use ndarray::{Array0, Array1, Array2, ArrayBase, Data, Dimension};
use ndarray_npy::{NpzReader, ReadableElement};

/// The docs/parity.md bound for the Rust log-mel frontend against the Python one.
const LOGMEL_BOUND: f64 = 1e-4;
const ROTATION_BOUND: f64 = 1e-5;

fn fixtures() -> NpzReader<File> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/numerics.npz");
    let f = File::open(&p).unwrap_or_else(|e| {
        panic!("cannot open {} ({e}); regenerate it with `PYTHONPATH=python python python/tools/make_numerics_fixtures.py`", p.display())
    });
    NpzReader::new(f).expect("numerics.npz is a valid npz")
}

fn get<A: ReadableElement, D: Dimension>(
    npz: &mut NpzReader<File>,
    name: &str,
) -> ndarray::Array<A, D> {
    npz.by_name(name)
        .unwrap_or_else(|e| panic!("fixture array '{name}': {e}"))
}

/// Checks `got` against `want` within the absolute `bound` (`livegesture::compare`: NaN or Inf on
/// either side, nothing compared, or other shapes fail); returns the max abs error, or an error naming
/// the tensor, the index of the largest difference (or of the non-finite value), the error and the bound.
fn check_bound<S1, S2, D>(
    name: &str,
    got: &ArrayBase<S1, D>,
    want: &ArrayBase<S2, D>,
    bound: f64,
) -> Result<f64, String>
where
    S1: Data<Elem = f32>,
    S2: Data<Elem = f32>,
    D: Dimension,
    D::Pattern: Debug,
{
    if got.shape() != want.shape() {
        return Err(format!(
            "{name}: shape {:?} differs from the reference shape {:?}",
            got.shape(),
            want.shape()
        ));
    }
    let g: Vec<f32> = got.iter().copied().collect();
    let w: Vec<f32> = want.iter().copied().collect();
    let d = compare::diff(&g, &w);
    let at = |i: Option<usize>| i.and_then(|i| got.indexed_iter().nth(i).map(|(p, _)| p));
    if let Some(p) = d.problem() {
        let i = at(d.index).map(|p| format!("{p:?}")).unwrap_or("-".into());
        return Err(format!("{name}: max abs error inf at index {i}: {p}"));
    }
    if d.max_abs <= bound {
        Ok(d.max_abs)
    } else {
        let (gv, wv) = d.values.expect("a value pair where the error is");
        Err(format!(
            "{name}: max abs error {:.3e} at index {:?} exceeds the bound {bound:.0e} (got {gv}, reference {wv})",
            d.max_abs,
            at(d.index).expect("a non-empty tensor has an index"),
        ))
    }
}

fn frontend(n_mels: usize) -> FrontendConfig {
    FrontendConfig {
        n_mels,
        ..FrontendConfig::default()
    }
}

#[test]
fn logmel_matches_python_within_bound() {
    let mut npz = fixtures();
    let audio: Array1<f32> = get(&mut npz, "audio");
    let audio = audio.to_vec();
    for n_mels in [64usize, 16] {
        let want: Array2<f32> = get(&mut npz, &format!("logmel{n_mels}"));
        let got = logmel(&audio, &frontend(n_mels)).unwrap();
        assert_eq!(got.nrows(), 120, "2.1 s holds 15 tokens of 8 mel frames");
        let name = format!("logmel (n_mels={n_mels})");
        match check_bound(&name, &got, &want, LOGMEL_BOUND) {
            Ok(err) => {
                eprintln!("{name}: max abs error vs Python {err:.3e} (bound {LOGMEL_BOUND:.0e})")
            }
            Err(msg) => panic!("{msg}"),
        }
    }
}

#[test]
fn logmel_check_fails_on_perturbed_reference() {
    let mut npz = fixtures();
    let audio: Array1<f32> = get(&mut npz, "audio");
    let mut want: Array2<f32> = get(&mut npz, "logmel64");
    let got = logmel(audio.as_slice().unwrap(), &frontend(64)).unwrap();
    // The unperturbed comparison passes ...
    assert!(check_bound("logmel64", &got, &want, LOGMEL_BOUND).is_ok());
    // ... and one cell off by 2e-4 must fail, naming the tensor, the index and the error.
    want[[57, 13]] += 2e-4;
    let msg = check_bound("logmel64", &got, &want, LOGMEL_BOUND).unwrap_err();
    assert!(msg.starts_with("logmel64: max abs error 2.0"), "{msg}");
    assert!(
        msg.contains("at index (57, 13)") && msg.contains("exceeds the bound 1e-4"),
        "{msg}"
    );
    // Shape mismatches and NaN are failures too.
    let short = want.slice(ndarray::s![..100, ..]).to_owned();
    assert!(check_bound("logmel64", &got, &short, LOGMEL_BOUND)
        .unwrap_err()
        .contains("shape"));
    let mut nan = got.clone();
    nan[[3, 4]] = f32::NAN;
    let msg = check_bound("logmel64", &nan, &got, LOGMEL_BOUND).unwrap_err();
    assert!(msg.contains("inf") && msg.contains("(3, 4)"), "{msg}");
    // on the reference side, and on both sides at once (NaN is never agreement)
    let msg = check_bound("logmel64", &got, &nan, LOGMEL_BOUND).unwrap_err();
    assert!(msg.contains("reference") && msg.contains("(3, 4)"), "{msg}");
    assert!(check_bound("logmel64", &nan, &nan, LOGMEL_BOUND).is_err());
    let empty = Array2::<f32>::zeros((0, 64));
    assert!(check_bound("logmel64", &empty, &empty, LOGMEL_BOUND).is_err());
}

#[test]
fn streaming_frontend_equals_offline_for_any_chunk_size() {
    let mut npz = fixtures();
    let audio: Array1<f32> = get(&mut npz, "audio");
    let audio = audio.to_vec();
    for n_mels in [64usize, 16] {
        let cfg = frontend(n_mels);
        let offline = logmel(&audio, &cfg).unwrap();
        for chunk in [1usize, 160, 3200, 16000, audio.len()] {
            let mut s = StreamingLogMel::new(&cfg).unwrap();
            let mut rows: Vec<f32> = Vec::new();
            for c in audio.chunks(chunk) {
                for token in s.push(c).unwrap() {
                    assert_eq!(token.dim(), (8, n_mels));
                    rows.extend(token.iter());
                }
            }
            let streamed = Array2::from_shape_vec((rows.len() / n_mels, n_mels), rows).unwrap();
            assert_eq!(
                streamed, offline,
                "n_mels {n_mels}, chunk size {chunk}: streaming differs from offline"
            );
        }
    }
}

#[test]
fn splitmix64_matches_python() {
    let mut npz = fixtures();
    let want: Array1<u64> = get(&mut npz, "splitmix_seed42");
    let mut g = SplitMix64::new(42);
    let got: Vec<u64> = (0..want.len()).map(|_| g.next_u64()).collect();
    assert_eq!(got, want.to_vec());
}

#[test]
fn sampled_tokens_match_python() {
    let mut npz = fixtures();
    let names = npz.names().unwrap();
    let count: Array0<i64> = get(&mut npz, "samp_count");
    let count = count.into_scalar();
    assert!(count >= 8);
    for i in 0..count {
        let cond: Array1<f32> = get(&mut npz, &format!("samp{i}_cond"));
        let uncond_name = format!("samp{i}_uncond");
        let uncond: Option<Array1<f32>> = names
            .iter()
            .any(|n| n == &uncond_name || *n == format!("{uncond_name}.npy"))
            .then(|| get(&mut npz, &uncond_name));
        let seed: Array1<u64> = get(&mut npz, &format!("samp{i}_seed"));
        let params: Array1<f64> = get(&mut npz, &format!("samp{i}_params"));
        let want: Array1<i64> = get(&mut npz, &format!("samp{i}_tokens"));
        let (gamma, temperature, top_k) = (params[0], params[1], params[2] as usize);
        let mut rng = SplitMix64::new(seed[0]);
        let got: Vec<i64> = (0..want.len())
            .map(|_| {
                sample_token(
                    cond.as_slice().unwrap(),
                    uncond.as_ref().map(|u| u.as_slice().unwrap()),
                    &mut rng,
                    gamma,
                    temperature,
                    top_k,
                )
                .unwrap() as i64
            })
            .collect();
        assert_eq!(
            got,
            want.to_vec(),
            "sampler case {i} (K={}, guided={}, gamma={gamma}, temperature={temperature}, top_k={top_k}, seed={})",
            cond.len(),
            uncond.is_some(),
            seed[0]
        );
    }
}

#[test]
fn rotations_match_python() {
    let mut npz = fixtures();
    let aa_in: Array2<f32> = get(&mut npz, "rot_aa_in");
    let d6_ref: Array2<f64> = get(&mut npz, "rot_d6_of_aa");
    let got = Array2::from_shape_fn(d6_ref.dim(), |(r, c)| {
        let aa = aa_in.row(r);
        axis_angle_to_rot6d([aa[0], aa[1], aa[2]])[c]
    });
    let err = check_bound(
        "axis_angle_to_rot6d",
        &got,
        &d6_ref.mapv(|x| x as f32),
        ROTATION_BOUND,
    )
    .unwrap_or_else(|m| panic!("{m}"));
    eprintln!("axis_angle_to_rot6d: max abs error vs Python {err:.3e}");

    let d6_in: Array2<f32> = get(&mut npz, "rot_d6_in");
    let aa_ref: Array2<f64> = get(&mut npz, "rot_aa_of_d6");
    let got = Array2::from_shape_fn(aa_ref.dim(), |(r, c)| {
        let d = d6_in.row(r);
        rot6d_to_axis_angle([d[0], d[1], d[2], d[3], d[4], d[5]])[c]
    });
    let err = check_bound(
        "rot6d_to_axis_angle",
        &got,
        &aa_ref.mapv(|x| x as f32),
        ROTATION_BOUND,
    )
    .unwrap_or_else(|m| panic!("{m}"));
    eprintln!("rot6d_to_axis_angle: max abs error vs Python {err:.3e}");
}

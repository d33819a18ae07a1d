//! [`MotionModel::step_many`], the batch step every door uses (the server, the bindings): for both
//! families, streams stepped together (different seeds, guidance, audio lengths and chunkings, ended
//! by a job) give the frames each gives on its own, up to tract's rounding for another batch size
//! (docs/parity.md); a stream of another model in the same call is stepped on its own; a bad job fails
//! alone. The comparison is shown to fail for a stream with another seed.

use livegesture_parity_tests as common;

use livegesture::audio::{read_wav_16k_mono, AudioSpan};
use livegesture::backend::{self, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::model::{self, MotionModel, MotionStream, StreamJob, StreamOptions};
use livegesture::output::Frame;

/// tract's batched-vs-alone bound (docs/parity.md, "approximate").
const BOUND: f32 = 1e-4;

fn load(dir: std::path::PathBuf) -> (Bundle, Box<dyn MotionModel>) {
    let bundle = Bundle::load(dir).expect("test bundle loads");
    let be = backend::create(&BackendOptions::default()).expect("tract");
    let m = model::load(&bundle, be.as_ref()).expect("model");
    (bundle, m)
}

fn audio(bundle: &Bundle, offset: usize, n: usize) -> Vec<f32> {
    let clip = read_wav_16k_mono(bundle.path("reference/clip.wav")).expect("reference clip");
    clip.iter().cycle().skip(offset).take(n).copied().collect()
}

fn alone(m: &dyn MotionModel, opts: &StreamOptions, a: &[f32]) -> Vec<Frame> {
    let mut s = m.new_stream(opts).unwrap();
    let mut out = s.push_audio(a).unwrap();
    out.extend(s.finish(AudioSpan::at_16k(a.len() as u64)).unwrap());
    out
}

fn max_diff(a: &[Frame], b: &[Frame]) -> f32 {
    assert_eq!(a.len(), b.len(), "frame counts differ");
    let mut worst = 0f32;
    for (x, y) in a.iter().zip(b) {
        assert_eq!(x.index, y.index);
        for (p, q) in x
            .poses
            .iter()
            .chain(&x.trans)
            .chain(&x.expressions)
            .zip(y.poses.iter().chain(&y.trans).chain(&y.expressions))
        {
            worst = worst.max((p - q).abs());
        }
    }
    worst
}

/// Steps `plans` together: every round pushes each stream's next chunk (chunk sizes differ per
/// stream), the last round of each stream also ends it. Returns each stream's frames.
fn together(m: &dyn MotionModel, plans: &[(StreamOptions, Vec<f32>, usize)]) -> Vec<Vec<Frame>> {
    let mut streams: Vec<Box<dyn MotionStream>> = plans
        .iter()
        .map(|(o, _, _)| m.new_stream(o).unwrap())
        .collect();
    let mut pos = vec![0usize; plans.len()];
    let mut out = vec![Vec::new(); plans.len()];
    let mut ended = vec![false; plans.len()];
    while ended.iter().any(|e| !e) {
        let mut jobs = Vec::new();
        let mut who = Vec::new();
        for (i, s) in streams.iter_mut().enumerate() {
            if ended[i] {
                continue;
            }
            let (_, a, chunk) = &plans[i];
            let end = (pos[i] + chunk).min(a.len());
            let piece = &a[pos[i]..end];
            pos[i] = end;
            let job = if end == a.len() {
                ended[i] = true;
                StreamJob::push_and_finish(s.as_mut(), piece, AudioSpan::at_16k(a.len() as u64))
            } else {
                StreamJob::push(s.as_mut(), piece)
            };
            jobs.push(job);
            who.push(i);
        }
        for (i, r) in who.into_iter().zip(m.step_many(&mut jobs)) {
            out[i].extend(r.expect("job"));
        }
    }
    out
}

fn opts(seed: u64, guidance: Option<f64>) -> StreamOptions {
    StreamOptions {
        seed,
        guidance,
        ..Default::default()
    }
}

fn check_family(
    bundle: &Bundle,
    m: &dyn MotionModel,
    extra: impl Fn(StreamOptions) -> StreamOptions,
) {
    let plans = vec![
        (extra(opts(1, None)), audio(bundle, 0, 16000 * 3), 3200),
        (
            extra(opts(2, Some(1.0))),
            audio(bundle, 7000, 16000 * 2 + 123),
            1111,
        ),
        (
            extra(opts(3, Some(2.0))),
            audio(bundle, 30000, 16000 * 4 + 5),
            16000,
        ),
    ];
    let got = together(m, &plans);
    for ((o, a, _), g) in plans.iter().zip(&got) {
        let want = alone(m, o, a);
        assert_eq!(
            g.len() as u64,
            AudioSpan::at_16k(a.len() as u64).frames(30),
            "seed {}: frames cover the input",
            o.seed
        );
        let d = max_diff(g, &want);
        assert!(
            d <= BOUND,
            "seed {}: batched vs alone differ by {d}",
            o.seed
        );
    }
    // the comparison can fail: another seed gives other motion
    let other = alone(m, &extra(opts(9, None)), &plans[0].1);
    assert!(max_diff(&got[0], &other) > BOUND);
}

#[test]
fn livegesture_streams_stepped_together_equal_each_alone() {
    let (bundle, m) = load(common::tiny_bundle());
    check_family(&bundle, m.as_ref(), |o| o);
}

#[test]
fn diffsheg_windows_stepped_together_equal_each_alone() {
    let (bundle, m) = load(common::diffsheg_tiny_bundle());
    // few DDIM steps keep the test short; one stream with other steps and jumps shares the calls
    check_family(&bundle, m.as_ref(), |o| StreamOptions {
        ddim_steps: Some(if o.seed == 3 { 4 } else { 5 }),
        jumps: Some(if o.seed == 2 { 1 } else { 2 }),
        ..o
    });
}

#[test]
fn foreign_streams_step_alone_and_a_bad_job_fails_alone() {
    for dir in [common::tiny_bundle(), common::diffsheg_tiny_bundle()] {
        let (bundle, m) = load(dir.clone());
        let (_, other_model) = load(dir);
        let o = StreamOptions {
            ddim_steps: bundle.diffsheg().is_ok().then_some(5),
            ..opts(4, None)
        };
        let a = audio(&bundle, 0, 16000 * 2);
        let want = alone(m.as_ref(), &o, &a);
        let mut mine = m.new_stream(&o).unwrap();
        let mut foreign = other_model.new_stream(&o).unwrap();
        let mut bad = m.new_stream(&o).unwrap();
        let span = AudioSpan::at_16k(a.len() as u64);
        let mut nan = a.clone();
        nan[100] = f32::NAN;
        // the bad stream claims ten times the audio it pushed
        let mut jobs = vec![
            StreamJob::push_and_finish(mine.as_mut(), &a, span),
            StreamJob::push_and_finish(foreign.as_mut(), &a, span),
            StreamJob::push_and_finish(bad.as_mut(), &a, AudioSpan::at_16k(10 * a.len() as u64)),
        ];
        let r = m.step_many(&mut jobs);
        drop(jobs);
        let mut r = r.into_iter();
        let g0 = r.next().unwrap().expect("own stream");
        let g1 = r.next().unwrap().expect("foreign stream");
        let e = r
            .next()
            .unwrap()
            .expect_err("a span that does not match the audio");
        assert!(format!("{e:#}").contains("finish"), "{e:#}");
        assert!(max_diff(&g0, &want) <= BOUND);
        assert_eq!(max_diff(&g1, &want), 0.0, "the foreign stream ran alone");
        // non-finite audio is refused for its job only
        let mut s = m.new_stream(&o).unwrap();
        let mut t = m.new_stream(&o).unwrap();
        let mut jobs = vec![
            StreamJob::push(s.as_mut(), &nan),
            StreamJob::push(t.as_mut(), &a[..16000]),
        ];
        let r = m.step_many(&mut jobs);
        assert!(r[0].is_err());
        assert!(r[1].is_ok());
    }
}

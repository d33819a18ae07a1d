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

/// tract's batched-vs-alone bound (docs/parity.md, "approximate"), scaled like every bound.
const BOUND: f64 = 1e-4;

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

/// The scaled difference of two frame sequences through the shared comparison
/// ([`common::frames_diff`], every field incl. foot contact): infinite when a value is NaN or Inf on
/// either side, nothing is compared, or the counts or indices differ (a plain `f32::max` fold drops
/// NaN, so NaN frames used to pass as identical).
fn max_diff(a: &[Frame], b: &[Frame]) -> f64 {
    common::frames_diff(a, b).1.scaled_error()
}

/// The comparison the tests use fails on NaN on either side, where the `f32::max` fold it replaced
/// reported 0 (issue 38 item 3: the old fold is kept here to show both outcomes).
#[test]
fn the_frame_comparison_fails_on_nan() {
    fn old_max_diff(a: &[Frame], b: &[Frame]) -> f32 {
        let mut worst = 0f32;
        for (x, y) in a.iter().zip(b) {
            for (p, q) in x.poses.iter().zip(&y.poses) {
                worst = worst.max((p - q).abs());
            }
        }
        worst
    }
    let (bundle, m) = load(common::tiny_bundle());
    let frames = alone(m.as_ref(), &opts(1, None), &audio(&bundle, 0, 16000));
    let nan: Vec<Frame> = frames
        .iter()
        .map(|f| {
            let mut f = f.clone();
            f.poses.iter_mut().for_each(|v| *v = f32::NAN);
            f
        })
        .collect();
    assert_eq!(
        old_max_diff(&nan, &frames),
        0.0,
        "premise: the old fold passed NaN frames"
    );
    assert!(max_diff(&nan, &frames).is_infinite());
    assert!(max_diff(&frames, &nan).is_infinite());
    assert_eq!(max_diff(&frames, &frames), 0.0);
    common::assert_nan_fails_either_side("step_many comparison", &frames, &frames, |g, w| {
        let d = max_diff(g, w);
        assert!(d <= BOUND, "{}", common::frames_diff(g, w).1)
    });
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

/// The caches of LiveGesture streams stepped together stay stacked between `step_many` calls (the
/// model's cohorts): streams that change company from call to call, step alone in between (their
/// caches called home), are reset, or are dropped while their caches are stacked with others', each
/// keep the frames they get alone.
#[test]
fn livegesture_streams_changing_company_keep_their_frames() {
    let (bundle, m) = load(common::tiny_bundle());
    check_changing_company(&bundle, m.as_ref());
}

/// The body of [`livegesture_streams_changing_company_keep_their_frames`], for any LiveGesture
/// bundle and model (also run on ring caches, `super::ring`).
pub(crate) fn check_changing_company(bundle: &Bundle, m: &dyn MotionModel) {
    let tok = bundle.frontend().token_end(0) as usize;
    let n = 5;
    let len = tok * 14 + 321;
    let audios: Vec<Vec<f32>> = (0..n).map(|i| audio(bundle, i * 5003, len)).collect();
    let os: Vec<StreamOptions> = (0..n)
        .map(|i| opts(i as u64 + 1, (i == 2).then_some(1.0)))
        .collect();
    let mut streams: Vec<Box<dyn MotionStream>> =
        os.iter().map(|o| m.new_stream(o).unwrap()).collect();
    let mut pos = vec![0usize; n];
    let mut out: Vec<Vec<Frame>> = vec![Vec::new(); n];
    // a stream that steps with the others and is dropped while its caches are stacked with theirs
    let mut extra = Some(m.new_stream(&opts(99, None)).unwrap());
    let filler = audio(bundle, 0, tok);
    for round in 0..12 {
        let mut jobs = Vec::new();
        let mut who = Vec::new();
        for (i, s) in streams.iter_mut().enumerate() {
            // varying company: stream i sits out some rounds; stream 4 steps alone on odd rounds
            if (round + i) % 3 == 0 && round % 4 != 0 {
                continue;
            }
            let end = (pos[i] + tok).min(len);
            let piece = &audios[i][pos[i]..end];
            pos[i] = end;
            if i == 4 && round % 2 == 1 {
                out[i].extend(s.push_audio(piece).unwrap());
                continue;
            }
            jobs.push(StreamJob::push(s.as_mut(), piece));
            who.push(i);
        }
        if let Some(e) = extra.as_mut() {
            jobs.push(StreamJob::push(e.as_mut(), &filler));
        }
        let results = m.step_many(&mut jobs);
        drop(jobs);
        for (k, r) in results.into_iter().enumerate() {
            let frames = r.expect("job");
            if let Some(&i) = who.get(k) {
                out[i].extend(frames);
            }
        }
        if round == 5 {
            extra = None;
        }
        if round == 7 {
            // stream 3 starts over
            streams[3].reset().unwrap();
            pos[3] = 0;
            out[3].clear();
        }
    }
    // the rest of every stream's audio and its end, all together
    let mut jobs: Vec<StreamJob> = streams
        .iter_mut()
        .enumerate()
        .map(|(i, s)| {
            StreamJob::push_and_finish(
                s.as_mut(),
                &audios[i][pos[i]..],
                AudioSpan::at_16k(len as u64),
            )
        })
        .collect();
    let results = m.step_many(&mut jobs);
    drop(jobs);
    for (i, r) in results.into_iter().enumerate() {
        out[i].extend(r.expect("job"));
    }
    for i in 0..n {
        let want = alone(m, &os[i], &audios[i]);
        assert_eq!(out[i].len(), want.len(), "stream {i}: frame count");
        let d = max_diff(&out[i], &want);
        assert!(d <= BOUND, "stream {i}: together vs alone differ by {d}");
    }
    // the comparison can fail: another stream's audio gives other motion
    assert!(max_diff(&out[0], &alone(m, &os[0], &audios[1])) > BOUND);
}

/// Streams stepped in the same company call after call are not copied again (their caches stay
/// stacked: `MotionModel::streams_regrouped` counts each joining once); a change of company copies
/// only the streams that change it.
#[test]
fn livegesture_streams_in_steady_company_are_not_copied() {
    let (bundle, m) = load(common::tiny_bundle());
    let len = bundle.frontend().token_end(12) as usize;
    let audios: Vec<Vec<f32>> = (0..3).map(|i| audio(&bundle, i * 4001, len)).collect();
    let mut streams: Vec<Box<dyn MotionStream>> = (0..3)
        .map(|i| m.new_stream(&opts(i + 1, None)).unwrap())
        .collect();
    assert_eq!(m.streams_regrouped(), 0);
    // the streams of `who` together, each pushed exactly the audio that completes its next token
    let step = |streams: &mut [Box<dyn MotionStream>], who: &[usize]| {
        let mut jobs: Vec<StreamJob> = streams
            .iter_mut()
            .enumerate()
            .filter(|(i, _)| who.contains(i))
            .map(|(i, s)| {
                let (from, to) = (s.samples_received(), s.next_unit_samples());
                StreamJob::push(s.as_mut(), &audios[i][from as usize..to as usize])
            })
            .collect();
        for r in m.step_many(&mut jobs) {
            assert!(!r.expect("job").is_empty(), "a token step without frames");
        }
    };
    // the three together, four tokens: each copied into the cohort once
    for k in 0..4 {
        step(&mut streams, &[0, 1, 2]);
        assert_eq!(m.streams_regrouped(), 3, "after token {k}");
    }
    // stream 2 sits out: it leaves the cohort (copied once), the other two stay
    step(&mut streams, &[0, 1]);
    assert_eq!(m.streams_regrouped(), 4);
    step(&mut streams, &[2]);
    assert_eq!(m.streams_regrouped(), 4);
    // back together: stream 2 joins again
    step(&mut streams, &[0, 1, 2]);
    assert_eq!(m.streams_regrouped(), 5);
    step(&mut streams, &[0, 1, 2]);
    assert_eq!(m.streams_regrouped(), 5);
}

/// Two cohorts due in one call (a server behind its tick grid steps two slots at once) step apart
/// as they are, copying nothing, and every stream keeps the frames it gets alone.
#[test]
fn livegesture_whole_cohorts_due_together_step_apart() {
    let (bundle, m) = load(common::tiny_bundle());
    let n = 24;
    let len = bundle.frontend().token_end(7) as usize + 100;
    let audios: Vec<Vec<f32>> = (0..n).map(|i| audio(&bundle, i * 997, len)).collect();
    let os: Vec<StreamOptions> = (0..n).map(|i| opts(i as u64 + 7, None)).collect();
    let mut streams: Vec<Box<dyn MotionStream>> =
        os.iter().map(|o| m.new_stream(o).unwrap()).collect();
    let mut out: Vec<Vec<Frame>> = vec![Vec::new(); n];
    let mut step = |streams: &mut [Box<dyn MotionStream>], who: std::ops::Range<usize>| {
        let mut jobs: Vec<StreamJob> = Vec::new();
        for (i, s) in streams.iter_mut().enumerate() {
            if who.contains(&i) {
                let (from, to) = (
                    s.samples_received() as usize,
                    s.next_unit_samples() as usize,
                );
                jobs.push(StreamJob::push(s.as_mut(), &audios[i][from..to]));
            }
        }
        for (i, r) in who.zip(m.step_many(&mut jobs)) {
            out[i].extend(r.expect("job"));
        }
    };
    // two cohorts of 12 (two slots), then both in every call
    for _ in 0..3 {
        step(&mut streams, 0..12);
        step(&mut streams, 12..24);
    }
    assert_eq!(m.streams_regrouped(), 24);
    for _ in 0..3 {
        step(&mut streams, 0..24);
    }
    assert_eq!(m.streams_regrouped(), 24, "whole cohorts were copied");
    let mut jobs: Vec<StreamJob> = streams
        .iter_mut()
        .enumerate()
        .map(|(i, s)| {
            let from = s.samples_received() as usize;
            StreamJob::push_and_finish(
                s.as_mut(),
                &audios[i][from..],
                AudioSpan::at_16k(len as u64),
            )
        })
        .collect();
    for (i, r) in m.step_many(&mut jobs).into_iter().enumerate() {
        out[i].extend(r.expect("job"));
    }
    drop(jobs);
    for i in 0..n {
        let want = alone(m.as_ref(), &os[i], &audios[i]);
        assert_eq!(out[i].len(), want.len(), "stream {i}: frame count");
        let d = max_diff(&out[i], &want);
        assert!(d <= BOUND, "stream {i}: apart vs alone differ by {d}");
    }
}

/// Streams of **one** model stepped on two threads at the same time (issue 37 item 4: the graphs are
/// shared, each run has its own plan state or session) give exactly the frames each gives alone:
/// same seed, same frames, whatever the interleaving. Both families, both backends; every push on
/// both threads starts together (a barrier per chunk), so their graph runs overlap. The comparison
/// is shown to fail for a stream with another seed.
fn check_two_threads(
    bundle: &Bundle,
    kind: backend::BackendKind,
    extra: impl Fn(StreamOptions) -> StreamOptions + Sync,
) {
    let be = backend::create(&BackendOptions {
        kind,
        ..Default::default()
    })
    .expect("backend");
    let m = model::load(bundle, be.as_ref()).expect("model");
    let plans = [
        (extra(opts(11, None)), audio(bundle, 0, 16000 * 3 + 77)),
        (extra(opts(12, Some(1.0))), audio(bundle, 9000, 16000 * 3)),
    ];
    let chunk = 2133;
    let rounds = plans
        .iter()
        .map(|(_, a)| a.len().div_ceil(chunk))
        .max()
        .unwrap_or(0);
    let both = std::sync::Barrier::new(plans.len());
    let m = m.as_ref();
    let threaded: Vec<Vec<Frame>> = std::thread::scope(|sc| {
        let hs: Vec<_> = plans
            .iter()
            .map(|(o, a)| {
                let both = &both;
                sc.spawn(move || {
                    let mut s = m.new_stream(o).unwrap();
                    let mut out = Vec::new();
                    let mut chunks = a.chunks(chunk);
                    for _ in 0..rounds {
                        both.wait();
                        if let Some(c) = chunks.next() {
                            out.extend(s.push_audio(c).unwrap());
                        }
                    }
                    out.extend(s.finish(AudioSpan::at_16k(a.len() as u64)).unwrap());
                    out
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for ((o, a), got) in plans.iter().zip(&threaded) {
        let want = alone(m, o, a);
        assert_eq!(
            got.len() as u64,
            AudioSpan::at_16k(a.len() as u64).frames(30),
            "{kind}, seed {}: frames cover the input",
            o.seed
        );
        assert_eq!(
            max_diff(got, &want),
            0.0,
            "{kind}, seed {}: the stream on its thread differs from the stream alone",
            o.seed
        );
    }
    // the comparison can fail: another seed gives other motion
    let other = alone(m, &extra(opts(9, None)), &plans[0].1);
    assert!(max_diff(&threaded[0], &other) > 0.0);
}

#[test]
fn livegesture_streams_on_two_threads_equal_each_alone() {
    let bundle = Bundle::load(common::tiny_bundle()).expect("test bundle loads");
    check_two_threads(&bundle, backend::BackendKind::Tract, |o| o);
    common::require_ort();
    check_two_threads(&bundle, backend::BackendKind::Ort, |o| o);
}

#[test]
fn diffsheg_streams_on_two_threads_equal_each_alone() {
    let bundle = Bundle::load(common::diffsheg_tiny_bundle()).expect("test bundle loads");
    let few = |o: StreamOptions| StreamOptions {
        ddim_steps: Some(4),
        ..o
    };
    check_two_threads(&bundle, backend::BackendKind::Tract, few);
    common::require_ort();
    check_two_threads(&bundle, backend::BackendKind::Ort, few);
}

/// [`LiveGestureModel::step_many_steps`], the token steps of `step_many` (what the parity `batch`
/// check compares): the same tokens as each stream stepped alone, the frames `step_many` gives (cut
/// at the end of an ended job's input), and a stream of another model refused for its job only.
#[test]
fn step_many_steps_gives_the_tokens_of_each_stream_alone() {
    use livegesture::model::livegesture::{LiveGestureGraphs, LiveGestureModel};
    let bundle = Bundle::load(common::tiny_bundle()).expect("test bundle loads");
    let be = backend::create(&BackendOptions::default()).expect("tract");
    let m = LiveGestureModel::from(LiveGestureGraphs::new(&bundle, be.as_ref()).unwrap());
    let g = LiveGestureGraphs::new(&bundle, be.as_ref()).unwrap();
    let plans: Vec<(StreamOptions, Vec<f32>)> = (0..3)
        .map(|i| {
            (
                opts(30 + i, (i == 2).then_some(1.0)),
                audio(&bundle, i as usize * 5003, 16000 * 2 + 777),
            )
        })
        .collect();
    let mut streams: Vec<Box<dyn MotionStream>> = plans
        .iter()
        .map(|(o, _)| m.new_stream(o).unwrap())
        .collect();
    let mut got = vec![Vec::new(); plans.len()];
    let n = plans[0].1.len();
    let mut pos = 0;
    while pos < n {
        let end = (pos + 4000).min(n);
        let mut jobs: Vec<StreamJob<'_>> = streams
            .iter_mut()
            .zip(&plans)
            .map(|(s, (_, a))| {
                if end == n {
                    StreamJob::push_and_finish(
                        s.as_mut(),
                        &a[pos..end],
                        AudioSpan::at_16k(n as u64),
                    )
                } else {
                    StreamJob::push(s.as_mut(), &a[pos..end])
                }
            })
            .collect();
        for (i, r) in m.step_many_steps(&mut jobs).into_iter().enumerate() {
            got[i].extend(r.expect("job"));
        }
        pos = end;
    }
    for (i, (o, a)) in plans.iter().enumerate() {
        let mut s = g.new_stream(o).unwrap();
        let mut want = g.push_steps(&mut s, a).unwrap();
        want.extend(g.finish_steps(&mut s, AudioSpan::at_16k(n as u64)).unwrap());
        let tokens = |v: &[livegesture::model::livegesture::TokenStep]| -> Vec<Vec<i64>> {
            v.iter().map(|s| s.tokens.clone()).collect()
        };
        assert!(want.len() >= 10, "stream {i}: {} tokens", want.len());
        assert_eq!(tokens(&got[i]), tokens(&want), "stream {i}: tokens");
        let frames = |v: &[livegesture::model::livegesture::TokenStep]| -> Vec<Frame> {
            v.iter().flat_map(|s| s.frames.clone()).collect()
        };
        assert_eq!(
            frames(&got[i]).len() as u64,
            AudioSpan::at_16k(n as u64).frames(30),
            "stream {i}: frames cut at the end of the input"
        );
        assert!(
            max_diff(&frames(&got[i]), &frames(&want)) <= BOUND,
            "stream {i}: {}",
            common::frames_diff(&frames(&got[i]), &frames(&want)).1
        );
    }
    // a stream of another model: refused for its job, the other job steps
    let other = LiveGestureModel::from(LiveGestureGraphs::new(&bundle, be.as_ref()).unwrap());
    let mut foreign = other.new_stream(&opts(1, None)).unwrap();
    let mut own = m.new_stream(&opts(1, None)).unwrap();
    let a = audio(&bundle, 0, 16000);
    let mut jobs = vec![
        StreamJob::push(foreign.as_mut(), &a),
        StreamJob::push(own.as_mut(), &a),
    ];
    let r = m.step_many_steps(&mut jobs);
    let e = r[0].as_ref().expect_err("a foreign stream");
    assert!(format!("{e:#}").contains("another model"), "{e:#}");
    assert!(!r[1].as_ref().expect("own stream").is_empty());
}

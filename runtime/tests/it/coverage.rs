//! Whole-audio coverage (docs/output.md): at the end of the audio the last partial token is completed with
//! silence and its frames are cut at the audio's end, so a stream emits exactly
//! `ceil(duration x 30)` frames, computed from the input's own sample count and rate. Checked through
//! the family-independent API ([`livegesture::model`]) and the LiveGesture pipeline.

use livegesture_parity_tests as common;

use livegesture::audio::{AudioSpan, Resampler16k};
use livegesture::backend::{self, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::model::livegesture::{LiveGestureGraphs, StreamOptions};
use livegesture::model::{self, MotionModel};
use livegesture::output::Frame;

fn bundle() -> Bundle {
    Bundle::load(common::tiny_bundle()).expect("test bundle loads")
}

fn load_model(b: &Bundle) -> Box<dyn MotionModel> {
    let be = backend::create(&BackendOptions::default()).unwrap();
    model::load(b, be.as_ref()).expect("model loads")
}

/// A deterministic speech-like signal (a few tones with an envelope) at `rate` Hz.
fn signal(n: u64, rate: u32) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let t = i as f64 / rate as f64;
            let env = 0.5 + 0.5 * (2.0 * std::f64::consts::PI * 3.0 * t).sin();
            (env * (0.3 * (2.0 * std::f64::consts::PI * 220.0 * t).sin()
                + 0.1 * (2.0 * std::f64::consts::PI * 1330.0 * t).sin())) as f32
        })
        .collect()
}

/// Runs `audio` (at `rate`) through a fresh stream in `chunk`-sample pieces, resampling like the
/// CLI does, then finishes it with the input's span.
fn run(m: &dyn MotionModel, audio: &[f32], rate: u32, chunk: usize) -> Vec<Frame> {
    let mut s = m
        .new_stream(&StreamOptions {
            seed: 7,
            ..Default::default()
        })
        .unwrap();
    let mut rs = Resampler16k::new(rate, "test").unwrap();
    let mut frames = Vec::new();
    for c in audio.chunks(chunk.max(1)) {
        frames.extend(s.push_audio(&rs.push(c).unwrap()).unwrap());
    }
    frames.extend(s.push_audio(&rs.finish().unwrap()).unwrap());
    let span = rs.input_span();
    assert_eq!(span, AudioSpan::new(audio.len() as u64, rate));
    frames.extend(s.finish(span).unwrap());
    assert_eq!(s.frames_emitted(), frames.len() as u64);
    frames
}

#[test]
fn the_frame_count_formula() {
    // the recording of issue 14: 5.86 s gives 176 frames, not 172
    assert_eq!(AudioSpan::at_16k(93_760).frames(30), 176);
    assert_eq!(AudioSpan::new(0, 44_100).frames(30), 0);
    assert_eq!(AudioSpan::new(1, 44_100).frames(30), 1);
    assert_eq!(AudioSpan::new(44_100, 44_100).frames(30), 30);
    assert_eq!(AudioSpan::new(44_101, 44_100).frames(30), 31);
    assert_eq!(AudioSpan::new(1470, 44_100).frames(30), 1); // exactly one frame's duration
    assert_eq!(AudioSpan::new(1471, 44_100).frames(30), 2);
}

#[test]
fn frames_cover_the_whole_audio_at_any_length_and_rate() {
    let b = bundle();
    let m = load_model(&b);
    let f = b.frontend();
    // 16 kHz: shorter than a token, on a token boundary, one sample past it, one sample before it
    let mut cases: Vec<(u64, u32)> = vec![
        (1, 16_000),
        (1000, 16_000),
        (f.token_end(0), 16_000),
        (f.token_end(0) + 1, 16_000),
        (f.token_end(3) - 1, 16_000),
        (f.token_end(3), 16_000),
        (f.token_end(3) + 1, 16_000),
    ];
    // other rates: one input sample past the input time of a token boundary, and a few lengths
    for rate in [8_000u32, 22_050, 44_100, 48_000] {
        let boundary = (f.token_end(4) * rate as u64).div_ceil(16_000);
        cases.extend([
            (boundary, rate),
            (boundary + 1, rate),
            (rate as u64 * 7 / 10, rate),
        ]);
    }
    for (n, rate) in cases {
        let frames = run(m.as_ref(), &signal(n, rate), rate, 4096);
        let want = (n * 30).div_ceil(rate as u64);
        assert_eq!(frames.len() as u64, want, "{n} samples at {rate} Hz");
        for (i, fr) in frames.iter().enumerate() {
            assert_eq!(fr.index, i as u64, "{n} samples at {rate} Hz");
        }
    }
}

#[test]
fn chunk_size_invariance_holds_with_finish() {
    let b = bundle();
    let m = load_model(&b);
    for (n, rate) in [(b.frontend().token_end(5) + 1, 16_000u32), (30_001, 44_100)] {
        let audio = signal(n, rate);
        let whole = run(m.as_ref(), &audio, rate, audio.len());
        assert_eq!(whole.len() as u64, (n * 30).div_ceil(rate as u64));
        for chunk in [1, 160, 3331] {
            let got = run(m.as_ref(), &audio, rate, chunk);
            assert_eq!(got, whole, "{n} samples at {rate} Hz in chunks of {chunk}");
        }
    }
}

#[test]
fn finish_refuses_a_span_that_does_not_match_the_audio() {
    let b = bundle();
    let m = load_model(&b);
    let f = b.frontend();
    let audio = signal(f.token_end(3) + 100, 16_000);
    let mut s = m.new_stream(&StreamOptions::default()).unwrap();
    let pushed = s.push_audio(&audio).unwrap().len() as u64;
    assert_eq!(pushed, 16);
    // two tokens more than was pushed
    let e = s
        .finish(AudioSpan::at_16k(f.token_end(5)))
        .unwrap_err()
        .to_string();
    assert!(e.contains("more than one token"), "{e}");
    // fewer frames than already emitted
    let e = s.finish(AudioSpan::at_16k(1000)).unwrap_err().to_string();
    assert!(e.contains("fewer frames than already produced"), "{e}");
    // the right span: one more token, cut at the end
    let last = s.finish(AudioSpan::at_16k(audio.len() as u64)).unwrap();
    assert_eq!(
        pushed + last.len() as u64,
        (audio.len() as u64 * 30).div_ceil(16_000)
    );
    // a finished stream refuses more audio until reset; reset gives the same motion again
    assert!(s.push_audio(&audio[..10]).is_err());
    assert!(s.finish(AudioSpan::at_16k(audio.len() as u64)).is_err());
    s.reset().unwrap();
    assert_eq!(s.frames_emitted(), 0);
    let again = s.push_audio(&audio).unwrap();
    assert_eq!(again.len() as u64, pushed);
}

#[test]
fn the_trait_stream_equals_the_pipeline() {
    let b = bundle();
    let m = load_model(&b);
    assert_eq!(m.family(), livegesture::bundle::Family::LiveGesture);
    let be = backend::create(&BackendOptions::default()).unwrap();
    let p = LiveGestureGraphs::new(&b, be.as_ref()).unwrap();
    let audio = signal(b.frontend().token_end(6) + 777, 16_000);
    let opts = StreamOptions {
        seed: 7,
        ..Default::default()
    };
    let mut s = p.new_stream(&opts).unwrap();
    let mut want = p.push(&mut s, &audio).unwrap();
    let steps = p
        .finish_steps(&mut s, AudioSpan::at_16k(audio.len() as u64))
        .unwrap();
    assert_eq!(steps.len(), 1);
    want.extend(steps.into_iter().flat_map(|s| s.frames));
    let got = run(m.as_ref(), &audio, 16_000, 1000);
    assert_eq!(got, want);
    let ts = m.new_stream(&opts).unwrap();
    assert_eq!((ts.frames_per_unit(), ts.lookahead_frames()), (4, 0));
}

//! `livegesture serve` on a DiffSHEG bundle (one stream per session, FOPPAS windows): the frames equal
//! `generate`'s for several message splits and input formats, the `ready` message names the family and
//! the look-ahead, two concurrent sessions each equal their own `generate`, refusals and the SIGTERM
//! drain behave as for LiveGesture.
//!
//! The reference is what `generate` computes: the WAV read by `read_wav_16k_mono`, one stream of the
//! model loaded through `livegesture::model::load` with the same seed and backend, ended by
//! `finish` with the input's own sample count and rate. One test also runs the `generate` binary.
//!
//! The bundle is `$LIVEGESTURE_DIFFSHEG_TINY_BUNDLE` (set by `scripts/test.sh`), else
//! `target/test-bundles/diffsheg-tiny`: window 24 frames, overlap 4, so a few seconds of audio run
//! several windows.

use crate::serve_common;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use livegesture::audio::AudioSpan;
use livegesture::bundle::{Bundle, Family};
use livegesture::model::{self, MotionModel, StreamOptions};
use livegesture::output::{Frame, FPS};
use livegesture_serve::{ServeConfig, Server};
use serve_common::{
    assert_equal, assert_matches_generate, assert_stereo_f32_splits, collect, connect, exited_ok,
    generate_binary, generate_input, max_diff, model_info, pcm_bytes, read_frames, session,
    spawn_serve, speech_of, tract_backend, within, Outcome, Ws,
};
use tokio_tungstenite::tungstenite::Message;

fn bundle_dir() -> PathBuf {
    let p = std::env::var_os("LIVEGESTURE_DIFFSHEG_TINY_BUNDLE")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/test-bundles/diffsheg-tiny")
        });
    assert!(
        p.join("manifest.json").exists(),
        "no DiffSHEG test bundle at {}: run `$LIVEGESTURE_PY export/export.py --family diffsheg --config tiny \
         --random-seed 0 --out target/test-bundles/diffsheg-tiny` or set LIVEGESTURE_DIFFSHEG_TINY_BUNDLE",
        p.display()
    );
    p
}

fn load_model() -> (Bundle, Box<dyn MotionModel>) {
    let bundle = Bundle::load(bundle_dir()).expect("bundle");
    assert_eq!(bundle.family(), Family::DiffSheg);
    let be = tract_backend();
    let m = model::load(&bundle, be.as_ref()).expect("model");
    (bundle, m)
}

fn start(cfg: ServeConfig) -> Server {
    Server::start("127.0.0.1:0".parse().unwrap(), cfg, || {
        let (bundle, m) = load_model();
        let info = model_info("diffsheg-test", &bundle, m.backend_name());
        Ok((m, info))
    })
    .expect("server starts")
}

/// `seconds` of the bundle's reference speech clip at 16 kHz (repeated if shorter).
fn speech(seconds: f64) -> Vec<f32> {
    speech_of(&bundle_dir(), seconds)
}

/// What `generate` computes for these interleaved samples (see the module docs).
fn reference(samples: &[f32], rate: u32, channels: u16, float: bool, seed: u64) -> Vec<Frame> {
    let (a16, input) = generate_input(samples, rate, channels, float);
    let (_bundle, m) = load_model();
    let mut s = m
        .new_stream(&StreamOptions {
            seed,
            ..Default::default()
        })
        .unwrap();
    let mut out = s.push_audio(&a16).unwrap();
    out.extend(s.finish(input).unwrap());
    assert_eq!(out.len() as u64, input.frames(FPS as u64));
    out
}

#[test]
fn frames_equal_generate_whatever_the_split() {
    let server = start(ServeConfig::default());
    let addr = server.addr();
    // 3.07 s = 93 frames (not a whole frame at the end): windows of 24 every 20 frames, a shorter
    // last window run at the end on audio padded with silence
    let audio = speech(3.07);
    let want = reference(&audio, 16000, 1, false, 3);
    assert_eq!(want.len(), 93);
    let bytes = pcm_bytes(&audio, false);
    // whole, odd sizes (a sample's two bytes straddle messages), 10 ms, 1 byte then larger, and one
    // message per window step (the window boundary falls inside a message)
    for cuts in [
        vec![bytes.len()],
        vec![333, 7, 1001],
        vec![320],
        vec![1, 4097, 3],
        vec![2 * 20 * 16000 / 30 + 2],
    ] {
        let got = within(120, session(addr, "?seed=3", &bytes, &cuts));
        let ready = got.ready.as_ref().expect("ready message");
        assert_eq!(ready["family"], "diffsheg");
        assert_eq!(ready["fps"], 30);
        assert_eq!(ready["seed"], 3);
        // the tiny bundle's FOPPAS: window 24, overlap 4 -> units of 20 frames, 4 frames look-ahead,
        // the first frame after the first window's 24 frames of audio
        assert_eq!(ready["frames_per_unit"], 20);
        assert_eq!(ready["lookahead_frames"], 4);
        assert_eq!(ready["first_frame_samples_16k"], 24 * 16000 / 30);
        assert_equal(&got.frames, &want, &format!("split {cuts:?}"));
        assert_eq!(got.done, Some(want.len() as u64));
        assert_eq!(got.close.as_ref().map(|c| c.0), Some(1000));
    }
    // a different seed gives different motion (the comparison above can fail)
    let other = within(120, session(addr, "?seed=4", &bytes, &[3200]));
    assert!(
        max_diff(&other.frames, &want, "seed 4") > 1e-3,
        "seed 4 gave the frames of seed 3"
    );
    // so does another guidance scale (the session's option reaches the stream)
    let g = within(120, session(addr, "?seed=3&guidance=2.5", &bytes, &[3200]));
    assert_eq!(g.ready.as_ref().unwrap()["guidance"], 2.5);
    assert!(max_diff(&g.frames, &want, "guidance 2.5") > 1e-4);
    let m = server.metrics().render();
    assert!(
        m.contains("livegesture_batch_size_bucket{le=\"1.0\"}"),
        "{m}"
    );
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn stereo_44k_f32_binary_equals_generate() {
    let server = start(ServeConfig::default());
    let addr = server.addr();
    let mono = speech(2.2);
    // 44.1 kHz stereo: the 16 kHz clip repeated per sample (a crude upsampling; any signal will do)
    let n44 = (mono.len() as f64 * 44100.0 / 16000.0) as usize;
    let inter: Vec<f32> = (0..n44)
        .flat_map(|i| {
            let v = mono[(i * 16000 / 44100).min(mono.len() - 1)];
            [v, 0.6 * v]
        })
        .collect();
    let want = reference(&inter, 44100, 2, true, 9);
    assert_eq!(
        want.len() as u64,
        AudioSpan::new(n44 as u64, 44100).frames(30)
    );
    let bytes = pcm_bytes(&inter, true);
    assert_stereo_f32_splits(addr, &bytes, &want, 120);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn frames_equal_the_generate_binary() {
    let server = start(ServeConfig::default());
    let audio = speech(2.5);
    let m = generate_binary(&bundle_dir(), &audio, 5);
    let got = within(
        120,
        session(server.addr(), "?seed=5", &pcm_bytes(&audio, false), &[640]),
    );
    // both cover the whole audio with the same frames (docs/output.md)
    assert_eq!(
        got.frames.len() as u64,
        AudioSpan::at_16k(audio.len() as u64).frames(30)
    );
    assert_matches_generate(&got.frames, &m, 1e-4);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn two_concurrent_sessions_each_equal_their_generate() {
    let server = start(ServeConfig::default());
    let addr = server.addr();
    let a = speech(3.0);
    let b: Vec<f32> = speech(4.0)[16000..].to_vec();
    let (wa, wb) = (
        reference(&a, 16000, 1, false, 1),
        reference(&b, 16000, 1, false, 2),
    );
    let (ba, bb) = (pcm_bytes(&a, false), pcm_bytes(&b, false));
    let (ga, gb) = within(180, async move {
        let mut sa = connect(addr, "?seed=1").await;
        let mut sb = connect(addr, "?seed=2").await;
        let chunk = 640;
        let (mut ia, mut ib) = (0, 0);
        while ia < ba.len() || ib < bb.len() {
            if ia < ba.len() {
                let n = chunk.min(ba.len() - ia);
                sa.send(Message::Binary(ba[ia..ia + n].to_vec().into()))
                    .await
                    .unwrap();
                ia += n;
            }
            if ib < bb.len() {
                let n = chunk.min(bb.len() - ib);
                sb.send(Message::Binary(bb[ib..ib + n].to_vec().into()))
                    .await
                    .unwrap();
                ib += n;
            }
        }
        for s in [&mut sa, &mut sb] {
            s.send(Message::Text(r#"{"type":"end"}"#.into()))
                .await
                .unwrap();
        }
        let (mut oa, mut ob) = (Outcome::default(), Outcome::default());
        tokio::join!(collect(&mut sa, &mut oa), collect(&mut sb, &mut ob));
        (oa, ob)
    });
    assert_equal(&ga.frames, &wa, "session A");
    assert_equal(&gb.frames, &wb, "session B");
    let m = server.metrics().render();
    assert!(m.contains("livegesture_sessions_total 2\n"), "{m}");
    server.shutdown();
    server.join().unwrap();
}

/// Connects once the previous session's slot is free (it is released just after its close frame).
async fn connect_when_free(addr: SocketAddr) -> Ws {
    for _ in 0..100 {
        match tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream")).await {
            Ok((ws, _)) => return ws,
            Err(tokio_tungstenite::tungstenite::Error::Http(r)) if r.status().as_u16() == 503 => {
                tokio::time::sleep(Duration::from_millis(50)).await
            }
            Err(e) => panic!("{e}"),
        }
    }
    panic!("the session slot was never released")
}

#[test]
fn refusals_and_limits_as_for_livegesture() {
    let server = start(ServeConfig {
        max_sessions: 1,
        max_message_bytes: 4096,
        ..Default::default()
    });
    let addr = server.addr();
    within(60, async {
        // an unknown query parameter (a sampler option the protocol does not take) is a 400
        match tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream?top_k=3")).await {
            Err(tokio_tungstenite::tungstenite::Error::Http(r)) => {
                assert_eq!(r.status().as_u16(), 400)
            }
            other => panic!("expected HTTP 400, got {other:?}"),
        }
        for (msg, code, word) in [
            (Message::Text("hello".into()), 1007, "malformed"),
            (Message::Text(r#"{"type":"pause"}"#.into()), 1003, "pause"),
            (Message::Binary(vec![0u8; 4097].into()), 1009, "limit"),
        ] {
            let mut ws = connect_when_free(addr).await;
            // at capacity while this one is live
            match tokio_tungstenite::connect_async(format!("ws://{addr}/v1/stream")).await {
                Err(tokio_tungstenite::tungstenite::Error::Http(r)) => {
                    assert_eq!(r.status().as_u16(), 503)
                }
                other => panic!("expected HTTP 503, got {other:?}"),
            }
            ws.send(msg).await.unwrap();
            let mut out = Outcome::default();
            collect(&mut ws, &mut out).await;
            let (c, reason) = out.close.expect("close with a reason");
            assert_eq!(c, code, "{reason}");
            assert!(reason.contains(word), "{reason}");
        }
        // end without audio: done with 0 frames
        let mut ws = connect_when_free(addr).await;
        ws.send(Message::Text(r#"{"type":"end"}"#.into()))
            .await
            .unwrap();
        let mut out = Outcome::default();
        collect(&mut ws, &mut out).await;
        assert_eq!(out.done, Some(0));
        assert_eq!(out.close.unwrap().0, 1000);
    });
    let m = server.metrics();
    assert_eq!(m.refusals("malformed"), 1);
    assert_eq!(m.refusals("unknown_message"), 1);
    assert_eq!(m.refusals("oversize"), 1);
    assert!(m.refusals("capacity") >= 3);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn sigterm_drains_complete_windows_closes_1001_and_exits_0() {
    let (child, addr, log) = spawn_serve(&bundle_dir());
    // 3.1 s = 93 frames of audio: windows at frames 0, 20, 40, 60 run (the one at 80 needs 104
    // frames of audio), so 80 frames are emitted before the end that never comes
    let audio = speech(3.1);
    let pid = child.id() as i32;
    let got = within(120, async move {
        let mut ws = connect(addr, "?seed=2").await;
        let ready = loop {
            match ws.next().await.unwrap().unwrap() {
                Message::Text(t) if t.contains("\"ready\"") => {
                    break serde_json::from_str::<serde_json::Value>(&t).unwrap()
                }
                _ => {}
            }
        };
        assert_eq!(ready["family"], "diffsheg");
        ws.send(Message::Binary(pcm_bytes(&audio, false).into()))
            .await
            .unwrap();
        let mut out = Outcome::default();
        // the last complete window's frames prove the whole message was pushed
        read_frames(&mut ws, &mut out, 80).await;
        unsafe { libc::kill(pid, libc::SIGTERM) };
        collect(&mut ws, &mut out).await;
        out
    });
    let log = exited_ok(child, log);
    assert_eq!(got.close.as_ref().map(|c| c.0), Some(1001), "{got:?}");
    let want = reference(&speech(3.1), 16000, 1, false, 2);
    assert_equal(&got.frames, &want[..80], "drained frames");
    assert!(log.contains("session 1 start"), "{log}");
    assert!(log.contains("session 1 end: close 1001"), "{log}");
}

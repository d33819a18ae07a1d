//! The fuzzed entry points, shared by the cargo-fuzz targets (`fuzz/fuzz_targets/*.rs`, nightly) and
//! their regression test on stable (`cli/tests/it/fuzz_regressions.rs`, which replays every file
//! of `fuzz/regressions/<target>/` and the committed corpus through the same functions). Each takes
//! arbitrary bytes; the property is that the parser returns (an error is fine) without panicking,
//! hanging or allocating without bound.

use std::io::Write;

#[cfg(feature = "serve")]
use livegesture::audio::RESAMPLE_BLOCK;
use livegesture::audio::{RawFormat, RawPcmDecoder, RawPcmStream, WavStream};
use livegesture::bundle::parse_manifest;
#[cfg(feature = "serve")]
use livegesture_serve::protocol::{
    SessionInput, SessionParams, CLOSE_INTERNAL, CLOSE_INVALID, CLOSE_UNSUPPORTED,
};

/// The WAV reader: the bytes as a `.wav` file, read to the end through [`WavStream`] (header probe,
/// hound, mono mix, resampling to 16 kHz).
pub fn wav(data: &[u8]) {
    let mut f = tempfile::Builder::new()
        .suffix(".wav")
        .tempfile()
        .expect("temporary file");
    f.write_all(data).expect("write the temporary file");
    f.flush().expect("flush the temporary file");
    if let Ok(s) = WavStream::open(f.path()) {
        for chunk in s.with_read_frames(997) {
            if chunk.is_err() {
                break;
            }
        }
    }
}

const FORMATS: [RawFormat; 3] = [RawFormat::S16Le, RawFormat::S32Le, RawFormat::F32Le];
const RATES: [u32; 6] = [16_000, 8_000, 22_050, 44_100, 48_000, 96_000];

/// The raw PCM decoder and stream: byte 0 picks the format, byte 1 the channel count (0 to 7),
/// byte 2 the rate and byte 3 where the rest is split into reads; the rest is the PCM data, decoded
/// in two pieces by [`RawPcmDecoder`] and read whole through [`RawPcmStream`].
pub fn raw_pcm(data: &[u8]) {
    let [f, ch, r, split, pcm @ ..] = data else {
        return;
    };
    let format = FORMATS[*f as usize % FORMATS.len()];
    let channels = u16::from(*ch % 8);
    if let Ok(mut d) = RawPcmDecoder::new(format, channels, "fuzz") {
        let at = (*split as usize).min(pcm.len());
        let _ = d.decode(&pcm[..at]);
        let _ = d.decode(&pcm[at..]);
        let _ = d.finish();
    }
    let rate = RATES[*r as usize % RATES.len()];
    if let Ok(s) = RawPcmStream::new(pcm, format, rate, channels, "fuzz") {
        for chunk in s.with_read_bytes(usize::from(*split).max(1)) {
            if chunk.is_err() {
                break;
            }
        }
    }
}

/// The bundle loader's manifest part: parsing (schema version, family, the family's sections) and
/// the self-consistency checks that need no file.
pub fn manifest(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(m) = parse_manifest(text, std::path::Path::new("fuzz/manifest.json")) {
        let _ = m.check();
    }
}

/// The serve protocol (docs/serve.md), everything a session does with a client's bytes: the input's first
/// line is the query string of `GET /v1/stream`, parsed as the server parses it (axum's `Query`,
/// then [`SessionParams::parse`]); the rest is a sequence of client messages for [`SessionInput`],
/// each a header byte (`% 3`: 0 binary PCM, 1 text, 2 the server starting to drain, no payload)
/// and, for binary and text, a 2-byte little-endian length and the payload, until a message is
/// refused (the session closes). Beyond not panicking it checks that a refusal carries one of the
/// protocol's close codes, that the 16 kHz output never exceeds twice the input frames plus one
/// resampler block (no message multiplies the work: `fuzz/regressions/serve_protocol/rate_1_*`), and
/// that at `{"type":"end"}` it has exactly `floor(frames * 16000 / rate)` samples (the resampler's
/// promise, docs/output.md).
#[cfg(feature = "serve")]
pub fn serve_protocol(data: &[u8]) {
    use axum::extract::Query;

    let (query, mut rest) = match data.iter().position(|&b| b == b'\n') {
        Some(i) => (&data[..i], &data[i + 1..]),
        None => (data, &[][..]),
    };
    let Ok(query) = std::str::from_utf8(query) else {
        return;
    };
    let Ok(uri) = format!("/v1/stream?{query}").parse::<axum::http::Uri>() else {
        return;
    };
    let Ok(Query(pairs)) = Query::<Vec<(String, String)>>::try_from_uri(&uri) else {
        return;
    };
    let Ok(params) = SessionParams::parse(&pairs) else {
        return;
    };
    let mut input = SessionInput::new(&params, "fuzz".into())
        .unwrap_or_else(|e| panic!("validated parameters {params:?} make no session: {e}"));
    let mut out: u64 = 0;
    let mut in_bytes: u64 = 0;
    while let [head, tail @ ..] = rest {
        if head % 3 == 2 {
            input.drain();
            rest = tail;
            continue;
        }
        let [l0, l1, tail @ ..] = tail else {
            return;
        };
        let n = usize::from(u16::from_le_bytes([*l0, *l1])).min(tail.len());
        let (msg, next) = tail.split_at(n);
        rest = next;
        let handled = if head % 3 == 0 {
            in_bytes += msg.len() as u64;
            input.binary(msg).map(|s16| {
                out += s16.len() as u64;
                let frames = in_bytes / params.frame_bytes() as u64;
                assert!(
                    out <= 2 * (frames + RESAMPLE_BLOCK as u64),
                    "{params:?}: {frames} input frames gave {out} samples at 16 kHz"
                );
            })
        } else {
            // a WebSocket text message is UTF-8 (tungstenite refuses others before the session)
            let Ok(text) = std::str::from_utf8(msg) else {
                continue;
            };
            input.text(text).map(|end| {
                out += end.tail.len() as u64;
                let want = end.input.samples * 16_000 / u64::from(end.input.sample_rate);
                assert_eq!(
                    out, want,
                    "{params:?}: {} input frames gave {out} samples at 16 kHz",
                    end.input.samples
                );
            })
        };
        if let Err(r) = handled {
            assert!(
                [CLOSE_UNSUPPORTED, CLOSE_INVALID, CLOSE_INTERNAL].contains(&r.code),
                "refusal with close code {}: {}",
                r.code,
                r.reason
            );
            assert!(!r.reason.is_empty(), "refusal {} without a reason", r.code);
            return;
        }
    }
}

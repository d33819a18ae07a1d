//! The fuzzed entry points, shared by the cargo-fuzz targets (`fuzz/fuzz_targets/*.rs`, nightly) and
//! their regression test on stable (`runtime/tests/fuzz_regressions.rs`, which replays every file
//! of `fuzz/regressions/<target>/` and the committed corpus through the same functions). Each takes
//! arbitrary bytes; the property is that the parser returns (an error is fine) without panicking,
//! hanging or allocating without bound.

use std::io::Write;

use livegesture::audio::{RawFormat, RawPcmDecoder, RawPcmStream, WavStream};
use livegesture::bundle::parse_manifest;

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

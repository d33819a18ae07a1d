//! A WAV file given as bytes (the page's test hook and `Model.generate`), decoded with `hound` with
//! the same conversions as the runtime's file reader (`livegesture::audio`): integer PCM scaled by
//! 2^-(bits-1) in f64, channels averaged in f64, then f32; non-finite float samples refused.

use std::io::Cursor;

use anyhow::{bail, ensure, Context, Result};

/// Mono samples at the file's own rate.
pub struct MonoAudio {
    pub samples: Vec<f32>,
    pub sample_rate: u32,
}

/// Decodes a whole WAV file (8/16/24/32-bit integer PCM or 32-bit float).
pub fn decode_mono(bytes: &[u8]) -> Result<MonoAudio> {
    ensure!(
        !bytes.is_empty(),
        "wav: the file is empty (0 bytes); expected a RIFF/WAVE file"
    );
    let mut r =
        hound::WavReader::new(Cursor::new(bytes)).context("wav: not a readable RIFF/WAVE file")?;
    let spec = r.spec();
    ensure!(spec.sample_rate > 0, "wav: sample rate is 0 Hz");
    let ch = spec.channels.max(1) as usize;
    let interleaved: Vec<f64> = match (spec.sample_format, spec.bits_per_sample) {
        (hound::SampleFormat::Int, b @ (8 | 16 | 24 | 32)) => {
            let scale = 1.0 / (1u64 << (b - 1)) as f64;
            r.samples::<i32>()
                .map(|s| s.map(|v| v as f64 * scale))
                .collect::<Result<_, _>>()
                .context("wav: the sample data ends early or is malformed")?
        }
        (hound::SampleFormat::Float, 32) => {
            let v: Vec<f32> = r
                .samples::<f32>()
                .collect::<Result<_, _>>()
                .context("wav: the sample data ends early or is malformed")?;
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                bail!("wav: sample {i} is {}; expected finite samples", v[i]);
            }
            v.into_iter().map(f64::from).collect()
        }
        (f, b) => bail!(
            "wav: unsupported encoding: {b}-bit {f:?}; expected 8, 16, 24 or 32-bit integer PCM or 32-bit float"
        ),
    };
    ensure!(
        !interleaved.is_empty(),
        "wav: the file contains no audio samples"
    );
    ensure!(
        interleaved.len().is_multiple_of(ch),
        "wav: the last frame is incomplete"
    );
    let samples = if ch == 1 {
        interleaved.iter().map(|&x| x as f32).collect()
    } else {
        interleaved
            .chunks_exact(ch)
            .map(|f| (f.iter().sum::<f64>() / ch as f64) as f32)
            .collect()
    };
    Ok(MonoAudio {
        samples,
        sample_rate: spec.sample_rate,
    })
}

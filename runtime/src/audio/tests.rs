//! Tests of WAV reading, raw PCM decoding and resampling.

use super::*;
use std::io::Write;
use std::path::Path;

fn tone(n: usize, rate: u32, f: f64, amp: f64) -> Vec<f64> {
    (0..n)
        .map(|i| amp * (2.0 * std::f64::consts::PI * f * i as f64 / rate as f64).sin())
        .collect()
}

fn write_int(path: &Path, rate: u32, channels: u16, bits: u16, frames: &[Vec<f64>]) {
    let spec = hound::WavSpec {
        channels,
        sample_rate: rate,
        bits_per_sample: bits,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    let max = (1i64 << (bits - 1)) as f64;
    for fr in frames {
        for &x in fr {
            let v = (x * max).round().clamp(-max, max - 1.0) as i32;
            w.write_sample(v).unwrap();
        }
    }
    w.finalize().unwrap();
}

fn write_float(path: &Path, rate: u32, channels: u16, frames: &[Vec<f32>]) {
    let spec = hound::WavSpec {
        channels,
        sample_rate: rate,
        bits_per_sample: 32,
        sample_format: hound::SampleFormat::Float,
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for fr in frames {
        for &x in fr {
            w.write_sample(x).unwrap();
        }
    }
    w.finalize().unwrap();
}

/// A hand-made WAV header: format tag, channels, rate, bits, then `data_bytes` of data.
fn handmade(
    path: &Path,
    tag: u16,
    channels: u16,
    rate: u32,
    bits: u16,
    data: &[u8],
    declared: u32,
) {
    let block = channels * bits.div_ceil(8);
    let mut v = Vec::new();
    v.extend(b"RIFF");
    v.extend((36 + declared).to_le_bytes());
    v.extend(b"WAVEfmt ");
    v.extend(16u32.to_le_bytes());
    v.extend(tag.to_le_bytes());
    v.extend(channels.to_le_bytes());
    v.extend(rate.to_le_bytes());
    v.extend((rate * block as u32).to_le_bytes());
    v.extend(block.to_le_bytes());
    v.extend(bits.to_le_bytes());
    v.extend(b"data");
    v.extend(declared.to_le_bytes());
    v.extend(data);
    std::fs::write(path, v).unwrap();
}

#[test]
fn int_depths_decode_exactly_at_16k() {
    let dir = tempfile::tempdir().unwrap();
    let x = tone(1600, 16000, 440.0, 0.5);
    for bits in [8u16, 16, 24, 32] {
        let p = dir.path().join(format!("i{bits}.wav"));
        let frames: Vec<Vec<f64>> = x.iter().map(|&v| vec![v]).collect();
        write_int(&p, 16000, 1, bits, &frames);
        let y = read_wav_16k_mono(&p).unwrap();
        assert_eq!(y.len(), 1600, "{bits}");
        // quantisation step, or f32 rounding for 32-bit
        let tol = (1.0 / (1u64 << (bits - 1)) as f64).max(1e-7);
        for (a, b) in x.iter().zip(&y) {
            assert!((a - *b as f64).abs() <= tol, "{bits}-bit: {a} vs {b}");
        }
    }
}

#[test]
fn float_passthrough_and_stereo_mix() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("f.wav");
    let frames: Vec<Vec<f32>> = (0..1000).map(|i| vec![i as f32 / 1000.0 - 0.5]).collect();
    write_float(&p, 16000, 1, &frames);
    let y = read_wav_16k_mono(&p).unwrap();
    assert_eq!(y, frames.iter().map(|f| f[0]).collect::<Vec<_>>());
    let info = WavStream::open(&p).unwrap().info().clone();
    assert!(info.is_float && info.channels == 1 && info.frames == 1000);

    let p2 = dir.path().join("s.wav");
    let st: Vec<Vec<f32>> = (0..1000)
        .map(|i| vec![0.25, (i % 3) as f32 * 0.25])
        .collect();
    write_float(&p2, 16000, 2, &st);
    let y = read_wav_16k_mono(&p2).unwrap();
    for (f, v) in st.iter().zip(&y) {
        assert_eq!(*v, (f[0] + f[1]) / 2.0);
    }
    let p3 = dir.path().join("q.wav");
    let q: Vec<Vec<f32>> = (0..100).map(|_| vec![0.1, 0.2, 0.3, 0.4]).collect();
    write_float(&p3, 16000, 4, &q);
    for v in read_wav_16k_mono(&p3).unwrap() {
        assert!((v - 0.25).abs() < 1e-7);
    }
}

#[test]
fn resamples_44k1_tone() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.wav");
    let n = 44100;
    let x = tone(n, 44100, 1000.0, 0.5);
    let frames: Vec<Vec<f64>> = x.iter().map(|&v| vec![v, v]).collect();
    write_int(&p, 44100, 2, 16, &frames);
    let y = read_wav_16k_mono(&p).unwrap();
    assert_eq!(y.len(), 16000);
    // Same tone at 16 kHz, aligned (delay removed); skip the edges.
    let want = tone(16000, 16000, 1000.0, 0.5);
    let err = (200..15800)
        .map(|i| (want[i] - y[i] as f64).abs())
        .fold(0.0, f64::max);
    assert!(err < 2e-3, "max error {err}");
    // Streaming with different read block sizes gives identical output.
    for rf in [1usize, 333, 100_000] {
        let z: Vec<f32> = WavStream::open(&p)
            .unwrap()
            .with_read_frames(rf)
            .flat_map(|c| c.unwrap())
            .collect();
        assert_eq!(z, y, "read_frames {rf}");
    }
}

#[test]
fn resampler_alignment_is_exact() {
    // A smooth pulse centred at 0.1 s must come out centred at output sample 1600.
    for rate in [
        8000u32, 11025, 22050, 24000, 32000, 44100, 48000, 96000, 44101,
    ] {
        let c = rate as f64 * 0.1;
        let x: Vec<f32> = (0..rate as usize / 5)
            .map(|i| {
                let d = (i as f64 - c) / (rate as f64 / 2000.0);
                (-d * d).exp() as f32
            })
            .collect();
        let mut r = Resampler16k::new(rate, "t").unwrap();
        let mut y = r.push(&x).unwrap();
        y.extend(r.finish().unwrap());
        assert_eq!(y.len() as u64, x.len() as u64 * 16000 / rate as u64);
        let (num, den) = y.iter().enumerate().fold((0.0, 0.0), |(n, d), (i, &v)| {
            (n + i as f64 * v as f64, d + v as f64)
        });
        let centroid = num / den;
        assert!(
            (centroid - 1600.0).abs() < 0.01,
            "rate {rate}: pulse centred at {centroid}, expected 1600"
        );
    }
}

#[test]
fn resampler_is_chunking_invariant() {
    let x: Vec<f32> = tone(30_000, 22050, 300.0, 0.7)
        .into_iter()
        .map(|v| v as f32)
        .collect();
    let mut whole = Resampler16k::new(22050, "t").unwrap();
    let mut a = whole.push(&x).unwrap();
    a.extend(whole.finish().unwrap());
    assert_eq!(a.len(), 30_000 * 16000 / 22050);
    for c in [1usize, 17, 1024, 5000] {
        let mut r = Resampler16k::new(22050, "t").unwrap();
        let mut b = Vec::new();
        for ch in x.chunks(c) {
            b.extend(r.push(ch).unwrap());
        }
        b.extend(r.finish().unwrap());
        assert_eq!(a, b, "chunk {c}");
    }
    // after finish the resampler is reusable
    let mut again = whole.push(&x).unwrap();
    again.extend(whole.finish().unwrap());
    assert_eq!(again, a);
}

#[test]
fn errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.wav");
    let e = read_wav_16k_mono(&missing).unwrap_err();
    assert!(matches!(e, AudioError::NotFound { .. }));
    assert!(e.to_string().contains("missing.wav"));

    let empty = dir.path().join("empty.wav");
    std::fs::write(&empty, b"").unwrap();
    let e = read_wav_16k_mono(&empty).unwrap_err();
    assert!(matches!(e, AudioError::EmptyFile { .. }), "{e}");
    assert!(e.to_string().contains("empty.wav"));

    let nos = dir.path().join("nosamples.wav");
    write_int(&nos, 16000, 1, 16, &[]);
    assert!(matches!(
        read_wav_16k_mono(&nos).unwrap_err(),
        AudioError::NoSamples { .. }
    ));

    let garbage = dir.path().join("garbage.wav");
    std::fs::write(&garbage, b"this is not audio at all, just some text\n").unwrap();
    let e = read_wav_16k_mono(&garbage).unwrap_err();
    assert!(matches!(e, AudioError::NotWav { .. }), "{e}");
    assert!(
        e.to_string().contains("garbage.wav") && e.to_string().contains("expected a RIFF/WAVE")
    );

    let riff_other = dir.path().join("avi.wav");
    std::fs::write(&riff_other, b"RIFF\x10\0\0\0AVI LIST\0\0\0\0").unwrap();
    assert!(matches!(
        read_wav_16k_mono(&riff_other).unwrap_err(),
        AudioError::NotWav { .. }
    ));

    let trunc = dir.path().join("trunc.wav");
    let frames: Vec<Vec<f64>> = tone(4000, 16000, 200.0, 0.3)
        .into_iter()
        .map(|v| vec![v])
        .collect();
    write_int(&trunc, 16000, 1, 16, &frames);
    let bytes = std::fs::read(&trunc).unwrap();
    std::fs::write(&trunc, &bytes[..bytes.len() - 1001]).unwrap();
    let e = read_wav_16k_mono(&trunc).unwrap_err();
    assert!(matches!(e, AudioError::Truncated { .. }), "{e}");
    assert!(e.to_string().contains("trunc.wav"));
    std::fs::write(&trunc, &bytes[..30]).unwrap();
    assert!(matches!(
        read_wav_16k_mono(&trunc).unwrap_err(),
        AudioError::Truncated { .. }
    ));
    std::fs::write(&trunc, &bytes[..3]).unwrap();
    assert!(matches!(
        read_wav_16k_mono(&trunc).unwrap_err(),
        AudioError::Truncated { .. }
    ));

    let b12 = dir.path().join("b12.wav");
    handmade(&b12, 1, 1, 16000, 12, &[0; 20], 20);
    let e = read_wav_16k_mono(&b12).unwrap_err();
    assert!(matches!(e, AudioError::UnsupportedEncoding { .. }), "{e}");
    assert!(e.to_string().contains("12-bit integer PCM"), "{e}");

    let f64p = dir.path().join("f64.wav");
    handmade(&f64p, 3, 1, 16000, 64, &[0; 32], 32);
    let e = read_wav_16k_mono(&f64p).unwrap_err();
    assert!(
        e.to_string().contains("64-bit IEEE float") && e.to_string().contains("32-bit float"),
        "{e}"
    );

    let adpcm = dir.path().join("adpcm.wav");
    handmade(&adpcm, 2, 1, 16000, 4, &[0; 32], 32);
    assert!(matches!(
        read_wav_16k_mono(&adpcm).unwrap_err(),
        AudioError::UnsupportedEncoding { .. }
    ));

    let nan = dir.path().join("nan.wav");
    write_float(&nan, 16000, 1, &[vec![0.0], vec![0.5], vec![f32::NAN]]);
    let e = read_wav_16k_mono(&nan).unwrap_err();
    assert!(matches!(e, AudioError::NonFinite { index: 2, .. }), "{e}");
    assert!(e.to_string().contains("nan.wav"));
}

#[test]
fn raw_pcm_split_anywhere() {
    // Stereo s16le at 16 kHz, fed one byte at a time vs all at once.
    let mut bytes = Vec::new();
    for i in 0..500i32 {
        bytes.extend(((i * 37 % 2000 - 1000) as i16).to_le_bytes());
        bytes.extend(((i * 11 % 600) as i16).to_le_bytes());
    }
    let mut d = RawPcmDecoder::new(RawFormat::S16Le, 2, "<stdin>").unwrap();
    let all = d.decode(&bytes).unwrap();
    assert_eq!(all.len(), 500);
    let mut d = RawPcmDecoder::new(RawFormat::S16Le, 2, "<stdin>").unwrap();
    let mut one = Vec::new();
    for b in &bytes {
        one.extend(d.decode(std::slice::from_ref(b)).unwrap());
    }
    assert_eq!(one, all);
    d.finish().unwrap();
    assert_eq!(
        all[1],
        ((37 - 1000) as f64 / 32768.0 + 11.0 / 32768.0) as f32 / 2.0
    );

    // Partial frame at the end is an error naming the stream.
    let mut d = RawPcmDecoder::new(RawFormat::F32Le, 1, "<stdin>").unwrap();
    d.decode(&[0, 0, 0]).unwrap();
    let e = d.finish().unwrap_err().to_string();
    assert!(e.contains("<stdin>") && e.contains("3 stray bytes"), "{e}");

    // f32le NaN refused with its index
    let mut d = RawPcmDecoder::new(RawFormat::F32Le, 1, "<stdin>").unwrap();
    let mut b = Vec::new();
    b.extend(0.5f32.to_le_bytes());
    b.extend(f32::INFINITY.to_le_bytes());
    assert!(matches!(
        d.decode(&b).unwrap_err(),
        AudioError::NonFinite { index: 1, .. }
    ));

    // s32le scaling
    let mut d = RawPcmDecoder::new(RawFormat::S32Le, 1, "x").unwrap();
    assert_eq!(d.decode(&i32::MIN.to_le_bytes()).unwrap(), vec![-1.0]);
    assert_eq!("F32LE".parse::<RawFormat>().unwrap(), RawFormat::F32Le);
    assert!("u8".parse::<RawFormat>().is_err());
    assert!(RawPcmDecoder::new(RawFormat::S16Le, 0, "x").is_err());
}

#[test]
fn raw_stream_resamples_and_is_read_size_invariant() {
    let x: Vec<f32> = tone(48_000, 48000, 440.0, 0.4)
        .into_iter()
        .map(|v| v as f32)
        .collect();
    let mut bytes = Vec::new();
    for v in &x {
        bytes.write_all(&v.to_le_bytes()).unwrap();
    }
    let collect = |rb: usize| -> Vec<f32> {
        RawPcmStream::new(
            io::Cursor::new(bytes.clone()),
            RawFormat::F32Le,
            48000,
            1,
            "<stdin>",
        )
        .unwrap()
        .with_read_bytes(rb)
        .flat_map(|c| c.unwrap())
        .collect()
    };
    let a = collect(4096);
    assert_eq!(a.len(), 16000);
    assert_eq!(collect(7), a);
    assert_eq!(collect(1 << 20), a);
    // at 16 kHz: untouched
    let mut b16 = Vec::new();
    for v in &x[..1000] {
        b16.extend(v.to_le_bytes());
    }
    let y: Vec<f32> =
        RawPcmStream::new(io::Cursor::new(b16), RawFormat::F32Le, 16000, 1, "<stdin>")
            .unwrap()
            .flat_map(|c| c.unwrap())
            .collect();
    assert_eq!(y, x[..1000].to_vec());
}

/// Every chunk of `s` (or its first error, as text).
fn drain<R: std::io::Read>(mut s: WavStream<R>) -> Result<(Vec<Vec<f32>>, AudioSpan), String> {
    let mut chunks = Vec::new();
    while let Some(c) = s.next_chunk().map_err(|e| e.to_string())? {
        chunks.push(c);
    }
    Ok((chunks, s.input_span()))
}

#[test]
fn bytes_and_readers_decode_as_the_file() {
    // the same files through WavStream::open, ::from_bytes and ::from_reader: the same chunks, span
    // and errors (named by the name given), good files and broken ones alike
    let dir = tempfile::tempdir().unwrap();
    let x = tone(30_000, 44_100, 300.0, 0.4);
    let stereo: Vec<Vec<f64>> = x.iter().map(|&v| vec![v, -0.5 * v]).collect();
    let files = [
        "stereo44k.wav",
        "mono8.wav",
        "float.wav",
        "nan.wav",
        "trunc.wav",
        "short.wav",
        "b12.wav",
        "garbage.wav",
        "empty.wav",
    ];
    write_int(&dir.path().join("stereo44k.wav"), 44_100, 2, 16, &stereo);
    let mono: Vec<Vec<f64>> = x[..5000].iter().map(|&v| vec![v]).collect();
    write_int(&dir.path().join("mono8.wav"), 22_050, 1, 8, &mono);
    write_float(
        &dir.path().join("float.wav"),
        16_000,
        1,
        &[vec![0.25], vec![-0.5], vec![0.125]],
    );
    write_float(
        &dir.path().join("nan.wav"),
        16_000,
        1,
        &[vec![0.0], vec![f32::NAN]],
    );
    write_int(&dir.path().join("trunc.wav"), 16_000, 1, 16, &mono);
    let t = std::fs::read(dir.path().join("trunc.wav")).unwrap();
    std::fs::write(dir.path().join("trunc.wav"), &t[..t.len() - 1001]).unwrap();
    std::fs::write(dir.path().join("short.wav"), &t[..30]).unwrap();
    handmade(&dir.path().join("b12.wav"), 1, 1, 16000, 12, &[0; 20], 20);
    std::fs::write(dir.path().join("garbage.wav"), b"not audio").unwrap();
    std::fs::write(dir.path().join("empty.wav"), b"").unwrap();
    let mut good = 0;
    for name in files {
        let path = dir.path().join(name);
        let bytes = std::fs::read(&path).unwrap();
        let from_file = WavStream::open(&path)
            .map_err(|e| e.to_string())
            .and_then(|s| drain(s.with_read_frames(1000)));
        let from_bytes = WavStream::from_bytes(&bytes[..], &path)
            .map_err(|e| e.to_string())
            .and_then(|s| drain(s.with_read_frames(1000)));
        let from_reader = WavStream::from_reader(std::io::Cursor::new(bytes.clone()), &path)
            .map_err(|e| e.to_string())
            .and_then(|s| drain(s.with_read_frames(1000)));
        assert_eq!(from_file, from_bytes, "{name}");
        assert_eq!(from_file, from_reader, "{name}");
        if let Err(e) = &from_bytes {
            assert!(e.contains(name), "{name}: {e}");
        } else {
            good += 1;
        }
    }
    assert_eq!(good, 3, "three of the files decode");
    // the name given is the one errors carry
    let e = WavStream::from_bytes(b"RIFF", "upload #3").unwrap_err();
    assert!(matches!(e, AudioError::Truncated { .. }), "{e}");
    assert!(e.to_string().starts_with("upload #3: "), "{e}");
    let e = WavStream::from_bytes(Vec::new(), "upload #4").unwrap_err();
    assert!(matches!(e, AudioError::EmptyFile { .. }), "{e}");
}

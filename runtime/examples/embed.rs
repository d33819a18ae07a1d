//! The library API in one page (docs/embedding.md): load a bundle, stream audio through a
//! `MotionStream` in chunks, finish, and check the frames against the whole-input path.
//!
//!   cargo run --release -p livegesture-core --example embed -- models/default speech.wav

use std::path::PathBuf;

use anyhow::{ensure, Context, Result};
use livegesture::audio::{AudioSpan, WavStream};
use livegesture::backend::{self, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::generate;
use livegesture::model::{self, StreamOptions};

fn main() -> Result<()> {
    let mut args = std::env::args_os().skip(1).map(PathBuf::from);
    let (Some(bundle_dir), Some(wav_path)) = (args.next(), args.next()) else {
        anyhow::bail!("usage: embed BUNDLE IN.wav");
    };

    // 1. load a bundle (verified against its manifest) and its family's model on a backend
    let bundle = Bundle::load(&bundle_dir)?;
    let be = backend::create(&BackendOptions::default())?; // tract; BackendKind::Ort for ONNX Runtime
    let model = model::load(&bundle, be.as_ref())?; // Box<dyn MotionModel>: Send + Sync

    // 2. a stream owns all its state; push 16 kHz mono audio in chunks of any size
    let opts = StreamOptions {
        seed: 7,
        ..Default::default()
    };
    let mut stream = model.new_stream(&opts)?;
    let mut wav = WavStream::open(&wav_path)?; // any rate and channel count -> 16 kHz mono chunks
    let mut frames = Vec::new();
    while let Some(block) = wav.next_chunk()? {
        for chunk in block.chunks(1600) {
            // 100 ms at a time, as from a microphone
            frames.extend(stream.push_audio(chunk)?);
        }
    }
    // 3. finish: the frames that cover the whole input, ceil(seconds * 30) of them
    let span: AudioSpan = wav.input_span(); // the input counted at its own rate
    frames.extend(stream.finish(span)?);
    println!(
        "{} frames for {:.3} s of audio ({} model on {}); frame 0 root rotation {:?}",
        frames.len(),
        span.seconds(),
        model.family(),
        model.backend_name(),
        &frames[0].poses[..3]
    );

    // the whole-input path of `livegesture generate` gives the same frames, bit for bit
    let whole = generate::generate_wav(model.as_ref(), &opts, &wav_path).context("generate")?;
    ensure!(
        whole.frames == frames,
        "streamed frames differ from generate's"
    );
    println!("equal to generate_wav: yes");
    Ok(())
}

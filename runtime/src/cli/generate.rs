//! `livegesture generate IN.wav -o OUT.npz`: a whole file, streamed through the bundle's model.
//!
//! The motion covers the whole audio (docs/output.md): `ceil(duration * 30)` frames, the last partial token
//! completed with silence and cut at the audio's end.
//!
//! The WAV is read block by block (memory for audio does not grow with its length); frames are
//! collected and the BEAT2 `.npz` is written atomically at the end, so no partial file is left on any
//! error. A progress bar is drawn on stderr when it is a terminal.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Result;
use indicatif::{ProgressBar, ProgressStyle};

use livegesture::audio::WavStream;
use livegesture::generate;
use livegesture::model::livegesture::FormChoice;
use livegesture::output::{FrameSink, NpzFrameWriter};

use super::common::{GenArgs, InputError, ModelArgs};

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  livegesture generate speech.wav -o motion.npz --seed 1 --guidance 1.25"
)]
pub struct Args {
    /// Input WAV file (any sample rate and channel count; 8/16/24/32-bit PCM or 32-bit float).
    #[arg(value_name = "IN.wav")]
    pub input: PathBuf,
    /// Output BEAT2 .npz (poses, trans, expressions, betas, model, gender, mocap_frame_rate), or a
    /// .bvh on the project's own skeleton (body and hands; no face parameters).
    #[arg(short, long, value_name = "OUT.npz")]
    pub output: PathBuf,
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub gen: GenArgs,
}

pub fn run(a: Args, form: FormChoice) -> Result<()> {
    let opts = a.gen.stream_options()?;
    if let Some(parent) = a.output.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !parent.is_dir() {
            return Err(InputError(format!(
                "{}: the output folder {} does not exist",
                a.output.display(),
                parent.display()
            ))
            .into());
        }
    }
    if a.output.is_dir() {
        return Err(InputError(format!(
            "{}: is a folder; expected an output file path",
            a.output.display()
        ))
        .into());
    }
    let mut wav = WavStream::open(&a.input)?;
    let bundle = a.model.bundle()?;
    let model = a.model.model(&bundle, form)?;
    let mut stream = super::common::new_stream(model.as_ref(), &opts)?;
    let total = wav.output_len();
    let bar = if std::io::stderr().is_terminal() {
        let b = ProgressBar::new(total);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {wide_bar} {percent:>3}% {msg} (eta {eta})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    let mut writer = NpzFrameWriter::new(&a.output);
    let input = a.input.display().to_string();
    // the one whole-input path (livegesture::generate), shared with the Python and C bindings
    let span = generate::stream_wav(stream.as_mut(), &mut wav, &input, &mut |frames, pushed| {
        for f in frames {
            writer.write_frame(f)?;
        }
        bar.set_position(pushed.min(total));
        bar.set_message(format!("{} frames", writer.frames()));
        Ok(())
    })?;
    bar.finish_and_clear();
    if a.output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bvh"))
    {
        livegesture::bvh::write_bvh(&a.output, &writer.motion()?)?; // docs/output.md: face stays in the npz
    } else {
        writer.finish()?;
    }
    eprintln!(
        "livegesture: wrote {} frames ({:.3} s of audio at {} Hz, {} fps, {} model on {}) to {}",
        writer.frames(),
        span.seconds(),
        span.sample_rate,
        model.fps(),
        model.family(),
        model.backend_name(),
        a.output.display()
    );
    Ok(())
}

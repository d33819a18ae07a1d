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
use livegesture::model::GraphForm;
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
    /// Output file, its format by extension: .npz (BEAT2: poses, trans, expressions, betas, model,
    /// gender, mocap_frame_rate), .bvh (the project's own skeleton; no face parameters), .glb or
    /// .gltf (glTF 2.0: skinned skeleton and one animation; no face parameters).
    #[arg(short, long, value_name = "OUT.npz|.bvh|.glb|.gltf")]
    pub output: PathBuf,
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub gen: GenArgs,
}

/// The file formats `-o` writes, by extension (docs/output.md, docs/avatars.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum OutputFormat {
    Npz,
    Bvh,
    Gltf,
}

/// The extensions `-o` accepts, as listed in the refusal.
const OUTPUT_EXTENSIONS: &str = ".npz, .bvh, .glb, .gltf";

impl OutputFormat {
    fn of(path: &std::path::Path) -> Result<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("npz") => Ok(Self::Npz),
            Some("bvh") => Ok(Self::Bvh),
            Some("glb" | "gltf") => Ok(Self::Gltf),
            other => Err(InputError::new(format!(
                "{}: cannot write {}; the output name must end in one of {OUTPUT_EXTENSIONS}",
                path.display(),
                other.map_or("a file without an extension".to_string(), |e| format!(
                    ".{e} files"
                )),
            ))
            .into()),
        }
    }
}

pub fn run(a: Args, form: GraphForm) -> Result<()> {
    let format = OutputFormat::of(&a.output)?;
    let opts = a.gen.stream_options()?;
    if let Some(parent) = a.output.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !parent.is_dir() {
            return Err(InputError::new(format!(
                "{}: the output folder {} does not exist",
                a.output.display(),
                parent.display()
            ))
            .into());
        }
    }
    if a.output.is_dir() {
        return Err(InputError::new(format!(
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
    // docs/output.md, docs/avatars.md: face expressions stay in the npz
    match format {
        OutputFormat::Npz => writer.finish()?,
        OutputFormat::Bvh => livegesture::bvh::write_bvh(&a.output, &writer.motion()?)?,
        OutputFormat::Gltf => livegesture::output::write_gltf_with_face(
            &a.output,
            &writer.motion()?,
            writer.face_track()?.as_ref(),
        )?,
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

//! `livegesture stream`: raw PCM on stdin, frames on stdout as soon as each token's audio is complete.
//! At the end of the input the last partial token is completed with silence and cut at the audio's
//! end, so the frames cover the whole input (docs/output.md).

use std::io::{BufWriter, Write};

use anyhow::Result;
use clap::ValueEnum;

use livegesture::audio::{RawFormat, RawPcmStream};
use livegesture::model::GraphForm;
use livegesture::output::{BinaryFrameWriter, FrameSink, JsonLinesWriter};

use super::common::{GenArgs, InputError, ModelArgs};

/// Frame record format on stdout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum OutputFormat {
    /// One JSON object per line: index, time_s, poses, trans, expressions, foot_contact.
    Jsonl,
    /// A 16-byte header then fixed 1104-byte little-endian records (see the output module docs).
    Binary,
}

fn parse_format(s: &str) -> Result<RawFormat, String> {
    s.parse()
}

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  arecord -f S16_LE -r 16000 -c 1 -t raw | livegesture stream --rate 16000 --format s16le"
)]
pub struct Args {
    /// Sample rate of the input in Hz (resampled to 16 kHz when different).
    #[arg(long, default_value_t = 16000)]
    pub rate: u32,
    /// Raw sample format: s16le, s32le or f32le.
    #[arg(long, value_parser = parse_format, default_value = "s16le")]
    pub format: RawFormat,
    /// Interleaved channels (mixed to mono).
    #[arg(long, default_value_t = 1)]
    pub channels: u16,
    /// Frame records on stdout.
    #[arg(long, value_enum, default_value_t = OutputFormat::Jsonl)]
    pub output: OutputFormat,
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub gen: GenArgs,
}

fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

pub fn run(a: Args, form: GraphForm) -> Result<()> {
    let opts = a.gen.stream_options()?;
    if a.rate == 0 || a.channels == 0 {
        return Err(InputError::new("--rate and --channels must be at least 1").into());
    }
    let bundle = a.model.bundle()?;
    let model = a.model.model(&bundle, form)?;
    let mut stream = super::common::new_stream(model.as_ref(), &opts)?;
    let stdin = std::io::stdin().lock();
    let mut input = RawPcmStream::new(stdin, a.format, a.rate, a.channels, "<stdin>")?;
    let out = BufWriter::new(std::io::stdout().lock());
    let mut sink: Box<dyn FrameSink> = match a.output {
        OutputFormat::Jsonl => Box::new(JsonLinesWriter::new(out)),
        OutputFormat::Binary => Box::new(BinaryFrameWriter::new(out)),
    };
    let result = (|| -> Result<()> {
        while let Some(chunk) = input.next_chunk()? {
            for f in stream.push_audio(&chunk)? {
                sink.write_frame(&f)?;
            }
        }
        // docs/output.md: at the end of the input, the last partial token is completed with silence
        for f in stream.finish(input.input_span())? {
            sink.write_frame(&f)?;
        }
        sink.finish()
    })();
    match result {
        Err(e) if is_broken_pipe(&e) => Ok(()), // the reader went away: a normal end of a live stream
        Err(e) => {
            let _ = std::io::stdout().flush();
            Err(e)
        }
        Ok(()) => Ok(()),
    }
}

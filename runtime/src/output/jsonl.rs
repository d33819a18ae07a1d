//! JSON lines: one frame per line (see the [module docs](super)).

use std::io::Write;

use anyhow::{Context, Result};

use super::{Frame, FrameSink};

/// Writes frames as JSON lines, flushing after every frame for live consumers.
#[derive(Debug)]
pub struct JsonLinesWriter<W: Write> {
    w: W,
    frames: u64,
}

impl<W: Write> JsonLinesWriter<W> {
    /// A writer into `w`.
    pub fn new(w: W) -> Self {
        Self { w, frames: 0 }
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.frames
    }

    /// The underlying writer.
    pub fn into_inner(self) -> W {
        self.w
    }
}

impl<W: Write> FrameSink for JsonLinesWriter<W> {
    fn write_frame(&mut self, frame: &Frame) -> Result<()> {
        let mut line = frame.to_json_line()?;
        line.push('\n');
        self.w
            .write_all(line.as_bytes())
            .context("output: writing a JSON line")?;
        self.w.flush().context("output: flushing JSON lines")?;
        self.frames += 1;
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        self.w.flush().context("output: flushing JSON lines")
    }
}

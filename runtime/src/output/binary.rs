//! The compact binary frame stream: a 16-byte header, then fixed 1104-byte records (see the
//! [module docs](super)).

use std::io::{self, Read, Write};

use anyhow::{bail, ensure, Context, Result};

use super::*;

/// The 16-byte binary stream header (see the module docs).
pub fn binary_header() -> [u8; BINARY_HEADER_LEN] {
    let mut h = [0u8; BINARY_HEADER_LEN];
    h[..8].copy_from_slice(&BINARY_MAGIC);
    h[8..10].copy_from_slice(&BINARY_VERSION.to_le_bytes());
    h[10..12].copy_from_slice(&(BINARY_HEADER_LEN as u16).to_le_bytes());
    h[12..14].copy_from_slice(&(BINARY_RECORD_LEN as u16).to_le_bytes());
    h[14..16].copy_from_slice(&(FPS as u16).to_le_bytes());
    h
}

/// Writes frames in the binary record format: the header before the first frame (or at `finish`
/// for an empty stream), then one record per frame, flushed after every frame.
#[derive(Debug)]
pub struct BinaryFrameWriter<W: Write> {
    w: W,
    header_written: bool,
    buf: Vec<u8>,
}

impl<W: Write> BinaryFrameWriter<W> {
    /// A writer into `w`.
    pub fn new(w: W) -> Self {
        Self {
            w,
            header_written: false,
            buf: Vec::with_capacity(BINARY_RECORD_LEN),
        }
    }

    fn ensure_header(&mut self) -> Result<()> {
        if !self.header_written {
            self.w
                .write_all(&binary_header())
                .context("output: writing the binary frame header")?;
            self.header_written = true;
        }
        Ok(())
    }

    /// The underlying writer.
    pub fn into_inner(self) -> W {
        self.w
    }
}

impl<W: Write> FrameSink for BinaryFrameWriter<W> {
    fn write_frame(&mut self, frame: &Frame) -> Result<()> {
        frame.check_finite()?;
        self.ensure_header()?;
        self.buf.clear();
        frame.encode_binary(&mut self.buf);
        self.w
            .write_all(&self.buf)
            .context("output: writing a binary frame record")?;
        self.w.flush().context("output: flushing binary frames")
    }

    fn finish(&mut self) -> Result<()> {
        self.ensure_header()?;
        self.w.flush().context("output: flushing binary frames")
    }
}

/// Reads a binary frame stream written by [`BinaryFrameWriter`].
#[derive(Debug)]
pub struct BinaryFrameReader<R: Read> {
    r: R,
    buf: Vec<u8>,
}

impl<R: Read> BinaryFrameReader<R> {
    /// Reads and checks the header.
    pub fn new(mut r: R) -> Result<Self> {
        let mut h = [0u8; BINARY_HEADER_LEN];
        r.read_exact(&mut h)
            .context("output: reading the binary frame header (16 bytes)")?;
        ensure!(
            h[..8] == BINARY_MAGIC,
            "output: not a LiveGesture binary frame stream (magic {:?}, expected \"LGFRAMES\")",
            &h[..8]
        );
        let u16_at = |i: usize| u16::from_le_bytes([h[i], h[i + 1]]);
        ensure!(
            u16_at(8) == BINARY_VERSION,
            "output: binary frame stream version {}, expected {BINARY_VERSION}",
            u16_at(8)
        );
        ensure!(
            u16_at(10) as usize == BINARY_HEADER_LEN && u16_at(12) as usize == BINARY_RECORD_LEN,
            "output: binary frame stream declares header {} / record {} bytes, expected {BINARY_HEADER_LEN} / {BINARY_RECORD_LEN}",
            u16_at(10),
            u16_at(12)
        );
        ensure!(
            u16_at(14) as u32 == FPS,
            "output: binary frame stream at {} fps, expected {FPS}",
            u16_at(14)
        );
        Ok(Self {
            r,
            buf: vec![0; BINARY_RECORD_LEN],
        })
    }

    /// The next frame, or `None` at a clean end of stream; an error for a partial record.
    pub fn next_frame(&mut self) -> Result<Option<Frame>> {
        let mut got = 0;
        while got < BINARY_RECORD_LEN {
            match self.r.read(&mut self.buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e).context("output: reading a binary frame record"),
            }
        }
        match got {
            0 => Ok(None),
            BINARY_RECORD_LEN => Frame::decode_binary(&self.buf).map(Some),
            n => bail!("output: binary frame stream ends inside a record ({n} of {BINARY_RECORD_LEN} bytes)"),
        }
    }
}

impl<R: Read> Iterator for BinaryFrameReader<R> {
    type Item = Result<Frame>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_frame().transpose()
    }
}

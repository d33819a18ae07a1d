//! The compact binary frame stream: a 16-byte header, then fixed records of 1104 bytes (version 1,
//! body only) or 1372 (version 2, with the face) (see the [module docs](super)).

use std::io::{self, Read, Write};

use anyhow::{bail, ensure, Context, Result};

use super::*;

/// The 16-byte binary stream header of a body-only stream (version 1; see the module docs).
pub fn binary_header() -> [u8; BINARY_HEADER_LEN] {
    binary_header_for(false)
}

/// The 16-byte binary stream header of frames with (`true`, version 2) or without the face.
pub fn binary_header_for(face: bool) -> [u8; BINARY_HEADER_LEN] {
    let (version, record) = binary_layout(face);
    let mut h = [0u8; BINARY_HEADER_LEN];
    h[..8].copy_from_slice(&BINARY_MAGIC);
    h[8..10].copy_from_slice(&version.to_le_bytes());
    h[10..12].copy_from_slice(&(BINARY_HEADER_LEN as u16).to_le_bytes());
    h[12..14].copy_from_slice(&(record as u16).to_le_bytes());
    h[14..16].copy_from_slice(&(FPS as u16).to_le_bytes());
    h
}

/// Writes frames in the binary record format: the header before the first frame (or at `finish`
/// for an empty stream, version 1), then one record per frame, flushed after every frame. The
/// first frame sets the version (2 when it carries the face); a later frame that differs is refused.
#[derive(Debug)]
pub struct BinaryFrameWriter<W: Write> {
    w: W,
    /// `Some(face)` once the header is written.
    header: Option<bool>,
    buf: Vec<u8>,
}

impl<W: Write> BinaryFrameWriter<W> {
    /// A writer into `w`.
    pub fn new(w: W) -> Self {
        Self {
            w,
            header: None,
            buf: Vec::with_capacity(BINARY_RECORD_LEN_FACE),
        }
    }

    fn ensure_header(&mut self, face: bool) -> Result<()> {
        match self.header {
            None => {
                self.w
                    .write_all(&binary_header_for(face))
                    .context("output: writing the binary frame header")?;
                self.header = Some(face);
            }
            Some(h) => ensure!(
                h == face,
                "output: a frame {} the face in a binary stream of version {} (frames {} it)",
                if face { "with" } else { "without" },
                binary_layout(h).0,
                if h { "with" } else { "without" }
            ),
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
        self.ensure_header(frame.face.is_some())?;
        self.buf.clear();
        frame.encode_binary(&mut self.buf);
        self.w
            .write_all(&self.buf)
            .context("output: writing a binary frame record")?;
        self.w.flush().context("output: flushing binary frames")
    }

    fn finish(&mut self) -> Result<()> {
        let face = self.header.unwrap_or(false);
        self.ensure_header(face)?;
        self.w.flush().context("output: flushing binary frames")
    }
}

/// Reads a binary frame stream written by [`BinaryFrameWriter`]: version 1 (frames without the
/// face) or 2 (frames with it).
#[derive(Debug)]
pub struct BinaryFrameReader<R: Read> {
    r: R,
    buf: Vec<u8>,
    version: u16,
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
        let version = u16_at(8);
        let face = match version {
            BINARY_VERSION => false,
            BINARY_VERSION_FACE => true,
            v => bail!(
                "output: binary frame stream version {v}, expected {BINARY_VERSION} (body) or {BINARY_VERSION_FACE} (body and face)"
            ),
        };
        let record = binary_layout(face).1;
        ensure!(
            u16_at(10) as usize == BINARY_HEADER_LEN && u16_at(12) as usize == record,
            "output: binary frame stream of version {version} declares header {} / record {} bytes, expected {BINARY_HEADER_LEN} / {record}",
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
            buf: vec![0; record],
            version,
        })
    }

    /// The stream's format version: 1 (body only) or 2 (frames carry the face).
    pub fn version(&self) -> u16 {
        self.version
    }

    /// The next frame, or `None` at a clean end of stream; an error for a partial record.
    pub fn next_frame(&mut self) -> Result<Option<Frame>> {
        let len = self.buf.len();
        let mut got = 0;
        while got < len {
            match self.r.read(&mut self.buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e).context("output: reading a binary frame record"),
            }
        }
        match got {
            0 => Ok(None),
            n if n == len => Frame::decode_binary(&self.buf).map(Some),
            n => bail!("output: binary frame stream ends inside a record ({n} of {len} bytes)"),
        }
    }
}

impl<R: Read> Iterator for BinaryFrameReader<R> {
    type Item = Result<Frame>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_frame().transpose()
    }
}

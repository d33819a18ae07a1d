//! Motion output: BEAT2-compatible `.npz` files and per-frame live records.
//!
//! # BEAT2 `.npz`
//!
//! [`write_beat2_npz`] (and [`NpzFrameWriter`], which collects frames and writes at
//! [`NpzFrameWriter::finish`]) writes an uncompressed zip of `.npy` (format 1.0) entries, the layout
//! `numpy.savez` produces and BEAT2 tools and the SMPL-X Blender add-on read:
//!
//! | key | dtype | shape |
//! |---|---|---|
//! | `poses` | `<f4` | `(T, 165)` axis-angle, 55 SMPL-X joints |
//! | `trans` | `<f4` | `(T, 3)` metres, Y up |
//! | `expressions` | `<f4` | `(T, 100)` |
//! | `betas` | `<f4` | `(300,)` zeros |
//! | `model` | `<U9` | `()` the string `smplx2020` |
//! | `gender` | `<U7` | `()` the string `neutral` |
//! | `mocap_frame_rate` | `<i8` | `()` 30 |
//!
//! String entries are numpy unicode scalars (UTF-32LE code points), so `np.load(f)["model"]` is a
//! `str` array just as in the BEAT2 files. The file is written **atomically**: to a temporary file in
//! the destination directory, synced, then renamed over the destination; on any error the temporary
//! file is removed and nothing appears at (or replaces) the destination.
//!
//! # Live frame records
//!
//! A [`Frame`] is one 30 fps motion frame: `index` (from 0), `time_s = index / 30`, `poses` (165),
//! `trans` (3), `expressions` (100), `foot_contact` (4, for joints 7, 8, 10, 11, 1 = in contact).
//!
//! **JSON lines** ([`JsonLinesWriter`]): one JSON object per line with exactly those keys, arrays as
//! JSON arrays of numbers (shortest round-tripping decimal form of each `f32`).
//!
//! **Binary** ([`BinaryFrameWriter`], [`BinaryFrameReader`]), all little-endian. A 16-byte header
//! once per stream:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | magic `LGFRAMES` (ASCII) |
//! | 8 | 2 | format version, `u16` = 1 |
//! | 10 | 2 | header length in bytes, `u16` = 16 |
//! | 12 | 2 | record length in bytes, `u16` = 1104 |
//! | 14 | 2 | frames per second, `u16` = 30 |
//!
//! then one fixed-size 1104-byte record per frame:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | `index`, `u64` |
//! | 8 | 8 | `time_s`, `f64` |
//! | 16 | 660 | `poses`, 165 x `f32` |
//! | 676 | 12 | `trans`, 3 x `f32` |
//! | 688 | 400 | `expressions`, 100 x `f32` |
//! | 1088 | 16 | `foot_contact`, 4 x `f32` |
//!
//! Writers refuse frames with NaN or infinite values, naming the frame and the field.

use std::fs::File;
use std::io::{self, BufWriter, Read, Seek, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use ndarray::{Array2, ArrayView2};
use serde::ser::SerializeStruct;
use serde::{Deserialize, Serialize, Serializer};

/// Motion frames per second.
pub const FPS: u32 = 30;
/// Axis-angle pose values per frame (55 joints x 3).
pub const POSE_DIM: usize = 165;
/// Translation values per frame.
pub const TRANS_DIM: usize = 3;
/// Expression coefficients per frame.
pub const EXPR_DIM: usize = 100;
/// Foot-contact values per frame (joints 7, 8, 10, 11).
pub const CONTACT_DIM: usize = 4;
/// Shape coefficients in a BEAT2 file (all zero here).
pub const BETAS_DIM: usize = 300;

/// Magic bytes that open a binary frame stream.
pub const BINARY_MAGIC: [u8; 8] = *b"LGFRAMES";
/// Binary frame stream format version.
pub const BINARY_VERSION: u16 = 1;
/// Binary header length in bytes.
pub const BINARY_HEADER_LEN: usize = 16;
/// Binary record length in bytes.
pub const BINARY_RECORD_LEN: usize = 16 + 4 * (POSE_DIM + TRANS_DIM + EXPR_DIM + CONTACT_DIM);

// ----------------------------------------------------------------------------------------- Frame

/// One 30 fps motion frame with its timestamp (see the module docs).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(try_from = "FrameRepr")]
pub struct Frame {
    /// Frame index from the start of the stream.
    pub index: u64,
    /// Timestamp in seconds, `index / 30`.
    pub time_s: f64,
    /// SMPL-X axis-angle, 55 joints x 3.
    pub poses: [f32; POSE_DIM],
    /// Root translation in metres.
    pub trans: [f32; TRANS_DIM],
    /// Expression coefficients.
    pub expressions: [f32; EXPR_DIM],
    /// Foot contact of joints 7, 8, 10, 11.
    pub foot_contact: [f32; CONTACT_DIM],
}

#[derive(Deserialize)]
struct FrameRepr {
    index: u64,
    time_s: f64,
    poses: Vec<f32>,
    trans: Vec<f32>,
    expressions: Vec<f32>,
    foot_contact: Vec<f32>,
}

fn to_array<const N: usize>(v: Vec<f32>, name: &str) -> Result<[f32; N], String> {
    let n = v.len();
    v.try_into()
        .map_err(|_| format!("frame field '{name}' has {n} values, expected {N}"))
}

impl TryFrom<FrameRepr> for Frame {
    type Error = String;

    fn try_from(r: FrameRepr) -> Result<Self, String> {
        Ok(Frame {
            index: r.index,
            time_s: r.time_s,
            poses: to_array(r.poses, "poses")?,
            trans: to_array(r.trans, "trans")?,
            expressions: to_array(r.expressions, "expressions")?,
            foot_contact: to_array(r.foot_contact, "foot_contact")?,
        })
    }
}

impl Serialize for Frame {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("Frame", 6)?;
        st.serialize_field("index", &self.index)?;
        st.serialize_field("time_s", &self.time_s)?;
        st.serialize_field("poses", &self.poses[..])?;
        st.serialize_field("trans", &self.trans[..])?;
        st.serialize_field("expressions", &self.expressions[..])?;
        st.serialize_field("foot_contact", &self.foot_contact[..])?;
        st.end()
    }
}

impl Frame {
    /// A frame with `time_s = index / 30`.
    pub fn new(
        index: u64,
        poses: [f32; POSE_DIM],
        trans: [f32; TRANS_DIM],
        expressions: [f32; EXPR_DIM],
        foot_contact: [f32; CONTACT_DIM],
    ) -> Self {
        Self {
            index,
            time_s: Self::time_of(index),
            poses,
            trans,
            expressions,
            foot_contact,
        }
    }

    /// An all-zero frame (rest pose) at `index`.
    pub fn zeros(index: u64) -> Self {
        Self::new(
            index,
            [0.0; POSE_DIM],
            [0.0; TRANS_DIM],
            [0.0; EXPR_DIM],
            [0.0; CONTACT_DIM],
        )
    }

    /// Timestamp of frame `index` in seconds: `index / 30`.
    pub fn time_of(index: u64) -> f64 {
        index as f64 / FPS as f64
    }

    /// An error naming the frame and field if any value is NaN or infinite.
    pub fn check_finite(&self) -> Result<()> {
        for (name, v) in [
            ("poses", &self.poses[..]),
            ("trans", &self.trans[..]),
            ("expressions", &self.expressions[..]),
            ("foot_contact", &self.foot_contact[..]),
        ] {
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                bail!("output: frame {} has a non-finite value ({}) in {name}[{i}]; expected finite values", self.index, v[i]);
            }
        }
        ensure!(
            self.time_s.is_finite(),
            "output: frame {} has a non-finite time_s",
            self.index
        );
        Ok(())
    }

    /// The frame as one line of JSON (without the trailing newline).
    pub fn to_json_line(&self) -> Result<String> {
        self.check_finite()?;
        Ok(serde_json::to_string(self)?)
    }

    /// Parses one JSON line written by [`Frame::to_json_line`].
    pub fn from_json_line(line: &str) -> Result<Self> {
        serde_json::from_str(line).context("output: invalid frame JSON line")
    }

    /// Appends the frame's 1104-byte binary record to `out`.
    pub fn encode_binary(&self, out: &mut Vec<u8>) {
        out.reserve(BINARY_RECORD_LEN);
        out.extend_from_slice(&self.index.to_le_bytes());
        out.extend_from_slice(&self.time_s.to_le_bytes());
        for v in self
            .poses
            .iter()
            .chain(&self.trans)
            .chain(&self.expressions)
            .chain(&self.foot_contact)
        {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// Decodes one binary record (exactly [`BINARY_RECORD_LEN`] bytes).
    pub fn decode_binary(rec: &[u8]) -> Result<Self> {
        ensure!(
            rec.len() == BINARY_RECORD_LEN,
            "output: a binary frame record has {BINARY_RECORD_LEN} bytes, got {}",
            rec.len()
        );
        let u64_at = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&rec[i..i + 8]);
            b
        };
        let mut floats = rec[16..]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
        let mut f = Frame::zeros(u64::from_le_bytes(u64_at(0)));
        f.time_s = f64::from_le_bytes(u64_at(8));
        for dst in f
            .poses
            .iter_mut()
            .chain(f.trans.iter_mut())
            .chain(f.expressions.iter_mut())
            .chain(f.foot_contact.iter_mut())
        {
            *dst = floats.next().unwrap_or(0.0);
        }
        Ok(f)
    }
}

// ----------------------------------------------------------------------------------------- sinks

/// Something frames can be streamed into, one at a time.
pub trait FrameSink {
    /// Writes one frame.
    fn write_frame(&mut self, frame: &Frame) -> Result<()>;
    /// Ends the stream (flushes, or writes the file for [`NpzFrameWriter`]).
    fn finish(&mut self) -> Result<()>;
}

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

// ----------------------------------------------------------------------------------------- npy / npz

/// A whole motion in BEAT2 layout.
#[derive(Debug, Clone, PartialEq)]
pub struct Beat2Motion {
    /// `(T, 165)` axis-angle.
    pub poses: Array2<f32>,
    /// `(T, 3)` translation.
    pub trans: Array2<f32>,
    /// `(T, 100)` expressions.
    pub expressions: Array2<f32>,
}

impl Beat2Motion {
    /// Number of frames `T`.
    pub fn len(&self) -> usize {
        self.poses.nrows()
    }

    /// True when there are no frames.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Checks shapes and finiteness.
    pub fn validate(&self) -> Result<()> {
        let t = self.poses.nrows();
        for (name, a, d) in [
            ("poses", &self.poses, POSE_DIM),
            ("trans", &self.trans, TRANS_DIM),
            ("expressions", &self.expressions, EXPR_DIM),
        ] {
            ensure!(
                a.dim() == (t, d),
                "output: {name} has shape {:?}, expected ({t}, {d})",
                a.dim()
            );
            if let Some((i, v)) = a.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                bail!(
                    "output: {name} has a non-finite value ({v}) at frame {}, column {}",
                    i / d,
                    i % d
                );
            }
        }
        Ok(())
    }
}

/// A `.npy` (format 1.0) header for `descr` and `shape`, padded so the data starts at a multiple of
/// 64 bytes as numpy does.
fn npy_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let shape_s = match shape {
        [] => "()".to_string(),
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_s}, }}");
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat(unpadded.div_ceil(64) * 64 - unpadded));
    dict.push('\n');
    let mut h = Vec::with_capacity(10 + dict.len());
    h.extend_from_slice(b"\x93NUMPY\x01\x00");
    h.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    h.extend_from_slice(dict.as_bytes());
    h
}

fn npy_f32(shape: &[usize], data: impl Iterator<Item = f32>) -> Vec<u8> {
    let mut v = npy_header("<f4", shape);
    for x in data {
        v.extend_from_slice(&x.to_le_bytes());
    }
    v
}

fn npy_i64_scalar(x: i64) -> Vec<u8> {
    let mut v = npy_header("<i8", &[]);
    v.extend_from_slice(&x.to_le_bytes());
    v
}

/// A numpy unicode scalar (`<U{n}`, UTF-32LE code points).
fn npy_str_scalar(s: &str) -> Vec<u8> {
    let n = s.chars().count().max(1);
    let mut v = npy_header(&format!("<U{n}"), &[]);
    for c in s.chars() {
        v.extend_from_slice(&(c as u32).to_le_bytes());
    }
    if s.is_empty() {
        v.extend_from_slice(&[0; 4]);
    }
    v
}

fn array_npy(a: &ArrayView2<f32>) -> Vec<u8> {
    let (r, c) = a.dim();
    npy_f32(&[r, c], a.iter().copied())
}

/// Writes `bytes` to `path` atomically with `write`: a temporary file in the same directory, synced,
/// then renamed. On error the temporary file is removed and `path` is untouched.
fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<&File>) -> Result<()>,
) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .with_context(|| format!("output: {} is not a file path", path.display()))?;
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{}.", name.to_string_lossy()))
        .suffix(".tmp")
        .tempfile_in(&dir)
        .with_context(|| {
            format!(
                "output: cannot create a temporary file in {}",
                dir.display()
            )
        })?;
    {
        let mut w = BufWriter::new(tmp.as_file());
        write(&mut w)?;
        w.flush()
            .with_context(|| format!("output: writing {}", path.display()))?;
    }
    tmp.as_file()
        .sync_all()
        .with_context(|| format!("output: syncing {}", path.display()))?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(tmp.path(), std::fs::Permissions::from_mode(0o644))
            .with_context(|| format!("output: setting permissions of {}", path.display()))?;
    }
    tmp.persist(path).map_err(|e| e.error).with_context(|| {
        format!(
            "output: cannot move the finished file to {}",
            path.display()
        )
    })?;
    Ok(())
}

/// Writes a BEAT2-compatible `.npz` atomically (see the module docs for keys, dtypes and shapes).
pub fn write_beat2_npz(path: impl AsRef<Path>, motion: &Beat2Motion) -> Result<()> {
    let path = path.as_ref();
    motion
        .validate()
        .with_context(|| format!("output: refusing to write {}", path.display()))?;
    let entries: Vec<(&str, Vec<u8>)> = vec![
        ("poses", array_npy(&motion.poses.view())),
        ("trans", array_npy(&motion.trans.view())),
        ("expressions", array_npy(&motion.expressions.view())),
        (
            "betas",
            npy_f32(&[BETAS_DIM], std::iter::repeat_n(0.0, BETAS_DIM)),
        ),
        ("model", npy_str_scalar("smplx2020")),
        ("gender", npy_str_scalar("neutral")),
        ("mocap_frame_rate", npy_i64_scalar(FPS as i64)),
    ];
    write_atomically(path, |w| {
        let mut zip = zip::ZipWriter::new(w);
        for (name, bytes) in &entries {
            let opts = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Stored)
                .large_file(bytes.len() as u64 >= u32::MAX as u64);
            zip.start_file(format!("{name}.npy"), opts)
                .with_context(|| format!("output: writing {name} into {}", path.display()))?;
            zip.write_all(bytes)
                .with_context(|| format!("output: writing {name} into {}", path.display()))?;
        }
        zip.finish()
            .with_context(|| format!("output: finishing {}", path.display()))?;
        Ok(())
    })
}

/// Reads `poses`, `trans` and `expressions` back from a BEAT2 `.npz` (float32 arrays).
pub fn read_beat2_npz(path: impl AsRef<Path>) -> Result<Beat2Motion> {
    let path = path.as_ref();
    let f = File::open(path).with_context(|| format!("output: cannot open {}", path.display()))?;
    read_beat2_from(f).with_context(|| format!("output: reading {}", path.display()))
}

fn read_beat2_from<R: Read + Seek>(r: R) -> Result<Beat2Motion> {
    let mut npz = ndarray_npy::NpzReader::new(r)?;
    let mut get = |name: &str| -> Result<Array2<f32>> {
        npz.by_name(name)
            .with_context(|| format!("key '{name}' (float32, 2-D)"))
    };
    let m = Beat2Motion {
        poses: get("poses")?,
        trans: get("trans")?,
        expressions: get("expressions")?,
    };
    m.validate()?;
    Ok(m)
}

/// Collects frames one at a time and writes the BEAT2 `.npz` at [`NpzFrameWriter::finish`]
/// (atomically). Frames must arrive with consecutive indices. Memory is about 1 KB per frame.
#[derive(Debug)]
pub struct NpzFrameWriter {
    path: PathBuf,
    poses: Vec<f32>,
    trans: Vec<f32>,
    expressions: Vec<f32>,
    next_index: Option<u64>,
    frames: usize,
    finished: bool,
}

impl NpzFrameWriter {
    /// A writer whose file will be `path`; nothing is written before `finish`.
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            poses: Vec::new(),
            trans: Vec::new(),
            expressions: Vec::new(),
            next_index: None,
            frames: 0,
            finished: false,
        }
    }

    /// Frames collected so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The collected motion.
    pub fn motion(&self) -> Result<Beat2Motion> {
        let t = self.frames;
        Ok(Beat2Motion {
            poses: Array2::from_shape_vec((t, POSE_DIM), self.poses.clone())?,
            trans: Array2::from_shape_vec((t, TRANS_DIM), self.trans.clone())?,
            expressions: Array2::from_shape_vec((t, EXPR_DIM), self.expressions.clone())?,
        })
    }
}

impl FrameSink for NpzFrameWriter {
    fn write_frame(&mut self, frame: &Frame) -> Result<()> {
        ensure!(
            !self.finished,
            "output: {} was already finished",
            self.path.display()
        );
        if let Some(want) = self.next_index {
            ensure!(frame.index == want, "output: frame {} arrived where frame {want} was expected (frames must be consecutive)", frame.index);
        }
        frame.check_finite()?;
        self.poses.extend_from_slice(&frame.poses);
        self.trans.extend_from_slice(&frame.trans);
        self.expressions.extend_from_slice(&frame.expressions);
        self.next_index = Some(frame.index + 1);
        self.frames += 1;
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        ensure!(
            !self.finished,
            "output: {} was already finished",
            self.path.display()
        );
        let t = self.frames;
        let motion = Beat2Motion {
            poses: Array2::from_shape_vec((t, POSE_DIM), std::mem::take(&mut self.poses))?,
            trans: Array2::from_shape_vec((t, TRANS_DIM), std::mem::take(&mut self.trans))?,
            expressions: Array2::from_shape_vec(
                (t, EXPR_DIM),
                std::mem::take(&mut self.expressions),
            )?,
        };
        self.finished = true;
        write_beat2_npz(&self.path, &motion)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(i: u64) -> Frame {
        let mut f = Frame::zeros(i);
        for (k, v) in f.poses.iter_mut().enumerate() {
            *v = (k as f32 * 0.01 + i as f32) * if k % 2 == 0 { 1.0 } else { -1.0 };
        }
        f.trans = [i as f32, 1.5, -0.25];
        for (k, v) in f.expressions.iter_mut().enumerate() {
            *v = k as f32 / 7.0;
        }
        f.foot_contact = [1.0, 0.0, 1.0, 0.0];
        f
    }

    #[test]
    fn npy_headers_are_aligned() {
        for (d, s) in [
            ("<f4", vec![3usize, 165]),
            ("<U9", vec![]),
            ("<f4", vec![300]),
        ] {
            let h = npy_header(d, &s);
            assert_eq!(h.len() % 64, 0);
            assert_eq!(*h.last().unwrap(), b'\n');
        }
        let h = String::from_utf8_lossy(&npy_header("<U9", &[])).to_string();
        assert!(h.contains("'descr': '<U9', 'fortran_order': False, 'shape': ()"));
        let s = npy_str_scalar("smplx2020");
        let hl = npy_header("<U9", &[]).len();
        assert_eq!(s.len(), hl + 36);
        assert_eq!(&s[hl..hl + 8], &[b's', 0, 0, 0, b'm', 0, 0, 0]);
    }

    #[test]
    fn npz_round_trip_and_keys() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("out.npz");
        let mut w = NpzFrameWriter::new(&p);
        for i in 0..5 {
            w.write_frame(&frame(i)).unwrap();
        }
        let expected = w.motion().unwrap();
        w.finish().unwrap();
        assert!(w.finish().is_err());
        let m = read_beat2_npz(&p).unwrap();
        assert_eq!(m, expected);
        assert_eq!(m.poses[[3, 1]], -(0.01 + 3.0));

        let mut npz = ndarray_npy::NpzReader::new(File::open(&p).unwrap()).unwrap();
        let mut names = npz.names().unwrap();
        names.sort();
        // (ndarray-npy lists entry names without the ".npy" suffix)
        assert_eq!(
            names,
            [
                "betas",
                "expressions",
                "gender",
                "mocap_frame_rate",
                "model",
                "poses",
                "trans"
            ]
        );
        let betas: ndarray::Array1<f32> = npz.by_name("betas.npy").unwrap();
        assert_eq!(betas.len(), 300);
        assert!(betas.iter().all(|&b| b == 0.0));
        let fr: ndarray::Array0<i64> = npz.by_name("mocap_frame_rate.npy").unwrap();
        assert_eq!(fr.into_scalar(), 30);
        // no temporary files left behind
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn npz_write_is_atomic_on_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.npz");
        std::fs::write(&p, b"previous").unwrap();
        let mut f = frame(0);
        f.poses[7] = f32::NAN;
        let bad = Beat2Motion {
            poses: Array2::from_shape_vec((1, POSE_DIM), f.poses.to_vec()).unwrap(),
            trans: Array2::zeros((1, 3)),
            expressions: Array2::zeros((1, 100)),
        };
        let e = write_beat2_npz(&p, &bad).unwrap_err();
        assert!(format!("{e:#}").contains("poses"), "{e:#}");
        assert_eq!(std::fs::read(&p).unwrap(), b"previous");
        // destination is a directory: the rename fails, no temp file remains
        let d = dir.path().join("adir");
        std::fs::create_dir(&d).unwrap();
        let ok = NpzFrameWriter::new(&d).motion().unwrap();
        assert!(write_beat2_npz(&d, &ok).is_err());
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left.len(), 2, "{left:?}");
        // missing directory
        assert!(write_beat2_npz(dir.path().join("nope/x.npz"), &ok).is_err());
        // non-consecutive frames
        let mut w = NpzFrameWriter::new(dir.path().join("y.npz"));
        w.write_frame(&frame(0)).unwrap();
        assert!(w.write_frame(&frame(2)).is_err());
    }

    #[test]
    fn json_lines_round_trip() {
        let mut w = JsonLinesWriter::new(Vec::new());
        for i in 0..3 {
            w.write_frame(&frame(i)).unwrap();
        }
        w.finish().unwrap();
        let text = String::from_utf8(w.into_inner()).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 3);
        let v: serde_json::Value = serde_json::from_str(lines[1]).unwrap();
        let keys: Vec<&String> = v.as_object().unwrap().keys().collect();
        for k in [
            "index",
            "time_s",
            "poses",
            "trans",
            "expressions",
            "foot_contact",
        ] {
            assert!(keys.iter().any(|x| x.as_str() == k), "{k}");
        }
        assert_eq!(v["poses"].as_array().unwrap().len(), 165);
        assert_eq!(v["time_s"].as_f64().unwrap(), 1.0 / 30.0);
        for (i, l) in lines.iter().enumerate() {
            assert_eq!(Frame::from_json_line(l).unwrap(), frame(i as u64));
        }
        assert!(Frame::from_json_line(
            r#"{"index":0,"time_s":0,"poses":[1],"trans":[],"expressions":[],"foot_contact":[]}"#
        )
        .unwrap_err()
        .to_string()
        .contains("invalid frame"));
        let mut bad = frame(4);
        bad.trans[2] = f32::INFINITY;
        let e = JsonLinesWriter::new(Vec::new())
            .write_frame(&bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("frame 4") && e.contains("trans[2]"), "{e}");
    }

    #[test]
    fn binary_round_trip() {
        assert_eq!(BINARY_RECORD_LEN, 1104);
        let mut w = BinaryFrameWriter::new(Vec::new());
        for i in 0..4 {
            w.write_frame(&frame(i)).unwrap();
        }
        w.finish().unwrap();
        let bytes = w.into_inner();
        assert_eq!(bytes.len(), 16 + 4 * 1104);
        assert_eq!(&bytes[..8], b"LGFRAMES");
        // spot-check the layout: frame 1's trans[0] at 16 + 1104 + 676
        let o = 16 + 1104 + 676;
        assert_eq!(f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()), 1.0);
        let frames: Vec<Frame> = BinaryFrameReader::new(&bytes[..])
            .unwrap()
            .map(|f| f.unwrap())
            .collect();
        assert_eq!(frames, (0..4).map(frame).collect::<Vec<_>>());
        // truncated record and bad magic are errors
        let mut r = BinaryFrameReader::new(&bytes[..bytes.len() - 10]).unwrap();
        for _ in 0..3 {
            r.next_frame().unwrap().unwrap();
        }
        assert!(r.next_frame().is_err());
        assert!(BinaryFrameReader::new(&b"NOTFRAMES_______"[..]).is_err());
        // empty stream still has its header
        let mut w = BinaryFrameWriter::new(Vec::new());
        w.finish().unwrap();
        assert_eq!(w.into_inner(), binary_header().to_vec());
    }
}

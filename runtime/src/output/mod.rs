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
//! JSON arrays of numbers (shortest round-tripping decimal form of each `f32`); from a bundle with the
//! face channel (docs/face.md) also `arkit` (52) and `visemes` (15).
//!
//! **Binary** ([`BinaryFrameWriter`], [`BinaryFrameReader`]), all little-endian. A 16-byte header
//! once per stream:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | magic `LGFRAMES` (ASCII) |
//! | 8 | 2 | format version, `u16`: 1 (body only) or 2 (body and face) |
//! | 10 | 2 | header length in bytes, `u16` = 16 |
//! | 12 | 2 | record length in bytes, `u16`: 1104 (version 1) or 1372 (version 2) |
//! | 14 | 2 | frames per second, `u16` = 30 |
//!
//! then one fixed-size record per frame:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | `index`, `u64` |
//! | 8 | 8 | `time_s`, `f64` |
//! | 16 | 660 | `poses`, 165 x `f32` |
//! | 676 | 12 | `trans`, 3 x `f32` |
//! | 688 | 400 | `expressions`, 100 x `f32` |
//! | 1088 | 16 | `foot_contact`, 4 x `f32` |
//! | 1104 | 208 | version 2 only: `arkit`, 52 x `f32` (ARKit names, Apple's order; docs/face.md) |
//! | 1312 | 60 | version 2 only: `visemes`, 15 x `f32` (`sil` ... `ou`) |
//!
//! Version 2 is version 1 with the face appended: a stream is version 2 exactly when its frames carry
//! the face (a bundle with the face channel), version 1 otherwise, so a version-1 reader still reads
//! every body-only stream and refuses a face stream by its version, never misreading it. The writer
//! takes the version from the first frame (an empty stream is version 1) and refuses a later frame
//! that differs. [`BinaryFrameReader`] reads both.
//!
//! Writers refuse frames with NaN or infinite values (and face values outside [0, 1]), naming the
//! frame and the field.
//!
//! # Layout
//!
//! [`Frame`] and [`FrameSink`] here; the sinks in `jsonl`, `binary` and `npz`; glTF 2.0 files
//! (`.glb`, `.gltf`: the project's skeleton and one animation, docs/avatars.md) in [`gltf`].

use anyhow::{bail, ensure, Context, Result};
use serde::ser::SerializeStruct;
use serde::{Deserialize, Serialize, Serializer};

mod binary;
pub mod gltf;
mod jsonl;
mod npz;

pub use binary::{binary_header, binary_header_for, BinaryFrameReader, BinaryFrameWriter};
pub use gltf::{gltf_from_frames, write_gltf, write_gltf_with_face, GltfContainer};
pub use jsonl::JsonLinesWriter;
pub use npz::{
    read_beat2_npz, write_beat2_npz, write_beat2_npz_with_face, Beat2Motion, FaceTrack,
    NpzFrameWriter,
};

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
/// Binary frame stream format version of a body-only stream.
pub const BINARY_VERSION: u16 = 1;
/// Binary frame stream format version of a stream whose frames carry the face.
pub const BINARY_VERSION_FACE: u16 = 2;
/// Binary header length in bytes.
pub const BINARY_HEADER_LEN: usize = 16;
/// Binary record length in bytes (version 1, body only).
pub const BINARY_RECORD_LEN: usize = 16 + 4 * (POSE_DIM + TRANS_DIM + EXPR_DIM + CONTACT_DIM);
/// Binary record length in bytes of version 2: the body, then `arkit` (52) and `visemes` (15).
pub const BINARY_RECORD_LEN_FACE: usize =
    BINARY_RECORD_LEN + 4 * (crate::face::ARKIT_DIM + crate::face::VISEME_DIM);

/// The binary format version and record length of frames with (`true`) or without the face.
pub fn binary_layout(face: bool) -> (u16, usize) {
    if face {
        (BINARY_VERSION_FACE, BINARY_RECORD_LEN_FACE)
    } else {
        (BINARY_VERSION, BINARY_RECORD_LEN)
    }
}

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
    /// The face channel (ARKit weights and visemes; docs/face.md): `None` from a bundle without one.
    pub face: Option<crate::face::FaceValues>,
}

#[derive(Deserialize)]
struct FrameRepr {
    index: u64,
    time_s: f64,
    poses: Vec<f32>,
    trans: Vec<f32>,
    expressions: Vec<f32>,
    foot_contact: Vec<f32>,
    #[serde(default)]
    arkit: Option<Vec<f32>>,
    #[serde(default)]
    visemes: Option<Vec<f32>>,
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
            face: match (r.arkit, r.visemes) {
                (None, None) => None,
                (Some(a), Some(v)) => Some(crate::face::FaceValues {
                    arkit: to_array(a, "arkit")?,
                    visemes: to_array(v, "visemes")?,
                }),
                _ => return Err("frame has one of 'arkit' and 'visemes' without the other".into()),
            },
        })
    }
}

impl Serialize for Frame {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("Frame", if self.face.is_some() { 8 } else { 6 })?;
        st.serialize_field("index", &self.index)?;
        st.serialize_field("time_s", &self.time_s)?;
        st.serialize_field("poses", &self.poses[..])?;
        st.serialize_field("trans", &self.trans[..])?;
        st.serialize_field("expressions", &self.expressions[..])?;
        st.serialize_field("foot_contact", &self.foot_contact[..])?;
        if let Some(f) = &self.face {
            st.serialize_field("arkit", &f.arkit[..])?;
            st.serialize_field("visemes", &f.visemes[..])?;
        }
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
            face: None,
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
        if let Some(f) = &self.face {
            f.check(self.index)?;
        }
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

    /// Appends the frame's binary record to `out`: 1104 bytes (version 1), or 1372 with the face
    /// appended (version 2) when the frame carries it.
    pub fn encode_binary(&self, out: &mut Vec<u8>) {
        out.reserve(binary_layout(self.face.is_some()).1);
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
        if let Some(f) = &self.face {
            for v in f.arkit.iter().chain(&f.visemes) {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }

    /// Decodes one binary record: [`BINARY_RECORD_LEN`] bytes (version 1) or
    /// [`BINARY_RECORD_LEN_FACE`] (version 2, with the face).
    pub fn decode_binary(rec: &[u8]) -> Result<Self> {
        let face = match rec.len() {
            BINARY_RECORD_LEN => false,
            BINARY_RECORD_LEN_FACE => true,
            n => bail!(
                "output: a binary frame record has {BINARY_RECORD_LEN} bytes (version 1) or {BINARY_RECORD_LEN_FACE} (version 2, with the face), got {n}"
            ),
        };
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
        let mut fv = crate::face::FaceValues {
            arkit: [0.0; crate::face::ARKIT_DIM],
            visemes: [0.0; crate::face::VISEME_DIM],
        };
        let face_slots: &mut [f32] = if face { &mut fv.arkit } else { &mut [] };
        let viseme_slots: &mut [f32] = if face { &mut fv.visemes } else { &mut [] };
        for dst in f
            .poses
            .iter_mut()
            .chain(f.trans.iter_mut())
            .chain(f.expressions.iter_mut())
            .chain(f.foot_contact.iter_mut())
            .chain(face_slots.iter_mut())
            .chain(viseme_slots.iter_mut())
        {
            *dst = floats.next().unwrap_or(0.0);
        }
        if face {
            f.face = Some(fv);
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

/// Writes `path` atomically with `write`: a temporary file `.<name>.XXXX.tmp` in the same directory,
/// synced, made world-readable (0644 on Unix), then renamed over `path`. On error the temporary file is
/// removed and `path` is untouched. Every file output of the crate (npz, BVH) goes through it.
#[cfg(feature = "files")]
pub(crate) fn write_atomically(
    path: &std::path::Path,
    write: impl FnOnce(&mut std::io::BufWriter<&std::fs::File>) -> Result<()>,
) -> Result<()> {
    use std::io::Write as _;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => std::path::PathBuf::from("."),
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
        let mut w = std::io::BufWriter::new(tmp.as_file());
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

/// Without the `files` feature (the WebAssembly build) no file is written: a clear refusal.
#[cfg(not(feature = "files"))]
pub(crate) fn write_atomically(
    path: &std::path::Path,
    _write: impl FnOnce(&mut std::io::BufWriter<&std::fs::File>) -> Result<()>,
) -> Result<()> {
    anyhow::bail!(
        "output: cannot write {}: this build of livegesture writes no files (built without the `files` feature)",
        path.display()
    )
}

#[cfg(test)]
mod tests;

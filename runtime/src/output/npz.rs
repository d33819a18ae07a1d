//! BEAT2-compatible `.npz` files, written atomically (see the [module docs](super)).

use std::fs::File;
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use ndarray::{arr0, Array1, Array2};
use ndarray_npy::{NpzWriter, WritableElement, WriteDataError};

use super::*;

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

/// A numpy unicode string of exactly `N` characters (`<U{N}`, UTF-32LE code points): the element of
/// the npz's string scalars (`model`, `gender`), which ndarray-npy has no type for. Everything else is
/// written by ndarray-npy's own elements.
#[derive(Debug, Clone, Copy)]
pub(super) struct NpyUnicode<const N: usize>([char; N]);

impl<const N: usize> NpyUnicode<N> {
    /// `s`, which must have exactly `N` characters.
    pub(super) fn new(s: &str) -> Result<Self> {
        let chars: Vec<char> = s.chars().collect();
        let a: [char; N] = chars
            .try_into()
            .map_err(|c: Vec<char>| anyhow::anyhow!("'{s}' has {} characters, not {N}", c.len()))?;
        Ok(Self(a))
    }
}

impl<const N: usize> WritableElement for NpyUnicode<N> {
    fn type_descriptor() -> py_literal::Value {
        py_literal::Value::String(format!("<U{N}"))
    }

    fn write<W: Write>(&self, mut w: W) -> Result<(), WriteDataError> {
        for c in self.0 {
            w.write_all(&(c as u32).to_le_bytes())?;
        }
        Ok(())
    }

    fn write_slice<W: Write>(slice: &[Self], mut w: W) -> Result<(), WriteDataError> {
        for x in slice {
            x.write(&mut w)?;
        }
        Ok(())
    }
}

/// The face channel of a whole motion (docs/face.md): `(T, 52)` ARKit weights and `(T, 15)` visemes.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceTrack {
    /// `(T, 52)` in [`crate::face::ARKIT_NAMES`] order.
    pub arkit: Array2<f32>,
    /// `(T, 15)` in [`crate::face::VISEME_NAMES`] order.
    pub visemes: Array2<f32>,
}

impl FaceTrack {
    /// The face of whole frames: `None` when no frame carries it, an error when only some do.
    pub fn from_frames(frames: &[Frame]) -> Result<Option<Self>> {
        let n = frames.iter().filter(|f| f.face.is_some()).count();
        if n == 0 {
            return Ok(None);
        }
        ensure!(
            n == frames.len(),
            "output: {n} of {} frames carry the face channel (all or none must)",
            frames.len()
        );
        let mut arkit = Vec::with_capacity(frames.len() * crate::face::ARKIT_DIM);
        let mut visemes = Vec::with_capacity(frames.len() * crate::face::VISEME_DIM);
        for f in frames.iter().filter_map(|f| f.face.as_ref()) {
            arkit.extend_from_slice(&f.arkit);
            visemes.extend_from_slice(&f.visemes);
        }
        Ok(Some(Self {
            arkit: Array2::from_shape_vec((frames.len(), crate::face::ARKIT_DIM), arkit)?,
            visemes: Array2::from_shape_vec((frames.len(), crate::face::VISEME_DIM), visemes)?,
        }))
    }
}

/// `s` padded with NULs to `N` characters (numpy's own padding of a `<U{N}` element).
fn padded<const N: usize>(s: &str) -> Result<NpyUnicode<N>> {
    let mut a = ['\0'; N];
    let chars: Vec<char> = s.chars().collect();
    ensure!(chars.len() <= N, "'{s}' has more than {N} characters");
    a[..chars.len()].copy_from_slice(&chars);
    Ok(NpyUnicode(a))
}

/// Writes a BEAT2-compatible `.npz` atomically (see the module docs for keys, dtypes and shapes).
pub fn write_beat2_npz(path: impl AsRef<Path>, motion: &Beat2Motion) -> Result<()> {
    write_beat2_npz_with_face(path, motion, None)
}

/// [`write_beat2_npz`] plus, with `face`, the keys `arkit` (T, 52) float32, `arkit_names` (52,) `<U19`,
/// `visemes` (T, 15) float32 and `viseme_names` (15,) `<U3` (docs/face.md).
pub fn write_beat2_npz_with_face(
    path: impl AsRef<Path>,
    motion: &Beat2Motion,
    face: Option<&FaceTrack>,
) -> Result<()> {
    let path = path.as_ref();
    if let Some(f) = face {
        let t = motion.len();
        ensure!(
            f.arkit.dim() == (t, crate::face::ARKIT_DIM)
                && f.visemes.dim() == (t, crate::face::VISEME_DIM),
            "output: refusing to write {}: face arkit {:?} / visemes {:?}, expected ({t}, 52) / ({t}, 15)",
            path.display(),
            f.arkit.dim(),
            f.visemes.dim()
        );
    }
    motion
        .validate()
        .with_context(|| format!("output: refusing to write {}", path.display()))?;
    let large = motion.poses.len() * 4 >= u32::MAX as usize;
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .large_file(large);
    write_atomically(path, |w| {
        let mut npz = NpzWriter::new_with_options(w, options);
        let what = |name: &str| format!("output: writing {name} into {}", path.display());
        npz.add_array("poses", &motion.poses)
            .with_context(|| what("poses"))?;
        npz.add_array("trans", &motion.trans)
            .with_context(|| what("trans"))?;
        npz.add_array("expressions", &motion.expressions)
            .with_context(|| what("expressions"))?;
        npz.add_array("betas", &Array1::<f32>::zeros(BETAS_DIM))
            .with_context(|| what("betas"))?;
        npz.add_array("model", &arr0(NpyUnicode::<9>::new("smplx2020")?))
            .with_context(|| what("model"))?;
        npz.add_array("gender", &arr0(NpyUnicode::<7>::new("neutral")?))
            .with_context(|| what("gender"))?;
        npz.add_array("mocap_frame_rate", &arr0(FPS as i64))
            .with_context(|| what("mocap_frame_rate"))?;
        if let Some(f) = face {
            let names: Vec<NpyUnicode<19>> = crate::face::ARKIT_NAMES
                .iter()
                .map(|n| padded::<19>(n))
                .collect::<Result<_>>()?;
            let vnames: Vec<NpyUnicode<3>> = crate::face::VISEME_NAMES
                .iter()
                .map(|n| padded::<3>(n))
                .collect::<Result<_>>()?;
            npz.add_array("arkit", &f.arkit)
                .with_context(|| what("arkit"))?;
            npz.add_array("arkit_names", &Array1::from_vec(names))
                .with_context(|| what("arkit_names"))?;
            npz.add_array("visemes", &f.visemes)
                .with_context(|| what("visemes"))?;
            npz.add_array("viseme_names", &Array1::from_vec(vnames))
                .with_context(|| what("viseme_names"))?;
        }
        npz.finish()
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
    arkit: Vec<f32>,
    visemes: Vec<f32>,
    face_frames: usize,
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
            arkit: Vec::new(),
            visemes: Vec::new(),
            face_frames: 0,
            next_index: None,
            frames: 0,
            finished: false,
        }
    }

    /// Frames collected so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The collected face channel: `None` when no frame carried it, an error when only some did.
    pub fn face_track(&self) -> Result<Option<FaceTrack>> {
        let t = self.frames;
        match self.face_frames {
            0 => Ok(None),
            n if n == t => Ok(Some(FaceTrack {
                arkit: Array2::from_shape_vec((t, crate::face::ARKIT_DIM), self.arkit.clone())?,
                visemes: Array2::from_shape_vec(
                    (t, crate::face::VISEME_DIM),
                    self.visemes.clone(),
                )?,
            })),
            n => bail!("output: {n} of {t} frames carry the face channel (all or none must)"),
        }
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
        if let Some(f) = &frame.face {
            self.arkit.extend_from_slice(&f.arkit);
            self.visemes.extend_from_slice(&f.visemes);
            self.face_frames += 1;
        }
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
        let face = match self.face_frames {
            0 => None,
            n if n == t => Some(FaceTrack {
                arkit: Array2::from_shape_vec(
                    (t, crate::face::ARKIT_DIM),
                    std::mem::take(&mut self.arkit),
                )?,
                visemes: Array2::from_shape_vec(
                    (t, crate::face::VISEME_DIM),
                    std::mem::take(&mut self.visemes),
                )?,
            }),
            n => bail!(
                "output: refusing to write {}: {n} of {t} frames carry the face channel (all or none must)",
                self.path.display()
            ),
        };
        write_beat2_npz_with_face(&self.path, &motion, face.as_ref())
    }
}

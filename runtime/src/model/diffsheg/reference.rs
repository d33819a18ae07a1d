//! `reference/rollout.npz` of a DiffSHEG bundle (docs/bundle.md): the seeded FOPPAS rollout with its
//! per-window inputs and outputs and the per-call trace of window 1.

use std::fs::File;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use ndarray::{ArrayD, IxDyn};
use ndarray_npy::NpzReader;

/// One array: shape and values.
#[derive(Debug, Clone, PartialEq)]
pub struct Array<T> {
    /// Shape.
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub data: Vec<T>,
}

/// An open `rollout.npz`; every getter names the file and the key on error.
pub struct RolloutReference {
    path: PathBuf,
    npz: NpzReader<File>,
}

impl std::fmt::Debug for RolloutReference {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RolloutReference")
            .field("path", &self.path)
            .finish()
    }
}

macro_rules! getter {
    ($name:ident, $t:ty, $what:literal) => {
        /// The array `key` (error if missing or of another dtype).
        pub fn $name(&mut self, key: &str) -> Result<Array<$t>> {
            let a: ArrayD<$t> = self.npz.by_name::<_, IxDyn>(key).with_context(|| {
                format!(
                    "{}: array '{key}' missing or not {}",
                    self.path.display(),
                    $what
                )
            })?;
            Ok(Array {
                shape: a.shape().to_vec(),
                data: a.iter().copied().collect(),
            })
        }
    };
}

impl RolloutReference {
    /// Opens `path`.
    pub fn open(path: &Path) -> Result<Self> {
        let f = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
        let npz =
            NpzReader::new(f).with_context(|| format!("{}: not a valid npz", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            npz,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    getter!(f32, f32, "float32");
    getter!(f64, f64, "float64");
    getter!(i64, i64, "int64");
    getter!(u64, u64, "uint64");

    /// A scalar int64 (or uint64) array as u64.
    pub fn scalar(&mut self, key: &str) -> Result<u64> {
        let v = match self.i64(key) {
            Ok(a) => a.data.first().map(|&v| v as u64),
            Err(_) => self.u64(key)?.data.first().copied(),
        };
        v.with_context(|| format!("{}: array '{key}' is empty", self.path.display()))
    }

    /// `windows` (K, 6): `[start, n, emitted, overlap_in, noise_start, noise_end]` per window.
    pub fn windows(&mut self) -> Result<Vec<[u64; 6]>> {
        let a = self.i64("windows")?;
        ensure!(
            a.shape.len() == 2 && a.shape[1] == 6,
            "{}: 'windows' has shape {:?}, expected (K, 6)",
            self.path.display(),
            a.shape
        );
        Ok(a.data
            .chunks_exact(6)
            .map(|r| std::array::from_fn(|i| r[i] as u64))
            .collect())
    }
}

//! The torch reference vectors and rollout travelling with a bundle (`reference/`).

use super::*;

/// The arrays of one `reference/<graph>.npz`, as tensors.
#[derive(Debug, Clone)]
pub struct ReferenceVectors {
    path: PathBuf,
    arrays: HashMap<String, Tensor>,
}

impl ReferenceVectors {
    /// Reads every array of the npz (float32 and int64; other dtypes are refused).
    pub fn load(path: &Path) -> Result<Self, ReferenceError> {
        let f = File::open(path).map_err(|e| ref_err(path, format!("cannot open: {e}")))?;
        let mut npz =
            NpzReader::new(f).map_err(|e| ref_err(path, format!("not a valid npz: {e}")))?;
        let names = npz
            .names()
            .map_err(|e| ref_err(path, format!("not a valid npz: {e}")))?;
        let mut arrays = HashMap::new();
        for n in names {
            let t = if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<f32> = a;
                Tensor::f32(a.shape().to_vec(), a.iter().copied().collect())
            } else if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<i64> = a;
                Tensor::i64(a.shape().to_vec(), a.iter().copied().collect())
            } else {
                return Err(ref_err(
                    path,
                    format!("array '{n}' is neither float32 nor int64"),
                ));
            };
            arrays.insert(n, t.map_err(|e| ref_err(path, e))?);
        }
        Ok(Self {
            path: path.to_path_buf(),
            arrays,
        })
    }

    /// The array `key`, or an error naming the file and the key.
    pub fn get(&self, key: &str) -> Result<&Tensor, ReferenceError> {
        self.arrays
            .get(key)
            .ok_or_else(|| ref_err(&self.path, format!("no array '{key}'")))
    }

    /// An integer scalar such as `n_steps`.
    pub fn scalar(&self, key: &str) -> Result<i64, ReferenceError> {
        match &self.get(key)?.data {
            TensorData::I64(v) if v.len() == 1 => Ok(v[0]),
            _ => Err(ref_err(
                &self.path,
                format!("'{key}' is not an integer scalar"),
            )),
        }
    }
}

/// The bundle's reference rollout (`reference/rollout.npz`).
#[derive(Debug, Clone)]
pub struct ReferenceRollout {
    pub tokens: Vec<Vec<i64>>,
    pub poses: Array2<f32>,
    pub trans: Array2<f32>,
    pub expressions: Array2<f32>,
    pub foot_contact: Array2<f32>,
    pub clip_repeats: usize,
    /// The seed stored beside the tokens, when the file has one.
    pub seed: Option<u64>,
}

impl ReferenceRollout {
    /// Reads `reference/rollout.npz`.
    pub fn load(path: &Path) -> Result<Self, ReferenceError> {
        let f = File::open(path).map_err(|e| ref_err(path, format!("cannot open: {e}")))?;
        let mut npz =
            NpzReader::new(f).map_err(|e| ref_err(path, format!("not a valid npz: {e}")))?;
        let mut f32_2 = |k: &str| -> Result<Array2<f32>, ReferenceError> {
            npz.by_name(k)
                .map_err(|e| ref_err(path, format!("'{k}': {e}")))
        };
        let poses = f32_2("poses")?;
        let trans = f32_2("trans")?;
        let expressions = f32_2("expressions")?;
        let foot_contact = f32_2("foot_contact")?;
        let tokens: Array2<i64> = npz
            .by_name("tokens")
            .map_err(|e| ref_err(path, format!("'tokens': {e}")))?;
        let reps: ndarray::Array0<i64> = npz
            .by_name("clip_repeats")
            .map_err(|e| ref_err(path, format!("'clip_repeats': {e}")))?;
        let reps = reps.into_scalar();
        let seed = match npz.by_name::<_, ndarray::Ix0>("seed") {
            Ok(a) => {
                let a: ndarray::Array0<u64> = a;
                Some(a.into_scalar())
            }
            Err(_) => npz
                .by_name::<_, ndarray::Ix0>("seed")
                .ok()
                .map(|a: ndarray::Array0<i64>| a.into_scalar() as u64),
        };
        if reps < 1 {
            return Err(ref_err(path, format!("clip_repeats is {reps}")));
        }
        Ok(Self {
            tokens: tokens.outer_iter().map(|r| r.to_vec()).collect(),
            poses,
            trans,
            expressions,
            foot_contact,
            clip_repeats: reps as usize,
            seed,
        })
    }
}

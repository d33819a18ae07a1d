//! The crate's tensor: a dense row-major `f32` or `i64` array whose axis 0 is the batch, with the row
//! operations the stream batches need (stack, split, append, remove, swap-remove) done in place.

use std::fmt;

use anyhow::{bail, ensure, Result};
use serde::{Deserialize, Serialize};

/// Element type of a tensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum DType {
    #[serde(rename = "float32")]
    F32,
    #[serde(rename = "int64")]
    I64,
}

impl DType {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            DType::F32 => 4,
            DType::I64 => 8,
        }
    }
}

impl fmt::Display for DType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DType::F32 => "float32",
            DType::I64 => "int64",
        })
    }
}

/// Tensor elements.
#[derive(Debug, Clone, PartialEq)]
pub enum TensorData {
    F32(Vec<f32>),
    I64(Vec<i64>),
}

/// A dense row-major tensor, axis 0 the batch.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub data: TensorData,
}

impl Default for Tensor {
    fn default() -> Self {
        Tensor {
            shape: vec![0],
            data: TensorData::F32(Vec::new()),
        }
    }
}

impl Tensor {
    /// A float tensor; errors when `data` does not fill `shape`.
    pub fn f32(shape: Vec<usize>, data: Vec<f32>) -> Result<Self> {
        ensure!(
            shape.iter().product::<usize>() == data.len(),
            "tensor of shape {shape:?} needs {} values, got {}",
            shape.iter().product::<usize>(),
            data.len()
        );
        Ok(Tensor {
            shape,
            data: TensorData::F32(data),
        })
    }

    /// An int64 tensor; errors when `data` does not fill `shape`.
    pub fn i64(shape: Vec<usize>, data: Vec<i64>) -> Result<Self> {
        ensure!(
            shape.iter().product::<usize>() == data.len(),
            "tensor of shape {shape:?} needs {} values, got {}",
            shape.iter().product::<usize>(),
            data.len()
        );
        Ok(Tensor {
            shape,
            data: TensorData::I64(data),
        })
    }

    /// Zeros of `dtype` and `shape`.
    pub fn zeros(dtype: DType, shape: Vec<usize>) -> Self {
        let n = shape.iter().product();
        let data = match dtype {
            DType::F32 => TensorData::F32(vec![0.0; n]),
            DType::I64 => TensorData::I64(vec![0; n]),
        };
        Tensor { shape, data }
    }

    /// Element type.
    pub fn dtype(&self) -> DType {
        match self.data {
            TensorData::F32(_) => DType::F32,
            TensorData::I64(_) => DType::I64,
        }
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        match &self.data {
            TensorData::F32(v) => v.len(),
            TensorData::I64(v) => v.len(),
        }
    }

    /// True for a tensor without elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Batch size (axis 0).
    pub fn batch(&self) -> usize {
        self.shape.first().copied().unwrap_or(1)
    }

    /// Elements per batch row.
    pub fn row_len(&self) -> usize {
        self.shape.iter().skip(1).product()
    }

    /// The float elements, or an error naming `what`.
    pub fn as_f32(&self, what: &str) -> Result<&[f32]> {
        match &self.data {
            TensorData::F32(v) => Ok(v),
            TensorData::I64(_) => bail!("{what}: expected a float32 tensor, got int64"),
        }
    }

    /// The int64 elements, or an error naming `what`.
    pub fn as_i64(&self, what: &str) -> Result<&[i64]> {
        match &self.data {
            TensorData::I64(v) => Ok(v),
            TensorData::F32(_) => bail!("{what}: expected an int64 tensor, got float32"),
        }
    }

    /// Concatenates tensors along the batch axis (all of the same dtype and row shape).
    pub fn concat(parts: &[Tensor]) -> Result<Tensor> {
        ensure!(!parts.is_empty(), "concat of no tensors");
        let first = &parts[0];
        let mut shape = first.shape.clone();
        let mut batch = 0;
        for p in parts {
            ensure!(
                p.shape[1..] == first.shape[1..] && p.dtype() == first.dtype(),
                "cannot stack tensors of shapes {:?} ({}) and {:?} ({})",
                first.shape,
                first.dtype(),
                p.shape,
                p.dtype()
            );
            batch += p.batch();
        }
        shape[0] = batch;
        let data = match first.dtype() {
            DType::F32 => {
                let mut v = Vec::with_capacity(shape.iter().product());
                for p in parts {
                    v.extend_from_slice(p.as_f32("concat")?);
                }
                TensorData::F32(v)
            }
            DType::I64 => {
                let mut v = Vec::with_capacity(shape.iter().product());
                for p in parts {
                    v.extend_from_slice(p.as_i64("concat")?);
                }
                TensorData::I64(v)
            }
        };
        Ok(Tensor { shape, data })
    }

    /// Splits along the batch axis into parts of `rows[i]` rows each (their sum must be the batch).
    pub fn split(&self, rows: &[usize]) -> Result<Vec<Tensor>> {
        ensure!(
            rows.iter().sum::<usize>() == self.batch(),
            "cannot split a batch of {} into {:?}",
            self.batch(),
            rows
        );
        let rl = self.row_len();
        let mut out = Vec::with_capacity(rows.len());
        let mut start = 0;
        for &r in rows {
            let mut shape = self.shape.clone();
            shape[0] = r;
            let range = start * rl..(start + r) * rl;
            let data = match &self.data {
                TensorData::F32(v) => TensorData::F32(v[range].to_vec()),
                TensorData::I64(v) => TensorData::I64(v[range].to_vec()),
            };
            out.push(Tensor { shape, data });
            start += r;
        }
        Ok(out)
    }

    /// Makes this tensor a `dtype` tensor of `shape` whose elements are about to be overwritten: the
    /// buffer is kept when the dtype matches and it is large enough (its contents are then stale,
    /// not zeroed); otherwise a new zeroed one is allocated (no copy of the old contents).
    pub fn prepare_output(&mut self, dtype: DType, shape: Vec<usize>) {
        let n: usize = shape.iter().product();
        fn fit<T: Copy + Default>(v: &mut Vec<T>, n: usize) {
            if n > v.capacity() {
                *v = vec![T::default(); n];
            } else {
                v.resize(n, T::default());
            }
        }
        match (&mut self.data, dtype) {
            (TensorData::F32(v), DType::F32) => fit(v, n),
            (TensorData::I64(v), DType::I64) => fit(v, n),
            (d, DType::F32) => *d = TensorData::F32(vec![0.0; n]),
            (d, DType::I64) => *d = TensorData::I64(vec![0; n]),
        }
        self.shape = shape;
    }

    fn check_rows(&self, start: usize, count: usize) -> Result<()> {
        ensure!(
            !self.shape.is_empty(),
            "a tensor without a batch axis has no rows"
        );
        ensure!(
            start + count <= self.batch(),
            "rows {start}..{} out of a batch of {}",
            start + count,
            self.batch()
        );
        Ok(())
    }

    /// A copy of rows `start .. start + count` (batch axis).
    pub fn rows(&self, start: usize, count: usize) -> Result<Tensor> {
        self.check_rows(start, count)?;
        let rl = self.row_len();
        let range = start * rl..(start + count) * rl;
        let mut shape = self.shape.clone();
        shape[0] = count;
        let data = match &self.data {
            TensorData::F32(v) => TensorData::F32(v[range].to_vec()),
            TensorData::I64(v) => TensorData::I64(v[range].to_vec()),
        };
        Ok(Tensor { shape, data })
    }

    /// Fails unless `other` has this tensor's dtype and row shape (every axis but the batch axis),
    /// naming both shapes: "cannot {verb} a tensor of shape .. ({dtype}) {preposition} a tensor of
    /// shape .. ({dtype})".
    fn ensure_same_rows(&self, other: &Tensor, verb: &str, preposition: &str) -> Result<()> {
        ensure!(
            !self.shape.is_empty()
                && self.shape.len() == other.shape.len()
                && self.shape[1..] == other.shape[1..]
                && self.dtype() == other.dtype(),
            "cannot {verb} a tensor of shape {:?} ({}) {preposition} a tensor of shape {:?} ({})",
            self.shape,
            self.dtype(),
            other.shape,
            other.dtype()
        );
        Ok(())
    }

    /// Appends the rows of `other` (same dtype and row shape) on the batch axis, in place: the buffer
    /// grows only when its capacity is exceeded.
    pub fn append_rows(&mut self, other: &Tensor) -> Result<()> {
        other.ensure_same_rows(self, "append rows of", "to")?;
        match (&mut self.data, &other.data) {
            (TensorData::F32(a), TensorData::F32(b)) => a.extend_from_slice(b),
            (TensorData::I64(a), TensorData::I64(b)) => a.extend_from_slice(b),
            _ => unreachable!("dtypes checked above"),
        }
        self.shape[0] += other.batch();
        Ok(())
    }

    /// Makes room for `rows` more rows on the batch axis, so that appending them does not grow the
    /// buffer step by step (each growth copies every row so far).
    pub fn reserve_rows(&mut self, rows: usize) {
        let n = rows * self.row_len();
        match &mut self.data {
            TensorData::F32(v) => v.reserve(n),
            TensorData::I64(v) => v.reserve(n),
        }
    }

    /// Appends rows `start .. start + count` of `src` (same dtype and row shape) on the batch axis,
    /// in place (no intermediate copy).
    pub fn append_rows_of(&mut self, src: &Tensor, start: usize, count: usize) -> Result<()> {
        src.check_rows(start, count)?;
        src.ensure_same_rows(self, "append rows of", "to")?;
        let rl = src.row_len();
        let range = start * rl..(start + count) * rl;
        match (&mut self.data, &src.data) {
            (TensorData::F32(a), TensorData::F32(b)) => a.extend_from_slice(&b[range]),
            (TensorData::I64(a), TensorData::I64(b)) => a.extend_from_slice(&b[range]),
            _ => unreachable!("dtypes checked above"),
        }
        self.shape[0] += count;
        Ok(())
    }

    /// Removes rows `start .. start + count`, shifting the later rows down (their order is kept); the
    /// buffer keeps its capacity.
    pub fn remove_rows(&mut self, start: usize, count: usize) -> Result<()> {
        self.check_rows(start, count)?;
        let rl = self.row_len();
        let range = start * rl..(start + count) * rl;
        match &mut self.data {
            TensorData::F32(v) => drop(v.drain(range)),
            TensorData::I64(v) => drop(v.drain(range)),
        }
        self.shape[0] -= count;
        Ok(())
    }

    /// Removes rows `start .. start + count` by moving the last `count` rows into their place (like
    /// `Vec::swap_remove`: one block copy whatever the batch, the other rows stay where they are); the
    /// buffer keeps its capacity. The removed block must be the tail or not overlap it.
    pub fn swap_remove_rows(&mut self, start: usize, count: usize) -> Result<()> {
        self.check_rows(start, count)?;
        let n = self.batch();
        if start + count < n {
            ensure!(
                start + count <= n - count,
                "swap_remove_rows: rows {start}..{} overlap the last {count} rows of {n}",
                start + count
            );
            let rl = self.row_len();
            let (src, dst) = ((n - count) * rl..n * rl, start * rl);
            match &mut self.data {
                TensorData::F32(v) => v.copy_within(src, dst),
                TensorData::I64(v) => v.copy_within(src, dst),
            }
        }
        let rl = self.row_len();
        match &mut self.data {
            TensorData::F32(v) => v.truncate((n - count) * rl),
            TensorData::I64(v) => v.truncate((n - count) * rl),
        }
        self.shape[0] -= count;
        Ok(())
    }

    /// Makes this tensor the concatenation of `parts` on the batch axis (like [`Tensor::concat`]),
    /// in its own buffer: no allocation once the buffer is large enough (a scratch tensor reused
    /// from run to run).
    pub fn stack_from(&mut self, parts: &[&Tensor]) -> Result<()> {
        let first = parts
            .first()
            .ok_or_else(|| anyhow::anyhow!("stack of no tensors"))?;
        let mut batch = 0;
        for p in parts {
            first.ensure_same_rows(p, "stack", "with")?;
            batch += p.batch();
        }
        let mut shape = first.shape.clone();
        shape[0] = batch;
        fn fill<T: Copy>(v: &mut Vec<T>, parts: &[&[T]]) {
            v.clear();
            for p in parts {
                v.extend_from_slice(p);
            }
        }
        match (&mut self.data, first.dtype()) {
            (TensorData::F32(v), DType::F32) => {
                let ps = parts
                    .iter()
                    .map(|p| p.as_f32("stack"))
                    .collect::<Result<Vec<_>>>()?;
                fill(v, &ps);
            }
            (TensorData::I64(v), DType::I64) => {
                let ps = parts
                    .iter()
                    .map(|p| p.as_i64("stack"))
                    .collect::<Result<Vec<_>>>()?;
                fill(v, &ps);
            }
            _ => {
                let owned: Vec<Tensor> = parts.iter().map(|p| (*p).clone()).collect();
                *self = Tensor::concat(&owned)?;
                return Ok(());
            }
        }
        self.shape = shape;
        Ok(())
    }

    /// (rows, blocks per row, slots, values per slot) of a tensor viewed as `(batch, .., slots,
    /// last)`: axis -2 the slots of a ring cache (docs/bundle.md#ring-caches).
    fn slot_view(&self) -> Result<(usize, usize, usize, usize)> {
        let r = self.shape.len();
        ensure!(
            r >= 3,
            "a ring cache has a batch axis, a slot axis (-2) and a last axis; got shape {:?}",
            self.shape
        );
        Ok((
            self.shape[0],
            self.shape[1..r - 2].iter().product(),
            self.shape[r - 2],
            self.shape[r - 1],
        ))
    }

    /// Writes rows `src_start .. src_start + count` of `entry` (one slot: this tensor's row shape
    /// with axis -2 of size 1, same dtype) into slot `slot` of axis -2 of rows `dst_start ..
    /// dst_start + count` of this tensor, in place: a ring cache's write of its new entry.
    pub fn write_slot(
        &mut self,
        dst_start: usize,
        entry: &Tensor,
        src_start: usize,
        count: usize,
        slot: usize,
    ) -> Result<()> {
        let (_, outer, slots, last) = self.slot_view()?;
        let r = self.shape.len();
        ensure!(
            entry.shape.len() == r
                && entry.shape[1..r - 2] == self.shape[1..r - 2]
                && entry.shape[r - 2] == 1
                && entry.shape[r - 1] == last
                && entry.dtype() == self.dtype(),
            "cannot write an entry of shape {:?} ({}) into a slot of a cache of shape {:?} ({})",
            entry.shape,
            entry.dtype(),
            self.shape,
            self.dtype()
        );
        ensure!(slot < slots, "slot {slot} of a cache of {slots} slots");
        self.check_rows(dst_start, count)?;
        entry.check_rows(src_start, count)?;
        fn write<T: Copy>(
            dst: &mut [T],
            src: &[T],
            n: usize,
            d0: usize,
            s0: usize,
            geo: (usize, usize, usize, usize),
        ) {
            let (outer, slots, last, slot) = geo;
            for row in 0..n {
                for o in 0..outer {
                    let d = (((d0 + row) * outer + o) * slots + slot) * last;
                    let s = ((s0 + row) * outer + o) * last;
                    dst[d..d + last].copy_from_slice(&src[s..s + last]);
                }
            }
        }
        let geo = (outer, slots, last, slot);
        match (&mut self.data, &entry.data) {
            (TensorData::F32(a), TensorData::F32(b)) => {
                write(a, b, count, dst_start, src_start, geo)
            }
            (TensorData::I64(a), TensorData::I64(b)) => {
                write(a, b, count, dst_start, src_start, geo)
            }
            _ => unreachable!("dtypes checked above"),
        }
        Ok(())
    }

    /// Rolls axis -2 of rows `start .. start + count` by `shift` slots, in place (slot `j` moves to
    /// `(j + shift) mod slots`, as `torch.roll`): a ring cache moved to another phase.
    pub fn roll_slots(&mut self, start: usize, count: usize, shift: usize) -> Result<()> {
        let (_, outer, slots, last) = self.slot_view()?;
        self.check_rows(start, count)?;
        let k = shift % slots.max(1);
        if k == 0 {
            return Ok(());
        }
        let block = slots * last;
        let range = start * outer * block..(start + count) * outer * block;
        match &mut self.data {
            TensorData::F32(v) => v[range]
                .chunks_mut(block)
                .for_each(|b| b.rotate_right(k * last)),
            TensorData::I64(v) => v[range]
                .chunks_mut(block)
                .for_each(|b| b.rotate_right(k * last)),
        }
        Ok(())
    }

    /// Copies rows `start .. start + dst.batch()` of this tensor into `dst` (same dtype and row
    /// shape), in place.
    pub fn copy_rows_to(&self, start: usize, dst: &mut Tensor) -> Result<()> {
        let count = dst.batch();
        self.check_rows(start, count)?;
        self.ensure_same_rows(dst, "copy rows of", "into")?;
        let rl = self.row_len();
        let range = start * rl..(start + count) * rl;
        match (&self.data, &mut dst.data) {
            (TensorData::F32(a), TensorData::F32(b)) => b.copy_from_slice(&a[range]),
            (TensorData::I64(a), TensorData::I64(b)) => b.copy_from_slice(&a[range]),
            _ => unreachable!("dtypes checked above"),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_slot_write_and_roll() {
        // 2 rows, 2 blocks, 3 slots of 2 values
        let mut c = Tensor::f32(vec![2, 2, 3, 2], (0..24).map(|x| x as f32).collect()).unwrap();
        let e = Tensor::f32(
            vec![2, 2, 1, 2],
            vec![-1.0, -2.0, -3.0, -4.0, -5.0, -6.0, -7.0, -8.0],
        )
        .unwrap();
        c.write_slot(1, &e, 0, 1, 2).unwrap();
        let v = c.as_f32("c").unwrap();
        assert_eq!(
            &v[12..24],
            &[12.0, 13.0, 14.0, 15.0, -1.0, -2.0, 18.0, 19.0, 20.0, 21.0, -3.0, -4.0]
        );
        assert_eq!(&v[..12], &(0..12).map(|x| x as f32).collect::<Vec<_>>()[..]);
        c.roll_slots(0, 1, 1).unwrap();
        let v = c.as_f32("c").unwrap();
        assert_eq!(
            &v[..12],
            &[4.0, 5.0, 0.0, 1.0, 2.0, 3.0, 10.0, 11.0, 6.0, 7.0, 8.0, 9.0]
        );
        // an entry of the wrong shape and a slot out of range are errors
        let bad = Tensor::f32(vec![2, 2, 2, 2], vec![0.0; 16]).unwrap();
        assert!(c.write_slot(0, &bad, 0, 1, 0).is_err());
        assert!(c.write_slot(0, &e, 0, 1, 3).is_err());
    }

    #[test]
    fn concat_split_round_trip() {
        let a = Tensor::f32(vec![1, 2], vec![1.0, 2.0]).unwrap();
        let b = Tensor::f32(vec![2, 2], vec![3.0, 4.0, 5.0, 6.0]).unwrap();
        let c = Tensor::concat(&[a.clone(), b.clone()]).unwrap();
        assert_eq!(c.shape, vec![3, 2]);
        let parts = c.split(&[1, 2]).unwrap();
        assert_eq!(parts, vec![a, b]);
        assert!(c.split(&[1, 1]).is_err());
    }

    #[test]
    fn stack_from_and_copy_rows_to_reuse_buffers() {
        let a = Tensor::f32(vec![1, 2], vec![1.0, 2.0]).unwrap();
        let b = Tensor::f32(vec![2, 2], vec![3.0, 4.0, 5.0, 6.0]).unwrap();
        let mut s = Tensor::f32(vec![4, 2], vec![9.0; 8]).unwrap();
        let cap = match &s.data {
            TensorData::F32(v) => v.as_ptr(),
            _ => unreachable!(),
        };
        s.stack_from(&[&a, &b]).unwrap();
        assert_eq!(s, Tensor::concat(&[a.clone(), b.clone()]).unwrap());
        // the same buffer, no allocation
        assert!(matches!(&s.data, TensorData::F32(v) if v.as_ptr() == cap));
        let mut a2 = Tensor::zeros(DType::F32, vec![1, 2]);
        let mut b2 = Tensor::zeros(DType::F32, vec![2, 2]);
        s.copy_rows_to(0, &mut a2).unwrap();
        s.copy_rows_to(1, &mut b2).unwrap();
        assert_eq!((a2, b2), (a.clone(), b.clone()));
        // out of range, other row shapes or dtypes are refused
        assert!(s
            .copy_rows_to(2, &mut Tensor::zeros(DType::F32, vec![2, 2]))
            .is_err());
        assert!(s
            .copy_rows_to(0, &mut Tensor::zeros(DType::F32, vec![1, 3]))
            .is_err());
        assert!(s
            .copy_rows_to(0, &mut Tensor::zeros(DType::I64, vec![1, 2]))
            .is_err());
        assert!(s
            .stack_from(&[&a, &Tensor::zeros(DType::F32, vec![1, 3])])
            .is_err());
        let mut t = Tensor::zeros(DType::F32, vec![0, 2]);
        t.append_rows_of(&b, 1, 1).unwrap();
        t.append_rows_of(&a, 0, 1).unwrap();
        assert_eq!(t.as_f32("t").unwrap(), &[5.0, 6.0, 1.0, 2.0]);
        assert!(t.append_rows_of(&b, 1, 2).is_err());
        // the refusal names both shapes and dtypes
        let e = t
            .append_rows_of(&Tensor::zeros(DType::I64, vec![1, 3]), 0, 1)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("[1, 3] (int64)") && e.contains("[2, 2] (float32)"),
            "{e}"
        );
        // another dtype than the buffer's: a fresh one
        let i = Tensor::i64(vec![2], vec![4, 7]).unwrap();
        s.stack_from(&[&i, &i]).unwrap();
        assert_eq!(s.as_i64("s").unwrap(), &[4, 7, 4, 7]);
    }

    fn rows_of(t: &Tensor) -> Vec<Vec<f32>> {
        let v = t.as_f32("t").unwrap();
        v.chunks(t.row_len()).map(<[f32]>::to_vec).collect()
    }

    #[test]
    fn row_editing_in_place() {
        // 5 rows of 2: row r holds [r, r + 0.5]
        let data: Vec<f32> = (0..5).flat_map(|r| [r as f32, r as f32 + 0.5]).collect();
        let t = Tensor::f32(vec![5, 2], data).unwrap();
        assert_eq!(
            rows_of(&t.rows(1, 2).unwrap()),
            vec![vec![1.0, 1.5], vec![2.0, 2.5]]
        );
        assert!(t.rows(4, 2).is_err());

        let mut a = t.clone();
        a.remove_rows(1, 2).unwrap();
        assert_eq!(a.shape, vec![3, 2]);
        assert_eq!(
            rows_of(&a),
            vec![vec![0.0, 0.5], vec![3.0, 3.5], vec![4.0, 4.5]]
        );

        let mut s = t.clone();
        s.swap_remove_rows(0, 2).unwrap(); // rows 3, 4 move into 0, 1
        assert_eq!(
            rows_of(&s),
            vec![vec![3.0, 3.5], vec![4.0, 4.5], vec![2.0, 2.5]]
        );
        let cap = match &s.data {
            TensorData::F32(v) => v.capacity(),
            _ => unreachable!(),
        };
        s.swap_remove_rows(2, 1).unwrap(); // the tail: just dropped
        assert_eq!(s.shape, vec![2, 2]);
        assert!(t.clone().swap_remove_rows(2, 2).is_err()); // overlaps the tail block

        // appending within the capacity left by a removal does not reallocate
        let extra = Tensor::f32(vec![1, 2], vec![9.0, 9.5]).unwrap();
        s.append_rows(&extra).unwrap();
        assert_eq!(s.shape, vec![3, 2]);
        assert_eq!(rows_of(&s)[2], vec![9.0, 9.5]);
        match &s.data {
            TensorData::F32(v) => assert_eq!(v.capacity(), cap),
            _ => unreachable!(),
        }
        assert!(s
            .append_rows(&Tensor::i64(vec![1, 2], vec![1, 2]).unwrap())
            .is_err());
        assert!(s
            .append_rows(&Tensor::f32(vec![1, 3], vec![0.0; 3]).unwrap())
            .is_err());

        // 1-D (step counters) work the same
        let mut c = Tensor::i64(vec![3], vec![7, 8, 9]).unwrap();
        c.swap_remove_rows(0, 1).unwrap();
        assert_eq!(c.as_i64("c").unwrap(), &[9, 8]);
        c.append_rows(&Tensor::i64(vec![1], vec![0]).unwrap())
            .unwrap();
        assert_eq!(c.as_i64("c").unwrap(), &[9, 8, 0]);
    }
}

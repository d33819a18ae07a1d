//! Where each graph's caches live during a token step: separately owned per stream (stacked before
//! each graph run and split after it) or already stacked in a [`super::StreamBatch`].

use anyhow::Result;

use crate::backend::Tensor;
use crate::bundle::CacheSpec;

/// Stacks the per-stream caches of one graph (`per_stream[i][c]`) into one tensor per cache, moving
/// instead of copying for a single stream.
pub(super) fn stack_caches(mut per_stream: Vec<Vec<Tensor>>) -> Result<Vec<Tensor>> {
    if per_stream.len() == 1 {
        return Ok(per_stream.pop().unwrap_or_default());
    }
    let n = per_stream.first().map(Vec::len).unwrap_or(0);
    (0..n)
        .map(|c| {
            let parts: Vec<Tensor> = per_stream
                .iter_mut()
                .map(|s| std::mem::take(&mut s[c]))
                .collect();
            Tensor::concat(&parts)
        })
        .collect()
}

/// Splits stacked caches back into per-stream caches of `rows[i]` rows.
pub(super) fn split_caches(stacked: Vec<Tensor>, rows: &[usize]) -> Result<Vec<Vec<Tensor>>> {
    if rows.len() == 1 {
        return Ok(vec![stacked]);
    }
    let mut out: Vec<Vec<Tensor>> = rows
        .iter()
        .map(|_| Vec::with_capacity(stacked.len()))
        .collect();
    for t in stacked {
        for (i, part) in t.split(rows)?.into_iter().enumerate() {
            out[i].push(part);
        }
    }
    Ok(out)
}

pub(super) fn zeros_for(caches: &[CacheSpec], rows: usize) -> Vec<Tensor> {
    caches.iter().map(|c| c.zeros(rows)).collect()
}

/// A graph of the chain, as a place for caches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Slot {
    AudioEncoder,
    Expert(usize),
    Fusion,
    Decoder(usize),
}

impl Slot {
    /// True for the graphs that carry both guidance branches (2 rows per guided stream).
    pub(super) fn branched(self) -> bool {
        matches!(self, Slot::Expert(_) | Slot::Fusion)
    }
}

/// Caches of every graph: one stream's, or the stacked caches of a [`StreamBatch`].
#[derive(Debug, Clone)]
pub(super) struct Caches {
    pub(super) audio_encoder: Vec<Tensor>,
    pub(super) experts: Vec<Vec<Tensor>>,
    pub(super) fusion: Vec<Tensor>,
    pub(super) decoders: Vec<Vec<Tensor>>,
}

impl Caches {
    pub(super) fn slots(&self) -> Vec<Slot> {
        let n = self.experts.len();
        std::iter::once(Slot::AudioEncoder)
            .chain((0..n).map(Slot::Expert))
            .chain(std::iter::once(Slot::Fusion))
            .chain((0..self.decoders.len()).map(Slot::Decoder))
            .collect()
    }

    pub(super) fn slot(&self, s: Slot) -> &Vec<Tensor> {
        match s {
            Slot::AudioEncoder => &self.audio_encoder,
            Slot::Expert(i) => &self.experts[i],
            Slot::Fusion => &self.fusion,
            Slot::Decoder(i) => &self.decoders[i],
        }
    }

    pub(super) fn slot_mut(&mut self, s: Slot) -> &mut Vec<Tensor> {
        match s {
            Slot::AudioEncoder => &mut self.audio_encoder,
            Slot::Expert(i) => &mut self.experts[i],
            Slot::Fusion => &mut self.fusion,
            Slot::Decoder(i) => &mut self.decoders[i],
        }
    }

    /// Zero caches like `template`'s (same tensors and row shapes) with `rows` rows in the branched
    /// graphs and one row in the others.
    pub(super) fn zeros_like(template: &Caches, branch_rows: usize) -> Caches {
        let mut out = template.clone();
        for s in template.slots() {
            let r = if s.branched() { branch_rows } else { 1 };
            for t in out.slot_mut(s) {
                let mut shape = t.shape.clone();
                shape[0] = r;
                *t = Tensor::zeros(t.dtype(), shape);
            }
        }
        out
    }
}

/// Where a token step takes each graph's caches from and puts the updated ones.
pub(super) trait CacheStore {
    /// The caches of `slot` for every stream of the step, stacked in stream order, and buffers the
    /// graph may write its new caches into (empty: none).
    fn take(&mut self, slot: Slot) -> Result<(Vec<Tensor>, Vec<Tensor>)>;
    /// Stores the caches a graph returned for `slot` (stacked like [`CacheStore::take`]'s), and the
    /// input caches it no longer needs.
    fn put(&mut self, slot: Slot, new: Vec<Tensor>, old: Vec<Tensor>) -> Result<()>;
}

/// Separately owned per-stream caches ([`LiveGestureGraphs::step_batch`]): stacked before each graph run and
/// split back after it.
pub(super) struct SeparateCaches<'a> {
    pub(super) caches: Vec<&'a mut Caches>,
    pub(super) branch_rows: Vec<usize>,
    pub(super) ones: Vec<usize>,
}

impl CacheStore for SeparateCaches<'_> {
    fn take(&mut self, slot: Slot) -> Result<(Vec<Tensor>, Vec<Tensor>)> {
        let stacked = stack_caches(
            self.caches
                .iter_mut()
                .map(|c| std::mem::take(c.slot_mut(slot)))
                .collect(),
        )?;
        Ok((stacked, Vec::new()))
    }

    fn put(&mut self, slot: Slot, new: Vec<Tensor>, _old: Vec<Tensor>) -> Result<()> {
        let rows = if slot.branched() {
            &self.branch_rows
        } else {
            &self.ones
        };
        for (c, part) in self.caches.iter_mut().zip(split_caches(new, rows)?) {
            *c.slot_mut(slot) = part;
        }
        Ok(())
    }
}

/// Caches already stacked on the batch axis ([`StreamBatch`]): handed to the graph and replaced by
/// its outputs, moved, never copied. Double-buffered: the graph writes its new caches into the
/// buffers of the previous step's input caches (`spare`), so a steady batch allocates nothing.
pub(super) struct StackedCaches<'a> {
    pub(super) cur: &'a mut Caches,
    pub(super) spare: &'a mut Caches,
}

impl CacheStore for StackedCaches<'_> {
    fn take(&mut self, slot: Slot) -> Result<(Vec<Tensor>, Vec<Tensor>)> {
        Ok((
            std::mem::take(self.cur.slot_mut(slot)),
            std::mem::take(self.spare.slot_mut(slot)),
        ))
    }

    fn put(&mut self, slot: Slot, new: Vec<Tensor>, old: Vec<Tensor>) -> Result<()> {
        *self.cur.slot_mut(slot) = new;
        *self.spare.slot_mut(slot) = old;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cache_stacking_round_trips() {
        let a = vec![
            Tensor::f32(vec![2, 3], vec![1.0; 6]).unwrap(),
            Tensor::i64(vec![2], vec![4, 4]).unwrap(),
        ];
        let b = vec![
            Tensor::f32(vec![1, 3], vec![2.0; 3]).unwrap(),
            Tensor::i64(vec![1], vec![7]).unwrap(),
        ];
        let stacked = stack_caches(vec![a.clone(), b.clone()]).unwrap();
        assert_eq!(stacked[0].shape, vec![3, 3]);
        assert_eq!(stacked[1].as_i64("step").unwrap(), &[4, 4, 7]);
        assert_eq!(split_caches(stacked, &[2, 1]).unwrap(), vec![a.clone(), b]);
        // a single stream moves without copying and comes back unchanged
        assert_eq!(stack_caches(vec![a.clone()]).unwrap(), a);
    }
}

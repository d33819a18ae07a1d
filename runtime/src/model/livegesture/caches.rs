//! Where each graph's caches live during a token step: separately owned per stream (stacked before
//! each graph run and split after it) or already stacked in a cohort (`super::cohorts`).

use std::collections::HashMap;

use anyhow::{ensure, Result};

use crate::backend::Tensor;
use crate::bundle::CacheSpec;

pub(super) fn zeros_for(caches: &[CacheSpec], rows: usize) -> Vec<Tensor> {
    caches.iter().map(|c| c.zeros(rows)).collect()
}

/// A graph of the chain, as a place for caches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
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

/// Caches of every graph: one stream's, or the stacked caches of a cohort (`super::cohorts`).
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

    /// Removes one stream's rows from every slot of these stacked caches: `branch` rows from
    /// `branch_start` in the branched graphs, row `row` in the others. `swap` moves the tail block
    /// (as many rows) into their place instead of shifting the later rows. With `keep` (the empty
    /// layout), returns a copy of the removed rows.
    pub(super) fn remove_stream_rows(
        &mut self,
        (branch_start, branch, row): (usize, usize, usize),
        swap: bool,
        keep: Option<&Caches>,
    ) -> Result<Option<Caches>> {
        let mut out = keep.cloned();
        for slot in self.slots() {
            let (start, count) = if slot.branched() {
                (branch_start, branch)
            } else {
                (row, 1)
            };
            let ts = self.slot_mut(slot);
            if let Some(out) = out.as_mut() {
                *out.slot_mut(slot) = ts
                    .iter()
                    .map(|t| t.rows(start, count))
                    .collect::<Result<Vec<_>>>()?;
            }
            for t in ts.iter_mut() {
                if swap {
                    t.swap_remove_rows(start, count)?;
                } else {
                    t.remove_rows(start, count)?;
                }
            }
        }
        Ok(out)
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

/// Buffers a [`SeparateCaches`] step reuses from step to step, per graph: the stacked input
/// caches and the buffers the graph writes its new caches into. A steady server allocates nothing
/// for its caches; the buffers keep the size of the largest batch seen.
#[derive(Debug, Default)]
pub(super) struct Scratch {
    stacked: HashMap<Slot, Vec<Tensor>>,
    /// Output buffers per graph, apart for single streams (whose new caches are kept, buffers and
    /// all: a batch-sized buffer must not end up held by one stream).
    spare: HashMap<(Slot, bool), Vec<Tensor>>,
}

/// Separately owned per-stream caches ([`LiveGestureGraphs::step_batch`]): copied into stacked
/// scratch buffers before each graph run and copied back into the streams' own buffers after it (a
/// single stream's caches are moved, not copied). No allocation once the scratch buffers are large
/// enough.
pub(super) struct SeparateCaches<'a> {
    pub(super) caches: Vec<&'a mut Caches>,
    pub(super) branch_rows: Vec<usize>,
    pub(super) scratch: &'a mut Scratch,
}

impl CacheStore for SeparateCaches<'_> {
    fn take(&mut self, slot: Slot) -> Result<(Vec<Tensor>, Vec<Tensor>)> {
        let single = self.caches.len() == 1;
        let spare = self
            .scratch
            .spare
            .remove(&(slot, single))
            .unwrap_or_default();
        if single {
            return Ok((std::mem::take(self.caches[0].slot_mut(slot)), spare));
        }
        let n = self.caches.first().map_or(0, |c| c.slot(slot).len());
        let mut stacked = self.scratch.stacked.remove(&slot).unwrap_or_default();
        stacked.resize_with(n, Tensor::default);
        for (c, t) in stacked.iter_mut().enumerate() {
            let parts: Vec<&Tensor> = self.caches.iter().map(|s| &s.slot(slot)[c]).collect();
            t.stack_from(&parts)?;
        }
        Ok((stacked, spare))
    }

    fn put(&mut self, slot: Slot, new: Vec<Tensor>, old: Vec<Tensor>) -> Result<()> {
        if self.caches.len() == 1 {
            *self.caches[0].slot_mut(slot) = new;
            self.scratch.spare.insert((slot, true), old);
            return Ok(());
        }
        let mut start = 0;
        for (i, c) in self.caches.iter_mut().enumerate() {
            let rows = if slot.branched() {
                self.branch_rows[i]
            } else {
                1
            };
            let mine = c.slot_mut(slot);
            ensure!(
                mine.len() == new.len(),
                "a graph returned {} caches, the stream has {}",
                new.len(),
                mine.len()
            );
            for (dst, src) in mine.iter_mut().zip(&new) {
                src.copy_rows_to(start, dst)?;
            }
            start += rows;
        }
        self.scratch.stacked.insert(slot, old);
        self.scratch.spare.insert((slot, false), new);
        Ok(())
    }
}

/// Caches already stacked on the batch axis (a cohort, `super::cohorts`): handed to the graph and replaced by
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

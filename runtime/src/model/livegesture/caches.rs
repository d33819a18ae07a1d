//! Where each graph's caches live during a token step: separately owned per stream (stacked before
//! each graph run and split after it) or already stacked in a cohort (`super::cohorts`).

use std::collections::HashMap;
use std::sync::Arc;

use anyhow::{bail, ensure, Result};

use crate::backend::Tensor;
use crate::bundle::{ring_slot, CacheSpec};

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

/// Which caches of each slot are ring caches (docs/bundle.md#ring-caches): `(slot, one flag per
/// cache)` for the slots that have any; empty for a form without ring caches.
pub(super) type RingMask = Arc<Vec<(Slot, Vec<bool>)>>;

/// The roll of a ring cache of `slots` slots from phase `from` to phase `to`.
fn phase_shift(from: u64, to: u64, slots: usize) -> usize {
    let s = slots.max(1) as u64;
    ((to % s + s - from % s) % s) as usize
}

/// Caches of every graph: one stream's, or the stacked caches of a cohort (`super::cohorts`).
#[derive(Debug, Clone)]
pub(super) struct Caches {
    pub(super) audio_encoder: Vec<Tensor>,
    pub(super) experts: Vec<Vec<Tensor>>,
    pub(super) fusion: Vec<Tensor>,
    pub(super) decoders: Vec<Vec<Tensor>>,
    /// The phase of the ring caches (docs/bundle.md#ring-caches): the write position of the next
    /// step, shared by every row (a stream's own count of steps, or its cohort's). Counted in every
    /// form; only ring caches depend on it.
    pub(super) phase: u64,
    /// The ring caches among these (empty without them).
    pub(super) ring: RingMask,
}

impl Caches {
    /// Moves the ring caches of every row to phase `to` (each rolled on its slot axis; the shift
    /// layout is phase 0): a stream's caches before they are stacked with caches at `to`.
    pub(super) fn rephase(&mut self, to: u64) -> Result<()> {
        let from = self.phase;
        let ring = self.ring.clone();
        for (slot, mask) in ring.iter() {
            for (t, &r) in self.slot_mut(*slot).iter_mut().zip(mask) {
                if r && t.batch() > 0 {
                    let k = phase_shift(from, to, t.shape[t.shape.len() - 2]);
                    t.roll_slots(0, t.batch(), k)?;
                }
            }
        }
        self.phase = to;
        Ok(())
    }

    /// Moves rows `start .. start + count` of the ring caches (of the branched graphs: the only
    /// ones with attention caches) from phase `from` to this cache's phase: a stream's rows just
    /// appended from a cohort at another phase.
    pub(super) fn rephase_rows(&mut self, start: usize, count: usize, from: u64) -> Result<()> {
        let to = self.phase;
        let ring = self.ring.clone();
        for (slot, mask) in ring.iter() {
            if !slot.branched() {
                bail!("ring caches in {slot:?}, a graph without guidance branches");
            }
            for (t, &r) in self.slot_mut(*slot).iter_mut().zip(mask) {
                if r {
                    let k = phase_shift(from, to, t.shape[t.shape.len() - 2]);
                    t.roll_slots(start, count, k)?;
                }
            }
        }
        Ok(())
    }

    /// Makes room for `streams` more streams of `branch_rows` rows in all in the branched graphs.
    pub(super) fn reserve(&mut self, streams: usize, branch_rows: usize) {
        for slot in self.slots() {
            let rows = if slot.branched() {
                branch_rows
            } else {
                streams
            };
            for t in self.slot_mut(slot).iter_mut() {
                t.reserve_rows(rows);
            }
        }
    }

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
        if let Some(out) = out.as_mut() {
            out.phase = self.phase;
        }
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
    /// The phase of the step's ring caches (docs/bundle.md#ring-caches): one for every row.
    fn phase(&self) -> u64;
    /// After a graph on ring caches: `caches` are the input caches [`CacheStore::take`] gave (the
    /// graph only read them), `out` what it returned for each (`specs`): the new entry of a ring
    /// cache, written in place into slot `phase mod slots`, or the new cache of another (`step`);
    /// `spare` the buffers `take` gave, unused.
    fn put_ring(
        &mut self,
        slot: Slot,
        out: Vec<Tensor>,
        caches: Vec<Tensor>,
        spare: Vec<Tensor>,
        specs: &[CacheSpec],
    ) -> Result<()>;
    /// After every graph of a step: the next step writes at the next phase.
    fn advance_phase(&mut self);
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
    /// The phase every stream's ring caches are at ([`Caches::rephase`] before the step).
    pub(super) phase: u64,
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

    fn phase(&self) -> u64 {
        self.phase
    }

    fn put_ring(
        &mut self,
        slot: Slot,
        out: Vec<Tensor>,
        mut caches: Vec<Tensor>,
        spare: Vec<Tensor>,
        specs: &[CacheSpec],
    ) -> Result<()> {
        ensure!(
            out.len() == specs.len() && caches.len() == specs.len(),
            "a graph on ring caches returned {} caches for {} inputs, its manifest lists {}",
            out.len(),
            caches.len(),
            specs.len()
        );
        let single = self.caches.len() == 1;
        if single {
            for ((c, o), spec) in caches.iter_mut().zip(out).zip(specs) {
                spec.store_output(c, o, self.phase)?;
            }
            *self.caches[0].slot_mut(slot) = caches;
            self.scratch.spare.insert((slot, true), spare);
            return Ok(());
        }
        // each stream's own caches get its rows of the entries (no copy of the whole caches back)
        let mut start = 0;
        for (i, c) in self.caches.iter_mut().enumerate() {
            let rows = if slot.branched() {
                self.branch_rows[i]
            } else {
                1
            };
            let mine = c.slot_mut(slot);
            ensure!(
                mine.len() == out.len(),
                "a graph returned {} caches, the stream has {}",
                out.len(),
                mine.len()
            );
            for ((dst, src), spec) in mine.iter_mut().zip(&out).zip(specs) {
                if spec.is_ring() {
                    let at = ring_slot(dst, self.phase)?;
                    dst.write_slot(0, src, start, rows, at)?;
                } else {
                    src.copy_rows_to(start, dst)?;
                }
            }
            start += rows;
        }
        self.scratch.stacked.insert(slot, caches);
        self.scratch.spare.insert((slot, false), spare);
        Ok(())
    }

    fn advance_phase(&mut self) {
        for c in self.caches.iter_mut() {
            c.phase = self.phase + 1;
        }
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

    fn phase(&self) -> u64 {
        self.cur.phase
    }

    /// The entries are written into the cohort's caches in place: no output buffers for the
    /// caches, no copy of them.
    fn put_ring(
        &mut self,
        slot: Slot,
        out: Vec<Tensor>,
        mut caches: Vec<Tensor>,
        spare: Vec<Tensor>,
        specs: &[CacheSpec],
    ) -> Result<()> {
        ensure!(
            out.len() == specs.len() && caches.len() == specs.len(),
            "a graph on ring caches returned {} caches for {} inputs, its manifest lists {}",
            out.len(),
            caches.len(),
            specs.len()
        );
        for ((c, o), spec) in caches.iter_mut().zip(out).zip(specs) {
            spec.store_output(c, o, self.cur.phase)?;
        }
        *self.cur.slot_mut(slot) = caches;
        *self.spare.slot_mut(slot) = spare;
        Ok(())
    }

    fn advance_phase(&mut self) {
        self.cur.phase += 1;
    }
}

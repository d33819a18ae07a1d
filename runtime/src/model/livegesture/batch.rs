//! [`StreamBatch`]: streams stepped together with their caches kept stacked between steps.

use anyhow::{anyhow, ensure, Context, Result};
use ndarray::Array2;

use super::caches::Caches;
use super::stream::StreamState;
use super::{Stream, StreamOptions};
use crate::audio::AudioSpan;

/// Identifies a stream inside a [`StreamBatch`] (unique within that batch, never reused).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StreamId(u64);

impl std::fmt::Display for StreamId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "stream #{}", self.0)
    }
}

#[derive(Debug)]
pub(super) struct Member {
    pub(super) id: StreamId,
    pub(super) state: StreamState,
}

/// Streams stepped together, with their caches kept stacked on the batch axis between steps.
///
/// Stream `i` (in [`StreamBatch::ids`] order) occupies row `i` of the `audio_encoder` and decoder
/// caches, and [`Stream::branch_rows`] consecutive rows (2 with guidance: conditional, then
/// unconditional) of the expert and fusion caches, after the rows of the streams before it.
/// [`LiveGestureGraphs::step_stream_batch`] hands these stacked caches to each graph and keeps the graph's
/// new caches in their place: no per-step stacking or splitting.
///
/// Streams join ([`StreamBatch::add`], their rows appended) and leave ([`StreamBatch::remove`]) at
/// any time between steps; each keeps its own seed, guidance and sampling settings, and its tokens
/// and frames are those it would get stepped alone. Removing a stream moves the last stream into its
/// place when both occupy the same number of rows (one stream's rows copied, whatever the batch
/// size), otherwise the later streams shift down; either way [`StreamBatch::ids`] gives the new order.
/// Buffers keep their capacity, so a stream joining after one left costs no reallocation.
///
/// After a failed step the batch refuses to step again until all its streams have been removed
/// (they come back poisoned: [`LiveGestureGraphs::reset`] them).
#[derive(Debug)]
pub struct StreamBatch {
    pub(super) members: Vec<Member>,
    /// Stacked caches of all members.
    pub(super) caches: Caches,
    /// Last step's input caches, as output buffers for the next step (contents stale; their batch
    /// size may lag behind `caches` after adds and removes: the backend resizes them).
    pub(super) spare: Caches,
    /// The same tensors with zero rows (the layout every added stream must match).
    pub(super) empty: Caches,
    pub(super) next_id: u64,
    pub(super) poisoned: bool,
}

impl StreamBatch {
    /// An empty batch whose streams will have caches shaped like `empty`'s (zero rows).
    pub(super) fn new(empty: Caches) -> Self {
        StreamBatch {
            members: Vec::new(),
            caches: empty.clone(),
            spare: empty.clone(),
            empty,
            next_id: 0,
            poisoned: false,
        }
    }

    /// Number of streams.
    pub fn len(&self) -> usize {
        self.members.len()
    }

    /// True without streams.
    pub fn is_empty(&self) -> bool {
        self.members.is_empty()
    }

    /// The streams in batch order: the order [`LiveGestureGraphs::step_stream_batch`] takes mel blocks in and
    /// returns token steps in. Changes only with [`StreamBatch::add`] (appends) and
    /// [`StreamBatch::remove`].
    pub fn ids(&self) -> Vec<StreamId> {
        self.members.iter().map(|m| m.id).collect()
    }

    /// Position of `id` in batch order.
    pub fn position(&self, id: StreamId) -> Option<usize> {
        self.members.iter().position(|m| m.id == id)
    }

    /// True when `id` is in the batch.
    pub fn contains(&self, id: StreamId) -> bool {
        self.position(id).is_some()
    }

    /// Rows of the expert and fusion batches (the sum of the streams' [`Stream::branch_rows`]).
    pub fn branch_rows(&self) -> usize {
        self.members.iter().map(|m| m.state.branch_rows()).sum()
    }

    /// True after a failed step (see the type's docs).
    pub fn is_poisoned(&self) -> bool {
        self.poisoned
    }

    fn member(&self, id: StreamId) -> Result<&Member> {
        self.members
            .iter()
            .find(|m| m.id == id)
            .with_context(|| format!("{id} is not in this batch"))
    }

    /// The options stream `id` was created with.
    pub fn options(&self, id: StreamId) -> Result<&StreamOptions> {
        Ok(&self.member(id)?.state.opts)
    }

    /// Tokens stream `id` has stepped so far.
    pub fn tokens_done(&self, id: StreamId) -> Result<u64> {
        Ok(self.member(id)?.state.t)
    }

    /// Feeds audio to stream `id`'s frontend, returning the mel frames of each completed token (for
    /// [`LiveGestureGraphs::step_stream_batch`]).
    pub fn push_audio(&mut self, id: StreamId, chunk: &[f32]) -> Result<Vec<Array2<f32>>> {
        let m = self
            .members
            .iter_mut()
            .find(|m| m.id == id)
            .with_context(|| format!("{id} is not in this batch"))?;
        m.state.push_audio(chunk)
    }

    /// Ends stream `id`'s audio (docs/output.md): the mel blocks of its silence-completed last token (step
    /// them with [`LiveGestureGraphs::step_stream_batch`](super::LiveGestureGraphs::step_stream_batch) like any other)
    /// and the number of frames that covers `input`; keep only the frames whose index is below it
    /// ([`super::cut_frames`]). See [`Stream::finish_audio`].
    pub fn finish_audio(
        &mut self,
        id: StreamId,
        input: AudioSpan,
    ) -> Result<(Vec<Array2<f32>>, u64)> {
        let m = self
            .members
            .iter_mut()
            .find(|m| m.id == id)
            .with_context(|| format!("{id} is not in this batch"))?;
        m.state.finish_audio(input)
    }

    /// Adds `stream` (fresh from [`LiveGestureGraphs::new_stream`], or one that has already stepped, e.g. one
    /// taken out of another batch) at the end of the batch: its caches are appended to the stacked
    /// ones. Errors for a poisoned stream or batch, or a stream of a bundle with other caches.
    pub fn add(&mut self, stream: Stream) -> Result<StreamId> {
        ensure!(
            !self.poisoned,
            "a step of this batch failed; remove its streams before adding new ones"
        );
        ensure!(
            !stream.poisoned,
            "the stream failed earlier; reset it before adding it to a batch"
        );
        let branch = stream.state.branch_rows();
        for slot in self.empty.slots() {
            let have = self.empty.slot(slot);
            let add = stream.caches.slot(slot);
            let rows = if slot.branched() { branch } else { 1 };
            ensure!(
                have.len() == add.len(),
                "the stream has {} caches for a graph with {} (a stream of another bundle?)",
                add.len(),
                have.len()
            );
            for (h, a) in have.iter().zip(add) {
                ensure!(
                    a.dtype() == h.dtype()
                        && a.shape.len() == h.shape.len()
                        && a.shape[1..] == h.shape[1..]
                        && a.batch() == rows,
                    "the stream's cache {:?} ({}) does not fit the batch's {:?} ({}) (a stream of another bundle?)",
                    a.shape,
                    a.dtype(),
                    h.shape,
                    h.dtype()
                );
            }
        }
        for slot in self.empty.slots() {
            for (h, a) in self
                .caches
                .slot_mut(slot)
                .iter_mut()
                .zip(stream.caches.slot(slot))
            {
                h.append_rows(a)?;
            }
        }
        let id = StreamId(self.next_id);
        self.next_id += 1;
        self.members.push(Member {
            id,
            state: stream.state,
        });
        Ok(id)
    }

    /// Takes stream `id` out of the batch, with its caches: the returned [`Stream`] can be stepped
    /// alone or added to a batch again and continues exactly where it was. The order of the remaining
    /// streams may change (see the type's docs).
    pub fn remove(&mut self, id: StreamId) -> Result<Stream> {
        let i = self
            .position(id)
            .with_context(|| format!("{id} is not in this batch"))?;
        let branch = self.members[i].state.branch_rows();
        if self.poisoned {
            let m = self.members.remove(i);
            if self.members.is_empty() {
                self.caches = self.empty.clone();
                self.spare = self.empty.clone();
                self.poisoned = false;
            }
            return Ok(Stream {
                state: m.state,
                caches: Caches::zeros_like(&self.empty, branch),
                poisoned: true,
            });
        }
        match self.remove_rows(i, branch) {
            Ok(caches) => {
                let last = self.members.len() - 1;
                let m = if i != last && self.members[last].state.branch_rows() == branch {
                    self.members.swap_remove(i)
                } else {
                    self.members.remove(i)
                };
                Ok(Stream {
                    state: m.state,
                    caches,
                    poisoned: false,
                })
            }
            Err(e) => {
                // cannot happen with consistent caches; keep the batch from stepping on broken ones
                self.poison();
                Err(e.context(format!("removing {id} from the batch")))
            }
        }
    }

    /// Copies out member `i`'s rows and removes them (moving the last member's rows into their place
    /// when it has as many).
    fn remove_rows(&mut self, i: usize, branch: usize) -> Result<Caches> {
        let last = self.members.len() - 1;
        let swap = i != last && self.members[last].state.branch_rows() == branch;
        let start_b: usize = self.members[..i]
            .iter()
            .map(|m| m.state.branch_rows())
            .sum();
        let out = self
            .caches
            .remove_stream_rows((start_b, branch, i), swap, Some(&self.empty))?;
        out.ok_or_else(|| anyhow!("the removed rows were not kept"))
    }

    /// Drops the (possibly incomplete) caches and refuses further steps until the batch is emptied.
    pub(super) fn poison(&mut self) {
        self.poisoned = true;
        self.caches = self.empty.clone();
        self.spare = self.empty.clone();
        if self.members.is_empty() {
            self.poisoned = false;
        }
    }
}

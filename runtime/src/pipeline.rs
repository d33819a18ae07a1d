//! The streaming pipeline: audio chunks in, SMPL-X frames out, zero look-ahead.
//!
//! This reproduces `python/livegesture/stream.py` step for step. Per motion token `t`, as soon as its
//! audio has arrived:
//!
//! 1. the stream's [`StreamingLogMel`] yields the token's `mel_frames_per_token` log-mel frames;
//! 2. `audio_encoder` turns them into the audio token `a_t` (once per stream);
//! 3. every `expert_<region>` reads the previous token of its region (BOS at `t = 0`) and `a_t`; the
//!    conditional (`cond = 1`) and unconditional (`cond = 0`) guidance branches are two rows on the
//!    batch axis;
//! 4. `fusion` gives per-region logits for both branches;
//! 5. classifier-free guidance and the seeded SplitMix64 sampler ([`crate::sampling`]) draw one token
//!    per region, in region order;
//! 6. `decoder_<region>` turns the token into frames `4t .. 4t+3` of region features;
//! 7. rot6d is converted to axis-angle and the region features are assembled into [`Frame`]s
//!    (translation and expressions copied, foot contact from the lower region's contact dims, eyes at
//!    rest), following the region layout in the manifest.
//!
//! With guidance `gamma == 1.0` the unconditional branch is not run at all (one row per stream), as in
//! Python.
//!
//! # State and batching
//!
//! A [`Stream`] owns all per-stream state (frontend buffer, every graph's caches, previous tokens, the
//! PRNG, the token counter). Its size is fixed: it does not grow with the stream's length. A
//! [`Pipeline`] owns the loaded graphs and is shared by any number of streams.
//!
//! Two ways to step many streams at once, every graph running once for all of them:
//!
//! - [`Pipeline::step_batch`] on separately owned [`Stream`]s: their caches are stacked on the batch
//!   axis before each graph run and split back after it (a copy of every cache, twice, per step);
//! - a [`StreamBatch`] ([`Pipeline::new_batch`], [`Pipeline::step_stream_batch`]) keeps the caches of
//!   its streams stacked between steps: each graph gets them as they are and its new caches simply
//!   replace them. Streams join and leave between steps ([`StreamBatch::add`], [`StreamBatch::remove`]).
//!
//! Stepping streams one by one, with `step_batch` or in a `StreamBatch` gives the same tokens and
//! frames.
//!
//! After an error inside a graph the caches are incomplete: the stream refuses further work until
//! [`Pipeline::reset`], a batch until its streams have been removed.

use anyhow::{bail, ensure, Context, Result};
use ndarray::Array2;

use crate::backend::{Backend, Tensor};
use crate::bundle::{Bundle, CacheSpec, GraphSpec};
use crate::frontend::{FrontendConfig, StreamingLogMel};
use crate::output::{Frame, CONTACT_DIM, EXPR_DIM, POSE_DIM, TRANS_DIM};
use crate::rotation::rot6d_to_axis_angle;
use crate::sampling::{sample_token, SplitMix64};

/// Generation settings of one stream; `None` takes the bundle's default.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StreamOptions {
    /// Seed of the stream's SplitMix64 generator.
    pub seed: u64,
    /// Classifier-free guidance scale gamma (1.0 disables guidance).
    pub guidance: Option<f64>,
    /// Sampling temperature (> 0).
    pub temperature: Option<f64>,
    /// Top-k (0 = all tokens).
    pub top_k: Option<usize>,
    /// Keep each step's logits in [`TokenStep::logits`] (for parity tools).
    pub record_logits: bool,
}

/// Logits of one token step, `(regions, codebook_size)` row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct StepLogits {
    /// Conditional branch.
    pub cond: Vec<f32>,
    /// Unconditional branch (absent without guidance).
    pub uncond: Option<Vec<f32>>,
}

/// The result of one token step of one stream.
#[derive(Debug, Clone, PartialEq)]
pub struct TokenStep {
    /// Token index `t` (from 0).
    pub token_index: u64,
    /// Sampled token per region, in region order.
    pub tokens: Vec<i64>,
    /// The fusion logits (only with [`StreamOptions::record_logits`]).
    pub logits: Option<StepLogits>,
    /// Frames `4t .. 4t + 3`.
    pub frames: Vec<Frame>,
}

/// The resolved layout of one region's features.
#[derive(Debug, Clone)]
struct RegionLayout {
    name: String,
    dim: usize,
    /// (joint, offset of its rot6d) pairs.
    rot6d: Vec<(usize, usize)>,
    trans: Option<usize>,
    contact: Option<usize>,
    expressions: Option<usize>,
}

/// Role of a data input of a graph.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Mel,
    PrevToken,
    Token,
    Audio,
    Cond,
    Hidden(usize),
}

/// One loaded graph with the roles of its data inputs.
struct Stage {
    spec: GraphSpec,
    runner: Box<dyn crate::backend::GraphRunner>,
    roles: Vec<Role>,
}

impl Stage {
    fn new(bundle: &Bundle, backend: &dyn Backend, name: &str, regions: &[String]) -> Result<Self> {
        let spec = bundle.graph(name)?.clone();
        let runner = backend
            .load(&spec, &bundle.graph_path(&spec))
            .with_context(|| {
                format!("loading graph '{name}' with the {} backend", backend.name())
            })?;
        let mut roles = Vec::new();
        for i in &spec.inputs {
            let role = match i.name.as_str() {
                "mel" => Role::Mel,
                "prev_token" => Role::PrevToken,
                "token" => Role::Token,
                "audio" => Role::Audio,
                "cond" => Role::Cond,
                n => match n
                    .strip_prefix("hidden_")
                    .and_then(|r| regions.iter().position(|x| x == r))
                {
                    Some(k) => Role::Hidden(k),
                    None => bail!("graph '{name}': unknown data input '{n}'"),
                },
            };
            roles.push(role);
        }
        Ok(Stage {
            spec,
            runner,
            roles,
        })
    }

    /// Runs with data inputs built by `data(role)` and the stacked `caches`, writing the new caches
    /// into the buffers of `spare` where the backend can (empty: fresh buffers). Returns (data
    /// outputs, new caches, the input caches: spare buffers for the next run).
    fn run(
        &mut self,
        mut data: impl FnMut(Role) -> Result<Tensor>,
        caches: Vec<Tensor>,
        spare: Vec<Tensor>,
    ) -> Result<(Vec<Tensor>, Vec<Tensor>, Vec<Tensor>)> {
        let n_data = self.roles.len();
        let mut inputs = Vec::with_capacity(n_data + caches.len());
        for &r in &self.roles {
            inputs.push(data(r)?);
        }
        inputs.extend(caches);
        let n_out = self.spec.outputs.len();
        let mut out = Vec::with_capacity(n_out + spare.len());
        if !spare.is_empty() {
            out.resize_with(n_out, Tensor::default);
            out.extend(spare);
        }
        self.runner.run_into(&inputs, &mut out)?;
        let caches = out.split_off(n_out);
        let old = inputs.split_off(n_data);
        Ok((out, caches, old))
    }
}

/// Stacks the per-stream caches of one graph (`per_stream[i][c]`) into one tensor per cache, moving
/// instead of copying for a single stream.
fn stack_caches(mut per_stream: Vec<Vec<Tensor>>) -> Result<Vec<Tensor>> {
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
fn split_caches(stacked: Vec<Tensor>, rows: &[usize]) -> Result<Vec<Vec<Tensor>>> {
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

fn zeros_for(caches: &[CacheSpec], rows: usize) -> Vec<Tensor> {
    caches.iter().map(|c| c.zeros(rows)).collect()
}

/// A graph of the chain, as a place for caches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Slot {
    AudioEncoder,
    Expert(usize),
    Fusion,
    Decoder(usize),
}

impl Slot {
    /// True for the graphs that carry both guidance branches (2 rows per guided stream).
    fn branched(self) -> bool {
        matches!(self, Slot::Expert(_) | Slot::Fusion)
    }
}

/// Caches of every graph: one stream's, or the stacked caches of a [`StreamBatch`].
#[derive(Debug, Clone)]
struct Caches {
    audio_encoder: Vec<Tensor>,
    experts: Vec<Vec<Tensor>>,
    fusion: Vec<Tensor>,
    decoders: Vec<Vec<Tensor>>,
}

impl Caches {
    fn slots(&self) -> Vec<Slot> {
        let n = self.experts.len();
        std::iter::once(Slot::AudioEncoder)
            .chain((0..n).map(Slot::Expert))
            .chain(std::iter::once(Slot::Fusion))
            .chain((0..self.decoders.len()).map(Slot::Decoder))
            .collect()
    }

    fn slot(&self, s: Slot) -> &Vec<Tensor> {
        match s {
            Slot::AudioEncoder => &self.audio_encoder,
            Slot::Expert(i) => &self.experts[i],
            Slot::Fusion => &self.fusion,
            Slot::Decoder(i) => &self.decoders[i],
        }
    }

    fn slot_mut(&mut self, s: Slot) -> &mut Vec<Tensor> {
        match s {
            Slot::AudioEncoder => &mut self.audio_encoder,
            Slot::Expert(i) => &mut self.experts[i],
            Slot::Fusion => &mut self.fusion,
            Slot::Decoder(i) => &mut self.decoders[i],
        }
    }

    /// Zero caches like `template`'s (same tensors and row shapes) with `rows` rows in the branched
    /// graphs and one row in the others.
    fn zeros_like(template: &Caches, branch_rows: usize) -> Caches {
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
trait CacheStore {
    /// The caches of `slot` for every stream of the step, stacked in stream order, and buffers the
    /// graph may write its new caches into (empty: none).
    fn take(&mut self, slot: Slot) -> Result<(Vec<Tensor>, Vec<Tensor>)>;
    /// Stores the caches a graph returned for `slot` (stacked like [`CacheStore::take`]'s), and the
    /// input caches it no longer needs.
    fn put(&mut self, slot: Slot, new: Vec<Tensor>, old: Vec<Tensor>) -> Result<()>;
}

/// Separately owned per-stream caches ([`Pipeline::step_batch`]): stacked before each graph run and
/// split back after it.
struct SeparateCaches<'a> {
    caches: Vec<&'a mut Caches>,
    branch_rows: Vec<usize>,
    ones: Vec<usize>,
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
struct StackedCaches<'a> {
    cur: &'a mut Caches,
    spare: &'a mut Caches,
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

/// Everything of one stream except its caches.
#[derive(Debug)]
struct StreamState {
    opts: StreamOptions,
    gamma: f64,
    temperature: f64,
    top_k: usize,
    frontend: StreamingLogMel,
    prev: Vec<i64>,
    rng: SplitMix64,
    t: u64,
}

impl StreamState {
    fn branch_rows(&self) -> usize {
        if self.gamma != 1.0 {
            2
        } else {
            1
        }
    }
}

/// One stream's state (see the module docs).
#[derive(Debug)]
pub struct Stream {
    state: StreamState,
    caches: Caches,
    poisoned: bool,
}

impl Stream {
    /// True when classifier-free guidance is on (gamma != 1).
    pub fn guided(&self) -> bool {
        self.state.gamma != 1.0
    }

    /// Rows this stream occupies in the expert and fusion batches (2 with guidance, else 1).
    pub fn branch_rows(&self) -> usize {
        self.state.branch_rows()
    }

    /// Guidance scale in use.
    pub fn guidance(&self) -> f64 {
        self.state.gamma
    }

    /// Temperature in use.
    pub fn temperature(&self) -> f64 {
        self.state.temperature
    }

    /// Top-k in use.
    pub fn top_k(&self) -> usize {
        self.state.top_k
    }

    /// The options the stream was created with.
    pub fn options(&self) -> &StreamOptions {
        &self.state.opts
    }

    /// Tokens stepped so far.
    pub fn tokens_done(&self) -> u64 {
        self.state.t
    }

    /// Frames emitted so far (`frames_per_token` per token).
    pub fn frames_done(&self) -> u64 {
        self.state.t * self.state.frontend.config().frames_per_token
    }

    /// Audio samples received so far.
    pub fn samples_received(&self) -> u64 {
        self.state.frontend.samples_received()
    }

    /// The previous token of every region (BOS before the first step).
    pub fn prev_tokens(&self) -> &[i64] {
        &self.state.prev
    }

    /// True after a failed step: the stream refuses further work until [`Pipeline::reset`].
    pub fn is_poisoned(&self) -> bool {
        self.poisoned
    }

    /// Feeds audio to the stream's frontend only, returning the mel frames of each completed token.
    /// Use with [`Pipeline::step_batch`] to step many streams together.
    pub fn push_audio(&mut self, chunk: &[f32]) -> Result<Vec<Array2<f32>>> {
        self.state.frontend.push(chunk)
    }
}

/// Identifies a stream inside a [`StreamBatch`] (unique within that batch, never reused).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct StreamId(u64);

impl std::fmt::Display for StreamId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "stream #{}", self.0)
    }
}

#[derive(Debug)]
struct Member {
    id: StreamId,
    state: StreamState,
}

/// Streams stepped together, with their caches kept stacked on the batch axis between steps.
///
/// Stream `i` (in [`StreamBatch::ids`] order) occupies row `i` of the `audio_encoder` and decoder
/// caches, and [`Stream::branch_rows`] consecutive rows (2 with guidance: conditional, then
/// unconditional) of the expert and fusion caches, after the rows of the streams before it.
/// [`Pipeline::step_stream_batch`] hands these stacked caches to each graph and keeps the graph's
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
/// (they come back poisoned: [`Pipeline::reset`] them).
#[derive(Debug)]
pub struct StreamBatch {
    members: Vec<Member>,
    /// Stacked caches of all members.
    caches: Caches,
    /// Last step's input caches, as output buffers for the next step (contents stale; their batch
    /// size may lag behind `caches` after adds and removes: the backend resizes them).
    spare: Caches,
    /// The same tensors with zero rows (the layout every added stream must match).
    empty: Caches,
    next_id: u64,
    poisoned: bool,
}

impl StreamBatch {
    /// Number of streams.
    pub fn len(&self) -> usize {
        self.members.len()
    }

    /// True without streams.
    pub fn is_empty(&self) -> bool {
        self.members.is_empty()
    }

    /// The streams in batch order: the order [`Pipeline::step_stream_batch`] takes mel blocks in and
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
    /// [`Pipeline::step_stream_batch`]).
    pub fn push_audio(&mut self, id: StreamId, chunk: &[f32]) -> Result<Vec<Array2<f32>>> {
        let m = self
            .members
            .iter_mut()
            .find(|m| m.id == id)
            .with_context(|| format!("{id} is not in this batch"))?;
        m.state.frontend.push(chunk)
    }

    /// Adds `stream` (fresh from [`Pipeline::new_stream`], or one that has already stepped, e.g. one
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
        let mut out = self.empty.clone();
        for slot in self.empty.slots() {
            let (start, count) = if slot.branched() {
                (start_b, branch)
            } else {
                (i, 1)
            };
            let ts = self.caches.slot_mut(slot);
            let mine = ts
                .iter()
                .map(|t| t.rows(start, count))
                .collect::<Result<Vec<_>>>()?;
            for t in ts.iter_mut() {
                if swap {
                    t.swap_remove_rows(start, count)?;
                } else {
                    t.remove_rows(start, count)?;
                }
            }
            *out.slot_mut(slot) = mine;
        }
        Ok(out)
    }

    /// Drops the (possibly incomplete) caches and refuses further steps until the batch is emptied.
    fn poison(&mut self) {
        self.poisoned = true;
        self.caches = self.empty.clone();
        self.spare = self.empty.clone();
        if self.members.is_empty() {
            self.poisoned = false;
        }
    }
}

/// The loaded graphs of a bundle, shared by any number of [`Stream`]s.
pub struct Pipeline {
    frontend: FrontendConfig,
    regions: Vec<RegionLayout>,
    bos: i64,
    codebook_size: usize,
    defaults: (f64, f64, usize),
    frames_per_token: usize,
    backend: String,
    audio_encoder: Stage,
    experts: Vec<Stage>,
    fusion: Stage,
    decoders: Vec<Stage>,
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline")
            .field("backend", &self.backend)
            .field(
                "regions",
                &self.regions.iter().map(|r| &r.name).collect::<Vec<_>>(),
            )
            .finish_non_exhaustive()
    }
}

fn resolve_layout(bundle: &Bundle) -> Result<Vec<RegionLayout>> {
    let mut out = Vec::new();
    for r in bundle.regions() {
        let mut l = RegionLayout {
            name: r.name.clone(),
            dim: r.dim,
            rot6d: Vec::new(),
            trans: None,
            contact: None,
            expressions: None,
        };
        for p in &r.parts {
            match p.name.as_str() {
                "rot6d" => {
                    let joints = p.joints.clone().unwrap_or_else(|| r.joints.clone());
                    ensure!(
                        joints.len() * 6 == p.dim,
                        "region '{}': rot6d part has {} dims for {} joints",
                        r.name,
                        p.dim,
                        joints.len()
                    );
                    for (k, j) in joints.into_iter().enumerate() {
                        ensure!(
                            j * 3 + 3 <= POSE_DIM,
                            "region '{}': joint {j} out of range",
                            r.name
                        );
                        l.rot6d.push((j, p.offset + 6 * k));
                    }
                }
                "trans" => {
                    ensure!(
                        p.dim == TRANS_DIM,
                        "region '{}': trans has {} dims",
                        r.name,
                        p.dim
                    );
                    l.trans = Some(p.offset);
                }
                "foot_contact" | "contact" => {
                    ensure!(
                        p.dim == CONTACT_DIM,
                        "region '{}': foot contact has {} dims",
                        r.name,
                        p.dim
                    );
                    l.contact = Some(p.offset);
                }
                "expressions" => {
                    ensure!(
                        p.dim == EXPR_DIM,
                        "region '{}': expressions have {} dims",
                        r.name,
                        p.dim
                    );
                    l.expressions = Some(p.offset);
                }
                other => bail!("region '{}': unknown feature part '{other}'", r.name),
            }
        }
        out.push(l);
    }
    Ok(out)
}

/// Bytes of per-stream state: caches of every graph (expert and fusion caches twice with guidance)
/// plus the frontend's sample buffer at its largest (one token span and one window of `f64`).
pub fn state_bytes(bundle: &Bundle, guided: bool) -> usize {
    let rows = if guided { 2 } else { 1 };
    let caches: usize = bundle
        .graphs()
        .iter()
        .map(|g| {
            let r = if g.name.starts_with("expert_") || g.name == "fusion" {
                rows
            } else {
                1
            };
            g.cache_row_bytes() * r
        })
        .sum();
    let f = bundle.frontend();
    let span = (f.token_end(0) as usize) + f.win_length + 1;
    caches + span * std::mem::size_of::<f64>() + bundle.regions().len() * 8
}

impl Pipeline {
    /// Loads every graph of `bundle` with `backend`.
    pub fn new(bundle: &Bundle, backend: &dyn Backend) -> Result<Self> {
        let names: Vec<String> = bundle
            .region_names()
            .iter()
            .map(|s| s.to_string())
            .collect();
        let regions = resolve_layout(bundle)?;
        let audio_encoder = Stage::new(bundle, backend, "audio_encoder", &names)?;
        let fusion = Stage::new(bundle, backend, "fusion", &names)?;
        let experts = names
            .iter()
            .map(|r| Stage::new(bundle, backend, &format!("expert_{r}"), &names))
            .collect::<Result<Vec<_>>>()?;
        let decoders = names
            .iter()
            .map(|r| Stage::new(bundle, backend, &format!("decoder_{r}"), &names))
            .collect::<Result<Vec<_>>>()?;
        let fpt = bundle.frontend().frames_per_token as usize;
        for (d, l) in decoders.iter().zip(&regions) {
            let m = d
                .spec
                .outputs
                .first()
                .with_context(|| format!("graph '{}' has no output", d.spec.name))?;
            ensure!(
                m.row_len() == fpt * l.dim,
                "graph '{}': output '{}' has {} values per stream, expected {fpt} frames x {} dims",
                d.spec.name,
                m.name,
                m.row_len(),
                l.dim
            );
        }
        let s = bundle.sampling();
        Ok(Pipeline {
            frontend: bundle.frontend().clone(),
            regions,
            bos: bundle.vocab().bos_token,
            codebook_size: bundle.vocab().codebook_size,
            defaults: (s.guidance, s.temperature, s.top_k),
            frames_per_token: fpt,
            backend: backend.name().to_string(),
            audio_encoder,
            experts,
            fusion,
            decoders,
        })
    }

    /// The backend the graphs run on.
    pub fn backend_name(&self) -> &str {
        &self.backend
    }

    /// The frontend configuration (sample rate, token grid).
    pub fn frontend(&self) -> &FrontendConfig {
        &self.frontend
    }

    /// Region names in order.
    pub fn region_names(&self) -> Vec<&str> {
        self.regions.iter().map(|r| r.name.as_str()).collect()
    }

    /// Codebook size K.
    pub fn codebook_size(&self) -> usize {
        self.codebook_size
    }

    /// A fresh stream (cold start: zero caches from the manifest, BOS previous tokens, seeded PRNG).
    pub fn new_stream(&self, opts: &StreamOptions) -> Result<Stream> {
        let gamma = opts.guidance.unwrap_or(self.defaults.0);
        let temperature = opts.temperature.unwrap_or(self.defaults.1);
        let top_k = opts.top_k.unwrap_or(self.defaults.2);
        ensure!(
            gamma.is_finite(),
            "guidance must be a finite number, got {gamma}"
        );
        ensure!(
            temperature.is_finite() && temperature > 0.0,
            "temperature must be > 0, got {temperature}"
        );
        let state = StreamState {
            opts: opts.clone(),
            gamma,
            temperature,
            top_k,
            frontend: StreamingLogMel::new(&self.frontend)?,
            prev: vec![self.bos; self.regions.len()],
            rng: SplitMix64::new(opts.seed),
            t: 0,
        };
        Ok(Stream {
            caches: self.initial_caches(state.branch_rows(), 1),
            state,
            poisoned: false,
        })
    }

    /// Zero caches from the manifest with `branch_rows` rows in the expert and fusion graphs and
    /// `rows` in the others.
    fn initial_caches(&self, branch_rows: usize, rows: usize) -> Caches {
        Caches {
            audio_encoder: zeros_for(&self.audio_encoder.spec.caches, rows),
            experts: self
                .experts
                .iter()
                .map(|e| zeros_for(&e.spec.caches, branch_rows))
                .collect(),
            fusion: zeros_for(&self.fusion.spec.caches, branch_rows),
            decoders: self
                .decoders
                .iter()
                .map(|d| zeros_for(&d.spec.caches, rows))
                .collect(),
        }
    }

    /// An empty [`StreamBatch`] for this pipeline's graphs; add streams with [`StreamBatch::add`].
    pub fn new_batch(&self) -> StreamBatch {
        let empty = self.initial_caches(0, 0);
        StreamBatch {
            members: Vec::new(),
            caches: empty.clone(),
            spare: empty.clone(),
            empty,
            next_id: 0,
            poisoned: false,
        }
    }

    /// Resets `stream` to a cold start with its original options (and seed).
    pub fn reset(&self, stream: &mut Stream) -> Result<()> {
        *stream = self.new_stream(&stream.state.opts.clone())?;
        Ok(())
    }

    /// Pushes audio (16 kHz mono, any chunk size) and returns the frames of every token it completes.
    pub fn push(&mut self, stream: &mut Stream, chunk: &[f32]) -> Result<Vec<Frame>> {
        Ok(self
            .push_steps(stream, chunk)?
            .into_iter()
            .flat_map(|s| s.frames)
            .collect())
    }

    /// Like [`Pipeline::push`], returning each token step (tokens, optional logits, frames).
    pub fn push_steps(&mut self, stream: &mut Stream, chunk: &[f32]) -> Result<Vec<TokenStep>> {
        ensure!(
            !stream.poisoned,
            "the stream failed earlier; reset it before pushing more audio"
        );
        let mels = stream.state.frontend.push(chunk)?;
        let mut out = Vec::with_capacity(mels.len());
        for mel in &mels {
            out.push(self.step(stream, mel)?);
        }
        Ok(out)
    }

    /// One token step of one stream from its mel frames `(mel_frames_per_token, n_mels)`.
    pub fn step(&mut self, stream: &mut Stream, mel: &Array2<f32>) -> Result<TokenStep> {
        let mut v = self.step_batch(&mut [stream], std::slice::from_ref(mel))?;
        v.pop().context("step_batch returned no result")
    }

    fn check_mels(&self, n: usize, mels: &[Array2<f32>]) -> Result<()> {
        ensure!(n == mels.len(), "{n} streams but {} mel blocks", mels.len());
        let mpt = self.frontend.mel_frames_per_token as usize;
        let n_mels = self.frontend.n_mels;
        for m in mels {
            ensure!(
                m.dim() == (mpt, n_mels),
                "mel block has shape {:?}, expected ({mpt}, {n_mels})",
                m.dim()
            );
        }
        Ok(())
    }

    /// One token step of several separately owned streams at once (`mels[i]` for `streams[i]`):
    /// every graph runs once with the streams' caches stacked on the batch axis before the run and
    /// split back after it. Streams may differ in guidance. For a set of streams stepped together
    /// again and again, a [`StreamBatch`] ([`Pipeline::step_stream_batch`]) avoids the stacking.
    pub fn step_batch(
        &mut self,
        streams: &mut [&mut Stream],
        mels: &[Array2<f32>],
    ) -> Result<Vec<TokenStep>> {
        self.check_mels(streams.len(), mels).context("step_batch")?;
        if streams.is_empty() {
            return Ok(Vec::new());
        }
        for s in streams.iter() {
            ensure!(
                !s.poisoned,
                "the stream failed earlier; reset it before stepping it again"
            );
        }
        for s in streams.iter_mut() {
            s.poisoned = true;
        }
        let mut states = Vec::with_capacity(streams.len());
        let mut store = SeparateCaches {
            caches: Vec::with_capacity(streams.len()),
            branch_rows: Vec::with_capacity(streams.len()),
            ones: vec![1; streams.len()],
        };
        for s in streams.iter_mut() {
            let s = &mut **s;
            store.branch_rows.push(s.state.branch_rows());
            states.push(&mut s.state);
            store.caches.push(&mut s.caches);
        }
        let out = self.step_inner(&mut states, &mut store, mels)?;
        for s in streams.iter_mut() {
            s.poisoned = false;
        }
        Ok(out)
    }

    /// One token step of every stream of `batch` (`mels[i]` for the `i`-th of [`StreamBatch::ids`]):
    /// every graph runs once on the batch's stacked caches, and the new caches it returns take their
    /// place (moved, not copied). Returns the token steps in the same order. The tokens and frames of
    /// each stream are those it would get stepped alone.
    pub fn step_stream_batch(
        &mut self,
        batch: &mut StreamBatch,
        mels: &[Array2<f32>],
    ) -> Result<Vec<TokenStep>> {
        self.check_mels(batch.len(), mels)
            .context("step_stream_batch")?;
        ensure!(
            !batch.poisoned,
            "a step of this batch failed earlier; remove its streams (and reset them) to use it again"
        );
        if batch.is_empty() {
            return Ok(Vec::new());
        }
        let mut states: Vec<&mut StreamState> =
            batch.members.iter_mut().map(|m| &mut m.state).collect();
        let mut store = StackedCaches {
            cur: &mut batch.caches,
            spare: &mut batch.spare,
        };
        let r = self.step_inner(&mut states, &mut store, mels);
        if r.is_err() {
            batch.poison();
        }
        r
    }

    /// The token step shared by [`Pipeline::step_batch`] and [`Pipeline::step_stream_batch`]; the mel
    /// blocks have been checked. On error the caches in `store` are incomplete.
    fn step_inner(
        &mut self,
        streams: &mut [&mut StreamState],
        store: &mut impl CacheStore,
        mels: &[Array2<f32>],
    ) -> Result<Vec<TokenStep>> {
        let n = streams.len();
        let n_regions = self.regions.len();
        let k = self.codebook_size;
        let mpt = self.frontend.mel_frames_per_token as usize;
        let n_mels = self.frontend.n_mels;

        // 1-2. audio encoder, one row per stream
        let mut mel_data = Vec::with_capacity(n * mpt * n_mels);
        for m in mels {
            mel_data.extend(m.iter().copied());
        }
        let mel_t = Tensor::f32(vec![n, mpt, n_mels], mel_data)?;
        let mut mel_opt = Some(mel_t);
        let (caches, spare) = store.take(Slot::AudioEncoder)?;
        let (out, new, old) = self.audio_encoder.run(
            |r| match r {
                Role::Mel => mel_opt.take().context("mel used twice"),
                other => bail!("audio_encoder: unexpected input {other:?}"),
            },
            caches,
            spare,
        )?;
        store.put(Slot::AudioEncoder, new, old)?;
        let audio = out
            .into_iter()
            .next()
            .context("audio_encoder returned no output")?;
        let da = audio.row_len();
        let audio_v = audio.as_f32("audio_encoder output")?;

        // 3. experts with both guidance branches on the batch axis
        let rows: Vec<usize> = streams.iter().map(|s| s.branch_rows()).collect();
        let total: usize = rows.iter().sum();
        let mut audio_rows = Vec::with_capacity(total * da);
        let mut cond = Vec::with_capacity(total);
        for (i, &r) in rows.iter().enumerate() {
            for b in 0..r {
                audio_rows.extend_from_slice(&audio_v[i * da..(i + 1) * da]);
                cond.push(if b == 0 { 1.0 } else { 0.0 });
            }
        }
        let audio_b = Tensor::f32(vec![total, da], audio_rows)?;
        let cond_b = Tensor::f32(vec![total], cond)?;
        let mut hidden = Vec::with_capacity(n_regions);
        for (ri, stage) in self.experts.iter_mut().enumerate() {
            let mut prev = Vec::with_capacity(total);
            for (s, &r) in streams.iter().zip(&rows) {
                prev.extend(std::iter::repeat_n(s.prev[ri], r));
            }
            let prev_t = Tensor::i64(vec![total], prev)?;
            let (caches, spare) = store.take(Slot::Expert(ri))?;
            let (out, new, old) = stage.run(
                |role| match role {
                    Role::PrevToken => Ok(prev_t.clone()),
                    Role::Audio => Ok(audio_b.clone()),
                    Role::Cond => Ok(cond_b.clone()),
                    other => bail!("expert: unexpected input {other:?}"),
                },
                caches,
                spare,
            )?;
            store.put(Slot::Expert(ri), new, old)?;
            hidden.push(
                out.into_iter()
                    .next()
                    .context("expert returned no output")?,
            );
        }

        // 4. fusion
        let (caches, spare) = store.take(Slot::Fusion)?;
        let (out, new, old) = self.fusion.run(
            |role| match role {
                Role::Hidden(i) => hidden
                    .get(i)
                    .cloned()
                    .context("fusion: missing hidden state"),
                Role::Audio => Ok(audio_b.clone()),
                Role::Cond => Ok(cond_b.clone()),
                other => bail!("fusion: unexpected input {other:?}"),
            },
            caches,
            spare,
        )?;
        store.put(Slot::Fusion, new, old)?;
        let logits = out
            .into_iter()
            .next()
            .context("fusion returned no output")?;
        ensure!(
            logits.shape == [total, n_regions, k],
            "fusion: logits have shape {:?}, expected [{total}, {n_regions}, {k}]",
            logits.shape
        );
        let lv = logits.as_f32("fusion logits")?;

        // 5. guided sampling, one uniform per region in region order
        let row_len = n_regions * k;
        let mut tokens_all: Vec<Vec<i64>> = Vec::with_capacity(n);
        let mut logits_all: Vec<Option<StepLogits>> = Vec::with_capacity(n);
        let mut row = 0;
        for (s, &r) in streams.iter_mut().zip(&rows) {
            let c = &lv[row * row_len..(row + 1) * row_len];
            let u = if r == 2 {
                Some(&lv[(row + 1) * row_len..(row + 2) * row_len])
            } else {
                None
            };
            let mut toks = Vec::with_capacity(n_regions);
            for ri in 0..n_regions {
                let cr = &c[ri * k..(ri + 1) * k];
                let ur = u.map(|u| &u[ri * k..(ri + 1) * k]);
                let tok = sample_token(cr, ur, &mut s.rng, s.gamma, s.temperature, s.top_k)
                    .with_context(|| {
                        format!(
                            "sampling region '{}' at token {}",
                            self.regions[ri].name, s.t
                        )
                    })?;
                toks.push(tok as i64);
            }
            logits_all.push(s.opts.record_logits.then(|| StepLogits {
                cond: c.to_vec(),
                uncond: u.map(<[f32]>::to_vec),
            }));
            tokens_all.push(toks);
            row += r;
        }

        // 6. decoders, one row per stream
        let mut feats: Vec<Tensor> = Vec::with_capacity(n_regions);
        for (ri, stage) in self.decoders.iter_mut().enumerate() {
            let tok_t = Tensor::i64(vec![n], tokens_all.iter().map(|t| t[ri]).collect())?;
            let (caches, spare) = store.take(Slot::Decoder(ri))?;
            let (out, new, old) = stage.run(
                |role| match role {
                    Role::Token => Ok(tok_t.clone()),
                    other => bail!("decoder: unexpected input {other:?}"),
                },
                caches,
                spare,
            )?;
            store.put(Slot::Decoder(ri), new, old)?;
            feats.push(
                out.into_iter()
                    .next()
                    .context("decoder returned no output")?,
            );
        }

        // 7. frames
        let mut results = Vec::with_capacity(n);
        for (i, ((s, toks), lg)) in streams
            .iter_mut()
            .zip(tokens_all)
            .zip(logits_all)
            .enumerate()
        {
            let frames = self.assemble_frames(&feats, i, s.t)?;
            results.push(TokenStep {
                token_index: s.t,
                tokens: toks.clone(),
                logits: lg,
                frames,
            });
            s.prev = toks;
            s.t += 1;
        }
        Ok(results)
    }

    /// Builds the frames of stream row `i` from the decoders' `(batch, frames_per_token, dim)` outputs.
    fn assemble_frames(&self, feats: &[Tensor], i: usize, t: u64) -> Result<Vec<Frame>> {
        let fpt = self.frames_per_token;
        let mut frames = Vec::with_capacity(fpt);
        for j in 0..fpt {
            let mut poses = [0f32; POSE_DIM];
            let mut trans = [0f32; TRANS_DIM];
            let mut expressions = [0f32; EXPR_DIM];
            let mut contact = [0f32; CONTACT_DIM];
            for (l, f) in self.regions.iter().zip(feats) {
                let v = f.as_f32("decoder output")?;
                let base = (i * fpt + j) * l.dim;
                let row = &v[base..base + l.dim];
                for &(joint, off) in &l.rot6d {
                    let d6 = [
                        row[off],
                        row[off + 1],
                        row[off + 2],
                        row[off + 3],
                        row[off + 4],
                        row[off + 5],
                    ];
                    poses[3 * joint..3 * joint + 3].copy_from_slice(&rot6d_to_axis_angle(d6));
                }
                if let Some(o) = l.trans {
                    trans.copy_from_slice(&row[o..o + TRANS_DIM]);
                }
                if let Some(o) = l.expressions {
                    expressions.copy_from_slice(&row[o..o + EXPR_DIM]);
                }
                if let Some(o) = l.contact {
                    contact.copy_from_slice(&row[o..o + CONTACT_DIM]);
                }
            }
            frames.push(Frame::new(
                fpt as u64 * t + j as u64,
                poses,
                trans,
                expressions,
                contact,
            ));
        }
        Ok(frames)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send<T: Send>() {}

    #[test]
    fn streams_and_pipelines_move_between_threads() {
        assert_send::<Stream>();
        assert_send::<Pipeline>();
        assert_send::<StreamBatch>();
    }

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

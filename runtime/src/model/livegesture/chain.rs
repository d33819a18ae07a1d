//! The per-token chain (module docs of [`super`], steps 1-7): one function per stage.

use anyhow::{bail, ensure, Context, Result};
use ndarray::Array2;

use super::caches::{CacheStore, Slot};
use super::stream::StreamState;
use super::{LiveGestureGraphs, StepLogits, TokenStep};
use crate::backend::{Backend, GraphRunner, Tensor};
use crate::bundle::{Bundle, GraphSpec, TensorSpec};
use crate::sampling::sample_token;

/// Role of a data input of a graph.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Mel,
    PrevToken,
    Token,
    Audio,
    Cond,
    Hidden(usize),
    /// The write position of a graph on ring caches (docs/bundle.md#ring-caches), from the store.
    Phase,
}

/// One loaded graph with the roles of its data inputs.
pub(super) struct Stage {
    pub(super) spec: GraphSpec,
    runner: Box<dyn GraphRunner>,
    roles: Vec<Role>,
}

impl Stage {
    pub(super) fn new(
        bundle: &Bundle,
        backend: &dyn Backend,
        name: &str,
        regions: &[String],
    ) -> Result<Self> {
        let spec = bundle.graph(name)?.clone();
        let runner = backend.load_from(bundle, &spec).with_context(|| {
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
                "phase" if spec.is_ring() => Role::Phase,
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

    pub(super) fn runner(&self) -> &dyn GraphRunner {
        self.runner.as_ref()
    }

    /// Runs with data inputs built by `data(role)` and the stacked `caches`, writing the new caches
    /// into the buffers of `spare` where the backend can (empty: fresh buffers). Returns (data
    /// outputs, new caches, the input caches: spare buffers for the next run).
    fn run(
        &self,
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

    /// Runs as `slot` of the chain: takes the slot's caches from `store`, runs with data inputs from
    /// `data`, puts the new caches back, and returns the graph's (single) data output.
    fn run_slot(
        &self,
        slot: Slot,
        store: &mut impl CacheStore,
        data: impl FnMut(Role) -> Result<Tensor>,
    ) -> Result<Tensor> {
        let (caches, spare) = store.take(slot)?;
        let out = if self.spec.is_ring() {
            // the caches are read-only inputs; the entries are written at the phase (no buffers)
            let rows = caches.first().map_or(0, Tensor::batch);
            let phase = i64::try_from(store.phase()).context("ring phase out of range")?;
            let mut phase = Some(Tensor::i64(vec![rows], vec![phase; rows])?);
            let mut data = data;
            let (out, entries, caches) = self.run(
                |r| match r {
                    Role::Phase => phase.take().context("phase used twice"),
                    other => data(other),
                },
                caches,
                Vec::new(),
            )?;
            store.put_ring(slot, entries, caches, spare, &self.spec.caches)?;
            out
        } else {
            let (out, new, old) = self.run(data, caches, spare)?;
            store.put(slot, new, old)?;
            out
        };
        out.into_iter()
            .next()
            .with_context(|| format!("{} returned no output", self.spec.name))
    }
}

/// The first output of `stage`'s graph (its data output).
fn first_output(stage: &Stage) -> Result<&TensorSpec> {
    let spec = &stage.spec;
    spec.outputs
        .first()
        .with_context(|| format!("graph '{}' has no output", spec.name))
}

/// Checks that `stage`'s input `name` holds one value per region per row: `(batch, regions)`.
fn check_region_input(stage: &Stage, name: &str, regions: usize) -> Result<()> {
    let spec = &stage.spec;
    let input = spec
        .inputs
        .iter()
        .find(|i| i.name == name)
        .with_context(|| format!("graph '{}' has no input '{name}'", spec.name))?;
    ensure!(
        input.row_len() == regions,
        "graph '{}': input '{name}' has {} values per row, expected one per region ({regions})",
        spec.name,
        input.row_len()
    );
    Ok(())
}

/// Checks that `stage` has the fused eXperts' contract for `regions` regions: `prev_token`
/// `(batch, regions)` and one output `hidden` `(batch, regions, d)`.
pub(super) fn check_fused_experts(stage: &Stage, regions: usize) -> Result<()> {
    check_region_input(stage, "prev_token", regions)?;
    let h = first_output(stage)?;
    ensure!(
        h.row_len() % regions == 0,
        "graph '{}': output '{}' has {} values per row, not a multiple of the {regions} regions",
        stage.spec.name,
        h.name,
        h.row_len()
    );
    Ok(())
}

/// Checks that decoder `stage` outputs `fpt` frames per token of the regions `dims` side by side:
/// `(batch, fpt, sum of dims)` (one region for a per-region decoder).
pub(super) fn check_decoder_output(stage: &Stage, dims: &[usize], fpt: usize) -> Result<()> {
    let m = first_output(stage)?;
    let width: usize = dims.iter().sum();
    ensure!(
        m.row_len() == fpt * width,
        "graph '{}': output '{}' has {} values per stream, expected {fpt} frames x {width} dims (the regions' {dims:?} side by side)",
        stage.spec.name,
        m.name,
        m.row_len()
    );
    Ok(())
}

/// Checks that `stage` has the fused decoders' contract for `regions` regions of `dims` features
/// and `fpt` frames per token: `token` `(batch, regions)` and one output `motion`
/// `(batch, fpt, sum of dims)`.
pub(super) fn check_fused_decoders(stage: &Stage, dims: &[usize], fpt: usize) -> Result<()> {
    check_region_input(stage, "token", dims.len())?;
    check_decoder_output(stage, dims, fpt)
}

/// The guidance-branch inputs shared by the experts and fusion: the audio token of each stream
/// repeated once per branch row, and the `cond` flag of each row (1 conditional, 0 unconditional).
struct Branches {
    /// Rows per stream (2 with guidance, else 1).
    rows: Vec<usize>,
    total: usize,
    audio: Tensor,
    cond: Tensor,
}

impl LiveGestureGraphs {
    /// One token step of `streams` from their mel blocks (checked by the caller): steps 1-7 of the
    /// module docs. Shared by [`LiveGestureGraphs::step_batch`] and the cohorts of `step_many` (`super::cohorts`), which
    /// differ only in where the caches live (`store`). On error the caches in `store` are incomplete.
    pub(super) fn step_inner(
        &self,
        streams: &mut [&mut StreamState],
        store: &mut impl CacheStore,
        mels: &[Array2<f32>],
    ) -> Result<Vec<TokenStep>> {
        let audio = self.encode_audio(store, mels)?;
        let rows: Vec<usize> = streams.iter().map(|s| s.branch_rows()).collect();
        let branches = Branches::new(&audio, rows)?;
        let hidden = self.run_experts(streams, store, &branches)?;
        let logits = self.run_fusion(store, &branches, hidden)?;
        let (tokens, logits) = self.sample(streams, &branches, &logits)?;
        let feats = self.run_decoders(store, &tokens)?;
        store.advance_phase();
        let mut results = Vec::with_capacity(streams.len());
        for (i, ((s, toks), lg)) in streams.iter_mut().zip(tokens).zip(logits).enumerate() {
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

    /// Steps 1-2: the audio encoder on every stream's mel block (one row per stream); returns the
    /// audio tokens `(streams, d_audio)`.
    fn encode_audio(&self, store: &mut impl CacheStore, mels: &[Array2<f32>]) -> Result<Tensor> {
        let (mpt, n_mels) = (
            self.frontend.mel_frames_per_token as usize,
            self.frontend.n_mels,
        );
        let mut mel_data = Vec::with_capacity(mels.len() * mpt * n_mels);
        for m in mels {
            mel_data.extend(m.iter().copied());
        }
        let mut mel = Some(Tensor::f32(vec![mels.len(), mpt, n_mels], mel_data)?);
        self.audio_encoder
            .run_slot(Slot::AudioEncoder, store, |r| match r {
                Role::Mel => mel.take().context("mel used twice"),
                other => bail!("audio_encoder: unexpected input {other:?}"),
            })
    }

    /// Step 3: every region's expert on both guidance branches; returns the hidden states in region
    /// order. The fused form runs one graph for all regions and splits its `hidden` by region.
    fn run_experts(
        &self,
        streams: &[&mut StreamState],
        store: &mut impl CacheStore,
        b: &Branches,
    ) -> Result<Vec<Tensor>> {
        let n_regions = self.regions.len();
        if self.experts.len() == 1 && n_regions > 1 {
            let mut prev = Vec::with_capacity(b.total * n_regions);
            for (s, &r) in streams.iter().zip(&b.rows) {
                for _ in 0..r {
                    prev.extend_from_slice(&s.prev[..n_regions]);
                }
            }
            let prev = Tensor::i64(vec![b.total, n_regions], prev)?;
            let stage = &self.experts[0];
            let name = stage.spec.name.clone();
            let hidden = stage.run_slot(Slot::Expert(0), store, |role| match role {
                Role::PrevToken => Ok(prev.clone()),
                Role::Audio => Ok(b.audio.clone()),
                Role::Cond => Ok(b.cond.clone()),
                other => bail!("{name}: unexpected input {other:?}"),
            })?;
            let hv = hidden.as_f32("fused eXperts hidden")?;
            let d = hidden.row_len() / n_regions;
            ensure!(
                hidden.shape.len() == 3
                    && hidden.shape[0] == b.total
                    && hidden.shape[1] == n_regions,
                "{name}: hidden has shape {:?}, expected [{}, {n_regions}, d]",
                hidden.shape,
                b.total
            );
            return (0..n_regions)
                .map(|ri| {
                    let mut v = Vec::with_capacity(b.total * d);
                    for row in 0..b.total {
                        let o = (row * n_regions + ri) * d;
                        v.extend_from_slice(&hv[o..o + d]);
                    }
                    Tensor::f32(vec![b.total, d], v)
                })
                .collect();
        }
        let mut hidden = Vec::with_capacity(self.experts.len());
        for (ri, stage) in self.experts.iter().enumerate() {
            let mut prev = Vec::with_capacity(b.total);
            for (s, &r) in streams.iter().zip(&b.rows) {
                prev.extend(std::iter::repeat_n(s.prev[ri], r));
            }
            let prev = Tensor::i64(vec![b.total], prev)?;
            hidden.push(stage.run_slot(Slot::Expert(ri), store, |role| match role {
                Role::PrevToken => Ok(prev.clone()),
                Role::Audio => Ok(b.audio.clone()),
                Role::Cond => Ok(b.cond.clone()),
                other => bail!("expert: unexpected input {other:?}"),
            })?);
        }
        Ok(hidden)
    }

    /// Step 4: fusion of the regions' hidden states; returns the logits
    /// `(branch rows, regions, codebook)`.
    fn run_fusion(
        &self,
        store: &mut impl CacheStore,
        b: &Branches,
        hidden: Vec<Tensor>,
    ) -> Result<Tensor> {
        let logits = self
            .fusion
            .run_slot(Slot::Fusion, store, |role| match role {
                Role::Hidden(i) => hidden
                    .get(i)
                    .cloned()
                    .context("fusion: missing hidden state"),
                Role::Audio => Ok(b.audio.clone()),
                Role::Cond => Ok(b.cond.clone()),
                other => bail!("fusion: unexpected input {other:?}"),
            })?;
        let (n_regions, k) = (self.regions.len(), self.codebook_size);
        ensure!(
            logits.shape == [b.total, n_regions, k],
            "fusion: logits have shape {:?}, expected [{}, {n_regions}, {k}]",
            logits.shape,
            b.total
        );
        Ok(logits)
    }

    /// Step 5: guided sampling, one uniform per region in region order from each stream's generator.
    /// Returns each stream's tokens and (when it records them) its logits.
    #[allow(clippy::type_complexity)]
    fn sample(
        &self,
        streams: &mut [&mut StreamState],
        b: &Branches,
        logits: &Tensor,
    ) -> Result<(Vec<Vec<i64>>, Vec<Option<StepLogits>>)> {
        let lv = logits.as_f32("fusion logits")?;
        let (n_regions, k) = (self.regions.len(), self.codebook_size);
        let row_len = n_regions * k;
        let mut tokens_all = Vec::with_capacity(streams.len());
        let mut logits_all = Vec::with_capacity(streams.len());
        let mut row = 0;
        for (s, &r) in streams.iter_mut().zip(&b.rows) {
            let c = &lv[row * row_len..(row + 1) * row_len];
            let u = (r == 2).then(|| &lv[(row + 1) * row_len..(row + 2) * row_len]);
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
        Ok((tokens_all, logits_all))
    }

    /// Step 6: every region's decoder on its sampled tokens (one row per stream); returns the region
    /// features `(streams, frames_per_token, dim)` in region order, or in the fused form the one
    /// output of `decoders_fused`, `(streams, frames_per_token, sum of the dims)` with the regions
    /// side by side (see [`LiveGestureGraphs::assemble_frames`]).
    fn run_decoders(
        &self,
        store: &mut impl CacheStore,
        tokens: &[Vec<i64>],
    ) -> Result<Vec<Tensor>> {
        let n_regions = self.regions.len();
        if self.decoders.len() == 1 && n_regions > 1 {
            let mut tok = Vec::with_capacity(tokens.len() * n_regions);
            for t in tokens {
                tok.extend_from_slice(&t[..n_regions]);
            }
            let tok = Tensor::i64(vec![tokens.len(), n_regions], tok)?;
            let stage = &self.decoders[0];
            let name = stage.spec.name.clone();
            let motion = stage.run_slot(Slot::Decoder(0), store, |role| match role {
                Role::Token => Ok(tok.clone()),
                other => bail!("{name}: unexpected input {other:?}"),
            })?;
            let width: usize = self.regions.iter().map(|l| l.dim).sum();
            ensure!(
                motion.shape == [tokens.len(), self.frames_per_token, width],
                "{name}: motion has shape {:?}, expected [{}, {}, {width}]",
                motion.shape,
                tokens.len(),
                self.frames_per_token
            );
            return Ok(vec![motion]);
        }
        let mut feats = Vec::with_capacity(self.decoders.len());
        for (ri, stage) in self.decoders.iter().enumerate() {
            let tok = Tensor::i64(vec![tokens.len()], tokens.iter().map(|t| t[ri]).collect())?;
            feats.push(stage.run_slot(Slot::Decoder(ri), store, |role| match role {
                Role::Token => Ok(tok.clone()),
                other => bail!("decoder: unexpected input {other:?}"),
            })?);
        }
        Ok(feats)
    }
}

impl Branches {
    /// Repeats each stream's audio token `rows[i]` times (conditional row first).
    fn new(audio: &Tensor, rows: Vec<usize>) -> Result<Self> {
        let da = audio.row_len();
        let audio_v = audio.as_f32("audio_encoder output")?;
        let total: usize = rows.iter().sum();
        let mut audio_rows = Vec::with_capacity(total * da);
        let mut cond = Vec::with_capacity(total);
        for (i, &r) in rows.iter().enumerate() {
            for b in 0..r {
                audio_rows.extend_from_slice(&audio_v[i * da..(i + 1) * da]);
                cond.push(if b == 0 { 1.0 } else { 0.0 });
            }
        }
        Ok(Branches {
            rows,
            total,
            audio: Tensor::f32(vec![total, da], audio_rows)?,
            cond: Tensor::f32(vec![total], cond)?,
        })
    }
}

//! The tract backend (pure Rust, no native dependency; the default).
//!
//! A graph is parsed once into a decluttered typed model with symbolic dimensions (the ONNX dim
//! parameters: `batch`, and DiffSHEG's window length `frames`). The first run with a given set of
//! sizes (batch, and `frames` where the graph has it) specialises the model to them (`set_symbols`),
//! optimises it (`into_optimized`) and keeps the runnable plan in a cache keyed by those sizes, so
//! streaming with a fixed batch optimises once (a DiffSHEG stream sees at most two window lengths, so
//! at most two plans per batch size).
//!
//! A plan is immutable and shared; each run takes a run state (`TypedSimpleState`: the plan's
//! per-run buffers) from the plan's pool, so threads run the same graph at the same time, each with
//! a state of its own. A state is made when a run finds none idle: as many exist per plan as runs of
//! that plan ever overlapped (one per thread that steps at the same moment).

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};

use anyhow::{ensure, Context, Result};
use tract_onnx::prelude::*;

use super::pool::Pool;
use super::{
    check_inputs, check_outputs, Backend, DType, GraphRunner, Tensor as LgTensor, TensorData,
};
use crate::bundle::{Dim, GraphSpec};

pub mod rows;
pub mod softmax;

/// The tract backend.
#[derive(Debug, Default, Clone)]
pub struct TractBackend;

impl TractBackend {
    /// A new tract backend.
    pub fn new() -> Self {
        TractBackend
    }
}

impl Backend for TractBackend {
    fn name(&self) -> &str {
        "tract"
    }

    fn describe(&self) -> String {
        "tract 0.23 (pure Rust, CPU)".into()
    }

    fn load(&self, spec: &GraphSpec, path: &Path) -> Result<Box<dyn GraphRunner>> {
        Ok(Box::new(TractGraph::load(spec, path)?))
    }

    fn load_bytes(
        &self,
        spec: &GraphSpec,
        path: &Path,
        bytes: &[u8],
    ) -> Result<Box<dyn GraphRunner>> {
        Ok(Box::new(TractGraph::load_bytes(spec, path, bytes)?))
    }
}

/// Row counts that get a plan of their own once [`GraphRunner::prepare_batches`] has run: a step of
/// another row count (a graph whose only symbol is the batch, every batched input and output with
/// the batch first) runs on the plan of the next larger count, its inputs padded with copies of
/// their last row and its outputs cut back to its own rows (rows are independent in every step
/// graph, so a padded run returns the same rows as a plan of that exact size, up to float rounding).
/// A plan optimised for a size runs the default bundle's graphs at 0.49-0.67x the time of the plan
/// with the batch left symbolic at 16 and 32 rows (`tract_symbolic`, BENCHMARKS.md), which
/// cannot pick tract's unicast elementwise kernels; each plan holds its own packed weights (about
/// 34 MiB for the default bundle's graphs), so the ladder grows by about 1.5x per step: a padded
/// run does at most 50 % more rows (a third at and above 4 rows), on average about 15 %.
/// Larger row counts run on the symbolic plan.
pub const TRACT_ROW_BUCKETS: &[usize] = &[1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64];

/// The smallest row count of [`TRACT_ROW_BUCKETS`] that holds `rows`.
pub fn row_bucket(rows: usize) -> Option<usize> {
    TRACT_ROW_BUCKETS.iter().copied().find(|&b| b >= rows)
}

/// A graph loaded with tract.
pub struct TractGraph {
    spec: GraphSpec,
    path: String,
    /// Decluttered model with symbolic dimensions.
    typed: TypedModel,
    /// Every symbol of the inputs' shapes, with the first (input, axis) where it appears.
    symbols: Vec<(Symbol, usize, usize)>,
    /// Plans per size of each symbol (in `symbols` order).
    plans: Mutex<HashMap<Vec<usize>, Arc<Plan>>>,
    /// After [`GraphRunner::prepare_batches`]: one plan with every symbol left symbolic (sizes
    /// resolved at run time), for the sizes without a plan of their own: no new plan is built.
    symbolic: Mutex<Option<Arc<Plan>>>,
    /// The input and output positions whose first axis is the batch; empty unless the only symbol
    /// is the batch and every input and output that has it has it first (`paddable`).
    batched_inputs: Vec<bool>,
    batched_outputs: Vec<bool>,
}

/// An optimised plan (immutable, shared by every run) and its idle run states.
struct Plan {
    plan: Arc<TypedSimplePlan>,
    states: Pool<TypedSimpleState>,
}

impl Plan {
    fn new(plan: Arc<TypedSimplePlan>) -> Self {
        // states are small (the plan's per-run buffers): one per overlapping run, no cap
        Self {
            plan,
            states: Pool::new(usize::MAX),
        }
    }
}

/// tract's optimisation of `model`, then the project's rewrites of the optimised graph
/// ([`softmax::on_last_axis`], [`rows::row_broadcasts`]), into a runnable plan.
pub fn optimise(model: TypedModel) -> TractResult<Arc<TypedSimplePlan>> {
    let mut m = model.into_optimized()?;
    if rewrite_on(softmax::SWITCH) {
        softmax::on_last_axis(&mut m)?;
    }
    if rewrite_on(rows::SWITCH) {
        rows::row_broadcasts(&mut m)?;
    }
    m.into_runnable()
}

/// Whether the rewrite with the environment switch `switch` is on: the default; `<switch>=generic`
/// keeps tract's own (for A/B measurements).
fn rewrite_on(switch: &str) -> bool {
    std::env::var(switch)
        .map(|v| v != "generic")
        .unwrap_or(true)
}

/// Locks a plan table (a table is consistent after any panic: one insert is its only change).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl std::fmt::Debug for TractGraph {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TractGraph")
            .field("graph", &self.spec.name)
            .field("plans", &lock(&self.plans).keys().collect::<Vec<_>>())
            .finish()
    }
}

impl TractGraph {
    /// Parses and declutters `path` (the graph `spec` of a verified bundle).
    pub fn load(spec: &GraphSpec, path: &Path) -> Result<Self> {
        let what = || {
            format!(
                "tract: loading graph '{}' from {}",
                spec.name,
                path.display()
            )
        };
        let model = tract_onnx::onnx().model_for_path(path).with_context(what)?;
        Self::from_inference(spec, path, model)
    }

    /// True when a run may be padded to the row count of a prepared plan ([`TRACT_ROW_BUCKETS`]).
    fn paddable(&self) -> bool {
        !self.batched_inputs.is_empty()
    }

    /// The row counts (the sizes of each symbol) that have a plan optimised for them, smallest first.
    pub fn plan_sizes(&self) -> Vec<Vec<usize>> {
        let mut k: Vec<Vec<usize>> = lock(&self.plans).keys().cloned().collect();
        k.sort();
        k
    }

    /// Parses and declutters the ONNX file's `bytes` (`path` names it in messages).
    pub fn load_bytes(spec: &GraphSpec, path: &Path, bytes: &[u8]) -> Result<Self> {
        let what = || {
            format!(
                "tract: loading graph '{}' from {}",
                spec.name,
                path.display()
            )
        };
        let model = tract_onnx::onnx()
            .model_for_read(&mut std::io::Cursor::new(bytes))
            .with_context(what)?;
        Self::from_inference(spec, path, model)
    }

    fn from_inference(spec: &GraphSpec, path: &Path, model: InferenceModel) -> Result<Self> {
        let what = || {
            format!(
                "tract: loading graph '{}' from {}",
                spec.name,
                path.display()
            )
        };
        let typed = model
            .into_typed()
            .and_then(|m| m.into_decluttered())
            .with_context(what)?;
        // every symbolic input dimension (batch, frames, mel_frames when it is its own symbol)
        let mut symbols: Vec<(Symbol, usize, usize)> = Vec::new();
        for i in 0..typed.inputs.len() {
            let fact = typed.input_fact(i).with_context(what)?;
            for (axis, d) in fact.shape.iter().enumerate() {
                if let TDim::Sym(sym) = d {
                    if !symbols.iter().any(|(s, _, _)| s == sym) {
                        symbols.push((sym.clone(), i, axis));
                    }
                }
            }
        }
        let leading = |shapes: Vec<(&str, DType, &[Dim])>| -> Option<Vec<bool>> {
            shapes
                .iter()
                .map(|(_, _, shape)| {
                    let at: Vec<usize> = (0..shape.len())
                        .filter(|&a| shape[a] == Dim::Batch)
                        .collect();
                    match at.as_slice() {
                        [] => Some(false),
                        [0] => Some(true),
                        _ => None,
                    }
                })
                .collect()
        };
        let (batched_inputs, batched_outputs) =
            match (leading(spec.all_inputs()), leading(spec.all_outputs())) {
                (Some(i), Some(o)) if symbols.len() == 1 => (i, o),
                _ => (Vec::new(), Vec::new()),
            };
        Ok(Self {
            spec: spec.clone(),
            path: path.display().to_string(),
            typed,
            symbols,
            plans: Mutex::default(),
            symbolic: Mutex::default(),
            batched_inputs,
            batched_outputs,
        })
    }

    /// The sizes of each symbol for these inputs (in `symbols` order).
    fn key_of(&self, inputs: &[LgTensor]) -> Vec<usize> {
        self.symbols
            .iter()
            .map(|&(_, i, axis)| {
                inputs
                    .get(i)
                    .and_then(|t| t.shape.get(axis))
                    .copied()
                    .unwrap_or(1)
            })
            .collect()
    }

    /// Optimises the model for the symbol sizes `key`.
    fn build(&self, key: &[usize]) -> Result<Plan> {
        let what = || {
            format!(
                "tract: optimising graph '{}' ({}) for sizes {key:?}",
                self.spec.name, self.path
            )
        };
        let model = if self.symbols.is_empty() {
            self.typed.clone()
        } else {
            let subs: HashMap<Symbol, TDim> = self
                .symbols
                .iter()
                .zip(key)
                .map(|((s, _, _), &v)| (s.clone(), TDim::Val(v as i64)))
                .collect();
            self.typed.set_symbols(&subs).with_context(what)?
        };
        let plan = optimise(model).with_context(what)?;
        Ok(Plan::new(plan))
    }

    /// The plan for the sizes of `inputs` and the row count it runs: its own size's plan, else
    /// (once prepared) the plan of the next prepared row count ([`TRACT_ROW_BUCKETS`]; the run is
    /// padded to it), else the symbolic one once prepared, else one optimised now (outside the
    /// table's lock; a plan built by two threads at once is kept once).
    fn plan_for(&self, inputs: &[LgTensor], batch: usize) -> Result<(Arc<Plan>, usize)> {
        let key = self.key_of(inputs);
        if let Some(p) = lock(&self.plans).get(&key) {
            return Ok((Arc::clone(p), batch));
        }
        if let Some(p) = lock(&self.symbolic).as_ref() {
            let padded = self.paddable().then(|| row_bucket(batch)).flatten();
            if let Some(rows) = padded {
                if let Some(b) = lock(&self.plans).get(&vec![rows]) {
                    return Ok((Arc::clone(b), rows));
                }
            }
            return Ok((Arc::clone(p), batch));
        }
        let built = Arc::new(self.build(&key)?);
        Ok((
            Arc::clone(lock(&self.plans).entry(key).or_insert(built)),
            batch,
        ))
    }
}

/// `t` as a tract tensor of `rows` rows (its batch axis first): the missing rows are copies of its
/// last row.
fn to_tract_padded(t: &LgTensor, rows: usize) -> Result<TValue> {
    let (have, row) = (t.batch(), t.row_len());
    if rows == have || have == 0 {
        return to_tract(t);
    }
    let mut shape = t.shape.clone();
    shape[0] = rows;
    fn pad<T: Copy>(v: &[T], row: usize, rows: usize) -> Vec<T> {
        let mut out = Vec::with_capacity(rows * row);
        out.extend_from_slice(v);
        let last = &v[v.len() - row..];
        while out.len() < rows * row {
            out.extend_from_slice(last);
        }
        out
    }
    let tensor = match &t.data {
        TensorData::F32(v) => tract_onnx::prelude::Tensor::from_shape(&shape, &pad(v, row, rows))?,
        TensorData::I64(v) => tract_onnx::prelude::Tensor::from_shape(&shape, &pad(v, row, rows))?,
    };
    Ok(tensor.into())
}

fn to_tract(t: &LgTensor) -> Result<TValue> {
    let tensor = match &t.data {
        TensorData::F32(v) => tract_onnx::prelude::Tensor::from_shape(&t.shape, v)?,
        TensorData::I64(v) => tract_onnx::prelude::Tensor::from_shape(&t.shape, v)?,
    };
    Ok(tensor.into())
}

/// The tract value `v` as a tensor of dtype `want`; with `rows`, only its first `rows` rows (a padded
/// run's own rows; the batch axis first).
fn from_tract(v: &TValue, want: DType, what: &str, rows: Option<usize>) -> Result<LgTensor> {
    let mut shape = v.shape().to_vec();
    let keep = match rows {
        Some(r) if shape.first().is_some_and(|&b| b > r) => {
            let row: usize = shape[1..].iter().product();
            shape[0] = r;
            Some(r * row)
        }
        _ => None,
    };
    fn take<T: Datum + Copy>(
        v: &TValue,
        what: &str,
        kind: &str,
        keep: Option<usize>,
    ) -> Result<Vec<T>> {
        let a = v
            .to_plain_array_view::<T>()
            .with_context(|| format!("{what}: expected {kind}"))?;
        // a contiguous view (the usual case) is one memcpy, not an element iterator
        Ok(match a.as_slice() {
            Some(s) => s[..keep.unwrap_or(s.len())].to_vec(),
            None => a.iter().copied().take(keep.unwrap_or(usize::MAX)).collect(),
        })
    }
    match want {
        DType::F32 => LgTensor::f32(shape, take::<f32>(v, what, "float32", keep)?),
        DType::I64 => LgTensor::i64(shape, take::<i64>(v, what, "int64", keep)?),
    }
}

impl GraphRunner for TractGraph {
    fn spec(&self) -> &GraphSpec {
        &self.spec
    }

    /// Builds the plans of the row counts of [`TRACT_ROW_BUCKETS`] that runs of the batch sizes in
    /// `sizes` will use (a graph whose only symbol is the batch, with it first everywhere; else the
    /// sizes up to 2 rows), and one plan with the symbols left symbolic for every other size: no
    /// run afterwards optimises a plan (0.1-0.2 s on a new size).
    fn prepare_batches(&self, sizes: &[usize]) -> Result<()> {
        if self.symbols.len() == 1 {
            let mut want: Vec<usize> = if self.paddable() {
                sizes.iter().filter_map(|&b| row_bucket(b)).collect()
            } else {
                sizes.iter().copied().filter(|&b| b <= 2).collect()
            };
            want.sort_unstable();
            want.dedup();
            for b in want {
                if !lock(&self.plans).contains_key(&vec![b]) {
                    let plan = Arc::new(self.build(&[b])?);
                    lock(&self.plans).entry(vec![b]).or_insert(plan);
                }
            }
        }
        if lock(&self.symbolic).is_none() && !self.symbols.is_empty() {
            let what = || {
                format!(
                    "tract: optimising graph '{}' ({}) with symbolic sizes",
                    self.spec.name, self.path
                )
            };
            let plan = optimise(self.typed.clone()).with_context(what)?;
            lock(&self.symbolic).get_or_insert_with(|| Arc::new(Plan::new(plan)));
        }
        Ok(())
    }

    fn run(&self, inputs: &[LgTensor]) -> Result<Vec<LgTensor>> {
        let batch = check_inputs(&self.spec, inputs)?;
        let (plan, rows) = self.plan_for(inputs, batch)?;
        let tv: TVec<TValue> = if rows == batch {
            inputs.iter().map(to_tract).collect::<Result<_>>()?
        } else {
            inputs
                .iter()
                .zip(&self.batched_inputs)
                .map(|(t, &b)| {
                    if b {
                        to_tract_padded(t, rows)
                    } else {
                        to_tract(t)
                    }
                })
                .collect::<Result<_>>()?
        };
        let name = &self.spec.name;
        let outs = plan
            .states
            .with(
                || {
                    plan.plan.spawn().with_context(|| {
                        format!("tract: a run state for graph '{name}' ({})", self.path)
                    })
                },
                |state| super::flush_denormals(|| state.run(tv)),
            )
            .with_context(|| format!("tract: running graph '{name}' (batch {batch})"))?;
        let specs = self.spec.all_outputs();
        ensure!(
            outs.len() == specs.len(),
            "tract: graph '{name}' returned {} outputs, expected {}",
            outs.len(),
            specs.len()
        );
        let out = outs
            .iter()
            .zip(specs)
            .enumerate()
            .map(|(k, (v, (oname, dtype, _)))| {
                let cut = (rows != batch && self.batched_outputs[k]).then_some(batch);
                from_tract(v, dtype, &format!("graph '{name}' output '{oname}'"), cut)
            })
            .collect::<Result<Vec<_>>>()?;
        check_outputs(&self.spec, &out, batch)?;
        Ok(out)
    }
}

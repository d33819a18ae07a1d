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
use crate::bundle::GraphSpec;

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

/// Batch sizes (rows) up to which [`GraphRunner::prepare_batches`] optimises a plan per size;
/// larger ones run on one plan with the batch left symbolic. A per-size plan runs 10-20% faster than
/// the symbolic one at 8-64 rows, but holds its own packed weights (the default bundle: about 34 MiB
/// per size) and takes 0.1-0.2 s to optimise: one per size up to 64 sessions would be 2 GiB. One
/// stream alone (1 row, 2 with guidance) keeps its per-size plans.
pub const TRACT_PREPARED_ROWS: usize = 2;

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
        Ok(Self {
            spec: spec.clone(),
            path: path.display().to_string(),
            typed,
            symbols,
            plans: Mutex::default(),
            symbolic: Mutex::default(),
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
        let plan = model
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .with_context(what)?;
        Ok(Plan::new(plan))
    }

    /// The plan for the sizes of `inputs`: its own, else the symbolic one once prepared, else one
    /// optimised now (outside the table's lock; a plan built by two threads at once is kept once).
    fn plan_for(&self, inputs: &[LgTensor]) -> Result<Arc<Plan>> {
        let key = self.key_of(inputs);
        if let Some(p) = lock(&self.plans).get(&key) {
            return Ok(Arc::clone(p));
        }
        if let Some(p) = lock(&self.symbolic).as_ref() {
            return Ok(Arc::clone(p));
        }
        let built = Arc::new(self.build(&key)?);
        Ok(Arc::clone(lock(&self.plans).entry(key).or_insert(built)))
    }
}

fn to_tract(t: &LgTensor) -> Result<TValue> {
    let tensor = match &t.data {
        TensorData::F32(v) => tract_onnx::prelude::Tensor::from_shape(&t.shape, v)?,
        TensorData::I64(v) => tract_onnx::prelude::Tensor::from_shape(&t.shape, v)?,
    };
    Ok(tensor.into())
}

fn from_tract(v: &TValue, want: DType, what: &str) -> Result<LgTensor> {
    let shape = v.shape().to_vec();
    match want {
        DType::F32 => {
            let a = v
                .to_plain_array_view::<f32>()
                .with_context(|| format!("{what}: expected float32"))?;
            // a contiguous view (the usual case) is one memcpy, not an element iterator
            let data = a
                .as_slice()
                .map_or_else(|| a.iter().copied().collect(), <[f32]>::to_vec);
            LgTensor::f32(shape, data)
        }
        DType::I64 => {
            let a = v
                .to_plain_array_view::<i64>()
                .with_context(|| format!("{what}: expected int64"))?;
            let data = a
                .as_slice()
                .map_or_else(|| a.iter().copied().collect(), <[i64]>::to_vec);
            LgTensor::i64(shape, data)
        }
    }
}

impl GraphRunner for TractGraph {
    fn spec(&self) -> &GraphSpec {
        &self.spec
    }

    /// Builds the plans of the batch sizes in `sizes` up to [`TRACT_PREPARED_ROWS`] (a graph whose
    /// only symbol is the batch), and one plan with the symbols left symbolic that every other size
    /// runs on from now on: no run afterwards optimises a plan (0.1-0.2 s on a new batch size).
    fn prepare_batches(&self, sizes: &[usize]) -> Result<()> {
        if self.symbols.len() == 1 {
            for &b in sizes.iter().filter(|&&b| b <= TRACT_PREPARED_ROWS) {
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
            let plan = self
                .typed
                .clone()
                .into_optimized()
                .and_then(|m| m.into_runnable())
                .with_context(what)?;
            lock(&self.symbolic).get_or_insert_with(|| Arc::new(Plan::new(plan)));
        }
        Ok(())
    }

    fn run(&self, inputs: &[LgTensor]) -> Result<Vec<LgTensor>> {
        let batch = check_inputs(&self.spec, inputs)?;
        let tv: TVec<TValue> = inputs.iter().map(to_tract).collect::<Result<_>>()?;
        let name = &self.spec.name;
        let plan = self.plan_for(inputs)?;
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
            .map(|(v, (oname, dtype, _))| {
                from_tract(v, dtype, &format!("graph '{name}' output '{oname}'"))
            })
            .collect::<Result<Vec<_>>>()?;
        check_outputs(&self.spec, &out, batch)?;
        Ok(out)
    }
}

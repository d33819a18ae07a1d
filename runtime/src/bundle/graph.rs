//! The manifest's description of a step graph: its tensors, its caches and their shapes.

use std::fmt;

use serde::{Deserialize, Deserializer, Serialize};
use serde_json::Value;

use crate::tensor::{DType, Tensor};

/// One dimension of a tensor in the manifest: the dynamic batch axis, a fixed size, or another named
/// dynamic axis.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Dim {
    /// The dynamic batch axis (written `"batch"` in the manifest).
    Batch,
    /// A fixed size.
    Fixed(usize),
    /// Another dynamic axis, written as its name (DiffSHEG's `frames`: the length of a window); its
    /// size comes with each run. Caches and LiveGesture graphs have none (checked at load).
    Named(String),
}

impl Dim {
    /// True when an actual size fits: the batch axis must be `batch`, a fixed size itself, a named
    /// axis any size.
    pub fn fits(&self, actual: usize, batch: usize) -> bool {
        match self {
            Dim::Batch => actual == batch,
            Dim::Fixed(n) => actual == *n,
            Dim::Named(_) => true,
        }
    }
}

impl<'de> Deserialize<'de> for Dim {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        match Value::deserialize(d)? {
            Value::String(s) if s == "batch" => Ok(Dim::Batch),
            Value::String(s) if !s.is_empty() => Ok(Dim::Named(s)),
            Value::Number(n) => n
                .as_u64()
                .map(|n| Dim::Fixed(n as usize))
                .ok_or_else(|| serde::de::Error::custom(format!("dimension {n} is not a size"))),
            other => Err(serde::de::Error::custom(format!(
                "dimension {other} is neither a size nor the name of an axis such as \"batch\""
            ))),
        }
    }
}

impl Serialize for Dim {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Dim::Batch => s.serialize_str("batch"),
            Dim::Fixed(n) => s.serialize_u64(*n as u64),
            Dim::Named(n) => s.serialize_str(n),
        }
    }
}

impl fmt::Display for Dim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Dim::Batch => f.write_str("batch"),
            Dim::Fixed(n) => write!(f, "{n}"),
            Dim::Named(n) => f.write_str(n),
        }
    }
}

/// True when `actual` is a shape of `shape` for batch size `batch` (same rank, every axis fits).
pub fn shape_fits(shape: &[Dim], actual: &[usize], batch: usize) -> bool {
    shape.len() == actual.len() && shape.iter().zip(actual).all(|(d, &a)| d.fits(a, batch))
}

/// True when the shape has a named dynamic axis besides the batch.
pub fn has_named_axis(shape: &[Dim]) -> bool {
    shape.iter().any(|d| matches!(d, Dim::Named(_)))
}

/// A shape as the manifest writes it, e.g. `[batch, 4, 32]`.
pub fn shape_string(shape: &[Dim]) -> String {
    let v: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    format!("[{}]", v.join(", "))
}

/// A tensor's shape with the batch axis set to `batch`. For shapes without named axes (caches,
/// LiveGesture graphs); a named axis counts as 0 here (check such shapes with [`shape_fits`]).
pub fn concrete_shape(shape: &[Dim], batch: usize) -> Vec<usize> {
    shape
        .iter()
        .map(|d| match d {
            Dim::Batch => batch,
            Dim::Fixed(n) => *n,
            Dim::Named(_) => 0,
        })
        .collect()
}

/// The product of the fixed dimensions.
fn fixed_product(shape: &[Dim]) -> usize {
    shape
        .iter()
        .map(|d| match d {
            Dim::Fixed(n) => *n,
            Dim::Batch | Dim::Named(_) => 1,
        })
        .product()
}

/// A data input or output of a graph.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct TensorSpec {
    pub name: String,
    pub dtype: DType,
    pub shape: Vec<Dim>,
}

impl TensorSpec {
    /// Elements per batch row (product of the fixed dimensions; named axes not counted).
    pub fn row_len(&self) -> usize {
        fixed_product(&self.shape)
    }
}

/// A cache of a step graph: fed as `input`, returned updated as `output`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct CacheSpec {
    pub name: String,
    pub input: String,
    pub output: String,
    pub dtype: DType,
    pub shape: Vec<Dim>,
    #[serde(default = "zeros_init")]
    pub init: String,
    /// Present for a ring cache (docs/bundle.md#ring-caches): the graph reads the cache and returns
    /// only its new entry, of this shape (the cache's with axis -2 of size 1), which the caller
    /// writes into slot `phase mod (slots)` of axis -2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub output_shape: Option<Vec<Dim>>,
}

fn zeros_init() -> String {
    "zeros".into()
}

impl CacheSpec {
    /// Elements per batch row.
    pub fn row_len(&self) -> usize {
        fixed_product(&self.shape)
    }

    /// Bytes per batch row.
    pub fn row_bytes(&self) -> usize {
        self.row_len() * self.dtype.size()
    }

    /// True for a ring cache: the graph returns its new entry ([`CacheSpec::output_shape`]).
    pub fn is_ring(&self) -> bool {
        self.output_shape.is_some()
    }

    /// The shape of the graph's output for this cache: the new entry of a ring cache, else the
    /// cache's shape.
    pub fn output_shape(&self) -> &[Dim] {
        self.output_shape.as_deref().unwrap_or(&self.shape)
    }

    /// Stores the graph's output `out` for this cache into `cache` (`phase`: the write position the
    /// graph ran at): a ring cache gets the new entry written into slot `phase mod (slots)` of axis
    /// -2 of every row; any other cache is replaced by `out`.
    pub fn store_output(&self, cache: &mut Tensor, out: Tensor, phase: u64) -> anyhow::Result<()> {
        if !self.is_ring() {
            *cache = out;
            return Ok(());
        }
        let rows = out.batch();
        let slot = ring_slot(cache, phase)?;
        cache.write_slot(0, &out, 0, rows, slot)
    }

    /// The initial cache for `batch` rows: zeros of the manifest's shape and dtype.
    pub fn zeros(&self, batch: usize) -> Tensor {
        Tensor::zeros(self.dtype, concrete_shape(&self.shape, batch))
    }
}

/// The slot of axis -2 of a ring cache that the entry of a step at `phase` goes to.
pub fn ring_slot(cache: &Tensor, phase: u64) -> anyhow::Result<usize> {
    let r = cache.shape.len();
    anyhow::ensure!(
        r >= 3 && cache.shape[r - 2] > 0,
        "a ring cache has a batch axis and a slot axis (-2) before its last, got shape {:?}",
        cache.shape
    );
    Ok((phase % cache.shape[r - 2] as u64) as usize)
}

/// One step graph of the bundle.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct GraphSpec {
    pub name: String,
    pub file: String,
    #[serde(default)]
    pub component: Option<String>,
    #[serde(default)]
    pub region: Option<String>,
    pub inputs: Vec<TensorSpec>,
    pub outputs: Vec<TensorSpec>,
    pub caches: Vec<CacheSpec>,
    #[serde(default)]
    pub reference: Option<String>,
}

impl GraphSpec {
    /// All input names in graph order: data inputs, then cache inputs.
    pub fn input_names(&self) -> Vec<&str> {
        self.inputs
            .iter()
            .map(|i| i.name.as_str())
            .chain(self.caches.iter().map(|c| c.input.as_str()))
            .collect()
    }

    /// All output names in graph order: data outputs, then cache outputs.
    pub fn output_names(&self) -> Vec<&str> {
        self.outputs
            .iter()
            .map(|o| o.name.as_str())
            .chain(self.caches.iter().map(|c| c.output.as_str()))
            .collect()
    }

    /// `(name, dtype, shape)` of every input in graph order.
    pub fn all_inputs(&self) -> Vec<(&str, DType, &[Dim])> {
        self.inputs
            .iter()
            .map(|i| (i.name.as_str(), i.dtype, i.shape.as_slice()))
            .chain(
                self.caches
                    .iter()
                    .map(|c| (c.input.as_str(), c.dtype, c.shape.as_slice())),
            )
            .collect()
    }

    /// `(name, dtype, shape)` of every output in graph order.
    pub fn all_outputs(&self) -> Vec<(&str, DType, &[Dim])> {
        self.outputs
            .iter()
            .map(|o| (o.name.as_str(), o.dtype, o.shape.as_slice()))
            .chain(
                self.caches
                    .iter()
                    .map(|c| (c.output.as_str(), c.dtype, c.output_shape())),
            )
            .collect()
    }

    /// True for a graph on ring caches (docs/bundle.md#ring-caches): it reads a `phase` input and
    /// returns the new entries of its ring caches.
    pub fn is_ring(&self) -> bool {
        self.caches.iter().any(CacheSpec::is_ring)
    }

    /// Cache bytes per batch row.
    pub fn cache_row_bytes(&self) -> usize {
        self.caches.iter().map(CacheSpec::row_bytes).sum()
    }

    /// The caches after one step of this graph run standalone (a reference chain: the parity
    /// checks), given its `inputs` in graph order (data inputs, then the caches it read) and its
    /// `outputs` in graph order. A graph on ring caches (docs/bundle.md#ring-caches) gets each
    /// new entry written into the cache it read at the step's phase (its `phase` input, the same in
    /// every row; read from row 0), and the cache outputs of `outputs` are replaced by the caches
    /// after the write, so that what is compared and chained is a whole cache either way; any
    /// other graph's caches are its cache outputs.
    pub fn chain_caches(
        &self,
        mut inputs: Vec<Tensor>,
        outputs: &mut [Tensor],
    ) -> anyhow::Result<Vec<Tensor>> {
        use anyhow::Context as _;
        let n_data = self.inputs.len();
        let n_out = self.outputs.len();
        anyhow::ensure!(
            inputs.len() == n_data + self.caches.len() && outputs.len() == n_out + self.caches.len(),
            "graph '{}': {} inputs and {} outputs for {} data inputs, {} data outputs and {} caches",
            self.name,
            inputs.len(),
            outputs.len(),
            n_data,
            n_out,
            self.caches.len()
        );
        let Some(k) = self.input_index("phase").filter(|_| self.is_ring()) else {
            return Ok(outputs[n_out..].to_vec());
        };
        let phase = *inputs[k]
            .as_i64("phase")?
            .first()
            .with_context(|| format!("graph '{}': its phase input has no rows", self.name))?;
        let phase = u64::try_from(phase)
            .with_context(|| format!("graph '{}': a negative ring phase {phase}", self.name))?;
        let mut caches = inputs.split_off(n_data);
        for (j, c) in self.caches.iter().enumerate() {
            let o = std::mem::take(&mut outputs[n_out + j]);
            c.store_output(&mut caches[j], o, phase)
                .with_context(|| format!("graph '{}', cache '{}'", self.name, c.name))?;
            outputs[n_out + j] = caches[j].clone();
        }
        Ok(caches)
    }

    /// Index of the data input `name`.
    pub fn input_index(&self, name: &str) -> Option<usize> {
        self.inputs.iter().position(|i| i.name == name)
    }

    /// Index of the data output `name`.
    pub fn output_index(&self, name: &str) -> Option<usize> {
        self.outputs.iter().position(|o| o.name == name)
    }
}

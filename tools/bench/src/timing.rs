//! Timing every graph run ([`TimingBackend`]) and order statistics of the times ([`Stats`]).

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::Result;
use serde::Serialize;

use livegesture::backend::{Backend, GraphRunner, Tensor};
use livegesture::bundle::GraphSpec;

/// Times of the graph runs since the last [`Recorder::drain`]: `(graph index, seconds)`.
#[derive(Debug, Default)]
pub struct Recorder {
    names: Mutex<Vec<String>>,
    events: Mutex<Vec<(usize, f64)>>,
}

impl Recorder {
    fn register(&self, name: &str) -> usize {
        let mut n = self.names.lock().unwrap_or_else(|e| e.into_inner());
        n.push(name.to_string());
        n.len() - 1
    }

    fn record(&self, id: usize, secs: f64) {
        self.events
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((id, secs));
    }

    /// Graph names by index.
    pub fn names(&self) -> Vec<String> {
        self.names.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Takes the recorded events.
    pub fn drain(&self) -> Vec<(usize, f64)> {
        std::mem::take(&mut *self.events.lock().unwrap_or_else(|e| e.into_inner()))
    }
}

/// A backend that times every graph run of the backend it wraps.
pub struct TimingBackend<'a> {
    inner: &'a dyn Backend,
    rec: Arc<Recorder>,
}

impl<'a> TimingBackend<'a> {
    /// Wraps `inner`; run times go to `rec`.
    pub fn new(inner: &'a dyn Backend, rec: Arc<Recorder>) -> Self {
        Self { inner, rec }
    }
}

struct TimedRunner {
    inner: Box<dyn GraphRunner>,
    id: usize,
    rec: Arc<Recorder>,
}

impl GraphRunner for TimedRunner {
    fn spec(&self) -> &GraphSpec {
        self.inner.spec()
    }

    fn run(&self, inputs: &[Tensor]) -> Result<Vec<Tensor>> {
        let t0 = Instant::now();
        let out = self.inner.run(inputs);
        self.rec.record(self.id, t0.elapsed().as_secs_f64());
        out
    }

    fn run_into(&self, inputs: &[Tensor], outputs: &mut Vec<Tensor>) -> Result<()> {
        let t0 = Instant::now();
        let out = self.inner.run_into(inputs, outputs);
        self.rec.record(self.id, t0.elapsed().as_secs_f64());
        out
    }
}

impl Backend for TimingBackend<'_> {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn load(&self, spec: &GraphSpec, path: &Path) -> Result<Box<dyn GraphRunner>> {
        let inner = self.inner.load(spec, path)?;
        Ok(Box::new(TimedRunner {
            inner,
            id: self.rec.register(&spec.name),
            rec: self.rec.clone(),
        }))
    }
}

/// Order statistics of a sample of times, in milliseconds.
#[derive(Debug, Clone, Serialize)]
pub struct Stats {
    pub n: usize,
    pub median: f64,
    pub p95: f64,
    pub p99: f64,
    pub mean: f64,
    pub min: f64,
    pub max: f64,
}

/// The `p`-th percentile ([`livegesture::stats::quantile`], the loadtest's too); NaN for no values.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    livegesture::stats::quantile(sorted, p / 100.0).unwrap_or(f64::NAN)
}

impl Stats {
    /// Statistics of `ms` (milliseconds).
    pub fn of(ms: &[f64]) -> Stats {
        let mut s = ms.to_vec();
        s.sort_by(f64::total_cmp);
        Stats {
            n: s.len(),
            median: percentile(&s, 50.0),
            p95: percentile(&s, 95.0),
            p99: percentile(&s, 99.0),
            mean: if s.is_empty() {
                f64::NAN
            } else {
                s.iter().sum::<f64>() / s.len() as f64
            },
            min: s.first().copied().unwrap_or(f64::NAN),
            max: s.last().copied().unwrap_or(f64::NAN),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_match_numpy() {
        let s = Stats::of(&[4.0, 1.0, 3.0, 2.0, 5.0]);
        assert_eq!(s.median, 3.0);
        assert!((s.p95 - 4.8).abs() < 1e-12);
        assert_eq!(s.min, 1.0);
        assert_eq!(s.max, 5.0);
    }
}

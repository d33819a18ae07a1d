//! The manifest sections only a LiveGesture bundle has: `regions`, `vocab` and `sampling`.
//!
//! They are required (and checked) when the manifest's `family` is `livegesture` and ignored
//! otherwise. The manifest's `pipeline` object (the chain order, as prose for readers) is not read:
//! the chain is fixed by the LiveGesture implementation (`model::livegesture`), whose graph roles are
//! checked against the graphs' inputs when the model loads.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::Manifest;

/// One part of a region's feature vector (`rot6d`, `trans`, `foot_contact`, `expressions`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct RegionPart {
    pub name: String,
    #[serde(default)]
    pub joints: Option<Vec<usize>>,
    pub offset: usize,
    pub dim: usize,
}

/// A body region and the layout of its feature vector.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct RegionSpec {
    pub name: String,
    pub dim: usize,
    pub joints: Vec<usize>,
    pub parts: Vec<RegionPart>,
}

impl RegionSpec {
    /// The part called `name`, if the region has it.
    pub fn part(&self, name: &str) -> Option<&RegionPart> {
        self.parts.iter().find(|p| p.name == name)
    }
}

/// Token vocabulary.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct Vocab {
    pub codebook_size: usize,
    pub bos_token: i64,
    #[serde(default)]
    pub mask_token: Option<i64>,
}

/// Sampling defaults of the bundle.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct SamplingDefaults {
    /// Classifier-free guidance scale gamma (1.0 disables guidance).
    pub guidance: f64,
    pub temperature: f64,
    /// Top-k (0 = all).
    pub top_k: usize,
    #[serde(default)]
    pub region_order: Vec<String>,
    #[serde(default)]
    pub prng: Option<String>,
}

/// One form of the chain's components (docs/bundle.md#forms-and-precision): which graphs compute the region eXperts, the
/// fusion and the region SVQ decoders.
///
/// `canonical`: one `expert_<region>` and one `decoder_<region>` graph per region, in region order.
/// `fused`: one graph (`experts_fused`) computing all eXperts on a region axis: `prev_token`
/// `(batch, regions)`, `hidden` `(batch, regions, d_model)`, caches of the canonical names stacked
/// on axis 1; and one graph (`decoders_fused`) computing all decoders with the regions side by side:
/// `token` `(batch, regions)`, `motion` `(batch, frames_per_token, sum of the region dims)` (region
/// `r` at the columns after the dims of the regions before it), caches of the canonical names with
/// the regions' channels side by side on the last axis.
/// `attention`: the canonical eXperts and decoders and the fusion graph `fusion_attention`, the
/// canonical fusion's inputs, outputs and caches with its attention cores as the opset-23 ONNX
/// `Attention` op (the form tract runs fastest).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct FormSpec {
    /// The graphs running the region eXperts in this form.
    pub experts: Vec<String>,
    /// The graphs running the region SVQ decoders in this form; empty (bundles exported before the
    /// fused decoders): the canonical `decoder_<region>` graphs.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub decoders: Vec<String>,
    /// The graph running the fusion in this form; absent (every form before `attention`): the
    /// canonical `fusion`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fusion: Option<String>,
}

/// The graphs of one form, resolved ([`LiveGestureManifest::form_graphs`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FormGraphs {
    /// The region eXperts: one graph per region, or one for all.
    pub experts: Vec<String>,
    /// The region SVQ decoders: one graph per region, or one for all.
    pub decoders: Vec<String>,
    /// The fusion graph.
    pub fusion: String,
}

/// The canonical fusion graph's name.
pub const FUSION: &str = "fusion";

/// The form names the runtime knows.
pub const FORMS: [&str; 3] = ["canonical", "fused", "attention"];

/// The LiveGesture sections of `manifest.json` (see the module docs).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct LiveGestureManifest {
    /// Regions in the chain's order (also the sampling order).
    pub regions: Vec<RegionSpec>,
    pub vocab: Vocab,
    pub sampling: SamplingDefaults,
    /// The forms the bundle carries (docs/bundle.md#forms-and-precision), by name; absent: the canonical form only.
    #[serde(default)]
    pub forms: BTreeMap<String, FormSpec>,
    /// The form each backend runs by default (`ort`, `tract`); absent: canonical.
    #[serde(default)]
    pub backend_forms: BTreeMap<String, String>,
}

impl LiveGestureManifest {
    /// Region names in order.
    pub fn region_names(&self) -> Vec<&str> {
        self.regions.iter().map(|r| r.name.as_str()).collect()
    }

    /// Names of the graphs the LiveGesture chain needs: `audio_encoder`, `expert_<region>`,
    /// `fusion`, `decoder_<region>`.
    pub fn graph_names(&self) -> Vec<String> {
        let mut wanted = vec!["audio_encoder".to_string(), "fusion".to_string()];
        for r in &self.regions {
            wanted.push(format!("expert_{}", r.name));
            wanted.push(format!("decoder_{}", r.name));
        }
        wanted
    }

    /// The forms of the bundle's region eXperts: the manifest's `forms`, with `canonical` (the
    /// `expert_<region>` graphs) when it does not list it.
    pub fn expert_forms(&self) -> BTreeMap<String, Vec<String>> {
        self.form_graphs()
            .into_iter()
            .map(|(k, f)| (k, f.experts))
            .collect()
    }

    /// The canonical graphs of one kind (`expert`, `decoder`): `<kind>_<region>` in region order.
    fn canonical_graphs(&self, kind: &str) -> Vec<String> {
        self.regions
            .iter()
            .map(|r| format!("{kind}_{}", r.name))
            .collect()
    }

    /// The bundle's forms with their graphs: the manifest's `forms`, with `canonical` when it does
    /// not list it, the canonical `decoder_<region>` graphs for a form that lists no decoders
    /// (bundles exported before the fused decoders) and the canonical `fusion` for a form that
    /// names no fusion (bundles exported before the attention form).
    pub fn form_graphs(&self) -> BTreeMap<String, FormGraphs> {
        let mut out: BTreeMap<String, FormGraphs> = self
            .forms
            .iter()
            .map(|(k, f)| {
                let decoders = if f.decoders.is_empty() {
                    self.canonical_graphs("decoder")
                } else {
                    f.decoders.clone()
                };
                (
                    k.clone(),
                    FormGraphs {
                        experts: f.experts.clone(),
                        decoders,
                        fusion: f.fusion.clone().unwrap_or_else(|| FUSION.to_string()),
                    },
                )
            })
            .collect();
        out.entry("canonical".into()).or_insert_with(|| FormGraphs {
            experts: self.canonical_graphs("expert"),
            decoders: self.canonical_graphs("decoder"),
            fusion: FUSION.to_string(),
        });
        out
    }

    /// The form `backend` runs by default: the manifest's `backend_forms`, else canonical.
    pub fn default_form(&self, backend: &str) -> &str {
        self.backend_forms
            .get(backend)
            .map(String::as_str)
            .unwrap_or("canonical")
    }

    /// The SVQ decoders `backend` runs with the form it runs by default ([`Self::default_form`],
    /// `--form auto`): that form's own, except that **tract runs the bundle's fused decoders**
    /// (`decoders_fused`, the one graph of a form that lists a single decoder graph) in place of
    /// per-region ones when the bundle has them. The decoders run after sampling, so the tokens are
    /// those of the form's own decoders, and the frames too (one stream: bit-identical on the tiny
    /// bundle; stacked streams: within the batch bound); on tract the one graph takes 0.50-0.76x the
    /// four's time (BENCHMARKS.md, "tract's fastest form per graph"). A form named explicitly
    /// (`--form`) runs its own decoders. Empty when the default form is not in the bundle.
    pub fn default_decoders(&self, backend: &str) -> Vec<String> {
        let forms = self.form_graphs();
        let own = forms
            .get(self.default_form(backend))
            .map(|f| f.decoders.clone())
            .unwrap_or_default();
        if backend == "tract" && own.len() > 1 {
            if let Some(f) = forms.values().find(|f| f.decoders.len() == 1) {
                return f.decoders.clone();
            }
        }
        own
    }

    /// Checks the sections against themselves and the common part; the error says what is wrong.
    pub(super) fn check(&self, m: &Manifest) -> Result<(), String> {
        if self.regions.is_empty() {
            return Err("no regions".into());
        }
        let names = self.region_names();
        if !self.sampling.region_order.is_empty() && self.sampling.region_order != names {
            return Err(format!(
                "sampling.region_order {:?} differs from the regions {:?}",
                self.sampling.region_order, names
            ));
        }
        for r in &self.regions {
            for p in &r.parts {
                if p.offset + p.dim > r.dim {
                    return Err(format!(
                        "region '{}': part '{}' ends at {} beyond the region's {} dims",
                        r.name,
                        p.name,
                        p.offset + p.dim,
                        r.dim
                    ));
                }
            }
        }
        for w in self.graph_names() {
            if !m.graphs.iter().any(|g| g.name == w) {
                return Err(format!("no graph named '{w}'"));
            }
        }
        for g in &m.graphs {
            for (name, _, shape) in g.all_inputs().into_iter().chain(g.all_outputs()) {
                if super::has_named_axis(shape) {
                    return Err(format!(
                        "graph '{}': tensor '{name}' has a named dynamic axis ({}); LiveGesture graphs have only the batch axis dynamic",
                        g.name,
                        super::shape_string(shape)
                    ));
                }
            }
        }
        for (name, f) in &self.forms {
            if !FORMS.contains(&name.as_str()) {
                return Err(format!(
                    "forms: unknown form '{name}' (this runtime knows {FORMS:?})"
                ));
            }
            let want = if name == "fused" {
                1
            } else {
                self.regions.len()
            };
            // `decoders` may be absent (empty): the canonical decoders
            for (field, graphs, allowed) in [
                ("experts", &f.experts, &[want][..]),
                ("decoders", &f.decoders, &[0, want][..]),
            ] {
                if !allowed.contains(&graphs.len()) {
                    return Err(format!(
                        "forms.{name}.{field} lists {} graphs, expected {want}",
                        graphs.len()
                    ));
                }
                for g in graphs {
                    if !m.graphs.iter().any(|x| &x.name == g) {
                        return Err(format!("forms.{name}.{field}: no graph named '{g}'"));
                    }
                }
            }
            if let Some(g) = &f.fusion {
                if !m.graphs.iter().any(|x| &x.name == g) {
                    return Err(format!("forms.{name}.fusion: no graph named '{g}'"));
                }
            }
        }
        for (backend, form) in &self.backend_forms {
            if form != "canonical" && !self.forms.contains_key(form) {
                return Err(format!(
                    "backend_forms.{backend} is '{form}', which is not in forms"
                ));
            }
        }
        if self.vocab.bos_token < 0 {
            return Err("vocab.bos_token is negative".into());
        }
        let s = &self.sampling;
        if s.temperature.is_nan() || s.temperature <= 0.0 || !s.guidance.is_finite() {
            return Err(format!(
                "sampling defaults out of range (guidance {}, temperature {})",
                s.guidance, s.temperature
            ));
        }
        Ok(())
    }
}

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

/// SMPL-X joints in a frame (docs/motion.md).
const SMPLX_JOINTS: usize = 55;
/// The eye joints, which belong to no region and are output at rest (docs/motion.md).
const EYE_JOINTS: [usize; 2] = [23, 24];
/// The frame fields outside `poses` that exactly one region holds (docs/motion.md), by part name.
const FRAME_PARTS: [&str; 3] = ["trans", "foot_contact", "expressions"];

/// Joint numbers as ranges: `[0, 1, 2, 25, 26, 27]` -> `"0-2, 25-27"`.
fn joint_ranges(joints: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while i < joints.len() {
        let mut j = i;
        while j + 1 < joints.len() && joints[j + 1] == joints[j] + 1 {
            j += 1;
        }
        out.push(if i == j {
            joints[i].to_string()
        } else {
            format!("{}-{}", joints[i], joints[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

/// Checks that `regions` cover the SMPL-X frame as docs/motion.md describes, whatever the region set
/// (the four regions, the full-body SVQ's one region, ...): every joint but the eyes in exactly one
/// region's `rot6d` part, the eyes in none, and exactly one `trans`, `foot_contact` and
/// `expressions` part among all regions. The error names what is missing or held twice.
pub fn check_coverage(regions: &[RegionSpec]) -> Result<(), String> {
    let mut owner: Vec<Option<&str>> = vec![None; SMPLX_JOINTS];
    let mut holders: BTreeMap<&str, Vec<&str>> =
        FRAME_PARTS.iter().map(|&p| (p, Vec::new())).collect();
    for r in regions {
        for p in &r.parts {
            match p.name.as_str() {
                "rot6d" => {
                    for &j in p.joints.as_ref().unwrap_or(&r.joints) {
                        if j >= SMPLX_JOINTS {
                            return Err(format!(
                                "region '{}': joint {j} does not exist (SMPL-X has {SMPLX_JOINTS})",
                                r.name
                            ));
                        }
                        if EYE_JOINTS.contains(&j) {
                            return Err(format!(
                                "region '{}': joint {j} is an eye, which belongs to no region (output at rest)",
                                r.name
                            ));
                        }
                        if let Some(o) = owner[j] {
                            return Err(format!(
                                "joint {j} is in two regions' rot6d parts ('{o}' and '{}')",
                                r.name
                            ));
                        }
                        owner[j] = Some(&r.name);
                    }
                }
                "contact" => holders.get_mut("foot_contact").unwrap().push(&r.name),
                other => {
                    if let Some(h) = holders.get_mut(other) {
                        h.push(&r.name);
                    }
                }
            }
        }
    }
    let mut missing = Vec::new();
    let joints: Vec<usize> = (0..SMPLX_JOINTS)
        .filter(|j| owner[*j].is_none() && !EYE_JOINTS.contains(j))
        .collect();
    if !joints.is_empty() {
        missing.push(format!("joints {} (rot6d)", joint_ranges(&joints)));
    }
    for (part, h) in &holders {
        match h.len() {
            0 => missing.push(format!("'{part}'")),
            1 => {}
            _ => return Err(format!("part '{part}' is in more than one region ({h:?})")),
        }
    }
    if missing.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "the regions {:?} do not cover the SMPL-X frame: no region holds {} (every joint but the eyes 23, 24, and translation, foot contact and expressions must be in exactly one region)",
            regions.iter().map(|r| r.name.as_str()).collect::<Vec<_>>(),
            missing.join(", ")
        ))
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

/// The form names the runtime knows (`fused_ring`, `attention_ring`: the `fused` and `attention`
/// forms on ring caches, docs/bundle.md#ring-caches).
pub const FORMS: [&str; 5] = [
    "canonical",
    "fused",
    "attention",
    "fused_ring",
    "attention_ring",
];

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

    /// The form `backend` runs when asked for `form` and that form's graphs: `None` or `"auto"`, its
    /// default form ([`Self::default_form`]) with the decoders it runs by default
    /// ([`Self::default_decoders`]); a named form, that form's own graphs. `None` when the bundle
    /// does not carry the form. The one rule for the runtime's chain and for what a page downloads.
    pub fn graphs_run_by(&self, backend: &str, form: Option<&str>) -> Option<(String, FormGraphs)> {
        let named = form.filter(|f| *f != "auto");
        let name = named.unwrap_or(self.default_form(backend)).to_string();
        let mut graphs = self.form_graphs().remove(&name)?;
        if named.is_none() {
            graphs.decoders = self.default_decoders(backend);
        }
        Some((name, graphs))
    }

    /// Checks the sections against themselves and the common part; the error says what is wrong.
    pub(super) fn check(&self, m: &Manifest) -> Result<(), String> {
        if self.regions.is_empty() {
            return Err("no regions".into());
        }
        check_coverage(&self.regions)?;
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
            let want = if name == "fused" || name == "fused_ring" {
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

#[cfg(test)]
mod tests {
    use serde_json::Value;

    use super::*;
    use crate::bundle::{parse_manifest, repo_default_bundle};

    /// models/default's manifest as JSON.
    fn default_manifest() -> Value {
        let p = repo_default_bundle().join("manifest.json");
        serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
    }

    fn default_regions() -> Vec<RegionSpec> {
        serde_json::from_value(default_manifest()["regions"].clone()).unwrap()
    }

    /// The four regions as one region `body`, their parts one after the other (the layout the
    /// exporter writes for the full-body SVQ variant).
    fn full_body(regions: &[RegionSpec]) -> RegionSpec {
        let (mut parts, mut joints, mut off) = (Vec::new(), Vec::new(), 0);
        for r in regions {
            for p in &r.parts {
                let mut p = p.clone();
                if p.name == "rot6d" && p.joints.is_none() {
                    p.joints = Some(r.joints.clone());
                }
                p.offset += off;
                parts.push(p);
            }
            joints.extend_from_slice(&r.joints);
            off += r.dim;
        }
        RegionSpec {
            name: "body".into(),
            dim: off,
            joints,
            parts,
        }
    }

    #[test]
    fn the_four_regions_and_one_full_body_region_cover_the_frame() {
        let four = default_regions();
        assert_eq!(four.len(), 4);
        check_coverage(&four).unwrap();
        let body = full_body(&four);
        assert_eq!((body.dim, body.parts.len()), (425, 7));
        check_coverage(&[body]).unwrap();
    }

    #[test]
    fn regions_that_miss_or_repeat_part_of_the_frame_are_refused_naming_it() {
        let four = default_regions();
        // no hands region: joints 25-54 are missing
        let e = check_coverage(&[four[0].clone(), four[2].clone(), four[3].clone()]).unwrap_err();
        assert!(
            e.contains("joints 25-54 (rot6d)") && e.contains("do not cover"),
            "{e}"
        );
        // a full-body region without foot contact and expressions
        let mut body = full_body(&four);
        body.parts
            .retain(|p| p.name != "foot_contact" && p.name != "expressions");
        let e = check_coverage(std::slice::from_ref(&body)).unwrap_err();
        assert!(
            e.contains("'foot_contact'") && e.contains("'expressions'") && !e.contains("joints"),
            "{e}"
        );
        // the lower body's rot6d dropped: its 9 joints, as ranges
        let mut body = full_body(&four);
        body.parts
            .retain(|p| p.joints.as_deref() != Some(&four[2].joints[..]));
        let e = check_coverage(&[body]).unwrap_err();
        assert!(e.contains("joints 0-2, 4-5, 7-8, 10-11 (rot6d)"), "{e}");
        // the jaw in two regions
        let mut two = four.clone();
        two.push(RegionSpec {
            name: "jaw".into(),
            ..four[3].clone()
        });
        let e = check_coverage(&two).unwrap_err();
        assert!(e.contains("joint 22 is in two regions"), "{e}");
        // an eye in a region
        let mut eyes = four.clone();
        eyes[3].parts[0].joints = Some(vec![22, 23]);
        let e = check_coverage(&eyes).unwrap_err();
        assert!(e.contains("joint 23 is an eye"), "{e}");
        // translation twice
        let mut trans = four.clone();
        let t = trans[2].part("trans").unwrap().clone();
        trans[0].parts.push(t);
        let e = check_coverage(&trans).unwrap_err();
        assert!(e.contains("part 'trans' is in more than one region"), "{e}");
    }

    #[test]
    fn a_manifest_whose_regions_do_not_cover_the_frame_is_refused() {
        let p = repo_default_bundle().join("manifest.json");
        let mut v = default_manifest();
        v["regions"].as_array_mut().unwrap().remove(1); // hands
        let m = parse_manifest(&v.to_string(), &p).unwrap();
        let e = m.check().unwrap_err();
        assert!(e.contains("joints 25-54 (rot6d)"), "{e}");
    }
}

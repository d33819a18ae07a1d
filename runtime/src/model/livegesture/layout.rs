//! Frame assembly from the decoders' region features, the state size of a stream, and what `info`
//! shows of a LiveGesture bundle.

use anyhow::Result;

use super::LiveGestureGraphs;
use crate::backend::Tensor;
use crate::bundle::Bundle;
use crate::model::regions::assemble_frame;
use crate::model::Description;
use crate::output::Frame;

/// True for the graphs that run both guidance branches (2 rows per guided stream): the experts and
/// fusion.
fn is_branched(graph: &str) -> bool {
    graph.starts_with("expert_") || graph.starts_with("experts_") || graph.starts_with("fusion")
}

/// The graphs of the forms other than canonical (docs/bundle.md#forms-and-precision): a stream holds the caches of one form.
fn other_form_graphs(bundle: &Bundle) -> Result<Vec<String>> {
    let forms = bundle.livegesture()?.form_graphs();
    let canonical = forms.get("canonical").cloned();
    Ok(forms
        .into_iter()
        .filter(|(k, _)| k != "canonical")
        .flat_map(|(_, f)| {
            f.experts
                .into_iter()
                .chain(f.decoders)
                .chain(std::iter::once(f.fusion))
        })
        .filter(|g| {
            !canonical
                .as_ref()
                .is_some_and(|c| c.experts.contains(g) || c.decoders.contains(g) || &c.fusion == g)
        })
        .collect())
}

/// Bytes of per-stream state: caches of every graph (expert and fusion caches twice with guidance)
/// plus the frontend's sample buffer at its largest (one token span and one window of `f64`). The
/// canonical form's caches are counted; the fused form's hold the same values.
pub fn state_bytes(bundle: &Bundle, guided: bool) -> Result<usize> {
    let n_regions = bundle.livegesture()?.regions.len();
    let rows = if guided { 2 } else { 1 };
    let skip = other_form_graphs(bundle)?;
    let caches: usize = bundle
        .graphs()
        .iter()
        .filter(|g| !skip.contains(&g.name))
        .map(|g| {
            let r = if is_branched(&g.name) { rows } else { 1 };
            g.cache_row_bytes() * r
        })
        .sum();
    let f = bundle.frontend();
    let span = (f.token_end(0) as usize) + f.win_length + 1;
    Ok(caches + span * std::mem::size_of::<f64>() + n_regions * 8)
}

impl LiveGestureGraphs {
    /// Builds the frames of stream row `i` from the decoders' outputs: one `(batch,
    /// frames_per_token, dim)` tensor per region (canonical form), or one `(batch,
    /// frames_per_token, sum of the dims)` tensor with the regions side by side in region order
    /// (`decoders_fused`).
    pub(super) fn assemble_frames(&self, feats: &[Tensor], i: usize, t: u64) -> Result<Vec<Frame>> {
        let fpt = self.frames_per_token;
        let values = feats
            .iter()
            .map(|f| f.as_f32("decoder output"))
            .collect::<Result<Vec<_>>>()?;
        // (values, values per frame, offset of the region in a frame) of each region
        let views: Vec<(&[f32], usize, usize)> = if values.len() == 1 {
            let width: usize = self.regions.iter().map(|l| l.dim).sum();
            let mut off = 0;
            self.regions
                .iter()
                .map(|l| {
                    off += l.dim;
                    (values[0], width, off - l.dim)
                })
                .collect()
        } else {
            values
                .iter()
                .zip(&self.regions)
                .map(|(v, l)| (*v, l.dim, 0))
                .collect()
        };
        Ok((0..fpt)
            .map(|j| {
                let rows = self.regions.iter().zip(&views).map(|(l, &(v, w, o))| {
                    let base = (i * fpt + j) * w + o;
                    &v[base..base + l.dim]
                });
                assemble_frame(fpt as u64 * t + j as u64, &self.regions, rows)
            })
            .collect())
    }
}

/// What `info` shows of a LiveGesture bundle ([`crate::model::describe`]).
pub fn describe(bundle: &Bundle) -> Result<Description> {
    let lg = bundle.livegesture()?;
    let s = &lg.sampling;
    let guided = s.guidance != 1.0;
    let regions: Vec<String> = lg
        .regions
        .iter()
        .map(|r| format!("{} ({} dims, {} joints)", r.name, r.dim, r.joints.len()))
        .collect();
    let (with, without) = (state_bytes(bundle, true)?, state_bytes(bundle, false)?);
    let kib = |n: usize| format!("{:.1} KiB", n as f64 / 1024.0);
    let forms = lg.form_graphs();
    // tract's `auto` decoders where they are not its form's own (`default_decoders`)
    let tract_decoders = Some(lg.default_decoders("tract")).filter(|d| {
        forms
            .get(lg.default_form("tract"))
            .is_some_and(|f| f.decoders != *d)
    });
    let lines = vec![
        ("regions".to_string(), regions.join(", ")),
        (
            "vocabulary".to_string(),
            format!(
                "codebook {} per region, BOS token {}",
                lg.vocab.codebook_size, lg.vocab.bos_token
            ),
        ),
        (
            "sampling".to_string(),
            format!(
                "guidance {}{}, temperature {}, top-k {}, PRNG {}",
                s.guidance,
                if guided { "" } else { " (off)" },
                s.temperature,
                if s.top_k == 0 {
                    "all".to_string()
                } else {
                    s.top_k.to_string()
                },
                s.prng.as_deref().unwrap_or("splitmix64")
            ),
        ),
        (
            "state".to_string(),
            format!(
                "{} per stream with guidance ({} without): caches, previous tokens, frontend buffer",
                kib(with),
                kib(without)
            ),
        ),
        ("look-ahead".to_string(), "0 (causal, one token at a time)".to_string()),
        (
            "forms".to_string(),
            format!(
                "{} (docs/bundle.md#forms-and-precision); runs ort: {}, tract: {} (a form chosen at load, or $LIVEGESTURE_FORM, overrides){}",
                forms
                    .iter()
                    .map(|(k, g)| format!(
                        "{k}: eXperts {}, fusion {}, decoders {}{}",
                        g.experts.join(" "),
                        g.fusion,
                        g.decoders.join(" "),
                        // docs/bundle.md#ring-caches: the form's graphs read their caches in place
                        if bundle.graph(&g.fusion).is_ok_and(|s| s.is_ring()) {
                            " (ring caches)"
                        } else {
                            ""
                        }
                    ))
                    .collect::<Vec<_>>()
                    .join("; "),
                lg.default_form("ort"),
                lg.default_form("tract"),
                tract_decoders
                    .as_ref()
                    .map(|d| format!("; tract's {} form runs the decoders {}", lg.default_form("tract"), d.join(" ")))
                    .unwrap_or_default()
            ),
        ),
    ];
    let mut json = serde_json::Map::new();
    json.insert("regions".into(), serde_json::json!(lg.region_names()));
    json.insert("sampling".into(), serde_json::to_value(&lg.sampling)?);
    json.insert("vocab".into(), serde_json::to_value(&lg.vocab)?);
    json.insert("forms".into(), serde_json::to_value(&forms)?);
    json.insert(
        "backend_decoders".into(),
        serde_json::json!({"ort": lg.default_decoders("ort"), "tract": lg.default_decoders("tract")}),
    );
    json.insert(
        "backend_forms".into(),
        serde_json::json!({"ort": lg.default_form("ort"), "tract": lg.default_form("tract")}),
    );
    json.insert(
        "state_bytes_per_stream".into(),
        serde_json::json!({"guided": with, "unguided": without}),
    );
    let rows_per_stream = bundle
        .graphs()
        .iter()
        .filter(|g| is_branched(&g.name))
        .map(|g| (g.name.clone(), if guided { 2 } else { 1 }))
        .collect();
    Ok(Description {
        lines,
        json,
        rows_per_stream,
    })
}

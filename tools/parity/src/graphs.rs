//! The graph check: every graph chained over its reference steps on each backend.

use super::*;

/// Outputs (graph order) of every chained step of one graph on one backend.
pub(super) type StepOutputs = Vec<Vec<Tensor>>;

pub(super) fn chain_graph(
    backend: &dyn Backend,
    bundle: &Bundle,
    spec: &GraphSpec,
    refv: &ReferenceVectors,
    n_steps: usize,
) -> Result<StepOutputs> {
    let runner = backend.load(spec, &bundle.graph_path(spec))?;
    let batch = refv
        .get(&format!("step0.input.{}", spec.inputs[0].name))?
        .batch();
    let mut caches: Vec<Tensor> = spec.caches.iter().map(|c| c.zeros(batch)).collect();
    let mut all = Vec::with_capacity(n_steps);
    for s in 0..n_steps {
        let mut inputs: Vec<Tensor> = spec
            .inputs
            .iter()
            .map(|i| refv.get(&format!("step{s}.input.{}", i.name)).cloned())
            .collect::<Result<_, _>>()?;
        inputs.extend(caches);
        let mut out = runner
            .run(&inputs)
            .with_context(|| format!("{} step {s}", backend.name()))?;
        // a graph on ring caches (docs/bundle.md#ring-caches): its entries are written into the
        // caches at the step's phase, and the caches after the write are compared and chained
        caches = spec.chain_caches(inputs, &mut out)?;
        all.push(out);
    }
    Ok(all)
}

/// A graph's reference vectors (`graphs[i].reference`, else `reference/<graph>.npz`) and their path.
pub(super) fn graph_reference(
    bundle: &Bundle,
    spec: &GraphSpec,
) -> Result<(PathBuf, ReferenceVectors), ReferenceError> {
    let rel = spec
        .reference
        .clone()
        .unwrap_or_else(|| format!("reference/{}.npz", spec.name));
    let path = bundle.path(&rel);
    let refv = ReferenceVectors::load(&path)?;
    Ok((path, refv))
}

// long: one row per graph and backend, the inputs built per graph kind in one match; to split per graph kind
pub(super) fn graph_rows(
    bundle: &Bundle,
    spec: &GraphSpec,
    backends: &[(BackendKind, Box<dyn Backend>)],
    rows: &mut Vec<Row>,
) -> Result<(), ReferenceError> {
    let (path, refv) = graph_reference(bundle, spec)?;
    let n_steps = refv.scalar("n_steps")?;
    if n_steps < 1 {
        return Err(ref_err(&path, format!("n_steps is {n_steps}")));
    }
    let n_steps = n_steps as usize;
    let last = n_steps - 1;
    // check the reference holds everything before running anything
    for s in 0..n_steps {
        for i in &spec.inputs {
            refv.get(&format!("step{s}.input.{}", i.name))?;
        }
        for o in &spec.outputs {
            refv.get(&format!("step{s}.output.{}", o.name))?;
        }
    }
    for c in &spec.caches {
        refv.get(&format!("step{last}.new_cache.{}", c.name))?;
    }
    // docs/parity.md's first row, torch step-by-step vs torch offline, is measured by the exporter (it needs
    // the PyTorch model) and recorded in the manifest's `checks`: reported as recorded.
    let checks = &bundle.manifest().checks[&spec.name];
    // the scale the exporter judged a recorded error at (`<key minus _max_abs>_scale`); bundles exported
    // before the bounds scaled record none: scale 1, the absolute bound they were checked against
    let scale_of = |key: &str| {
        checks[format!("{}_scale", key.trim_end_matches("_max_abs"))]
            .as_f64()
            .unwrap_or(1.0)
    };
    let recorded_detail = "measured by export/export.py, read from manifest.json `checks`";
    // a graph of another form (docs/bundle.md#forms-and-precision) is checked against the canonical
    // graphs it replaces; every other graph against the torch offline forward. A missing record fails,
    // naming the key it looked for.
    let is_form_graph = is_form_graph(bundle, &spec.name);
    let form_keys = [
        (
            "torch_fused_vs_canonical_max_abs",
            "torch fused vs canonical",
        ),
        ("torch_form_vs_canonical_max_abs", "torch form vs canonical"),
    ];
    if !is_form_graph {
        let key = "torch_step_vs_offline_max_abs";
        match checks[key].as_f64() {
            Some(e) => rows.push(Row::recorded(
                Check::Graph,
                &spec.name,
                "torch step vs offline",
                e,
                scale_of(key),
                TORCH_STEP_VS_OFFLINE,
                recorded_detail.into(),
            )),
            None => rows.push(Row::failed(
                Check::Graph,
                &spec.name,
                "torch step vs offline",
                "(all, recorded by export)",
                TORCH_STEP_VS_OFFLINE,
                format!(
                    "manifest.json has no checks.{}.{key} (the exporter records it for every canonical graph)",
                    spec.name
                ),
            )),
        }
    } else {
        match form_keys
            .into_iter()
            .find_map(|(key, what)| checks[key].as_f64().map(|e| (e, key, what)))
        {
            Some((e, key, what)) => rows.push(Row::recorded(
                Check::Graph,
                &spec.name,
                what,
                e,
                scale_of(key),
                TORCH_FUSED_VS_CANONICAL,
                recorded_detail.into(),
            )),
            None => rows.push(Row::failed(
                Check::Graph,
                &spec.name,
                "torch form vs canonical",
                "(all, recorded by export)",
                TORCH_FUSED_VS_CANONICAL,
                format!(
                    "manifest.json has neither checks.{0}.{1} nor checks.{0}.{2} (the exporter records one for every graph of another form)",
                    spec.name, form_keys[0].0, form_keys[1].0
                ),
            )),
        }
    }
    let mut runs: Vec<(BackendKind, std::result::Result<StepOutputs, String>)> = Vec::new();
    for (kind, be) in backends {
        let r =
            chain_graph(be.as_ref(), bundle, spec, &refv, n_steps).map_err(|e| format!("{e:#}"));
        runs.push((*kind, r));
    }
    let outputs = spec.output_names();
    // a reduced-precision bundle's reference vectors are the f32 bundle's (torch on the f32 weights),
    // checked with the bound export/quantize.py measured and stated per graph
    // (docs/bundle.md#forms-and-precision)
    let reduced_key = "reduced_vs_f32_torch_bound";
    let reduced = bundle
        .is_reduced_precision()
        .then(|| checks[reduced_key].as_f64());
    for (kind, run) in &runs {
        let (comparison, bound) = match (kind, reduced) {
            (_, Some(None)) => {
                rows.push(Row::failed(
                    Check::Graph,
                    &spec.name,
                    format!("{kind} vs f32 torch"),
                    "(all)",
                    ORT_VS_TORCH,
                    format!(
                        "manifest.json has no checks.{}.{reduced_key}: a reduced-precision bundle states \
                         its bound against the f32 torch reference vectors (export/quantize.py)",
                        spec.name
                    ),
                ));
                continue;
            }
            (BackendKind::Ort, Some(Some(b))) => ("ort vs f32 torch".to_string(), b),
            (BackendKind::Tract, Some(Some(b))) => {
                ("tract vs f32 torch".to_string(), b + TRACT_VS_ORT)
            }
            (BackendKind::Ort, None) => {
                (format!("ort vs {}", bundle.reference_name()), ORT_VS_TORCH)
            }
            (BackendKind::Tract, None) => (
                format!("tract vs {}", bundle.reference_name()),
                TRACT_VS_TORCH,
            ),
        };
        let steps = match run {
            Ok(s) => s,
            Err(e) => {
                rows.push(Row::failed(
                    Check::Graph,
                    &spec.name,
                    &comparison,
                    "(all)",
                    bound,
                    format!("{kind} could not run the graph: {e}"),
                ));
                continue;
            }
        };
        for (k, o) in spec.outputs.iter().enumerate() {
            let mut m = MaxAbs::default();
            for (s, out) in steps.iter().enumerate() {
                m.add(
                    s as u64,
                    &out[k],
                    refv.get(&format!("step{s}.output.{}", o.name))?,
                );
            }
            rows.push(Row::max_abs(
                Check::Graph,
                &spec.name,
                &comparison,
                &o.name,
                &m,
                bound,
            ));
        }
        for (k, c) in spec.caches.iter().enumerate() {
            let mut m = MaxAbs::default();
            m.add(
                last as u64,
                &steps[last][spec.outputs.len() + k],
                refv.get(&format!("step{last}.new_cache.{}", c.name))?,
            );
            rows.push(Row::max_abs(
                Check::Graph,
                &spec.name,
                &comparison,
                &c.output,
                &m,
                bound,
            ));
        }
    }
    let ort = runs.iter().find(|r| r.0 == BackendKind::Ort);
    let tract = runs.iter().find(|r| r.0 == BackendKind::Tract);
    if let (Some((_, Ok(o))), Some((_, Ok(t)))) = (ort, tract) {
        for (k, name) in outputs.iter().enumerate() {
            let mut m = MaxAbs::default();
            for s in 0..n_steps {
                m.add(s as u64, &t[s][k], &o[s][k]);
            }
            rows.push(Row::max_abs(
                Check::Graph,
                &spec.name,
                "tract vs ort",
                *name,
                &m,
                TRACT_VS_ORT,
            ));
        }
    } else if ort.is_some() && tract.is_some() {
        rows.push(Row::failed(
            Check::Graph,
            &spec.name,
            "tract vs ort",
            "(all)",
            TRACT_VS_ORT,
            "not compared: a backend could not run the graph (see above)".into(),
        ));
    }
    Ok(())
}

/// Whether `name` is a graph of a form other than the canonical one only (`experts_fused`,
/// `decoders_fused`, `fusion_attention`, ...): its torch figure is the form-vs-canonical one.
fn is_form_graph(bundle: &Bundle, name: &str) -> bool {
    let Ok(lg) = bundle.livegesture() else {
        return false;
    };
    let forms = lg.form_graphs();
    let in_form = |f: &livegesture::bundle::FormGraphs| {
        f.experts.iter().chain(&f.decoders).any(|g| g == name) || f.fusion == name
    };
    let canonical = forms.get("canonical").is_some_and(in_form);
    !canonical
        && forms
            .iter()
            .any(|(k, f)| k.as_str() != "canonical" && in_form(f))
}

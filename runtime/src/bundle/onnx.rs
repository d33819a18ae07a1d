//! Checks a graph's ONNX file against its manifest entry (names, order, element types, ranks, fixed
//! dimensions), reading only the protobuf (no backend involved).

use std::path::Path;

use tract_onnx::pb;
use tract_onnx::prelude::Framework;

use super::{shape_string, BundleError, Dim, GraphSpec};
use crate::tensor::DType;

fn onnx_dtype(elem_type: i32) -> Option<DType> {
    match elem_type {
        1 => Some(DType::F32),
        7 => Some(DType::I64),
        _ => None,
    }
}

fn onnx_dtype_name(elem_type: i32) -> String {
    match elem_type {
        1 => "float32".into(),
        7 => "int64".into(),
        6 => "int32".into(),
        10 => "float16".into(),
        11 => "float64".into(),
        9 => "bool".into(),
        other => format!("ONNX element type {other}"),
    }
}

/// Checks a graph's ONNX inputs/outputs (names, order, dtypes, ranks, fixed dims) against the manifest.
pub(super) fn check_graph_io(g: &GraphSpec, path: &Path, bytes: &[u8]) -> Result<(), BundleError> {
    let proto: pb::ModelProto = tract_onnx::onnx()
        .proto_model_for_read(&mut &bytes[..])
        .map_err(|e| BundleError::BadOnnx {
            path: path.to_path_buf(),
            detail: format!("{e:#}"),
        })?;
    let graph = proto.graph.as_ref().ok_or_else(|| BundleError::BadOnnx {
        path: path.to_path_buf(),
        detail: "the model has no graph".into(),
    })?;
    let mismatch = |detail: String| BundleError::GraphMismatch {
        path: path.to_path_buf(),
        graph: g.name.clone(),
        detail,
    };
    let initializers: std::collections::HashSet<&str> =
        graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let actual_inputs: Vec<&pb::ValueInfoProto> = graph
        .input
        .iter()
        .filter(|v| !initializers.contains(v.name.as_str()))
        .collect();
    for (kind, actual, expected) in [
        ("inputs", actual_inputs, g.all_inputs()),
        ("outputs", graph.output.iter().collect(), g.all_outputs()),
    ] {
        let an: Vec<&str> = actual.iter().map(|v| v.name.as_str()).collect();
        let en: Vec<&str> = expected.iter().map(|e| e.0).collect();
        if an != en {
            return Err(mismatch(format!(
                "{kind} are {an:?} in the ONNX file, manifest.json lists {en:?}"
            )));
        }
        for (v, (name, dtype, shape)) in actual.iter().zip(&expected) {
            let Some(pb::type_proto::Value::TensorType(t)) =
                v.r#type.as_ref().and_then(|t| t.value.as_ref())
            else {
                return Err(mismatch(format!(
                    "'{name}' is not a tensor in the ONNX file"
                )));
            };
            if onnx_dtype(t.elem_type) != Some(*dtype) {
                return Err(mismatch(format!(
                    "'{name}' is {} in the ONNX file, manifest.json says {}",
                    onnx_dtype_name(t.elem_type),
                    dtype
                )));
            }
            let Some(s) = t.shape.as_ref() else {
                return Err(mismatch(format!("'{name}' has no shape in the ONNX file")));
            };
            if s.dim.len() != shape.len() {
                return Err(mismatch(format!(
                    "'{name}' has rank {} in the ONNX file, manifest.json says rank {} {}",
                    s.dim.len(),
                    shape.len(),
                    shape_string(shape)
                )));
            }
            for (axis, (d, e)) in s.dim.iter().zip(shape.iter()).enumerate() {
                use pb::tensor_shape_proto::dimension::Value as DV;
                match (d.value.as_ref(), e) {
                    (Some(DV::DimValue(a)), Dim::Fixed(b)) if *a == *b as i64 => {}
                    // symbolic in the file: the batch axis, or a size the exporter could not fold
                    // (checked on every run instead)
                    (Some(DV::DimParam(_)) | None, _) => {}
                    (actual, _) => {
                        let a = match actual {
                            Some(DV::DimValue(a)) => a.to_string(),
                            Some(DV::DimParam(p)) => format!("'{p}'"),
                            None => "?".into(),
                        };
                        return Err(mismatch(format!(
                            "'{name}' axis {axis} is {a} in the ONNX file, manifest.json says {e} (shape {})",
                            shape_string(shape)
                        )));
                    }
                }
            }
        }
    }
    Ok(())
}

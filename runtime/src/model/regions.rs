//! Region features -> SMPL-X frames, for every family: the manifest's `regions` (each region's
//! feature layout: `rot6d` joints, `trans`, `foot_contact`, `expressions`) resolved once
//! ([`resolve_layouts`]), then each frame assembled from one feature row per region
//! ([`assemble_frame`]): rot6d -> axis-angle, translation and expressions copied, foot contact from
//! the contact dims, joints no region covers (the eyes) at rest. LiveGesture feeds its decoders'
//! outputs; a family that produces one motion vector per frame passes its region slices.

use anyhow::{bail, ensure, Result};

use crate::bundle::RegionSpec;
use crate::output::{Frame, CONTACT_DIM, EXPR_DIM, POSE_DIM, TRANS_DIM};
use crate::rotation::rot6d_to_axis_angle;

/// The resolved layout of one region's features.
#[derive(Debug, Clone)]
pub struct RegionLayout {
    /// The region's name.
    pub name: String,
    /// Features per frame.
    pub dim: usize,
    /// (joint, offset of its rot6d) pairs.
    rot6d: Vec<(usize, usize)>,
    trans: Option<usize>,
    contact: Option<usize>,
    expressions: Option<usize>,
}

/// Resolves each region's parts (`rot6d` joints, `trans`, `foot_contact`, `expressions`) to offsets,
/// checking their sizes against the SMPL-X frame.
pub fn resolve_layouts(regions: &[RegionSpec]) -> Result<Vec<RegionLayout>> {
    let mut out = Vec::new();
    for r in regions {
        let mut l = RegionLayout {
            name: r.name.clone(),
            dim: r.dim,
            rot6d: Vec::new(),
            trans: None,
            contact: None,
            expressions: None,
        };
        for p in &r.parts {
            match p.name.as_str() {
                "rot6d" => {
                    let joints = p.joints.clone().unwrap_or_else(|| r.joints.clone());
                    ensure!(
                        joints.len() * 6 == p.dim,
                        "region '{}': rot6d part has {} dims for {} joints",
                        r.name,
                        p.dim,
                        joints.len()
                    );
                    for (k, j) in joints.into_iter().enumerate() {
                        ensure!(
                            j * 3 + 3 <= POSE_DIM,
                            "region '{}': joint {j} out of range",
                            r.name
                        );
                        l.rot6d.push((j, p.offset + 6 * k));
                    }
                }
                "trans" => {
                    ensure!(
                        p.dim == TRANS_DIM,
                        "region '{}': trans has {} dims",
                        r.name,
                        p.dim
                    );
                    l.trans = Some(p.offset);
                }
                "foot_contact" | "contact" => {
                    ensure!(
                        p.dim == CONTACT_DIM,
                        "region '{}': foot contact has {} dims",
                        r.name,
                        p.dim
                    );
                    l.contact = Some(p.offset);
                }
                "expressions" => {
                    ensure!(
                        p.dim == EXPR_DIM,
                        "region '{}': expressions have {} dims",
                        r.name,
                        p.dim
                    );
                    l.expressions = Some(p.offset);
                }
                other => bail!("region '{}': unknown feature part '{other}'", r.name),
            }
        }
        out.push(l);
    }
    Ok(out)
}

/// Frame `index` from one feature row per region (`rows[k]` has `layouts[k].dim` values).
pub fn assemble_frame<'a>(
    index: u64,
    layouts: &[RegionLayout],
    rows: impl IntoIterator<Item = &'a [f32]>,
) -> Frame {
    let mut poses = [0f32; POSE_DIM];
    let mut trans = [0f32; TRANS_DIM];
    let mut expressions = [0f32; EXPR_DIM];
    let mut contact = [0f32; CONTACT_DIM];
    for (l, row) in layouts.iter().zip(rows) {
        for &(joint, off) in &l.rot6d {
            let d6 = [
                row[off],
                row[off + 1],
                row[off + 2],
                row[off + 3],
                row[off + 4],
                row[off + 5],
            ];
            poses[3 * joint..3 * joint + 3].copy_from_slice(&rot6d_to_axis_angle(d6));
        }
        if let Some(o) = l.trans {
            trans.copy_from_slice(&row[o..o + TRANS_DIM]);
        }
        if let Some(o) = l.expressions {
            expressions.copy_from_slice(&row[o..o + EXPR_DIM]);
        }
        if let Some(o) = l.contact {
            contact.copy_from_slice(&row[o..o + CONTACT_DIM]);
        }
    }
    Frame::new(index, poses, trans, expressions, contact)
}

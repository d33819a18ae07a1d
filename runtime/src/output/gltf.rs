// long: one output format in one file: the document's layout (module doc), its assembly section by section and its checks
//! glTF 2.0 output (`generate -o motion.glb` or `motion.gltf`, docs/avatars.md) on the project's own
//! skeleton ([`crate::skeleton`]).
//!
//! # The document
//!
//! - **Nodes 0..55** are the 55 joints, in SMPL-X order, named with the SMPL-X joint names, each one's
//!   `translation` its rest offset from the parent in **metres** (Y up, the body faces +Z). The root
//!   `pelvis` (node 0) sits at its rest offset (`trans = 0`). Rest rotations are the identity.
//! - **Node 55** (`body`) holds a simple mesh skinned to the joints: one box per bone (parent joint to
//!   child joint, weighted wholly to the parent), and a box for the head and jaw. It is a root node
//!   without a transform, as glTF wants of a skinned mesh node.
//! - **One skin** over the 55 joints; `inverseBindMatrices` undo each joint's rest position.
//! - **One animation** (`motion`): one sampler and channel per joint for `rotation` (unit quaternions
//!   `(x, y, z, w)` from the frame's axis-angle, [`crate::rotation`]), and one for the pelvis's
//!   `translation` (`trans + rest offset of the pelvis`, metres). Keyframe `k` is at `k / 30` s, one
//!   per frame, interpolation `LINEAR`; a motion of `T` frames (the frames that cover the audio,
//!   docs/output.md) spans `T / 30` s of audio with its last key at `(T - 1) / 30`. Each joint's
//!   quaternions keep one hemisphere from frame to frame (`q` and `-q` are the same rotation) so that
//!   interpolation between keys takes the short way.
//! - With the face channel (docs/face.md): **node 56** (`face`), a child of the `head` joint, holds the
//!   ICT-FaceKit face region ([`crate::face::mesh`]) with 52 morph targets named as ARKit names them
//!   (`mesh.extras.targetNames`, in Apple's order; sparse POSITION deltas), and the animation gains one
//!   `weights` channel on it (52 weights per key, the frames' `arkit`). The FLAME expression coefficients
//!   stay in the `.npz`. The jaw opening of the body is the `jaw` joint's rotation.
//!
//! # Containers
//!
//! - `.glb`: the binary container (a 12-byte header, a JSON chunk padded with spaces, a BIN chunk
//!   padded with zeros to 4 bytes), one buffer without `uri`.
//! - `.gltf`: JSON text with the buffer embedded as a `data:application/octet-stream;base64,` URI, so
//!   the file is whole on its own.
//!
//! Both are written atomically (a temporary file in the destination folder, renamed). The document
//! types are the `gltf-json` crate's.

use std::io::Write as _;
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use base64::Engine as _;
use gltf_json as json;
use json::validation::{Checked::Valid, USize64};

use crate::output::{Beat2Motion, FaceTrack, Frame, EXPR_DIM, POSE_DIM, TRANS_DIM};
use crate::rotation::{axis_angle_to_matrix, matrix_to_quaternion};
use crate::skeleton::{children, rest_joints, rest_offsets, JOINT_NAMES, N_JOINTS, PARENTS};

/// The generator string written into `asset.generator`.
pub const GENERATOR: &str = concat!("livegesture ", env!("CARGO_PKG_VERSION"));

/// Index of the mesh node (after the 55 joint nodes).
pub const MESH_NODE: usize = N_JOINTS;
/// Index of the face node (with the face channel), a child of the head joint.
pub const FACE_NODE: usize = N_JOINTS + 1;
/// The head joint (SMPL-X index 15), parent of the face node.
const HEAD_JOINT: usize = 15;
/// The face node's offset from the head joint, metres (the face in front of the skull box).
const FACE_OFFSET: [f32; 3] = [0.0, 0.07, 0.045];

/// Which glTF container to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GltfContainer {
    /// `.glb`: binary container, buffer in the BIN chunk.
    Glb,
    /// `.gltf`: JSON with the buffer embedded as a base64 data URI.
    Gltf,
}

impl GltfContainer {
    /// The container for a file name's extension (`glb` or `gltf`, any case), if it is one.
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "glb" => Some(Self::Glb),
            "gltf" => Some(Self::Gltf),
            _ => None,
        }
    }
}

/// The binary buffer under construction: views are appended 4-byte aligned.
struct Bin {
    data: Vec<u8>,
}

impl Bin {
    fn view(
        &mut self,
        root: &mut json::Root,
        bytes: &[u8],
        target: Option<json::buffer::Target>,
        stride: Option<usize>,
    ) -> json::Index<json::buffer::View> {
        while !self.data.len().is_multiple_of(4) {
            self.data.push(0);
        }
        let offset = self.data.len();
        self.data.extend_from_slice(bytes);
        root.push(json::buffer::View {
            buffer: json::Index::new(0),
            byte_length: USize64(bytes.len() as u64),
            byte_offset: Some(USize64(offset as u64)),
            byte_stride: stride.map(json::buffer::Stride),
            name: None,
            target: target.map(Valid),
            extensions: None,
            extras: Default::default(),
        })
    }
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

#[allow(clippy::too_many_arguments)]
fn accessor(
    root: &mut json::Root,
    view: json::Index<json::buffer::View>,
    count: usize,
    component: json::accessor::ComponentType,
    type_: json::accessor::Type,
    min: Option<Vec<f32>>,
    max: Option<Vec<f32>>,
    name: Option<&str>,
) -> json::Index<json::Accessor> {
    root.push(json::Accessor {
        buffer_view: Some(view),
        byte_offset: None,
        count: USize64(count as u64),
        component_type: Valid(json::accessor::GenericComponentType(component)),
        extensions: None,
        extras: Default::default(),
        type_: Valid(type_),
        min: min.map(json::Value::from),
        max: max.map(json::Value::from),
        name: name.map(str::to_string),
        normalized: false,
        sparse: None,
    })
}

fn min_max(v: &[f32], width: usize) -> (Vec<f32>, Vec<f32>) {
    let mut lo = vec![f32::INFINITY; width];
    let mut hi = vec![f32::NEG_INFINITY; width];
    for row in v.chunks_exact(width) {
        for ((l, h), x) in lo.iter_mut().zip(hi.iter_mut()).zip(row) {
            *l = l.min(*x);
            *h = h.max(*x);
        }
    }
    (lo, hi)
}

/// Unit quaternion `(x, y, z, w)` (glTF order) of an axis-angle rotation.
pub fn axis_angle_to_gltf_quaternion(aa: [f32; 3]) -> [f32; 4] {
    let q = matrix_to_quaternion(&axis_angle_to_matrix(aa.map(f64::from)));
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    [q[1] / n, q[2] / n, q[3] / n, q[0] / n].map(|x| x as f32)
}

/// The per-joint rotation keys (`T x 4` floats per joint), hemisphere-continuous over time.
fn rotation_keys(motion: &Beat2Motion) -> Vec<Vec<f32>> {
    let t_len = motion.len();
    let mut keys: Vec<Vec<f32>> = (0..N_JOINTS)
        .map(|_| Vec::with_capacity(4 * t_len))
        .collect();
    for t in 0..t_len {
        let p = motion.poses.row(t);
        for (j, k) in keys.iter_mut().enumerate() {
            let mut q = axis_angle_to_gltf_quaternion([p[3 * j], p[3 * j + 1], p[3 * j + 2]]);
            if t > 0 {
                let prev = &k[k.len() - 4..];
                let d: f32 = (0..4).map(|i| prev[i] * q[i]).sum();
                if d < 0.0 {
                    q = q.map(|x| -x);
                }
            }
            k.extend_from_slice(&q);
        }
    }
    keys
}

/// A box mesh: `(positions, normals, joints, indices)` appended to the given vectors.
struct MeshData {
    positions: Vec<f32>,
    normals: Vec<f32>,
    joints: Vec<u8>,
    indices: Vec<u16>,
}

impl MeshData {
    /// A box from `a` to `b` (rest positions) of half-width `r`, bound to joint `joint`.
    fn bone_box(&mut self, a: [f64; 3], b: [f64; 3], r: f64, joint: usize) {
        let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-6);
        let u = d.map(|x| x / len);
        // two axes perpendicular to u
        let helper = if u[1].abs() < 0.9 {
            [0.0, 1.0, 0.0]
        } else {
            [1.0, 0.0, 0.0]
        };
        let cross = |p: [f64; 3], q: [f64; 3]| {
            [
                p[1] * q[2] - p[2] * q[1],
                p[2] * q[0] - p[0] * q[2],
                p[0] * q[1] - p[1] * q[0],
            ]
        };
        let norm = |v: [f64; 3]| {
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / n)
        };
        let v = norm(cross(u, helper));
        let w = cross(u, v);
        // 8 corners: along u at 0 or len, +-r along v and w
        let corner = |s: f64, sv: f64, sw: f64| -> [f64; 3] {
            std::array::from_fn(|k| a[k] + u[k] * s + (v[k] * sv + w[k] * sw) * r)
        };
        // faces as (normal, 4 corners counter-clockwise seen from outside)
        let faces: [([f64; 3], [[f64; 3]; 4]); 6] = [
            (
                u.map(|x| -x),
                [
                    corner(0.0, -1.0, -1.0),
                    corner(0.0, -1.0, 1.0),
                    corner(0.0, 1.0, 1.0),
                    corner(0.0, 1.0, -1.0),
                ],
            ),
            (
                u,
                [
                    corner(len, -1.0, -1.0),
                    corner(len, 1.0, -1.0),
                    corner(len, 1.0, 1.0),
                    corner(len, -1.0, 1.0),
                ],
            ),
            (
                v,
                [
                    corner(0.0, 1.0, -1.0),
                    corner(0.0, 1.0, 1.0),
                    corner(len, 1.0, 1.0),
                    corner(len, 1.0, -1.0),
                ],
            ),
            (
                v.map(|x| -x),
                [
                    corner(0.0, -1.0, -1.0),
                    corner(len, -1.0, -1.0),
                    corner(len, -1.0, 1.0),
                    corner(0.0, -1.0, 1.0),
                ],
            ),
            (
                w,
                [
                    corner(0.0, -1.0, 1.0),
                    corner(len, -1.0, 1.0),
                    corner(len, 1.0, 1.0),
                    corner(0.0, 1.0, 1.0),
                ],
            ),
            (
                w.map(|x| -x),
                [
                    corner(0.0, -1.0, -1.0),
                    corner(0.0, 1.0, -1.0),
                    corner(len, 1.0, -1.0),
                    corner(len, -1.0, -1.0),
                ],
            ),
        ];
        for (n, quad) in faces {
            let base = (self.positions.len() / 3) as u16;
            for c in quad {
                self.positions.extend(c.map(|x| x as f32));
                self.normals.extend(n.map(|x| x as f32));
                self.joints.extend([joint as u8, 0, 0, 0]);
            }
            self.indices
                .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }
}

/// The simple skinned body: a box per bone (bound to the parent joint), a head and a jaw.
fn body_mesh() -> MeshData {
    let pos = rest_joints();
    let mut m = MeshData {
        positions: Vec::new(),
        normals: Vec::new(),
        joints: Vec::new(),
        indices: Vec::new(),
    };
    for j in 0..N_JOINTS {
        let p = PARENTS[j];
        if p < 0 {
            continue;
        }
        let p = p as usize;
        if matches!(j, 22..=24) {
            continue; // jaw and eyes: the head and jaw boxes below
        }
        let r = if j >= 25 {
            0.007
        } else if matches!(p, 16..=21) {
            0.035
        } else if matches!(p, 1 | 2 | 4 | 5) {
            0.05
        } else {
            0.06
        };
        m.bone_box(pos[p], pos[j], r, p);
    }
    let head = pos[15];
    // the skull: above the head joint, bound to the head
    m.bone_box(head, [head[0], head[1] + 0.2, head[2]], 0.085, 15);
    // the jaw: from the jaw joint forward, bound to the jaw (opens with it)
    let jaw = pos[22];
    m.bone_box(jaw, [jaw[0], jaw[1] - 0.01, jaw[2] + 0.07], 0.03, 22);
    m
}

/// The glTF document (JSON) and its binary buffer for `motion`.
pub fn gltf_document(motion: &Beat2Motion) -> Result<(json::Root, Vec<u8>)> {
    gltf_document_with_face(motion, None)
}

/// The face mesh with its 52 morph targets, and the node that holds it (a child of the head joint).
// long: one glTF mesh built in order (positions, normals, indices, 52 morph targets, their accessors and views); its parts share the same indices
fn face_node(root: &mut json::Root, bin: &mut Bin) -> Result<json::Index<json::Node>> {
    use json::accessor::{ComponentType as C, Type as Ty};
    let m = crate::face::mesh::face_mesh()?;
    let n = m.n_vertices();
    let (lo, hi) = min_max(&m.positions, 3);
    let v = bin.view(
        root,
        &f32_bytes(&m.positions),
        Some(json::buffer::Target::ArrayBuffer),
        None,
    );
    let a_pos = accessor(root, v, n, C::F32, Ty::Vec3, Some(lo), Some(hi), None);
    let idx: Vec<u8> = m.triangles.iter().flat_map(|i| i.to_le_bytes()).collect();
    let v = bin.view(
        root,
        &idx,
        Some(json::buffer::Target::ElementArrayBuffer),
        None,
    );
    let a_idx = accessor(
        root,
        v,
        m.triangles.len(),
        C::U16,
        Ty::Scalar,
        None,
        None,
        None,
    );
    let mut targets = Vec::with_capacity(m.targets.len());
    for (name, (vi, d)) in crate::face::ARKIT_NAMES.iter().zip(&m.targets) {
        // a target that moves nothing (tongueOut: the face region has no tongue) stores one zero delta
        let (vi, d): (Vec<u16>, Vec<f32>) = if vi.is_empty() {
            (vec![0], vec![0.0; 3])
        } else {
            (vi.clone(), d.clone())
        };
        // min/max over all vertices: the moving ones' deltas and the zeros of the others
        let (mut lo, mut hi) = min_max(&d, 3);
        for k in 0..3 {
            lo[k] = lo[k].min(0.0);
            hi[k] = hi[k].max(0.0);
        }
        let iv = bin.view(
            root,
            &vi.iter().flat_map(|i| i.to_le_bytes()).collect::<Vec<u8>>(),
            None,
            None,
        );
        let dv = bin.view(root, &f32_bytes(&d), None, None);
        let a = root.push(json::Accessor {
            buffer_view: None,
            byte_offset: None,
            count: USize64(n as u64),
            component_type: Valid(json::accessor::GenericComponentType(C::F32)),
            extensions: None,
            extras: Default::default(),
            type_: Valid(Ty::Vec3),
            min: Some(json::Value::from(lo)),
            max: Some(json::Value::from(hi)),
            name: Some(name.to_string()),
            normalized: false,
            sparse: Some(json::accessor::sparse::Sparse {
                count: USize64(vi.len() as u64),
                indices: json::accessor::sparse::Indices {
                    buffer_view: iv,
                    byte_offset: USize64(0),
                    component_type: Valid(json::accessor::IndexComponentType(C::U16)),
                    extensions: None,
                    extras: Default::default(),
                },
                values: json::accessor::sparse::Values {
                    buffer_view: dv,
                    byte_offset: USize64(0),
                    extensions: None,
                    extras: Default::default(),
                },
                extensions: None,
                extras: Default::default(),
            }),
        });
        targets.push(json::mesh::MorphTarget {
            positions: Some(a),
            normals: None,
            tangents: None,
        });
    }
    let material = root.push(json::Material {
        name: Some("face".to_string()),
        pbr_metallic_roughness: json::material::PbrMetallicRoughness {
            base_color_factor: json::material::PbrBaseColorFactor([0.85, 0.68, 0.58, 1.0]),
            metallic_factor: json::material::StrengthFactor(0.0),
            roughness_factor: json::material::StrengthFactor(0.6),
            ..Default::default()
        },
        double_sided: true,
        ..Default::default()
    });
    let mut attributes = std::collections::BTreeMap::new();
    attributes.insert(Valid(json::mesh::Semantic::Positions), a_pos);
    let names = serde_json::json!({ "targetNames": &crate::face::ARKIT_NAMES[..] });
    let mesh = root.push(json::Mesh {
        extensions: None,
        extras: Some(serde_json::value::to_raw_value(&names)?),
        name: Some("face".to_string()),
        primitives: vec![json::mesh::Primitive {
            attributes,
            extensions: None,
            extras: Default::default(),
            indices: Some(a_idx),
            material: Some(material),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: Some(targets),
        }],
        weights: Some(vec![0.0; crate::face::ARKIT_DIM]),
    });
    Ok(root.push(json::Node {
        mesh: Some(mesh),
        name: Some("face".to_string()),
        translation: Some(FACE_OFFSET),
        ..Default::default()
    }))
}

/// [`gltf_document`] with the face channel's head mesh and weights animation when `face` is given
/// (see the module docs).
// long: the glTF document assembled in the order of its sections (joints, mesh, skin, animation, face), each a commented block; to split into one function per section
pub fn gltf_document_with_face(
    motion: &Beat2Motion,
    face: Option<&FaceTrack>,
) -> Result<(json::Root, Vec<u8>)> {
    motion.validate()?;
    if let Some(f) = face {
        ensure!(
            f.arkit.dim() == (motion.len(), crate::face::ARKIT_DIM),
            "output: face arkit has shape {:?}, expected ({}, {})",
            f.arkit.dim(),
            motion.len(),
            crate::face::ARKIT_DIM
        );
    }
    let t_len = motion.len();
    ensure!(
        t_len > 0,
        "output: the motion has no frames; a glTF animation needs at least one keyframe"
    );
    let mut root = json::Root {
        asset: json::Asset {
            copyright: None,
            extensions: None,
            extras: Default::default(),
            generator: Some(GENERATOR.to_string()),
            min_version: None,
            version: "2.0".to_string(),
        },
        ..Default::default()
    };
    let mut bin = Bin { data: Vec::new() };
    use json::accessor::{ComponentType as C, Type as Ty};

    // joints
    let off = rest_offsets();
    for j in 0..N_JOINTS {
        let kids = children(j);
        root.push(json::Node {
            children: if kids.is_empty() {
                None
            } else {
                Some(kids.iter().map(|&c| json::Index::new(c as u32)).collect())
            },
            name: Some(JOINT_NAMES[j].to_string()),
            translation: Some(off[j].map(|x| x as f32)),
            ..Default::default()
        });
    }

    // mesh
    let mesh = body_mesh();
    let n_vert = mesh.positions.len() / 3;
    let weights: Vec<f32> = (0..n_vert).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect();
    let (lo, hi) = min_max(&mesh.positions, 3);
    let v = bin.view(
        &mut root,
        &f32_bytes(&mesh.positions),
        Some(json::buffer::Target::ArrayBuffer),
        None,
    );
    let a_pos = accessor(
        &mut root,
        v,
        n_vert,
        C::F32,
        Ty::Vec3,
        Some(lo),
        Some(hi),
        None,
    );
    let v = bin.view(
        &mut root,
        &f32_bytes(&mesh.normals),
        Some(json::buffer::Target::ArrayBuffer),
        None,
    );
    let a_nrm = accessor(&mut root, v, n_vert, C::F32, Ty::Vec3, None, None, None);
    let v = bin.view(
        &mut root,
        &mesh.joints,
        Some(json::buffer::Target::ArrayBuffer),
        None,
    );
    let a_jnt = accessor(&mut root, v, n_vert, C::U8, Ty::Vec4, None, None, None);
    let v = bin.view(
        &mut root,
        &f32_bytes(&weights),
        Some(json::buffer::Target::ArrayBuffer),
        None,
    );
    let a_wgt = accessor(&mut root, v, n_vert, C::F32, Ty::Vec4, None, None, None);
    let idx: Vec<u8> = mesh.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let v = bin.view(
        &mut root,
        &idx,
        Some(json::buffer::Target::ElementArrayBuffer),
        None,
    );
    let a_idx = accessor(
        &mut root,
        v,
        mesh.indices.len(),
        C::U16,
        Ty::Scalar,
        None,
        None,
        None,
    );
    let material = root.push(json::Material {
        name: Some("body".to_string()),
        pbr_metallic_roughness: json::material::PbrMetallicRoughness {
            base_color_factor: json::material::PbrBaseColorFactor([0.55, 0.62, 0.75, 1.0]),
            metallic_factor: json::material::StrengthFactor(0.0),
            roughness_factor: json::material::StrengthFactor(0.7),
            ..Default::default()
        },
        ..Default::default()
    });
    let mut attributes = std::collections::BTreeMap::new();
    attributes.insert(Valid(json::mesh::Semantic::Positions), a_pos);
    attributes.insert(Valid(json::mesh::Semantic::Normals), a_nrm);
    attributes.insert(Valid(json::mesh::Semantic::Joints(0)), a_jnt);
    attributes.insert(Valid(json::mesh::Semantic::Weights(0)), a_wgt);
    let mesh_index = root.push(json::Mesh {
        extensions: None,
        extras: Default::default(),
        name: Some("body".to_string()),
        primitives: vec![json::mesh::Primitive {
            attributes,
            extensions: None,
            extras: Default::default(),
            indices: Some(a_idx),
            material: Some(material),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }],
        weights: None,
    });

    // skin: inverse bind matrices undo the rest position (rest rotations are the identity)
    let rest = rest_joints();
    let mut ibm = Vec::with_capacity(16 * N_JOINTS);
    for p in rest.iter() {
        // column-major 4x4: identity with translation -p
        ibm.extend_from_slice(&[1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
        ibm.extend_from_slice(&[-p[0] as f32, -p[1] as f32, -p[2] as f32, 1.0]);
    }
    let v = bin.view(&mut root, &f32_bytes(&ibm), None, None);
    let a_ibm = accessor(&mut root, v, N_JOINTS, C::F32, Ty::Mat4, None, None, None);
    let skin = root.push(json::Skin {
        extensions: None,
        extras: Default::default(),
        inverse_bind_matrices: Some(a_ibm),
        joints: (0..N_JOINTS as u32).map(json::Index::new).collect(),
        name: Some("smplx".to_string()),
        skeleton: Some(json::Index::new(0)),
    });
    let mesh_node = root.push(json::Node {
        mesh: Some(mesh_index),
        skin: Some(skin),
        name: Some("body".to_string()),
        ..Default::default()
    });
    debug_assert_eq!(mesh_node.value(), MESH_NODE);
    if face.is_some() {
        let fnode = face_node(&mut root, &mut bin)?;
        debug_assert_eq!(fnode.value(), FACE_NODE);
        root.nodes[HEAD_JOINT]
            .children
            .get_or_insert_with(Vec::new)
            .push(fnode);
    }

    // animation
    let times: Vec<f32> = (0..t_len)
        .map(|t| Frame::time_of(t as u64) as f32)
        .collect();
    let v = bin.view(&mut root, &f32_bytes(&times), None, None);
    let a_time = accessor(
        &mut root,
        v,
        t_len,
        C::F32,
        Ty::Scalar,
        Some(vec![times[0]]),
        Some(vec![times[t_len - 1]]),
        Some("time"),
    );
    let mut samplers = Vec::with_capacity(N_JOINTS + 1);
    let mut channels = Vec::with_capacity(N_JOINTS + 1);
    let mut channel = |root: &mut json::Root,
                       data: &[f32],
                       ty: json::accessor::Type,
                       node: usize,
                       path: json::animation::Property| {
        let v = bin.view(root, &f32_bytes(data), None, None);
        let out = accessor(root, v, t_len, C::F32, ty, None, None, None);
        let s = json::Index::new(samplers.len() as u32);
        samplers.push(json::animation::Sampler {
            extensions: None,
            extras: Default::default(),
            input: a_time,
            interpolation: Valid(json::animation::Interpolation::Linear),
            output: out,
        });
        channels.push(json::animation::Channel {
            sampler: s,
            target: json::animation::Target {
                extensions: None,
                extras: Default::default(),
                node: json::Index::new(node as u32),
                path: Valid(path),
            },
            extensions: None,
            extras: Default::default(),
        });
    };
    let trans: Vec<f32> = (0..t_len)
        .flat_map(|t| {
            let r = motion.trans.row(t);
            [0, 1, 2].map(|k| (r[k] as f64 + off[0][k]) as f32)
        })
        .collect();
    channel(
        &mut root,
        &trans,
        Ty::Vec3,
        0,
        json::animation::Property::Translation,
    );
    for (j, keys) in rotation_keys(motion).iter().enumerate() {
        channel(
            &mut root,
            keys,
            Ty::Vec4,
            j,
            json::animation::Property::Rotation,
        );
    }
    if let Some(f) = face {
        // one key of 52 weights per frame: the output accessor holds T * 52 scalars
        let w: Vec<f32> = f.arkit.iter().copied().collect();
        let v = bin.view(&mut root, &f32_bytes(&w), None, None);
        let out = accessor(
            &mut root,
            v,
            w.len(),
            C::F32,
            Ty::Scalar,
            None,
            None,
            Some("arkit"),
        );
        let s = json::Index::new(samplers.len() as u32);
        samplers.push(json::animation::Sampler {
            extensions: None,
            extras: Default::default(),
            input: a_time,
            interpolation: Valid(json::animation::Interpolation::Linear),
            output: out,
        });
        channels.push(json::animation::Channel {
            sampler: s,
            target: json::animation::Target {
                extensions: None,
                extras: Default::default(),
                node: json::Index::new(FACE_NODE as u32),
                path: Valid(json::animation::Property::MorphTargetWeights),
            },
            extensions: None,
            extras: Default::default(),
        });
    }
    root.push(json::Animation {
        extensions: None,
        extras: Default::default(),
        channels,
        name: Some("motion".to_string()),
        samplers,
    });

    let scene = root.push(json::Scene {
        extensions: None,
        extras: Default::default(),
        name: Some("livegesture".to_string()),
        nodes: vec![json::Index::new(0), mesh_node],
    });
    root.scene = Some(scene);
    while !bin.data.len().is_multiple_of(4) {
        bin.data.push(0);
    }
    root.push(json::Buffer {
        byte_length: USize64(bin.data.len() as u64),
        name: None,
        uri: None,
        extensions: None,
        extras: Default::default(),
    });
    Ok((root, bin.data))
}

/// The `.glb` bytes of `motion`.
pub fn glb_bytes(motion: &Beat2Motion) -> Result<Vec<u8>> {
    glb_bytes_with_face(motion, None)
}

/// [`glb_bytes`] with the face channel when given.
pub fn glb_bytes_with_face(motion: &Beat2Motion, face: Option<&FaceTrack>) -> Result<Vec<u8>> {
    let (root, bin) = gltf_document_with_face(motion, face)?;
    let mut js = root.to_vec().context("output: serialising the glTF JSON")?;
    while !js.len().is_multiple_of(4) {
        js.push(b' ');
    }
    let total = 12 + 8 + js.len() + 8 + bin.len();
    let Ok(total32) = u32::try_from(total) else {
        bail!("output: the glTF binary would be {total} bytes, over the format's 4 GiB limit");
    };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&js);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    Ok(out)
}

/// The `.gltf` text of `motion` (buffer embedded as a base64 data URI).
pub fn gltf_text(motion: &Beat2Motion) -> Result<String> {
    gltf_text_with_face(motion, None)
}

/// [`gltf_text`] with the face channel when given.
pub fn gltf_text_with_face(motion: &Beat2Motion, face: Option<&FaceTrack>) -> Result<String> {
    let (mut root, bin) = gltf_document_with_face(motion, face)?;
    root.buffers[0].uri = Some(format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    ));
    root.to_string_pretty()
        .context("output: serialising the glTF JSON")
}

/// The glTF bytes of whole frames (in order, from index 0), in the given container: the library's
/// entry point for motion collected from a stream.
pub fn gltf_from_frames(frames: &[Frame], container: GltfContainer) -> Result<Vec<u8>> {
    let motion = Beat2Motion::from_frames(frames)?;
    let face = FaceTrack::from_frames(frames)?;
    match container {
        GltfContainer::Glb => glb_bytes_with_face(&motion, face.as_ref()),
        GltfContainer::Gltf => Ok(gltf_text_with_face(&motion, face.as_ref())?.into_bytes()),
    }
}

impl Beat2Motion {
    /// The motion of whole frames, in order from index 0 (as a stream emits them); an error names
    /// the first frame out of order or with a non-finite value.
    pub fn from_frames(frames: &[Frame]) -> Result<Self> {
        let t = frames.len();
        let mut poses = Vec::with_capacity(t * POSE_DIM);
        let mut trans = Vec::with_capacity(t * TRANS_DIM);
        let mut expressions = Vec::with_capacity(t * EXPR_DIM);
        for (i, f) in frames.iter().enumerate() {
            ensure!(
                f.index == i as u64,
                "output: frame {i} of the motion has index {}; expected the frames in order from 0",
                f.index
            );
            f.check_finite()?;
            poses.extend_from_slice(&f.poses);
            trans.extend_from_slice(&f.trans);
            expressions.extend_from_slice(&f.expressions);
        }
        Ok(Self {
            poses: ndarray::Array2::from_shape_vec((t, POSE_DIM), poses)?,
            trans: ndarray::Array2::from_shape_vec((t, TRANS_DIM), trans)?,
            expressions: ndarray::Array2::from_shape_vec((t, EXPR_DIM), expressions)?,
        })
    }
}

/// Writes `motion` as glTF to `path` (`.glb` or `.gltf`, by extension), atomically.
pub fn write_gltf(path: impl AsRef<Path>, motion: &Beat2Motion) -> Result<()> {
    write_gltf_with_face(path, motion, None)
}

/// [`write_gltf`] with the face channel's head mesh and weights when `face` is given.
pub fn write_gltf_with_face(
    path: impl AsRef<Path>,
    motion: &Beat2Motion,
    face: Option<&FaceTrack>,
) -> Result<()> {
    let path = path.as_ref();
    let Some(container) = GltfContainer::from_path(path) else {
        bail!(
            "output: {}: a glTF file name ends in .glb or .gltf",
            path.display()
        );
    };
    let bytes = match container {
        GltfContainer::Glb => glb_bytes_with_face(motion, face),
        GltfContainer::Gltf => gltf_text_with_face(motion, face).map(String::into_bytes),
    }
    .with_context(|| format!("output: refusing to write {}", path.display()))?;
    crate::output::write_atomically(path, |w| {
        w.write_all(&bytes)
            .with_context(|| format!("output: writing {}", path.display()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    fn motion(t: usize) -> Beat2Motion {
        let mut m = Beat2Motion {
            poses: Array2::zeros((t, 165)),
            trans: Array2::zeros((t, 3)),
            expressions: Array2::zeros((t, 100)),
        };
        for f in 0..t {
            // the left elbow turns about Y, through pi and beyond (a sign flip of w >= 0 quaternions)
            m.poses[[f, 3 * 18 + 1]] = 0.5 * f as f32;
            m.poses[[f, 3 * 22]] = 0.2;
            m.trans[[f, 0]] = 0.01 * f as f32;
        }
        m
    }

    #[test]
    fn document_layout() {
        let m = motion(10);
        let (root, bin) = gltf_document(&m).unwrap();
        assert_eq!(root.nodes.len(), N_JOINTS + 1);
        assert_eq!(root.nodes[0].name.as_deref(), Some("pelvis"));
        assert_eq!(root.nodes[22].name.as_deref(), Some("jaw"));
        assert_eq!(root.skins[0].joints.len(), N_JOINTS);
        let anim = &root.animations[0];
        assert_eq!(anim.channels.len(), N_JOINTS + 1);
        assert_eq!(root.accessors[anim.samplers[0].input.value()].count.0, 10);
        assert_eq!(root.buffers[0].byte_length.0 as usize, bin.len());
        assert_eq!(bin.len() % 4, 0);
        // every view lies within the buffer and every accessor's offset is aligned
        for v in &root.buffer_views {
            let o = v.byte_offset.unwrap().0 as usize;
            assert_eq!(o % 4, 0);
            assert!(o + v.byte_length.0 as usize <= bin.len());
        }
    }

    #[test]
    fn rotations_match_the_axis_angle_and_stay_continuous() {
        let m = motion(12);
        let keys = rotation_keys(&m);
        for t in 0..12 {
            let q = &keys[18][4 * t..4 * t + 4];
            let n: f32 = q.iter().map(|x| x * x).sum();
            assert!((n - 1.0).abs() < 1e-6);
            // rotation about Y by 0.5 t: (0, +-sin, 0, +-cos) with one sign
            let a = 0.5 * t as f32;
            let s = if q[1] * (a / 2.0).sin() >= 0.0 {
                1.0
            } else {
                -1.0
            };
            assert!((q[1] - s * (a / 2.0).sin()).abs() < 1e-5, "{t}: {q:?}");
            assert!((q[3] - s * (a / 2.0).cos()).abs() < 1e-5, "{t}: {q:?}");
            if t > 0 {
                let p = &keys[18][4 * t - 4..4 * t];
                let d: f32 = (0..4).map(|i| p[i] * q[i]).sum();
                assert!(d > 0.0, "hemisphere jump at frame {t}");
            }
        }
    }

    #[test]
    fn glb_container_and_gltf_text() {
        let m = motion(3);
        let glb = glb_bytes(&m).unwrap();
        assert_eq!(&glb[0..4], b"glTF");
        assert_eq!(u32::from_le_bytes(glb[4..8].try_into().unwrap()), 2);
        assert_eq!(
            u32::from_le_bytes(glb[8..12].try_into().unwrap()) as usize,
            glb.len()
        );
        let jlen = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
        assert_eq!(&glb[16..20], b"JSON");
        let root = json::Root::from_slice(&glb[20..20 + jlen]).unwrap();
        assert!(root.buffers[0].uri.is_none());
        assert_eq!(&glb[20 + jlen + 4..20 + jlen + 8], b"BIN\0");
        let text = gltf_text(&m).unwrap();
        let root = json::Root::from_str(&text).unwrap();
        assert!(root.buffers[0]
            .uri
            .as_deref()
            .unwrap()
            .starts_with("data:application/octet-stream;base64,"));
    }

    #[test]
    fn bad_motion_is_refused() {
        let mut m = motion(2);
        m.poses[[1, 5]] = f32::NAN;
        assert!(glb_bytes(&m).is_err());
        assert!(glb_bytes(&motion(0)).is_err());
        let dir = tempfile::tempdir().unwrap();
        assert!(write_gltf(dir.path().join("x.fbx"), &motion(2)).is_err());
        assert!(write_gltf(dir.path().join("x.glb"), &m).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}

//! BVH output (`generate -o motion.bvh`, docs/output.md) on the project's own skeleton ([`crate::skeleton`]).
//!
//! - `HIERARCHY`: the 55 SMPL-X joints with their SMPL-X names and parents; `OFFSET`s are the
//!   project's rest offsets in **centimetres** (the usual BVH unit; in Blender import with scale 0.01
//!   to get metres). Y is up, the body faces +Z. The root (`pelvis`) has `OFFSET 0 0 0` and six
//!   channels `Xposition Yposition Zposition Zrotation Xrotation Yrotation`; its position channels
//!   are the pelvis position `trans + rest offset of the pelvis` (cm), so readers that add the root
//!   offset and readers that do not agree. Every other joint has `Zrotation Xrotation Yrotation`.
//!   A joint without children ends in an `End Site` half as long as its own offset.
//! - `MOTION`: 30 fps (`Frame Time: 0.0333333`), one line per frame. Each joint's local rotation is
//!   the frame's axis-angle as a matrix `R`, written as Euler angles in degrees with
//!   `R = Rz(z) * Rx(x) * Ry(y)` (the channel order, applied to column vectors).
//! - Face parameters (jaw opening aside, which is the `jaw` joint) cannot live in BVH; expressions stay
//!   in the `.npz`.
//!
//! The file is written atomically (a temporary file in the destination folder, renamed).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use anyhow::{Context, Result};

use crate::output::{Beat2Motion, FPS};
use crate::rotation::{axis_angle_to_matrix, Mat3};
use crate::skeleton::{children, rest_offsets, JOINT_NAMES, N_JOINTS, PARENTS};

/// Centimetres per metre (BVH lengths are in cm).
pub const BVH_SCALE: f64 = 100.0;

/// `R = Rz(z) Rx(x) Ry(y)` -> (z, x, y) in radians.
pub fn matrix_to_euler_zxy(r: &Mat3) -> [f64; 3] {
    let sx = r[2][1].clamp(-1.0, 1.0);
    let x = sx.asin();
    if sx.abs() < 1.0 - 1e-9 {
        let y = (-r[2][0]).atan2(r[2][2]);
        let z = (-r[0][1]).atan2(r[1][1]);
        [z, x, y]
    } else {
        // gimbal lock (x = +-90 deg): y folded into z
        let z = r[1][0].atan2(r[0][0]);
        [z, x, 0.0]
    }
}

/// `Rz(z) Rx(x) Ry(y)` from angles in radians.
pub fn euler_zxy_to_matrix(z: f64, x: f64, y: f64) -> Mat3 {
    let (sz, cz) = z.sin_cos();
    let (sx, cx) = x.sin_cos();
    let (sy, cy) = y.sin_cos();
    let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    mul(&mul(&rz, &rx), &ry)
}

fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut o = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            o[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    o
}

fn write_joint(out: &mut String, j: usize, depth: usize, off: &[[f64; 3]; N_JOINTS]) {
    let ind = "  ".repeat(depth);
    let o = if PARENTS[j] < 0 { [0.0; 3] } else { off[j] };
    let kind = if PARENTS[j] < 0 { "ROOT" } else { "JOINT" };
    let _ = writeln!(out, "{ind}{kind} {}", JOINT_NAMES[j]);
    let _ = writeln!(out, "{ind}{{");
    let _ = writeln!(
        out,
        "{ind}  OFFSET {:.6} {:.6} {:.6}",
        o[0] * BVH_SCALE,
        o[1] * BVH_SCALE,
        o[2] * BVH_SCALE
    );
    if PARENTS[j] < 0 {
        let _ = writeln!(
            out,
            "{ind}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
        );
    } else {
        let _ = writeln!(out, "{ind}  CHANNELS 3 Zrotation Xrotation Yrotation");
    }
    let kids = children(j);
    if kids.is_empty() {
        let e = off[j].map(|v| v * 0.5 * BVH_SCALE);
        let _ = writeln!(
            out,
            "{ind}  End Site\n{ind}  {{\n{ind}    OFFSET {:.6} {:.6} {:.6}\n{ind}  }}",
            e[0], e[1], e[2]
        );
    }
    for c in kids {
        write_joint(out, c, depth + 1, off);
    }
    let _ = writeln!(out, "{ind}}}");
}

/// Joints in the order their channels appear in a frame line (depth-first, children in joint order).
pub fn channel_order() -> Vec<usize> {
    fn visit(j: usize, out: &mut Vec<usize>) {
        out.push(j);
        for c in children(j) {
            visit(c, out);
        }
    }
    let mut v = Vec::with_capacity(N_JOINTS);
    visit(0, &mut v);
    v
}

/// The BVH text of `motion`.
pub fn bvh_text(motion: &Beat2Motion) -> Result<String> {
    motion.validate()?;
    let off = rest_offsets();
    let mut s = String::with_capacity(8192 + motion.len() * N_JOINTS * 3 * 12);
    s.push_str("HIERARCHY\n");
    write_joint(&mut s, 0, 0, &off);
    let _ = writeln!(
        s,
        "MOTION\nFrames: {}\nFrame Time: {:.7}",
        motion.len(),
        1.0 / FPS as f64
    );
    let order = channel_order();
    for t in 0..motion.len() {
        let tr = motion.trans.row(t);
        let mut line = String::with_capacity(N_JOINTS * 3 * 12 + 40);
        for k in 0..3 {
            let _ = write!(line, "{:.6} ", (tr[k] as f64 + off[0][k]) * BVH_SCALE);
        }
        let p = motion.poses.row(t);
        for (n, &j) in order.iter().enumerate() {
            let aa = [p[3 * j] as f64, p[3 * j + 1] as f64, p[3 * j + 2] as f64];
            let [z, x, y] = matrix_to_euler_zxy(&axis_angle_to_matrix(aa));
            let sep = if n + 1 == order.len() { "" } else { " " };
            let _ = write!(
                line,
                "{:.6} {:.6} {:.6}{sep}",
                z.to_degrees(),
                x.to_degrees(),
                y.to_degrees()
            );
        }
        s.push_str(&line);
        s.push('\n');
    }
    Ok(s)
}

/// Writes `motion` as BVH to `path`, atomically.
pub fn write_bvh(path: impl AsRef<Path>, motion: &Beat2Motion) -> Result<()> {
    let path = path.as_ref();
    let text = bvh_text(motion)
        .with_context(|| format!("output: refusing to write {}", path.display()))?;
    crate::output::write_atomically(path, |w| {
        w.write_all(text.as_bytes())
            .with_context(|| format!("output: writing {}", path.display()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array2;

    #[test]
    fn euler_round_trip() {
        let mut worst: f64 = 0.0;
        let mut seed = 1u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        for _ in 0..2000 {
            let aa = [rnd() * 3.0, rnd() * 3.0, rnd() * 3.0];
            let r = axis_angle_to_matrix(aa);
            let [z, x, y] = matrix_to_euler_zxy(&r);
            let r2 = euler_zxy_to_matrix(z, x, y);
            for i in 0..3 {
                for j in 0..3 {
                    worst = worst.max((r[i][j] - r2[i][j]).abs());
                }
            }
        }
        assert!(worst < 1e-9, "{worst}");
        // gimbal lock: x = 90 deg
        let r = euler_zxy_to_matrix(0.3, std::f64::consts::FRAC_PI_2, 0.2);
        let [z, x, y] = matrix_to_euler_zxy(&r);
        let r2 = euler_zxy_to_matrix(z, x, y);
        for i in 0..3 {
            for j in 0..3 {
                assert!((r[i][j] - r2[i][j]).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn text_layout() {
        let m = Beat2Motion {
            poses: Array2::zeros((2, 165)),
            trans: Array2::zeros((2, 3)),
            expressions: Array2::zeros((2, 100)),
        };
        let t = bvh_text(&m).unwrap();
        assert_eq!(t.matches("JOINT ").count() + t.matches("ROOT ").count(), 55);
        assert_eq!(t.matches('{').count(), t.matches('}').count());
        assert!(t.contains("Frames: 2\nFrame Time: 0.0333333\n"));
        let last = t.lines().last().unwrap();
        assert_eq!(last.split(' ').count(), 6 + 54 * 3);
        assert!(last.starts_with("0.000000 95.000000 0.000000 "));
        let mut bad = m.clone();
        bad.poses[[0, 4]] = f32::NAN;
        assert!(bvh_text(&bad).is_err());
    }
}

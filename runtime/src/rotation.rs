//! Rotation conversions with the pytorch3d conventions of `python/livegesture/rotation.py`.
//!
//! - **rot6d** is the first two **rows** of the rotation matrix (`R[..2, ..]` flattened, 6 numbers).
//!   It is decoded by Gram–Schmidt: `b1 = a1 / |a1|`, `b2 = normalize(a2 - (b1 · a2) b1)`,
//!   `b3 = b1 × b2`, and the matrix rows are `b1, b2, b3`. Normalisation divides by
//!   `max(|v|, 1e-12)` as `torch.nn.functional.normalize` does.
//! - **matrix → quaternion** `(w, x, y, z)` uses pytorch3d's robust choice among four candidates: the
//!   candidate built from the largest of `sqrt(max(0, 1 ± m00 ± m11 ± m22))`, divided by
//!   `2 max(q_abs, 0.1)`, normalised, and flipped so that `w >= 0`.
//! - **quaternion → axis-angle**: `half = atan2(|xyz|, w)`, `aa = xyz * (2 half / sin(half))`, with the
//!   series `2 + half² / 3` when `|xyz| < 1e-6`.
//! - **axis-angle → matrix**: Rodrigues `I + a K + b K²` with `a = sin θ / θ`, `b = (1 - cos θ) / θ²`,
//!   and the series `a = 1 - θ²/6`, `b = 1/2 - θ²/24` when `θ² < 1e-8`.
//!
//! Axis-angle goes through a unit quaternion, which is stable near angle 0 and near pi. All internal
//! arithmetic is `f64`; the convenience functions take and return `f32` as the model tensors do.

use anyhow::{ensure, Result};

/// A 3×3 matrix, row-major (`m[row][col]`).
pub type Mat3 = [[f64; 3]; 3];

const NORM_EPS: f64 = 1e-12;

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize<const N: usize>(v: [f64; N]) -> [f64; N] {
    let n = v.iter().map(|x| x * x).sum::<f64>().sqrt().max(NORM_EPS);
    v.map(|x| x / n)
}

/// rot6d (first two rows) → rotation matrix by Gram–Schmidt.
pub fn rot6d_to_matrix(d6: [f64; 6]) -> Mat3 {
    let a1 = [d6[0], d6[1], d6[2]];
    let a2 = [d6[3], d6[4], d6[5]];
    let b1 = normalize(a1);
    let p = dot(b1, a2);
    let b2 = normalize([a2[0] - p * b1[0], a2[1] - p * b1[1], a2[2] - p * b1[2]]);
    let b3 = cross(b1, b2);
    [b1, b2, b3]
}

/// Rotation matrix → rot6d (its first two rows).
pub fn matrix_to_rot6d(r: &Mat3) -> [f64; 6] {
    [r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2]]
}

/// Rotation matrix → unit quaternion `(w, x, y, z)` with `w >= 0` (pytorch3d's robust branch choice).
pub fn matrix_to_quaternion(r: &Mat3) -> [f64; 4] {
    let [[m00, m01, m02], [m10, m11, m12], [m20, m21, m22]] = *r;
    let q_abs = [
        (1.0 + m00 + m11 + m22).max(0.0).sqrt(),
        (1.0 + m00 - m11 - m22).max(0.0).sqrt(),
        (1.0 - m00 + m11 - m22).max(0.0).sqrt(),
        (1.0 - m00 - m11 + m22).max(0.0).sqrt(),
    ];
    // argmax, first index on ties (as torch.argmax)
    let mut idx = 0;
    for i in 1..4 {
        if q_abs[i] > q_abs[idx] {
            idx = i;
        }
    }
    let cand = match idx {
        0 => [q_abs[0] * q_abs[0], m21 - m12, m02 - m20, m10 - m01],
        1 => [m21 - m12, q_abs[1] * q_abs[1], m10 + m01, m02 + m20],
        2 => [m02 - m20, m10 + m01, q_abs[2] * q_abs[2], m12 + m21],
        _ => [m10 - m01, m20 + m02, m21 + m12, q_abs[3] * q_abs[3]],
    };
    let denom = 2.0 * q_abs[idx].max(0.1);
    let q = normalize(cand.map(|x| x / denom));
    if q[0] < 0.0 {
        q.map(|x| -x)
    } else {
        q
    }
}

/// Unit quaternion `(w, x, y, z)`, `w >= 0` → axis-angle (axis × angle).
pub fn quaternion_to_axis_angle(q: [f64; 4]) -> [f64; 3] {
    let xyz = [q[1], q[2], q[3]];
    let s = dot(xyz, xyz).sqrt();
    let half = s.atan2(q[0]);
    let factor = if s < 1e-6 {
        2.0 + half * half / 3.0
    } else {
        2.0 * half / half.sin()
    };
    xyz.map(|x| x * factor)
}

/// Axis-angle → rotation matrix (Rodrigues with the small-angle series).
pub fn axis_angle_to_matrix(aa: [f64; 3]) -> Mat3 {
    let theta2 = dot(aa, aa);
    let theta = theta2.max(1e-24).sqrt();
    let (a, b) = if theta2 < 1e-8 {
        (1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0)
    } else {
        (theta.sin() / theta, (1.0 - theta.cos()) / theta2.max(1e-24))
    };
    let [x, y, z] = aa;
    let k = [[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]];
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let kk: f64 = (0..3).map(|l| k[i][l] * k[l][j]).sum();
            r[i][j] = if i == j { 1.0 } else { 0.0 } + a * k[i][j] + b * kk;
        }
    }
    r
}

/// Rotation matrix → axis-angle (through the quaternion).
pub fn matrix_to_axis_angle(r: &Mat3) -> [f64; 3] {
    quaternion_to_axis_angle(matrix_to_quaternion(r))
}

/// rot6d → axis-angle, `f32` in and out (`f64` inside).
pub fn rot6d_to_axis_angle(d6: [f32; 6]) -> [f32; 3] {
    matrix_to_axis_angle(&rot6d_to_matrix(d6.map(f64::from))).map(|x| x as f32)
}

/// Axis-angle → rot6d, `f32` in and out (`f64` inside).
pub fn axis_angle_to_rot6d(aa: [f32; 3]) -> [f32; 6] {
    matrix_to_rot6d(&axis_angle_to_matrix(aa.map(f64::from))).map(|x| x as f32)
}

/// Converts a flat run of joints from rot6d (`6 n` values) to axis-angle (`3 n` values).
pub fn rot6d_slice_to_axis_angle(d6: &[f32]) -> Result<Vec<f32>> {
    ensure!(
        d6.len().is_multiple_of(6),
        "rotation: rot6d data has {} values, not a multiple of 6",
        d6.len()
    );
    let mut out = Vec::with_capacity(d6.len() / 2);
    for c in d6.chunks_exact(6) {
        out.extend(rot6d_to_axis_angle([c[0], c[1], c[2], c[3], c[4], c[5]]));
    }
    Ok(out)
}

/// Converts a flat run of joints from axis-angle (`3 n` values) to rot6d (`6 n` values).
pub fn axis_angle_slice_to_rot6d(aa: &[f32]) -> Result<Vec<f32>> {
    ensure!(
        aa.len().is_multiple_of(3),
        "rotation: axis-angle data has {} values, not a multiple of 3",
        aa.len()
    );
    let mut out = Vec::with_capacity(aa.len() * 2);
    for c in aa.chunks_exact(3) {
        out.extend(axis_angle_to_rot6d([c[0], c[1], c[2]]));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn mat_close(a: &Mat3, b: &Mat3, tol: f64) -> bool {
        (0..3).all(|i| (0..3).all(|j| (a[i][j] - b[i][j]).abs() <= tol))
    }

    fn axes() -> Vec<[f64; 3]> {
        vec![
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            normalize([1.0, 2.0, -3.0]),
            normalize([-0.3, 0.1, 0.9]),
        ]
    }

    #[test]
    fn round_trip_all_angles() {
        for axis in axes() {
            for angle in [
                0.0,
                1e-9,
                1e-7,
                1e-4,
                0.01,
                0.5,
                1.0,
                2.0,
                3.0,
                PI - 1e-3,
                PI - 1e-6,
            ] {
                let aa = axis.map(|x| x * angle);
                let r = axis_angle_to_matrix(aa);
                // orthonormal
                for i in 0..3 {
                    for j in 0..3 {
                        let d = dot(r[i], r[j]);
                        assert!((d - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
                    }
                }
                // rot6d -> matrix reproduces the matrix
                assert!(mat_close(&rot6d_to_matrix(matrix_to_rot6d(&r)), &r, 1e-12));
                // matrix -> axis-angle -> matrix
                let back = matrix_to_axis_angle(&r);
                assert!(
                    mat_close(&axis_angle_to_matrix(back), &r, 1e-9),
                    "axis {axis:?} angle {angle}"
                );
                // away from pi the axis-angle itself comes back
                if angle < 3.1 {
                    for k in 0..3 {
                        assert!(
                            (back[k] - aa[k]).abs() < 1e-9,
                            "axis {axis:?} angle {angle}: {back:?} vs {aa:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn exactly_pi_gives_angle_pi() {
        for axis in axes() {
            let r = axis_angle_to_matrix(axis.map(|x| x * PI));
            let aa = matrix_to_axis_angle(&r);
            let n = dot(aa, aa).sqrt();
            assert!((n - PI).abs() < 1e-7, "{n}");
            let c = dot(aa, axis) / n;
            assert!((c.abs() - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn quaternion_has_nonnegative_w_and_unit_norm() {
        for axis in axes() {
            for angle in [0.0, 0.3, 2.9, PI] {
                let q = matrix_to_quaternion(&axis_angle_to_matrix(axis.map(|x| x * angle)));
                assert!(q[0] >= 0.0);
                assert!(
                    (dot([q[0], q[1], q[2]], [q[0], q[1], q[2]]) + q[3] * q[3] - 1.0).abs() < 1e-12
                );
            }
        }
    }

    #[test]
    fn gram_schmidt_of_unnormalised_input() {
        let r = rot6d_to_matrix([2.0, 0.0, 0.0, 1.0, 3.0, 0.0]);
        assert!(mat_close(
            &r,
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            1e-15
        ));
        // degenerate input does not produce NaN
        let z = rot6d_to_matrix([0.0; 6]);
        assert!(z.iter().flatten().all(|x| x.is_finite()));
    }

    #[test]
    fn f32_slices() {
        let aa = [0.1f32, -0.2, 0.3, 0.0, 0.0, 0.0];
        let d6 = axis_angle_slice_to_rot6d(&aa).unwrap();
        assert_eq!(d6.len(), 12);
        let back = rot6d_slice_to_axis_angle(&d6).unwrap();
        for (a, b) in aa.iter().zip(&back) {
            assert!((a - b).abs() < 1e-6);
        }
        assert!(rot6d_slice_to_axis_angle(&[0.0; 7]).is_err());
        assert!(axis_angle_slice_to_rot6d(&[0.0; 4]).is_err());
    }
}

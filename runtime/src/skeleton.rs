//! The project's own SMPL-X-like skeleton: the Rust mirror of `python/livegesture/skeleton.py`.
//!
//! Standard SMPL-X joint order, names and parents (55 joints); rest offsets in metres that the project
//! defines itself (Y up, the body faces +Z, the character's left is +X), since SMPL-X's are licensed.
//! `poses[3j..3j+3]` is joint j's axis-angle rotation relative to its parent (joint 0's is global);
//! the pelvis sits at `trans + REST_OFFSETS[0]`. A test checks that both definitions agree.

/// Number of joints.
pub const N_JOINTS: usize = 55;

/// Parent of every joint (`-1` for the root).
pub const PARENTS: [i32; N_JOINTS] = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15, 20, 25,
    26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38, 21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49,
    50, 21, 52, 53,
];

/// SMPL-X joint names.
pub const JOINT_NAMES: [&str; N_JOINTS] = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "jaw",
    "left_eye_smplhf",
    "right_eye_smplhf",
    "left_index1",
    "left_index2",
    "left_index3",
    "left_middle1",
    "left_middle2",
    "left_middle3",
    "left_pinky1",
    "left_pinky2",
    "left_pinky3",
    "left_ring1",
    "left_ring2",
    "left_ring3",
    "left_thumb1",
    "left_thumb2",
    "left_thumb3",
    "right_index1",
    "right_index2",
    "right_index3",
    "right_middle1",
    "right_middle2",
    "right_middle3",
    "right_pinky1",
    "right_pinky2",
    "right_pinky3",
    "right_ring1",
    "right_ring2",
    "right_ring3",
    "right_thumb1",
    "right_thumb2",
    "right_thumb3",
];

const BODY: [[f64; 3]; 25] = [
    [0.0, 0.95, 0.0],
    [0.062, -0.090, -0.005],
    [-0.062, -0.090, -0.005],
    [0.0, 0.110, -0.015],
    [0.035, -0.380, 0.005],
    [-0.035, -0.380, 0.005],
    [0.0, 0.130, 0.005],
    [-0.010, -0.400, -0.040],
    [0.010, -0.400, -0.040],
    [0.0, 0.055, 0.025],
    [0.020, -0.055, 0.120],
    [-0.020, -0.055, 0.120],
    [0.0, 0.215, -0.035],
    [0.075, 0.120, -0.020],
    [-0.075, 0.120, -0.020],
    [0.0, 0.090, 0.050],
    [0.110, 0.035, -0.010],
    [-0.110, 0.035, -0.010],
    [0.260, -0.012, -0.020],
    [-0.260, -0.012, -0.020],
    [0.252, 0.008, 0.000],
    [-0.252, 0.008, 0.000],
    [0.0, -0.010, 0.030],
    [0.032, 0.060, 0.090],
    [-0.032, 0.060, 0.090],
];

/// Left-hand finger offsets (proximal from the wrist, middle, distal); order index, middle, pinky,
/// ring, thumb. The right hand mirrors X.
const LEFT_HAND: [[[f64; 3]; 3]; 5] = [
    [
        [0.090, -0.004, 0.026],
        [0.036, -0.002, 0.000],
        [0.025, -0.002, 0.000],
    ],
    [
        [0.095, -0.002, 0.004],
        [0.038, -0.002, 0.000],
        [0.027, -0.002, 0.000],
    ],
    [
        [0.078, -0.008, -0.036],
        [0.022, -0.002, 0.000],
        [0.019, -0.002, 0.000],
    ],
    [
        [0.088, -0.005, -0.017],
        [0.033, -0.002, 0.000],
        [0.025, -0.002, 0.000],
    ],
    [
        [0.030, -0.015, 0.028],
        [0.028, -0.006, 0.020],
        [0.024, -0.002, 0.014],
    ],
];

/// Rest offsets from the parent joint in metres (joint 0: the pelvis at `trans = 0`).
pub fn rest_offsets() -> [[f64; 3]; N_JOINTS] {
    let mut off = [[0.0; 3]; N_JOINTS];
    off[..25].copy_from_slice(&BODY);
    for (side, base) in [(1.0, 25), (-1.0, 40)] {
        for (fi, finger) in LEFT_HAND.iter().enumerate() {
            for (k, v) in finger.iter().enumerate() {
                off[base + 3 * fi + k] = [side * v[0], v[1], v[2]];
            }
        }
    }
    off
}

/// Joint positions of the rest pose with `trans = 0`.
pub fn rest_joints() -> [[f64; 3]; N_JOINTS] {
    let off = rest_offsets();
    let mut out = [[0.0; 3]; N_JOINTS];
    for j in 0..N_JOINTS {
        out[j] = match PARENTS[j] {
            p if p < 0 => off[j],
            p => {
                let q = out[p as usize];
                [q[0] + off[j][0], q[1] + off[j][1], q[2] + off[j][2]]
            }
        };
    }
    out
}

/// The skeleton as JSON: `names`, `parents` (-1 for the root), `offsets` (metres, from the parent,
/// [`rest_offsets`]) and `units` (`m`): what the browser page poses, served by `livegesture serve`
/// as `/skeleton.json` and returned by the WebAssembly binding's `skeletonJson()`.
pub fn skeleton_json() -> String {
    serde_json::json!({
        "names": &JOINT_NAMES[..],
        "parents": &PARENTS[..],
        "offsets": rest_offsets().to_vec(),
        "units": "m",
    })
    .to_string()
}

/// Children of joint `j`, in joint order.
pub fn children(j: usize) -> Vec<usize> {
    (0..N_JOINTS).filter(|&c| PARENTS[c] == j as i32).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tree_is_consistent() {
        for (j, &p) in PARENTS.iter().enumerate() {
            assert!(p < j as i32, "joint {j} has parent {p} after it");
        }
        assert_eq!(children(20), vec![25, 28, 31, 34, 37]); // left wrist: five fingers
        assert_eq!(children(15), vec![22, 23, 24]); // head: jaw and eyes
    }
}

//! `livegesture generate -o x.glb / x.gltf` (docs/avatars.md) and the output-name check: the glTF files
//! hold the same motion as the npz of the same run, and a name the CLI does not write is refused.
//! The Khronos validator and Blender check the files in scripts/test.sh (runtime/web/tests/gltf-validate.mjs,
//! runtime/tests/blender/check_import.py).

use livegesture_parity_tests as common;

use std::path::Path;
use std::process::Output;

use gltf_json as json;
use livegesture::compare::{diff, Diff};
use livegesture::output::read_beat2_npz;
use livegesture::skeleton::{rest_offsets, JOINT_NAMES, N_JOINTS};

fn generate(wav: &Path, out: &Path) -> Output {
    crate::support::livegesture()
        .args([
            "generate",
            wav.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--bundle", common::tiny_bundle().to_str().unwrap()])
        .args(["--backend", "tract", "--seed", "4"])
        .output()
        .expect("run livegesture")
}

fn short_wav(dir: &Path, seconds: f64) -> std::path::PathBuf {
    let mut r = hound::WavReader::open(common::tiny_bundle().join("reference/clip.wav")).unwrap();
    let spec = r.spec();
    let n = (seconds * spec.sample_rate as f64) as usize * spec.channels as usize;
    let p = dir.join("speech.wav");
    let mut w = hound::WavWriter::create(&p, spec).unwrap();
    for s in r.samples::<i16>().take(n) {
        w.write_sample(s.unwrap()).unwrap();
    }
    w.finalize().unwrap();
    p
}

/// The JSON document and binary buffer of a .glb file.
fn read_glb(p: &Path) -> (json::Root, Vec<u8>) {
    let b = std::fs::read(p).unwrap();
    assert_eq!(&b[..4], b"glTF", "{}: no glTF magic", p.display());
    assert_eq!(
        u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize,
        b.len()
    );
    let jl = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
    let root = json::Root::from_slice(&b[20..20 + jl]).unwrap();
    let bl = u32::from_le_bytes(b[20 + jl..24 + jl].try_into().unwrap()) as usize;
    (root, b[28 + jl..28 + jl + bl].to_vec())
}

fn floats(root: &json::Root, bin: &[u8], accessor: usize) -> Vec<f32> {
    let a = &root.accessors[accessor];
    let v = &root.buffer_views[a.buffer_view.unwrap().value()];
    let start =
        v.byte_offset.map_or(0, |o| o.0 as usize) + a.byte_offset.map_or(0, |o| o.0 as usize);
    bin[start..start + v.byte_length.0 as usize]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

/// The rotation matrix of an axis-angle vector by Rodrigues' formula, written here independently of
/// the writer (`R = I + sin(t) K + (1 - cos(t)) K^2`, `K` the cross-product matrix of the unit axis),
/// row-major.
fn rodrigues(v: [f32; 3]) -> [f64; 9] {
    let v = v.map(f64::from);
    let t = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if t < 1e-12 {
        return [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    }
    let (x, y, z) = (v[0] / t, v[1] / t, v[2] / t);
    let k = [0.0, -z, y, z, 0.0, -x, -y, x, 0.0];
    let mut r = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            let kk: f64 = (0..3).map(|m| k[3 * i + m] * k[3 * m + j]).sum();
            r[3 * i + j] =
                f64::from(u8::from(i == j)) + t.sin() * k[3 * i + j] + (1.0 - t.cos()) * kk;
        }
    }
    r
}

/// The rotation matrix of a glTF quaternion `(x, y, z, w)` (row-major), not normalised: a key that is
/// not a unit quaternion gives a matrix that is not the rotation.
fn quaternion_matrix(q: &[f32]) -> [f64; 9] {
    let [x, y, z, w] = [q[0], q[1], q[2], q[3]].map(f64::from);
    [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - z * w),
        2.0 * (x * z + y * w),
        2.0 * (x * y + z * w),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - x * w),
        2.0 * (x * z - y * w),
        2.0 * (y * z + x * w),
        1.0 - 2.0 * (x * x + y * y),
    ]
}

/// glTF rotation keys (`4 x n` floats) against the axis-angles they stand for (`3 x n`), through the
/// shared comparison (NaN or Inf on either side, nothing compared, count mismatch: fails): the
/// matrices of both, element by element.
fn rotations_vs_oracle(keys: &[f32], axis_angles: &[f32]) -> Diff {
    let (mut got, mut want) = (Vec::new(), Vec::new());
    if keys.len() / 4 != axis_angles.len() / 3 {
        return diff(&[], &[0.0]);
    }
    for (q, v) in keys.chunks_exact(4).zip(axis_angles.chunks_exact(3)) {
        got.extend(quaternion_matrix(q).map(|x| x as f32));
        want.extend(rodrigues([v[0], v[1], v[2]]).map(|x| x as f32));
    }
    diff(&got, &want)
}

/// issue 38 item 6: the oracle is independent of the writer. A quaternion convention bug (the
/// conjugate: the inverse rotation) agrees with itself, as the old check that used the writer's
/// function on both sides measured, and fails the Rodrigues oracle; so does a NaN key.
#[test]
fn the_rotation_oracle_catches_a_convention_bug_and_nan() {
    use livegesture::output::gltf::axis_angle_to_gltf_quaternion;
    let aa: Vec<[f32; 3]> = vec![
        [0.3, -0.2, 0.9],
        [1.5, 0.1, -0.4],
        [0.0, 0.0, 0.0],
        [-2.0, 1.0, 0.5],
    ];
    let flat: Vec<f32> = aa.iter().flatten().copied().collect();
    let keys: Vec<f32> = aa
        .iter()
        .flat_map(|v| axis_angle_to_gltf_quaternion(*v))
        .collect();
    let d = rotations_vs_oracle(&keys, &flat);
    assert!(d.within(1e-6), "the writer's keys vs Rodrigues: {d}");
    // the conjugate (x, y, z negated): the same function on both sides agrees with itself exactly
    let conj = |q: [f32; 4]| [-q[0], -q[1], -q[2], q[3]];
    let bad: Vec<f32> = aa
        .iter()
        .flat_map(|v| conj(axis_angle_to_gltf_quaternion(*v)))
        .collect();
    let old_worst = aa
        .iter()
        .map(|v| {
            let (w, g) = (
                conj(axis_angle_to_gltf_quaternion(*v)),
                conj(axis_angle_to_gltf_quaternion(*v)),
            );
            1.0 - (0..4).map(|i| w[i] * g[i]).sum::<f32>().abs()
        })
        .fold(0f32, f32::max);
    assert!(
        old_worst < 1e-6,
        "premise: the writer-as-oracle check passes the bug"
    );
    assert!(!rotations_vs_oracle(&bad, &flat).within(1e-3));
    let mut nan = keys.clone();
    nan[5] = f32::NAN;
    let d = rotations_vs_oracle(&nan, &flat);
    assert!(!d.within(f64::MAX) && d.nonfinite.is_some(), "{d}");
    assert!(!rotations_vs_oracle(&keys[..8], &flat).within(f64::MAX));
}

#[test]
fn glb_and_gltf_hold_the_npz_motion() {
    let tmp = tempfile::tempdir().unwrap();
    let wav = short_wav(tmp.path(), 2.3);
    for name in ["m.npz", "m.glb", "m.gltf"] {
        let o = generate(&wav, &tmp.path().join(name));
        assert!(
            o.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let npz = read_beat2_npz(tmp.path().join("m.npz")).unwrap();
    let t_len = npz.len();
    assert_eq!(t_len, (2.3f64 * 30.0).ceil() as usize);
    let (root, bin) = read_glb(&tmp.path().join("m.glb"));
    assert_eq!(root.skins[0].joints.len(), N_JOINTS);
    let off = rest_offsets();
    for j in 0..N_JOINTS {
        assert_eq!(root.nodes[j].name.as_deref(), Some(JOINT_NAMES[j]));
        let t = root.nodes[j].translation.unwrap();
        for k in 0..3 {
            assert!((t[k] as f64 - off[j][k]).abs() < 1e-6);
        }
    }
    let anim = &root.animations[0];
    let times = floats(&root, &bin, anim.samplers[0].input.value());
    assert_eq!(times.len(), t_len);
    assert!((times[t_len - 1] - (t_len - 1) as f32 / 30.0).abs() < 1e-6);
    let mut rotations = 0;
    for ch in &anim.channels {
        let node = ch.target.node.value();
        let out = floats(
            &root,
            &bin,
            anim.samplers[ch.sampler.value()].output.value(),
        );
        match ch.target.path {
            json::validation::Checked::Valid(json::animation::Property::Rotation) => {
                let aa: Vec<f32> = (0..t_len)
                    .flat_map(|t| {
                        let p = npz.poses.row(t);
                        [p[3 * node], p[3 * node + 1], p[3 * node + 2]]
                    })
                    .collect();
                let d = rotations_vs_oracle(&out, &aa);
                assert!(d.within(1e-5), "glb rotation of {}: {d}", JOINT_NAMES[node]);
                rotations += 1;
            }
            _ => {
                assert_eq!(node, 0, "translation only on the pelvis");
                let want: Vec<f32> = (0..t_len)
                    .flat_map(|t| (0..3).map(move |k| (t, k)))
                    .map(|(t, k)| npz.trans[[t, k]] + off[0][k] as f32)
                    .collect();
                let d = diff(&out, &want);
                assert!(d.within(1e-6), "glb pelvis translation: {d}");
            }
        }
    }
    assert_eq!(rotations, N_JOINTS, "one rotation channel per joint");
    // the .gltf holds the same document with its buffer embedded
    let text = std::fs::read_to_string(tmp.path().join("m.gltf")).unwrap();
    let g = json::Root::from_str(&text).unwrap();
    assert!(g.buffers[0]
        .uri
        .as_deref()
        .unwrap()
        .starts_with("data:application/octet-stream;base64,"));
    assert_eq!(g.animations[0].channels.len(), anim.channels.len());
    assert_eq!(g.buffers[0].byte_length.0 as usize, bin.len());
}

#[test]
fn output_names_the_cli_does_not_write_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let wav = short_wav(tmp.path(), 0.5);
    for name in ["motion.txt", "motion.fbx", "motion", "motion.npz.tmp"] {
        let out = tmp.path().join(name);
        let o = generate(&wav, &out);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{name}: {err}");
        assert!(
            err.contains(".npz, .bvh, .glb, .gltf") && err.contains(name),
            "{name}: the refusal names the file and the supported extensions: {err}"
        );
        assert!(!out.exists(), "{name}: a file was left");
    }
    let left: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 1, "only the input remains: {left:?}");
    // any case of a supported extension is written
    let o = generate(&wav, &tmp.path().join("UPPER.GLB"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

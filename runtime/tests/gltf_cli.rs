//! `livegesture generate -o x.glb / x.gltf` (docs/avatars.md) and the output-name check: the glTF files
//! hold the same motion as the npz of the same run, and a name the CLI does not write is refused.
//! The Khronos validator and Blender check the files in scripts/test.sh (runtime/web/tests/gltf-validate.mjs,
//! runtime/tests/blender/check_import.py).

use livegesture_parity_tests as common;

use std::path::Path;
use std::process::{Command, Output};

use gltf_json as json;
use livegesture::output::{gltf::axis_angle_to_gltf_quaternion, read_beat2_npz};
use livegesture::skeleton::{rest_offsets, JOINT_NAMES, N_JOINTS};

fn generate(wav: &Path, out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_livegesture"))
        .env_remove("LIVEGESTURE_BUNDLE")
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
    let mut worst = 0f32;
    for ch in &anim.channels {
        let node = ch.target.node.value();
        let out = floats(
            &root,
            &bin,
            anim.samplers[ch.sampler.value()].output.value(),
        );
        for t in 0..t_len {
            match ch.target.path {
                json::validation::Checked::Valid(json::animation::Property::Rotation) => {
                    let p = npz.poses.row(t);
                    let want = axis_angle_to_gltf_quaternion([
                        p[3 * node],
                        p[3 * node + 1],
                        p[3 * node + 2],
                    ]);
                    let got = &out[4 * t..4 * t + 4];
                    let dot: f32 = (0..4).map(|i| want[i] * got[i]).sum();
                    worst = worst.max(1.0 - dot.abs());
                }
                _ => {
                    assert_eq!(node, 0, "translation only on the pelvis");
                    for k in 0..3 {
                        let want = npz.trans[[t, k]] + off[0][k] as f32;
                        worst = worst.max((out[3 * t + k] - want).abs());
                    }
                }
            }
        }
    }
    assert!(worst < 1e-6, "glb vs npz: {worst}");
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

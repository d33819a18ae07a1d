//! Tests of the frame records and the npz, JSON lines and binary sinks.

use super::npz::NpyUnicode;
use super::*;
use std::fs::File;
use std::path::Path;

use ndarray::Array2;

fn frame(i: u64) -> Frame {
    let mut f = Frame::zeros(i);
    for (k, v) in f.poses.iter_mut().enumerate() {
        *v = (k as f32 * 0.01 + i as f32) * if k % 2 == 0 { 1.0 } else { -1.0 };
    }
    f.trans = [i as f32, 1.5, -0.25];
    for (k, v) in f.expressions.iter_mut().enumerate() {
        *v = k as f32 / 7.0;
    }
    f.foot_contact = [1.0, 0.0, 1.0, 0.0];
    f
}

/// The raw `.npy` bytes of entry `name` of an uncompressed npz: (header text, data).
fn raw_entry(p: &Path, name: &str) -> (String, Vec<u8>) {
    use std::io::Read;
    let mut z = zip::ZipArchive::new(File::open(p).unwrap()).unwrap();
    let mut f = z.by_name(&format!("{name}.npy")).unwrap();
    let mut bytes = Vec::new();
    f.read_to_end(&mut bytes).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00", "{name}: npy format 1.0");
    let hl = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    // numpy aligns the data to 64 bytes
    assert_eq!((10 + hl) % 64, 0, "{name}: header not aligned");
    let header = String::from_utf8(bytes[10..10 + hl].to_vec()).unwrap();
    (header, bytes[10 + hl..].to_vec())
}

#[test]
fn npz_entries_are_numpy_arrays_and_unicode_scalars() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("out.npz");
    let mut w = NpzFrameWriter::new(&p);
    for i in 0..3 {
        w.write_frame(&frame(i)).unwrap();
    }
    w.finish().unwrap();
    let (h, data) = raw_entry(&p, "model");
    assert!(
        h.contains("'descr': '<U9'") && h.contains("'shape': ()"),
        "{h}"
    );
    let chars: String = data
        .chunks(4)
        .map(|c| char::from_u32(u32::from_le_bytes(c.try_into().unwrap())).unwrap())
        .collect();
    assert_eq!(chars, "smplx2020");
    let (h, data) = raw_entry(&p, "gender");
    assert!(h.contains("'descr': '<U7'"), "{h}");
    assert_eq!(data.len(), 7 * 4);
    let (h, data) = raw_entry(&p, "poses");
    assert!(
        h.contains("'descr': '<f4'") && h.contains("'shape': (3, 165)"),
        "{h}"
    );
    assert_eq!(data.len(), 3 * 165 * 4);
    let (h, _) = raw_entry(&p, "mocap_frame_rate");
    assert!(
        h.contains("'descr': '<i8'") && h.contains("'shape': ()"),
        "{h}"
    );
    assert!(NpyUnicode::<3>::new("four").is_err());
}

#[test]
fn npz_round_trip_and_keys() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("out.npz");
    let mut w = NpzFrameWriter::new(&p);
    for i in 0..5 {
        w.write_frame(&frame(i)).unwrap();
    }
    let expected = w.motion().unwrap();
    w.finish().unwrap();
    assert!(w.finish().is_err());
    let m = read_beat2_npz(&p).unwrap();
    assert_eq!(m, expected);
    assert_eq!(m.poses[[3, 1]], -(0.01 + 3.0));

    let mut npz = ndarray_npy::NpzReader::new(File::open(&p).unwrap()).unwrap();
    let mut names = npz.names().unwrap();
    names.sort();
    // (ndarray-npy lists entry names without the ".npy" suffix)
    assert_eq!(
        names,
        [
            "betas",
            "expressions",
            "gender",
            "mocap_frame_rate",
            "model",
            "poses",
            "trans"
        ]
    );
    let betas: ndarray::Array1<f32> = npz.by_name("betas.npy").unwrap();
    assert_eq!(betas.len(), 300);
    assert!(betas.iter().all(|&b| b == 0.0));
    let fr: ndarray::Array0<i64> = npz.by_name("mocap_frame_rate.npy").unwrap();
    assert_eq!(fr.into_scalar(), 30);
    // no temporary files left behind
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn npz_write_is_atomic_on_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.npz");
    std::fs::write(&p, b"previous").unwrap();
    let mut f = frame(0);
    f.poses[7] = f32::NAN;
    let bad = Beat2Motion {
        poses: Array2::from_shape_vec((1, POSE_DIM), f.poses.to_vec()).unwrap(),
        trans: Array2::zeros((1, 3)),
        expressions: Array2::zeros((1, 100)),
    };
    let e = write_beat2_npz(&p, &bad).unwrap_err();
    assert!(format!("{e:#}").contains("poses"), "{e:#}");
    assert_eq!(std::fs::read(&p).unwrap(), b"previous");
    // destination is a directory: the rename fails, no temp file remains
    let d = dir.path().join("adir");
    std::fs::create_dir(&d).unwrap();
    let ok = NpzFrameWriter::new(&d).motion().unwrap();
    assert!(write_beat2_npz(&d, &ok).is_err());
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 2, "{left:?}");
    // missing directory
    assert!(write_beat2_npz(dir.path().join("nope/x.npz"), &ok).is_err());
    // non-consecutive frames
    let mut w = NpzFrameWriter::new(dir.path().join("y.npz"));
    w.write_frame(&frame(0)).unwrap();
    assert!(w.write_frame(&frame(2)).is_err());
}

#[test]
fn json_lines_round_trip() {
    let mut w = JsonLinesWriter::new(Vec::new());
    for i in 0..3 {
        w.write_frame(&frame(i)).unwrap();
    }
    w.finish().unwrap();
    let text = String::from_utf8(w.into_inner()).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 3);
    let v: serde_json::Value = serde_json::from_str(lines[1]).unwrap();
    let keys: Vec<&String> = v.as_object().unwrap().keys().collect();
    for k in [
        "index",
        "time_s",
        "poses",
        "trans",
        "expressions",
        "foot_contact",
    ] {
        assert!(keys.iter().any(|x| x.as_str() == k), "{k}");
    }
    assert_eq!(v["poses"].as_array().unwrap().len(), 165);
    assert_eq!(v["time_s"].as_f64().unwrap(), 1.0 / 30.0);
    for (i, l) in lines.iter().enumerate() {
        assert_eq!(Frame::from_json_line(l).unwrap(), frame(i as u64));
    }
    assert!(Frame::from_json_line(
        r#"{"index":0,"time_s":0,"poses":[1],"trans":[],"expressions":[],"foot_contact":[]}"#
    )
    .unwrap_err()
    .to_string()
    .contains("invalid frame"));
    let mut bad = frame(4);
    bad.trans[2] = f32::INFINITY;
    let e = JsonLinesWriter::new(Vec::new())
        .write_frame(&bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame 4") && e.contains("trans[2]"), "{e}");
}

#[test]
fn binary_round_trip() {
    assert_eq!(BINARY_RECORD_LEN, 1104);
    let mut w = BinaryFrameWriter::new(Vec::new());
    for i in 0..4 {
        w.write_frame(&frame(i)).unwrap();
    }
    w.finish().unwrap();
    let bytes = w.into_inner();
    assert_eq!(bytes.len(), 16 + 4 * 1104);
    assert_eq!(&bytes[..8], b"LGFRAMES");
    // spot-check the layout: frame 1's trans[0] at 16 + 1104 + 676
    let o = 16 + 1104 + 676;
    assert_eq!(f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()), 1.0);
    let frames: Vec<Frame> = BinaryFrameReader::new(&bytes[..])
        .unwrap()
        .map(|f| f.unwrap())
        .collect();
    assert_eq!(frames, (0..4).map(frame).collect::<Vec<_>>());
    // truncated record and bad magic are errors
    let mut r = BinaryFrameReader::new(&bytes[..bytes.len() - 10]).unwrap();
    for _ in 0..3 {
        r.next_frame().unwrap().unwrap();
    }
    assert!(r.next_frame().is_err());
    assert!(BinaryFrameReader::new(&b"NOTFRAMES_______"[..]).is_err());
    // empty stream still has its header
    let mut w = BinaryFrameWriter::new(Vec::new());
    w.finish().unwrap();
    assert_eq!(w.into_inner(), binary_header().to_vec());
}

fn face_frame(i: u64) -> Frame {
    let mut f = frame(i);
    let mut v = crate::face::FaceValues {
        arkit: [0.0; crate::face::ARKIT_DIM],
        visemes: [0.0; crate::face::VISEME_DIM],
    };
    v.arkit[17] = 0.25 + i as f32 / 100.0; // jawOpen
    v.visemes[10] = 1.0; // aa
    f.face = Some(v);
    f
}

#[test]
fn binary_version_2_carries_the_face() {
    assert_eq!(BINARY_RECORD_LEN_FACE, 1372);
    let mut w = BinaryFrameWriter::new(Vec::new());
    for i in 0..3 {
        w.write_frame(&face_frame(i)).unwrap();
    }
    w.finish().unwrap();
    let bytes = w.into_inner();
    assert_eq!(bytes.len(), 16 + 3 * 1372);
    assert_eq!(&bytes[..16], &binary_header_for(true));
    assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]), 2);
    assert_eq!(u16::from_le_bytes([bytes[12], bytes[13]]), 1372);
    // frame 2's jawOpen (arkit[17]) at 16 + 2 * 1372 + 1104 + 17 * 4; its `aa` at 1312 + 10 * 4
    let o = 16 + 2 * 1372 + 1104 + 17 * 4;
    let jaw = face_frame(2).face.unwrap().arkit[17];
    assert_eq!(f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()), jaw);
    let o = 16 + 2 * 1372 + 1312 + 40;
    assert_eq!(f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()), 1.0);
    let r = BinaryFrameReader::new(&bytes[..]).unwrap();
    assert_eq!(r.version(), 2);
    let frames: Vec<Frame> = r.map(|f| f.unwrap()).collect();
    assert_eq!(frames, (0..3).map(face_frame).collect::<Vec<_>>());
    // a body-only frame in a face stream (and the reverse) is refused, naming the version
    let mut w = BinaryFrameWriter::new(Vec::new());
    w.write_frame(&face_frame(0)).unwrap();
    let e = format!("{:#}", w.write_frame(&frame(1)).unwrap_err());
    assert!(e.contains("version 2"), "{e}");
    let mut w = BinaryFrameWriter::new(Vec::new());
    w.write_frame(&frame(0)).unwrap();
    let e = format!("{:#}", w.write_frame(&face_frame(1)).unwrap_err());
    assert!(e.contains("version 1"), "{e}");
    // a face value out of [0, 1] is refused
    let mut bad = face_frame(5);
    bad.face.as_mut().unwrap().arkit[3] = 1.5;
    let e = format!(
        "{:#}",
        BinaryFrameWriter::new(Vec::new())
            .write_frame(&bad)
            .unwrap_err()
    );
    assert!(e.contains("frame 5") && e.contains("arkit[3]"), "{e}");
    // a header whose record length does not match its version, and an unknown version, are refused
    let mut h = binary_header_for(true);
    h[12..14].copy_from_slice(&1104u16.to_le_bytes());
    let e = format!("{:#}", BinaryFrameReader::new(&h[..]).unwrap_err());
    assert!(e.contains("version 2") && e.contains("1372"), "{e}");
    let mut h = binary_header();
    h[8] = 3;
    let e = format!("{:#}", BinaryFrameReader::new(&h[..]).unwrap_err());
    assert!(e.contains("version 3"), "{e}");
    // a record of neither length
    assert!(Frame::decode_binary(&bytes[16..16 + 1200]).is_err());
}

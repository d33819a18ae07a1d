use super::*;

fn params() -> BlinkParams {
    BlinkParams {
        first_lo: 15,
        first_hi: 90,
        gap_lo: 60,
        gap_hi: 150,
        duration: 7,
    }
}

#[test]
fn blinks_match_the_python_process() {
    // python: livegesture.face.blink.blinks(0, 600): peaks (weight > 0.99) at these frames
    let mut b = Blinker::new(params(), 0);
    let w: Vec<f32> = (0..600).map(|_| b.next_weight()).collect();
    let peaks: Vec<usize> = (0..600).filter(|&i| w[i] > 0.99).collect();
    assert_eq!(peaks, vec![39, 110, 226, 314, 374, 510]);
    assert!((w[36] - 0.382_683_43).abs() < 1e-6, "{}", w[36]);
    assert!(w.iter().all(|x| (0.0..=1.0).contains(x)));
    // another seed, another process
    let mut c = Blinker::new(params(), 1);
    let w1: Vec<f32> = (0..600).map(|_| c.next_weight()).collect();
    assert_ne!(w, w1);
}

#[test]
fn names_are_apples_and_openxrs() {
    assert_eq!(ARKIT_NAMES.len(), 52);
    assert_eq!(ARKIT_NAMES[0], "eyeBlinkLeft");
    assert_eq!(ARKIT_NAMES[7], "eyeBlinkRight");
    assert_eq!(ARKIT_NAMES[17], "jawOpen");
    assert_eq!(ARKIT_NAMES[51], "tongueOut");
    let set: std::collections::BTreeSet<_> = ARKIT_NAMES.iter().collect();
    assert_eq!(set.len(), 52);
    assert_eq!(VISEME_NAMES[10], "aa");
}

#[test]
fn face_values_out_of_range_are_refused() {
    let mut f = FaceValues {
        arkit: [0.0; ARKIT_DIM],
        visemes: [0.0; VISEME_DIM],
    };
    f.visemes[0] = 1.0;
    f.check(3).unwrap();
    f.arkit[17] = f32::NAN;
    let e = f.check(3).unwrap_err().to_string();
    assert!(e.contains("frame 3") && e.contains("arkit[17]"), "{e}");
    f.arkit[17] = 1.5;
    assert!(f.check(3).is_err());
}

//! DiffSHEG sampler vs the Python reference rollout, without graphs: the recorded per-call trace of
//! window 1 is replayed through the Rust sampler (noise, DDIM, RePaint jumps, blending), which must
//! reproduce every recorded input bit for bit, and the window's result from its last call.
//!
//! The bundle is the fixture's tiny DiffSHEG bundle (`livegesture_parity_tests::diffsheg_tiny_bundle`:
//! `$LIVEGESTURE_DIFFSHEG_TINY_BUNDLE`, set by `scripts/test.sh`, else exported once).

use std::path::PathBuf;
use std::sync::Arc;

use livegesture::bundle::DiffshegManifest as DiffshegSections;
use livegesture::model::diffsheg::foppas::{
    plan_windows, SamplerOptions, WindowSampler, MOTION_DIM,
};
use livegesture::model::diffsheg::noise::{fill_normals, NoiseStream};
use livegesture::model::diffsheg::reference::RolloutReference;

fn bundle() -> PathBuf {
    livegesture_parity_tests::diffsheg_tiny_bundle()
}

struct Fixture {
    sections: DiffshegSections,
    opts: SamplerOptions,
    rollout: RolloutReference,
    seed: u64,
}

fn fixture() -> Fixture {
    let dir = bundle();
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
    let sections = DiffshegSections::parse(&manifest).unwrap();
    let ro = &manifest["reference"]["rollout_options"];
    let g = |k: &str| ro[k].as_u64().unwrap() as usize;
    let opts = SamplerOptions {
        steps: g("steps"),
        guidance: ro["guidance"].as_f64().unwrap(),
        window: g("window"),
        overlap: g("overlap"),
        jumps: g("jumps"),
        blend_steps: g("blend_steps"),
    };
    let mut rollout = RolloutReference::open(&dir.join("reference/rollout.npz")).unwrap();
    let seed = rollout.scalar("seed").unwrap();
    Fixture {
        sections,
        opts,
        rollout,
        seed,
    }
}

fn bits32(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn windows_and_noise_counts_match_the_rollout() {
    let mut f = fixture();
    let t = f.rollout.scalar("frames").unwrap() as usize;
    let windows = f.rollout.windows().unwrap();
    let plan = plan_windows(t, f.opts.window, f.opts.overlap);
    assert_eq!(plan.len(), windows.len());
    assert!(windows.len() >= 4);
    let mut pos = 0;
    for (k, (w, (s, n))) in windows.iter().zip(plan).enumerate() {
        assert_eq!((w[0] as usize, w[1] as usize), (s, n), "window {k}");
        assert_eq!(w[4], pos, "window {k}: noise start");
        let drawn = f.opts.normals_per_window(n, k > 0);
        assert_eq!(w[5] - w[4], drawn, "window {k}: normals drawn");
        pos = w[5];
    }
    assert!(
        windows.last().unwrap()[1] < f.opts.window as u64,
        "last window shorter"
    );
}

#[test]
fn window1_trace_is_reproduced_bit_for_bit() {
    let mut f = fixture();
    let windows = f.rollout.windows().unwrap();
    let [start, n, _, l, noise_start, noise_end] = windows[1];
    let (n, l) = (n as usize, l as usize);
    assert!(start > 0 && l == f.opts.overlap);
    let known = f.rollout.f32("window1.known").unwrap().data;
    let calls = f.rollout.scalar("window1.trace.calls").unwrap() as usize;
    assert_eq!(calls, f.opts.calls_per_window(true));
    let schedule = Arc::new(f.sections.schedule.clone());
    let noise = NoiseStream {
        seed: f.seed,
        position: noise_start,
    };
    let mut w = WindowSampler::new(n, Some(&known), f.opts, schedule.clone(), noise).unwrap();
    // x_T is the window's first n x D normals
    let mut xt = vec![0f32; n * MOTION_DIM];
    fill_normals(f.seed, noise_start, &mut xt);
    let mut fed = 0;
    for c in 0..4 {
        let x = f.rollout.f32(&format!("window1.trace{c}.x")).unwrap().data;
        let t = f.rollout.scalar(&format!("window1.trace{c}.t")).unwrap() as i64;
        let eps = f
            .rollout
            .f64(&format!("window1.trace{c}.eps"))
            .unwrap()
            .data;
        let call = w.next_call().expect("a pending call");
        assert_eq!(call.t, t, "call {c}: timestep");
        assert_eq!(
            bits32(call.x),
            bits32(&x),
            "call {c}: x differs from the Python trace"
        );
        if c == 0 {
            assert_eq!(bits32(&x), bits32(&xt), "x_T");
        }
        w.feed(&eps).unwrap();
        fed += 1;
    }
    assert_eq!(w.calls(), fed);
    // the last call (j = 0): x, eps -> the window's result, blended with the known frames
    let last = calls - 1;
    let x = f
        .rollout
        .f32(&format!("window1.trace{last}.x"))
        .unwrap()
        .data;
    let t = f.rollout.scalar(&format!("window1.trace{last}.t")).unwrap() as i64;
    let eps = f
        .rollout
        .f64(&format!("window1.trace{last}.eps"))
        .unwrap()
        .data;
    assert_eq!(t, 0);
    let mut w = WindowSampler::new(n, Some(&known), f.opts, schedule, noise)
        .unwrap()
        .resume_at_last_step(&x)
        .unwrap();
    w.feed(&eps).unwrap();
    let (x0, _) = w.finish().unwrap();
    let want = f.rollout.f32("window1.x0").unwrap().data;
    assert_eq!(bits32(&x0), bits32(&want), "window 1 result");
    // the first overlap frame equals the held frame of window 0 exactly (w_0 = 0)
    assert_eq!(bits32(&x0[..MOTION_DIM]), bits32(&known[..MOTION_DIM]));
    assert!(noise_end > noise_start);
}

#[test]
fn a_changed_eps_changes_the_next_call() {
    // the replay above is not vacuous: one ulp in one eps value changes the next x
    let mut f = fixture();
    let windows = f.rollout.windows().unwrap();
    let n = windows[1][1] as usize;
    let known = f.rollout.f32("window1.known").unwrap().data;
    let noise = NoiseStream {
        seed: f.seed,
        position: windows[1][4],
    };
    let schedule = Arc::new(f.sections.schedule.clone());
    let mut w = WindowSampler::new(n, Some(&known), f.opts, schedule, noise).unwrap();
    let mut eps = f.rollout.f64("window1.trace0.eps").unwrap().data;
    let i = 7 * MOTION_DIM + 3;
    eps[i] = f64::from_bits(eps[i].to_bits() + (1 << 40));
    w.feed(&eps).unwrap();
    let x1 = f.rollout.f32("window1.trace1.x").unwrap().data;
    assert_ne!(bits32(w.next_call().unwrap().x), bits32(&x1));
}

#[test]
fn denormalised_features_follow_the_rule() {
    let mut f = fixture();
    let mut motion = f.rollout.f32("motion").unwrap().data;
    let feats = f.rollout.f32("features").unwrap().data;
    f.sections.denormalise(&mut motion);
    assert_eq!(bits32(&motion), bits32(&feats));
}

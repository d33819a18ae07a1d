"""DiffSHEG: portable noise, schedule, DDIM, guidance, FOPPAS windows and overlap, the stream, training, export."""
import json
import math
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]

from livegesture import checkpoint as ckpt  # noqa: E402
from livegesture.compare import assert_within, diff as compare_diff  # noqa: E402
from livegesture.diffsheg import noise, schedule  # noqa: E402
from livegesture.diffsheg.denoiser import MOTION_DIM  # noqa: E402
from livegesture.diffsheg.foppas import (SamplerOptions, TorchBackend, generate_clip, guided_eps,  # noqa: E402
                                         n_frames_for, plan_windows, sample_window)
from livegesture.sampling import SplitMix64  # noqa: E402


@pytest.fixture(scope="module")
def tiny():
    return ckpt.random_model("tiny", seed=3, family="diffsheg")


def speech(seconds, seed=0):
    rng = np.random.RandomState(seed)
    t = np.arange(int(16000 * seconds)) / 16000
    env = np.clip(np.sin(2 * np.pi * 2.1 * t), 0, None)
    return (0.3 * env * np.sin(2 * np.pi * 150 * t) + 0.01 * rng.randn(len(t))).astype(np.float32)


# ----------------------------------------------------------------------------- noise

def test_noise_vectorised_equals_scalar_definition():
    for seed, pos in [(0, 0), (12345, 10 ** 6), (2 ** 63 + 5, 2 ** 40)]:
        v = noise.normals(seed, pos, 500)
        s = np.array([noise.normal_scalar(seed, pos + k) for k in range(500)], dtype=np.float32)
        assert np.array_equal(v.view(np.uint32), s.view(np.uint32)), seed


def test_noise_uses_splitmix64_draws_in_order():
    g = SplitMix64(99)
    u = [g.next_f64() for _ in range(6)]
    for k in range(3):
        r = math.sqrt(-2.0 * noise.ln_01(1.0 - u[2 * k]))
        assert noise.normal_scalar(99, k) == np.float32(r * noise.cos_2pi(u[2 * k + 1]))


def test_noise_pinned_values():
    """The contract's first normals (Rust reproduces these bit for bit)."""
    got = [float(x).hex() for x in noise.normals(0, 0, 4)]
    assert got == ['-0x1.e247d20000000p+0', '0x1.d2241c0000000p-3', '-0x1.c5813a0000000p-3', '0x1.55aeae0000000p-4']


def test_owned_ln_and_cos_are_accurate_and_agree_with_libm_after_the_f32_cast():
    x = np.random.RandomState(1).rand(20000)
    x1 = 1.0 - x
    ln = noise.ln_01_vec(x1)
    assert np.abs(ln - np.log(x1)).max() <= 4e-16 * np.maximum(1, np.abs(np.log(x1))).max()
    assert np.abs(noise.cos_2pi_vec(x) - np.cos(2 * np.pi * x)).max() < 2e-15
    assert noise.ln_01(1.0) == 0.0 and noise.cos_2pi(0.0) == 1.0
    ours = noise.normals(5, 0, 20000)
    g = SplitMix64(5)
    libm = np.array([np.float32(math.sqrt(-2 * math.log(1 - g.next_f64())) * math.cos(2 * math.pi * g.next_f64()))
                     for _ in range(20000)])
    diff = ours.view(np.int32).astype(np.int64) - libm.view(np.int32).astype(np.int64)
    assert np.abs(diff).max() <= 1 and (diff != 0).mean() < 1e-3


def test_noise_moments_and_stream_position():
    z = noise.normals(7, 0, 200000).astype(np.float64)
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1) < 0.01 and abs(((z ** 4).mean()) - 3) < 0.06
    s = noise.NoiseStream(7)
    a, b = s.take((3, 5)), s.take((2,))
    assert s.position == 17
    assert np.array_equal(np.concatenate([a.ravel(), b]), noise.normals(7, 0, 17))


# ----------------------------------------------------------------------------- schedule

def test_schedule_table():
    b = schedule.betas()
    assert b[0] == 1e-4 and b[-1] == 0.02 and np.allclose(b, np.linspace(1e-4, 0.02, 1000), rtol=0, atol=1e-18)
    ab = schedule.alphas_cumprod()
    assert ab[0] == 1.0 - 1e-4 and np.array_equal(ab, np.cumprod(1.0 - b))
    assert np.all(np.diff(ab) < 0) and 0 < ab[-1] < 1e-4
    bits = schedule.f64_bits(ab)
    assert np.array_equal(np.array([int(h, 16) for h in bits], dtype=np.uint64).view(np.float64), ab)
    assert list(schedule.ddim_timesteps(25)) == list(range(0, 1000, 40))
    with pytest.raises(ValueError):
        schedule.ddim_timesteps(0)


# ----------------------------------------------------------------------------- DDIM, guidance

class OracleBackend:
    """The exact eps of a data distribution concentrated on one motion c: eps = (x_t - sqrt(ab) c) / sqrt(1-ab)."""

    def __init__(self, c, ab, uncond_shift=0.0):
        self.c, self.ab, self.shift = c, ab, uncond_shift

    def denoise(self, x, t, audio, speaker, cond):
        a = self.ab[t][:, None, None]
        eps = (x.astype(np.float64) - np.sqrt(a) * self.c) / np.sqrt(1 - a)
        return (eps + self.shift * (1 - cond)[:, None, None]).astype(np.float32)


def test_ddim_recovers_the_single_point_distribution():
    ab = schedule.alphas_cumprod()
    n = 12
    c = np.random.RandomState(0).randn(n, MOTION_DIM)
    opts = SamplerOptions(steps=25, guidance=1.0, window=n, overlap=0)
    x0 = sample_window(OracleBackend(c, ab), np.zeros((n, 4), np.float32), 0, noise.NoiseStream(3), None, opts, ab)
    assert np.abs(x0 - c).max() < 1e-4


def test_guidance_combines_in_float64():
    ab = schedule.alphas_cumprod()
    c = np.zeros((4, MOTION_DIM))
    be = OracleBackend(c, ab, uncond_shift=1.0)
    x = np.random.RandomState(1).randn(4, MOTION_DIM).astype(np.float32)
    e1 = guided_eps(be, x, 500, np.zeros((4, 2), np.float32), 0, 1.0)
    e2 = guided_eps(be, x, 500, np.zeros((4, 2), np.float32), 0, 1.25)
    cond = be.denoise(x[None], np.array([500]), None, None, np.array([1.0], np.float32))[0].astype(np.float64)
    unc = be.denoise(x[None], np.array([500]), None, None, np.array([0.0], np.float32))[0].astype(np.float64)
    assert np.array_equal(e1, cond) and np.array_equal(e2, unc + 1.25 * (cond - unc))


# ----------------------------------------------------------------------------- FOPPAS

@pytest.mark.parametrize("T", [1, 5, 24, 25, 44, 45, 97, 98, 300])
def test_window_plan_covers_the_stream(T):
    N, L = 24, 4
    plan = plan_windows(T, N, L)
    assert plan[0][0] == 0 and plan[-1][0] + plan[-1][1] == T
    for (s0, n0), (s1, n1) in zip(plan, plan[1:]):
        assert n0 == N and s1 == s0 + N - L and n1 > L
    assert all(n <= N for _, n in plan)


def test_overlap_is_fixed_to_the_previous_windows_frames(tiny):
    """With no blending the overlap of every window is bit-identical to the previous window's held frames;
    with the default blend (last 2 steps) the first overlap frame still is, and the later ones move away."""
    a = speech(4.0)
    for blend in (0, 2):
        ro = generate_clip(tiny, a, seed=5, record=True, blend_steps=blend)
        W = ro["stream"].windows
        assert len(W) >= 4 and W[-1]["n"] < tiny.cfg.window
        L = tiny.cfg.overlap
        for prev, cur in zip(W, W[1:]):
            assert np.array_equal(cur["known"], prev["x0"][-L:])
            if blend == 0:
                assert np.array_equal(cur["x0"][:L], prev["x0"][-L:])
            else:
                assert np.array_equal(cur["x0"][0], prev["x0"][-L])
                assert not np.array_equal(cur["x0"][1:L], prev["x0"][-L + 1:])
        assert len(ro["poses"]) == n_frames_for(len(a))


def test_noise_draw_order_and_count(tiny):
    cfg = tiny.cfg
    ro = generate_clip(tiny, speech(3.0), seed=1, record=True)
    W = ro["stream"].windows
    D, S, U, L = MOTION_DIM, cfg.ddim_steps, cfg.jumps, cfg.overlap
    for k, w in enumerate(W):
        n = w["n"]
        want = n * D if k == 0 else n * D + (S - 1) * (U * L * D + (U - 1) * n * D)
        assert w["noise_end"] - w["noise_start"] == want
        assert w["noise_start"] == (W[k - 1]["noise_end"] if k else 0)


def test_stream_is_chunk_size_invariant_and_covers_the_audio(tiny):
    a = speech(2.3, seed=2)
    ref = generate_clip(tiny, a, seed=9)
    for chunk in (7, 160, 4000, 16000):
        g = generate_clip(tiny, a, seed=9, chunk=chunk)
        for k in ("poses", "trans", "expressions"):
            assert np.array_equal(g[k], ref[k]), (chunk, k)
    assert len(ref["poses"]) == n_frames_for(len(a)) == math.ceil(len(a) * 30 / 16000)


def test_stream_ending_on_the_held_frames(tiny):
    """T == N: the push path runs window 0 as a non-last window and emits the held frames at finish; the
    result equals the offline plan of one window."""
    N = tiny.cfg.window
    a = speech(1.0)[: N * 16000 // 30]
    assert n_frames_for(len(a)) == N
    whole = generate_clip(tiny, a, seed=2, record=True)
    assert len(whole["stream"].windows) == 1 and len(whole["poses"]) == N
    assert plan_windows(N, N, tiny.cfg.overlap) == [(0, N)]


def test_seed_and_speaker_change_the_motion(tiny):
    a = speech(1.5)
    g0, g1 = generate_clip(tiny, a, seed=0), generate_clip(tiny, a, seed=1)
    g2 = generate_clip(tiny, a, seed=0, speaker=1)
    assert not np.array_equal(g0["poses"], g1["poses"]) and not np.array_equal(g0["poses"], g2["poses"])


def test_bad_inputs_are_rejected(tiny):
    with pytest.raises(ValueError, match="window"):
        SamplerOptions.from_config(tiny.cfg, window=tiny.cfg.window + 1)
    with pytest.raises(ValueError, match="overlap"):
        SamplerOptions.from_config(tiny.cfg, overlap=tiny.cfg.window)
    with pytest.raises(ValueError, match="NaN"):
        generate_clip(tiny, np.array([0.0, np.nan], np.float32))


# ----------------------------------------------------------------------------- training and checkpoints

def test_training_smoke_and_checkpoint_roundtrip(tiny_corpus, tmp_path):
    from livegesture.diffsheg.train import train
    final = train("tiny", str(tiny_corpus), str(tmp_path / "run"), overrides={"steps": 6, "batch": 2})
    log = [json.loads(x) for x in (tmp_path / "run" / "train_log.jsonl").read_text().splitlines()]
    assert log and all(np.isfinite(r["loss"]) for r in log)
    m = ckpt.load(final)
    assert m.family == "diffsheg" and (m.speaker_numbers >= 0).any()
    g = generate_clip(m, speech(1.0), seed=0)
    assert np.isfinite(g["poses"]).all() and len(g["poses"]) == 30


def test_fine_tuning_with_augmented_audio(tiny_corpus, tmp_path):
    """--init-from: the source's weights, normalisation and style ids are the start (and the
    normalisation and style ids stay); --augment N: windows read the clean mel or one of N copies."""
    from livegesture.diffsheg.train import WindowData, train
    from livegesture.train import TrainData
    src = train("tiny", str(tiny_corpus), str(tmp_path / "a"), overrides={"steps": 4, "batch": 2})
    # the source is trained with other motion statistics than the corpus gives: fine-tuning keeps them
    a = ckpt.load(src)
    with torch.no_grad():
        a.motion_std.mul_(1.5)
        a.speech_encoder.mel_mean.add_(0.25)
    src2 = tmp_path / "src2.pt"
    ckpt.save(a, src2, provenance=a.provenance)
    final = train("tiny", str(tiny_corpus), str(tmp_path / "b"), overrides={"steps": 3, "batch": 2, "augment": 1},
                  init_from=str(src2))
    b = ckpt.load(final)
    assert torch.equal(a.motion_std, b.motion_std) and torch.equal(a.motion_mean, b.motion_mean)
    assert torch.equal(a.speech_encoder.mel_mean, b.speech_encoder.mel_mean)
    assert torch.equal(a.speaker_numbers, b.speaker_numbers)
    changed = [k for k, v in a.state_dict().items() if not torch.equal(v, b.state_dict()[k])]
    assert changed, "3 steps of fine-tuning changed no weight"
    assert b.provenance["init_from"] == str(src2) and b.provenance["augment"] == 1
    # an unrelated initial model would differ far more than 3 EMA-averaged steps from the source
    w = "denoiser.gesture_out.weight" if "denoiser.gesture_out.weight" in b.state_dict() else changed[0]
    fresh = ckpt.load(train("tiny", str(tiny_corpus), str(tmp_path / "c"), overrides={"steps": 3, "batch": 2,
                                                                                          "seed": 5}))
    assert (b.state_dict()[w] - a.state_dict()[w]).abs().max() < (fresh.state_dict()[w] - a.state_dict()[w]).abs().max()
    # windows draw the clean mel and the augmented copy
    cfg = a.cfg
    td = TrainData(str(tiny_corpus), cfg, None, augment=1, seed=0)
    wd = WindowData(td, {s: i for i, s in enumerate(sorted({c.speaker for c in td.clips}))})
    rng = np.random.default_rng(0)
    seen = set()
    for _ in range(8):
        x0, mel, spk = wd.batch(rng, 8, 4)
        for m in mel.numpy():
            for vs in td.mel_variants:
                for k, v in enumerate(vs):
                    if any(np.array_equal(v[i:i + 16], m) for i in range(0, len(v) - 15, 2)):
                        seen.add(k)
    assert seen == {0, 1}
    with pytest.raises(SystemExit, match="config"):
        train("default", str(tiny_corpus), str(tmp_path / "d"), overrides={"steps": 1}, init_from=str(src2))


# ----------------------------------------------------------------------------- export

@pytest.fixture(scope="module")
def bundle(tmp_path_factory, tiny):
    from export import export as exporter
    from export import diffsheg_export
    out = tmp_path_factory.mktemp("dsb") / "diffsheg-tiny"
    man = exporter.build_bundle(tiny, out, provenance={"training": "none (test)"}, reference_wav=None,
                                ref_seconds=2.0, rollout_tokens=0, log=lambda *a: None,
                                builder=diffsheg_export.build, rollout_windows=4)
    return out, man


def test_manifest_validates_and_files_match(bundle):
    from export import export as exporter
    out, _ = bundle
    schema = json.loads((ROOT / "export" / "manifest.schema.json").read_text())
    man = json.loads((out / "manifest.json").read_text())
    jsonschema.validate(man, schema)
    assert man["family"] == "diffsheg" and [g["name"] for g in man["graphs"]] == ["speech_encoder", "denoiser"]
    for rel, info in man["files"].items():
        assert exporter.sha256(out / rel) == info["sha256"], rel
    ab = np.array([int(h, 16) for h in man["diffusion"]["alphas_cumprod_f64_bits"]], dtype=np.uint64).view(np.float64)
    assert np.array_equal(ab, schema_ab := schedule.alphas_cumprod()) and np.array_equal(man["diffusion"]["alphas_cumprod"], schema_ab)
    broken = {k: v for k, v in man.items() if k != "foppas"}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(broken, schema)


def test_reference_vectors_replay_on_onnxruntime(bundle):
    import onnxruntime as ort
    out, man = bundle
    for g in man["graphs"]:
        ref = np.load(out / g["reference"])
        sess = ort.InferenceSession(str(out / g["file"]), providers=["CPUExecutionProvider"])
        for c in range(int(ref["n_calls"])):
            feed = {i["name"]: ref[f"call{c}.input.{i['name']}"] for i in g["inputs"]}
            got = sess.run(None, feed)[0]
            name = g["outputs"][0]["name"]
            assert_within(got, ref[f"call{c}.output.{name}"], 1e-5, f"{g['name']} call {c}")


def test_rollout_replays_on_onnxruntime(bundle, tiny):
    from export import diffsheg_export
    out, man = bundle
    ro = np.load(out / "reference" / "rollout.npz")
    be = diffsheg_export.OrtBackend(out / "speech_encoder.onnx", out / "denoiser.onnx")
    g = generate_clip(tiny, ro["audio"], seed=int(ro["seed"]), speaker=int(ro["speaker"]), backend=be, record=True)
    W = ro["windows"]
    assert len(W) == 4 and W[-1][1] < man["foppas"]["window"] and len(g["poses"]) == int(ro["frames"])
    assert [(w["start"], w["n"]) for w in g["stream"].windows] == [tuple(w[:2]) for w in W]
    assert [w["noise_end"] for w in g["stream"].windows] == list(W[:, 5])
    d = compare_diff(g["poses"], ro["poses"])
    assert d.within(diffsheg_export.ROLLOUT_ORT_BOUND), d
    assert d.max_abs <= man["checks"]["rollout"]["ort_vs_torch_poses_max_abs"] + 1e-6
    assert man["checks"]["rollout"]["ort_vs_torch_motion_max_abs"] <= diffsheg_export.ROLLOUT_ORT_BOUND
    feats = tiny.denormalise(ro["motion"])
    assert np.array_equal(feats, ro["features"])


def test_export_catches_a_broken_graph(bundle, tiny):
    """Must fail: the exported denoiser no longer matches a perturbed torch model; the error names it."""
    import copy
    from export import diffsheg_export
    from export.verify import ExportCheckError
    out, _ = bundle
    broken = copy.deepcopy(tiny)
    with torch.no_grad():
        broken.denoiser.ges.out.weight.add_(1e-3)
    with pytest.raises(ExportCheckError, match="graph 'denoiser', output 'eps'"):
        diffsheg_export.check_ort_vs_torch(broken, "denoiser", out / "denoiser.onnx")
    err, scale = diffsheg_export.check_ort_vs_torch(tiny, "denoiser", out / "denoiser.onnx")
    assert err <= 1e-5 * scale and scale >= 1.0


def test_export_cli_refuses_bad_input(tmp_path):
    from export import export as exporter
    assert exporter.main(["--family", "diffsheg", "--config", "nope", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    assert exporter.main(["--checkpoint", str(bad), "--out", str(tmp_path / "y")]) == 2
    assert not (tmp_path / "y").exists()


def test_export_sampler_defaults(tmp_path):
    """export --guidance / --jumps write the bundle's default sampler settings (manifest sections, reference
    rollout, provenance); they are DiffSHEG options and are checked before anything is written."""
    from export import export as exporter
    out = tmp_path / "b"
    assert exporter.main(["--family", "diffsheg", "--config", "tiny", "--random-seed", "0", "--guidance", "2",
                          "--jumps", "1", "--rollout-windows", "4", "--out", str(out)]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["diffusion"]["guidance"]["scale"] == 2.0 and man["foppas"]["jumps"] == 1
    assert man["model"]["config"]["guidance"] == 2.0 and man["model"]["config"]["jumps"] == 1
    assert man["reference"]["rollout_options"]["guidance"] == 2.0 and man["reference"]["rollout_options"]["jumps"] == 1
    from livegesture.diffsheg.config import get_config
    tiny_cfg = get_config("tiny")
    assert man["provenance"]["sampler_defaults"]["set_at_export"] == {"guidance": 2.0, "jumps": 1}
    assert man["provenance"]["sampler_defaults"]["model_config"] == {"guidance": tiny_cfg.guidance,
                                                                       "jumps": tiny_cfg.jumps}
    assert exporter.main(["--family", "diffsheg", "--config", "tiny", "--jumps", "0", "--out", str(tmp_path / "z")]) == 2
    assert exporter.main(["--config", "tiny", "--guidance", "2", "--out", str(tmp_path / "lg")]) == 2
    assert not (tmp_path / "z").exists() and not (tmp_path / "lg").exists()


def test_stream_generate_clip_dispatches_on_family(tiny):
    """livegesture.stream.generate_clip (used by livegesture.eval --checkpoint) runs FOPPAS for a DiffSHEG model."""
    from livegesture.stream import generate_clip as any_family
    a = speech(1.2)
    g, h = any_family(tiny, a, seed=4), generate_clip(tiny, a, seed=4)
    assert np.array_equal(g["poses"], h["poses"]) and len(g["poses"]) == n_frames_for(len(a))
    with pytest.raises(ValueError, match="top_k"):
        any_family(tiny, a, top_k=3)


def test_batched_clips_equal_their_streams(tiny):
    from livegesture.diffsheg.foppas import generate_clips
    audios = [speech(1.0, 1), speech(2.7, 2), speech(0.5, 3), speech(2.7, 4)]
    seeds = [3, 4, 5, 6]
    many = generate_clips(tiny, audios, seeds)
    for a, s, g in zip(audios, seeds, many):
        one = generate_clip(tiny, a, seed=s)
        assert len(g["poses"]) == len(one["poses"]) == n_frames_for(len(a))
        for k in ("poses", "trans", "expressions"):
            assert np.abs(g[k] - one[k]).max() < 1e-4, k

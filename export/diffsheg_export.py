"""DiffSHEG bundles: ``speech_encoder`` and ``denoiser`` graphs, manifest, reference vectors, seeded FOPPAS
rollout, export-time checks. Called by export.py (``--family diffsheg`` or a diffsheg checkpoint); the format
is documented in docs/bundle.md, section "DiffSHEG bundles".

Checks (each failure names the graph, the output, the call and the error; the bundle is not written):
1. ONNX structure: onnx.checker, opset 17, no If/Loop/Scan, static ranks, batch axis dynamic, the only other
   dynamic axes are the window's ``frames`` / ``mel_frames``;
2. onnxruntime vs torch, every graph, batches 1, 2, 5 and window lengths N, a shorter one and L + 1
   (docs/parity.md: 1e-5 scaled by the torch output's magnitude, ``max(1, max|torch|)``);
3. the seeded FOPPAS rollout: onnxruntime graphs vs torch graphs through the same sampler (frames max abs and
   scale, recorded in ``checks``; bounded by ``ROLLOUT_ORT_BOUND``, scaled), and the rollout pushed in 1 s chunks equals the
   whole-clip rollout bit for bit (chunk-size invariance of the Python reference).
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

from livegesture.compare import diff
from livegesture.diffsheg import foppas, noise, schedule
from livegesture.diffsheg.denoiser import EXP_DIM, GES_DIM, MOTION_DIM
from livegesture.diffsheg.foppas import SamplerOptions, TorchBackend, generate_clip, plan_windows
from livegesture.diffsheg.model import DiffSHEG, motion_layout
from livegesture.frontend import logmel

from .bundle_writer import (OPSET, export_provenance, file_table, manifest_head, reference_audio, save_stamped,
                           write_manifest, write_wav)
from .verify import ExportCheckError

ORT_VS_TORCH = 1e-5
# normalised motion, whole rollout, onnxruntime vs torch: the project's rollout frame bound (docs/parity.md), not the
# former 1e-3; measured on models/diffsheg 6.1e-6 (checks.rollout), on the tiny export 9.5e-7
ROLLOUT_ORT_BOUND = 1e-4
ROLLOUT_SEED = 1234
GRAPHS = ("speech_encoder", "denoiser")


def data_io(model: DiffSHEG, graph: str) -> tuple[list[dict], list[dict]]:
    cfg = model.cfg
    f32, i64 = "float32", "int64"
    if graph == "speech_encoder":
        return ([{"name": "mel", "dtype": f32, "shape": ["batch", "mel_frames", cfg.frontend.n_mels]}],
                [{"name": "audio", "dtype": f32, "shape": ["batch", "frames", cfg.audio_dim]}])
    if graph == "denoiser":
        return ([{"name": "x_t", "dtype": f32, "shape": ["batch", "frames", MOTION_DIM]},
                 {"name": "t", "dtype": i64, "shape": ["batch"]},
                 {"name": "audio", "dtype": f32, "shape": ["batch", "frames", cfg.audio_dim]},
                 {"name": "speaker", "dtype": i64, "shape": ["batch"]},
                 {"name": "cond", "dtype": f32, "shape": ["batch"]}],
                [{"name": "eps", "dtype": f32, "shape": ["batch", "frames", MOTION_DIM]}])
    raise ValueError(f"unknown diffsheg graph {graph!r}")


class Graph(nn.Module):
    def __init__(self, model: DiffSHEG, graph: str):
        super().__init__()
        self.model, self.graph = model, graph

    def forward(self, *a):
        if self.graph == "speech_encoder":
            return self.model.speech_encoder(a[0])
        return self.model.denoiser(*a)


def random_inputs(model: DiffSHEG, graph: str, batch: int, n: int, g: torch.Generator) -> dict:
    cfg = model.cfg
    if graph == "speech_encoder":
        return {"mel": torch.randn(batch, 2 * n, cfg.frontend.n_mels, generator=g) * 2.0 - 6.0}
    return {"x_t": torch.randn(batch, n, MOTION_DIM, generator=g),
            "t": torch.randint(0, cfg.diffusion_steps, (batch,), generator=g),
            "audio": torch.randn(batch, n, cfg.audio_dim, generator=g),
            "speaker": torch.randint(0, cfg.n_speakers, (batch,), generator=g),
            "cond": torch.tensor([1.0 if i % 2 == 0 else 0.0 for i in range(batch)])}


def export_graph(model: DiffSHEG, graph: str, path: Path):
    import onnx
    ins, outs = data_io(model, graph)
    g = torch.Generator().manual_seed(0)
    inp = random_inputs(model, graph, 2, model.cfg.window, g)
    names_in, names_out = [i["name"] for i in ins], [o["name"] for o in outs]
    dyn = {}
    for spec in ins + outs:
        dyn[spec["name"]] = {k: s for k, s in enumerate(spec["shape"]) if isinstance(s, str)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(Graph(model, graph).eval(), tuple(inp[n] for n in names_in), str(path),
                          input_names=names_in, output_names=names_out, dynamic_axes=dyn, opset_version=OPSET,
                          do_constant_folding=True, dynamo=False)
    m = onnx.load(str(path))
    got = [i.name for i in m.graph.input]
    if got != names_in:
        raise ExportCheckError(f"graph '{graph}': exported inputs {got} differ from {names_in}")
    save_stamped(m, path, model, graph, family="diffsheg")


def check_structure(path: Path, graph: str, model: DiffSHEG):
    import onnx
    m = onnx.load(str(path))
    onnx.checker.check_model(m, full_check=True)
    opset = max(o.version for o in m.opset_import if o.domain in ("", "ai.onnx"))
    if opset < OPSET:
        raise ExportCheckError(f"graph '{graph}': opset {opset} < {OPSET}")
    bad = sorted({n.op_type for n in m.graph.node if n.op_type in ("If", "Loop", "Scan")})
    if bad:
        raise ExportCheckError(f"graph '{graph}': data-dependent control flow {bad} is not allowed")
    ins, outs = data_io(model, graph)
    want = {s["name"]: s["shape"] for s in ins + outs}
    for v in list(m.graph.input) + list(m.graph.output):
        dims = v.type.tensor_type.shape.dim
        exp = want[v.name]
        if len(dims) != len(exp):
            raise ExportCheckError(f"graph '{graph}': tensor '{v.name}' has rank {len(dims)}, expected {len(exp)}")
        for d, e in zip(dims, exp):
            if isinstance(e, str) and d.dim_param != e:
                raise ExportCheckError(f"graph '{graph}': tensor '{v.name}' axis should be dynamic '{e}', "
                                       f"got {d.dim_param or d.dim_value}")
            if not isinstance(e, str) and d.dim_value != e:
                raise ExportCheckError(f"graph '{graph}': tensor '{v.name}' axis should be {e}, "
                                       f"got {d.dim_param or d.dim_value}")


def ort_session(path: Path):
    import onnxruntime as ort
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


class OrtBackend:
    """The sampler's backend on onnxruntime (the same interface as foppas.TorchBackend)."""

    def __init__(self, enc_path: Path, den_path: Path):
        self.enc, self.den = ort_session(enc_path), ort_session(den_path)

    def encode(self, mel):
        return self.enc.run(None, {"mel": np.ascontiguousarray(mel, np.float32)})[0]

    def denoise(self, x, t, audio, speaker, cond):
        return self.den.run(None, {"x_t": np.ascontiguousarray(x, np.float32), "t": np.asarray(t, np.int64),
                                   "audio": np.ascontiguousarray(audio, np.float32),
                                   "speaker": np.asarray(speaker, np.int64), "cond": np.asarray(cond, np.float32)})[0]


def check_lengths(cfg) -> list[int]:
    N, L = cfg.window, cfg.overlap
    return sorted({N, max(L + 1, N // 2 + 1), L + 1})


@torch.no_grad()
def check_ort_vs_torch(model: DiffSHEG, graph: str, path: Path, batches=(1, 2, 5), seed: int = 0) -> tuple[float, float]:
    """onnxruntime vs torch on every call; returns (error, scale) of the worst call relative to its scale, or raises
    ExportCheckError naming the graph, output, call, error and scale."""
    sess = ort_session(path)
    worst = (0.0, 1.0)
    call = 0
    for B in batches:
        for n in check_lengths(model.cfg):
            g = torch.Generator().manual_seed(seed + 100 * B + n)
            inp = random_inputs(model, graph, B, n, g)
            want = Graph(model, graph)(*inp.values()).numpy()
            got = sess.run(None, {k: v.numpy() for k, v in inp.items()})[0]
            name = data_io(model, graph)[1][0]["name"]
            if got.shape != want.shape:
                raise ExportCheckError(f"onnxruntime vs torch: graph '{graph}', output '{name}', call {call} "
                                       f"(batch {B}, {n} frames): shape {got.shape}, expected {want.shape}")
            d = diff(got, want)
            if not d.within(ORT_VS_TORCH):
                raise ExportCheckError(f"onnxruntime vs torch: graph '{graph}', output '{name}', call {call} "
                                       f"(batch {B}, {n} frames): max abs error {d.max_abs:.3g} exceeds "
                                       f"{ORT_VS_TORCH:g} x scale {d.scale:.4g} = {ORT_VS_TORCH * d.scale:.3g} "
                                       f"({d.describe()})")
            if d.scaled_error > worst[0] / worst[1]:
                worst = (d.max_abs, d.scale)
            call += 1
    return worst


@torch.no_grad()
def graph_reference(model: DiffSHEG, graph: str, seed: int) -> dict:
    """Torch inputs/outputs of several calls: ``call{c}.input.<name>``, ``call{c}.output.<name>``; batches 2
    (guidance pair: cond 1, 0), 3 and 1; window lengths N, shorter, L + 1. No caches: windows carry no graph state."""
    g = torch.Generator().manual_seed(seed)
    out = {}
    cfg = model.cfg
    plan = [(2, cfg.window), (3, check_lengths(cfg)[1]), (1, cfg.overlap + 1), (2, cfg.window)]
    for c, (B, n) in enumerate(plan):
        inp = random_inputs(model, graph, B, n, g)
        o = Graph(model, graph)(*inp.values())
        for k, v in inp.items():
            out[f"call{c}.input.{k}"] = v.numpy()
        out[f"call{c}.output.{data_io(model, graph)[1][0]['name']}"] = o.numpy()
    out["n_calls"] = np.array(len(plan))
    return out


def rollout_audio(clip: np.ndarray, cfg, windows: int) -> tuple[np.ndarray, int]:
    """Audio for a rollout of ``windows`` windows whose last one is shorter than N: T frames with
    T = N + (windows - 2)(N - L) + (N - L) // 2 + L, the last frame only partly covered by audio."""
    N, L = cfg.window, cfg.overlap
    T = N + (windows - 2) * (N - L) + (N - L) // 2 + L
    n_samples = T * 16000 // 30 - 100
    reps = int(np.ceil(n_samples / len(clip)))
    return np.tile(clip, reps)[:n_samples], T


# long: the bundle's files in the order they are verified and written (graphs, reference clip, rollout, manifest)
def build(model: DiffSHEG, tmp: Path, *, provenance, reference_wav, ref_seconds, rollout_tokens, log,
          rollout_windows: int = 5) -> dict:
    cfg = model.cfg
    if rollout_windows < 4:
        raise ExportCheckError(f"--rollout-windows must be >= 4, got {rollout_windows}")
    (tmp / "reference").mkdir()
    graphs, checks = [], {}
    for i, graph in enumerate(GRAPHS):
        t0 = time.time()
        path = tmp / f"{graph}.onnx"
        export_graph(model, graph, path)
        check_structure(path, graph, model)
        e_ort, s_ort = check_ort_vs_torch(model, graph, path)
        np.savez_compressed(tmp / "reference" / f"{graph}.npz", **graph_reference(model, graph, seed=i))
        ins, outs = data_io(model, graph)
        graphs.append({"name": graph, "file": path.name, "component": type(model.components()[graph]).__name__,
                       "inputs": ins, "outputs": outs, "caches": [], "reference": f"reference/{graph}.npz"})
        checks[graph] = {"ort_vs_torch_max_abs": e_ort, "ort_vs_torch_scale": s_ort,
                         "lengths_checked": check_lengths(cfg),
                         "batches_checked": [1, 2, 5]}
        log(f"  {graph:<16} ort-vs-torch {e_ort:.2e}  ({time.time() - t0:.1f}s)")

    # reference clip, its log-mel, and the seeded FOPPAS rollout (torch graphs; then the same with onnxruntime)
    clip, clip_desc = reference_audio(reference_wav, ref_seconds)
    write_wav(tmp / "reference" / "clip.wav", clip)
    clip = (np.clip(np.round(clip * 32767), -32768, 32767) / 32768.0).astype(np.float32)
    np.save(tmp / "reference" / "logmel.npy", logmel(clip, cfg.frontend))
    audio, T = rollout_audio(clip, cfg, rollout_windows)
    opts = SamplerOptions.from_config(cfg)
    spk = model.default_speaker()
    t0 = time.time()
    ro = generate_clip(model, audio, seed=ROLLOUT_SEED, speaker=spk, record=True)
    secs = time.time() - t0
    st = ro["stream"]
    plan = plan_windows(T, opts.window, opts.overlap)
    if len(ro["poses"]) != T or [(w["start"], w["n"]) for w in st.windows] != plan:
        raise ExportCheckError(f"rollout: windows {[(w['start'], w['n']) for w in st.windows]} / {len(ro['poses'])} "
                               f"frames differ from the plan {plan} / {T}")
    if len(plan) != rollout_windows or plan[-1][1] >= opts.window:
        raise ExportCheckError(f"rollout: expected {rollout_windows} windows with a shorter last one, got {plan}")
    ch = generate_clip(model, audio, seed=ROLLOUT_SEED, speaker=spk, chunk=16000)
    if not all(np.array_equal(ro[k], ch[k]) for k in ("poses", "trans", "expressions")):
        raise ExportCheckError("rollout: pushing the clip in 1 s chunks changed the frames (chunk-size invariance)")
    ort = OrtBackend(tmp / "speech_encoder.onnx", tmp / "denoiser.onnx")
    ro_ort = generate_clip(model, audio, seed=ROLLOUT_SEED, speaker=spk, backend=ort, record=True)
    x_t = np.concatenate([w["x0"][:w["emit"]] for w in st.windows])
    x_o = np.concatenate([w["x0"][:w["emit"]] for w in ro_ort["stream"].windows])
    d_x = diff(x_o, x_t)
    e_x = d_x.max_abs
    e_p = diff(ro_ort["poses"], ro["poses"]).max_abs
    e_e = diff(ro_ort["expressions"], ro["expressions"]).max_abs
    if not d_x.within(ROLLOUT_ORT_BOUND):
        raise ExportCheckError(f"rollout onnxruntime vs torch: graphs 'speech_encoder', 'denoiser', output 'motion "
                               f"(normalised)': {d_x.describe()} > {ROLLOUT_ORT_BOUND:g} x scale {d_x.scale:.4g}")
    checks["rollout"] = {"ort_vs_torch_motion_max_abs": e_x, "ort_vs_torch_motion_scale": d_x.scale,
                         "ort_vs_torch_poses_max_abs": e_p,
                         "ort_vs_torch_expressions_max_abs": e_e, "chunk_1s_vs_whole": "identical",
                         "noise_positions_equal": st.noise_position == ro_ort["stream"].noise_position}
    log(f"  rollout          {len(plan)} windows, {T} frames in {secs:.1f}s; ort vs torch: motion {e_x:.2e}, "
        f"poses {e_p:.2e}")
    ref = {"seed": np.array(ROLLOUT_SEED, dtype=np.uint64), "speaker": np.array(spk, dtype=np.int64),
           "audio": audio.astype(np.float32), "n_samples": np.array(len(audio)), "frames": np.array(T),
           "windows": np.array([[w["start"], w["n"], w["emit"], w["overlap_in"], w["noise_start"], w["noise_end"]]
                                for w in st.windows], dtype=np.int64),
           "motion": x_t, "features": model.denormalise(x_t),
           "poses": ro["poses"], "trans": ro["trans"], "expressions": ro["expressions"],
           "foot_contact": ro["foot_contact"]}
    for k, w in enumerate(st.windows):
        ref[f"window{k}.mel"] = w["mel"]
        ref[f"window{k}.audio"] = w["audio"]
        ref[f"window{k}.x0"] = w["x0"]
        if w["known"] is not None:
            ref[f"window{k}.known"] = w["known"]
    tr = st.windows[1]["trace"]
    keep = list(range(min(4, len(tr)))) + [len(tr) - 1]
    ref["window1.trace.calls"] = np.array(len(tr))
    for c in sorted(set(keep)):
        ref[f"window1.trace{c}.x"] = tr[c]["x"]
        ref[f"window1.trace{c}.t"] = np.array(tr[c]["t"])
        ref[f"window1.trace{c}.eps"] = tr[c]["eps"]
    np.savez_compressed(tmp / "reference" / "rollout.npz", **ref)

    ab = schedule.alphas_cumprod(cfg.diffusion_steps, cfg.beta_start, cfg.beta_end)
    taus = schedule.ddim_timesteps(opts.steps, cfg.diffusion_steps)
    manifest = {
        **manifest_head("diffsheg", "DiffSHEG", cfg, model, {
            "mel_frames_per_frame": cfg.frontend.mel_frames_per_token // cfg.frontend.frames_per_token,
            "frame_start_sample": "k * sample_rate // fps",
            "frames_for_samples": "(n_samples * fps + sample_rate - 1) // sample_rate"}),
        "motion": {
            "dim": MOTION_DIM, "layout": motion_layout(),
            "gesture_branch": {"offset": 0, "dim": GES_DIM}, "expression_branch": {"offset": GES_DIM, "dim": EXP_DIM},
            "normalised": True,
            "denormalisation": "in the runtime, per element in float32: feature = x * std + mean (one f32 multiply, "
                               "then one f32 add, no fused multiply-add); std/mean = normalisation[region] at the "
                               "region's offset in motion.layout",
        },
        "speakers": {"count": cfg.n_speakers,
                     "beat2_speaker_numbers": [int(s) for s in model.speaker_numbers.tolist()],
                     "default": spk,
                     "meaning": "style id = index; beat2_speaker_numbers[i] is the BEAT2 speaker it was trained "
                                "on (-1: unused slot)"},
        "graphs": graphs,
        "pipeline": {
            "order": ["speech_encoder", "denoiser x (steps x jumps)"],
            "speech_encoder": "once per window, batch = streams; input the window's 2n log-mel frames "
                              "(2 s .. 2(s+n)-1), output its n per-frame audio features",
            "denoiser": "per DDIM step and jump: batch rows [cond=1, cond=0] per stream (guidance 1.0: only cond=1); "
                        "x_t, t, audio, speaker are the same in both rows",
            "caches": "none: windows carry no graph state; the state between windows is foppas.state",
        },
        "normalisation": model.normalisation(),
        "diffusion": {
            "train_steps": cfg.diffusion_steps, "beta_schedule": "linear", "beta_start": cfg.beta_start,
            "beta_end": cfg.beta_end, "prediction": "epsilon", "definition": schedule.__doc__.strip(),
            "alphas_cumprod": [float(v) for v in ab], "alphas_cumprod_f64_bits": schedule.f64_bits(ab),
            "ddim": {"steps": opts.steps, "eta": 0.0, "timesteps_rule": "tau_j = j * (train_steps // steps), "
                     "j = 0 .. steps-1, visited descending", "timesteps": [int(v) for v in taus]},
            "guidance": {"scale": opts.guidance, "formula": "eps = u + scale * (c - u)", "precision": "float64",
                         "branches": "denoiser rows cond=1 (c) and cond=0 (u); scale == 1.0: only cond=1"},
            "in_graph": "the denoiser computes x0^E = (x_t^E - sqrt(1-ab[t]) eps^E) / sqrt(ab[t]) itself in float32 "
                        "(tables of sqrt(ab), sqrt(1-ab) cast to f32); t must be in 0 .. train_steps-1",
        },
        "foppas": {
            "window": opts.window, "overlap": opts.overlap, "jumps": opts.jumps, "blend_steps": opts.blend_steps,
            "max_window": cfg.window, "first_window": "plain DDIM (no known frames, 1 pass per step)",
            "definition": foppas.__doc__.strip(),
            "state": [
                {"name": "next_start", "dtype": "int64", "meaning": "first frame of the next window"},
                {"name": "overlap", "dtype": "float32", "shape": [opts.overlap, MOTION_DIM],
                 "meaning": "the last L normalised frames of the previous window, held back (absent before the "
                            "first window)"},
                {"name": "noise_position", "dtype": "uint64", "init": 0, "meaning": "normals drawn so far"},
                {"name": "audio_buffer", "meaning": "the frontend's samples from frame_end(2*next_start) - win_length "
                                                    "on (no encoder state: every window is encoded from its own mel)"},
            ],
        },
        "noise": {"prng": "splitmix64", "transform": "box-muller (cosine branch), owned ln/cos polynomials, float64, "
                  "cast to float32", "definition": noise.__doc__.strip(),
                  "draw_order": "per stream, seeded with the stream's seed: per window: x_T (n x D); then per DDIM "
                                "step j descending, per jump u: [known (L x D) if L > 0 and j > 0], then after the "
                                "denoiser call [jump (n x D) if u < U_j - 1]; row-major (frame, feature)"},
        "reference": {"graphs": {g["name"]: g["reference"] for g in graphs}, "clip": "reference/clip.wav",
                      "clip_source": clip_desc, "clip_seconds": round(len(clip) / 16000, 3),
                      "logmel": "reference/logmel.npy", "rollout": "reference/rollout.npz",
                      "rollout_seed": ROLLOUT_SEED, "rollout_speaker": spk,
                      "rollout_audio": f"reference/clip.wav tiled, first {len(audio)} samples (also stored as 'audio')",
                      "rollout_frames": T, "rollout_windows": [list(w) for w in plan],
                      "rollout_options": opts.to_dict()},
        "checks": checks,
        "files": file_table(tmp),
        "provenance": {**provenance, "export": export_provenance()},
    }
    write_manifest(tmp, manifest)
    return manifest

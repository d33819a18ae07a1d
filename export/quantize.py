#!/usr/bin/env python
"""Derive a reduced-precision bundle from an f32 LiveGesture bundle (issue 15 deliverable 3, docs/bundle.md#forms-and-precision).

    python export/quantize.py --bundle models/default --precision f16 --out target/default-f16
    python export/quantize.py --bundle models/default --precision int8 --out target/default-int8
    python export/quantize.py --bundle target/paper-bundle --precision int8 --out target/paper-int8
    # after scripts/eval_bundle.sh on both bundles (same corpus, seeds, backend): the metrics beside f32
    python export/quantize.py --record-metrics target/default-f16 --metrics-f32 F32/eval.json \
        --metrics-reduced F16/eval.json --metrics-command "scripts/eval_bundle.sh ..."

`f16` / `bf16` (manifest ``float16`` / ``bfloat16``): weight storage only. Every float32 initializer and
``Constant`` tensor of more than one element is stored in the reduced type (round to nearest even) and followed
by a ``Cast`` to float32 under its original name; a tensor with a value outside the reduced type's finite range
(an attention mask's -1e9, for example) stays float32. The arithmetic is the f32 graph's, in float32: both
backends fold the ``Cast`` of a constant when they load the graph, so the gain is the size of the files, not
speed. The error against the f32 model is the rounding of the weights alone. tract 0.23 has no bfloat16 type
(tract-onnx maps ``FLOAT16`` only), so a bf16 bundle loads on onnxruntime only.

`int8`: dynamic quantization of every MatMul/Gemm whose weight is an initializer
(``onnxruntime.quantization.quantize_dynamic``, int8 weights, symmetric, per output channel with
``--per-channel``): each such product becomes ``DynamicQuantizeLinear`` (the activation to uint8 with a scale
and zero point computed from the activation itself, every step) + ``MatMulInteger`` (int8 weights, int32
accumulation) + the scale multiply and the bias add in f32. The weights use 7 bits (``reduce_range``: integers
in [-64, 64]): on x86-64 without VNNI (AVX2, AVX-512 without VNNI) onnxruntime multiplies uint8 by int8 with
``vpmaddubsw``, which adds two products in int16 and saturates when they pass 32767 (255 x 127 x 2 does); with
7-bit weights no pair can (255 x 64 x 2 = 32640), so every CPU computes the exact integer products that tract
and VNNI compute. Full 8-bit weights measured 0.30-0.61 scaled error against torch on the tiny export on an
AVX2-only AMD EPYC (saturation), 7-bit ones 0.012-0.034 (docs/bundle.md#reduced-precision). Standard ONNX ops (opset 17), run by onnxruntime
and tract. The RoPE rotation matrices are ``Constant`` nodes, not initializers, and stay f32, as do the
codebook embeddings (Gather), layer norms and attention arithmetic.

The reduced bundle is a separate bundle (docs/bundle.md#forms-and-precision), never a change of the f32 one:

- its graphs are the quantized ones, its manifest the f32 manifest with ``precision`` added and the files
  table rewritten; ``model``, ``regions``, ``normalisation``, ``sampling`` and the reference clip are the f32
  bundle's;
- its graph reference vectors are the f32 bundle's, unchanged (``reference/<graph>.npz``: torch's outputs on
  the f32 weights, an independent side: never the reduced graphs' own outputs, which a wrong reduced graph
  would reproduce). Each graph's error against them is measured here (onnxruntime on the reduced graph, the
  scaled error ``max|a - b| / max(1, max|torch|)`` of docs/parity.md over every output and step, and the max abs
  error) and a bound is stated in the manifest, ``checks.<graph>.reduced_vs_f32_torch_bound`` (the measured
  scaled error x ``BOUND_MARGIN``, rounded up to one significant digit: a scaled bound, stated once; the checker
  multiplies it by the reference's scale as it does every bound): ``livegesture parity`` checks the runtime's ort
  and tract against the f32 torch vectors with that bound, and tract against ort with 1e-4. A graph whose measured
  error exceeds the precision's limit (``ERROR_LIMIT``, far above what rounding the weights does) is refused:
  the reduced graph is wrong, not rounded;
- its reference rollout (same clip, repeats and seed) is stepped with the reduced graphs by the Python chain of
  ``bench/ort_python_peer.py`` (a reduced model samples other tokens than the f32 one once a draw is near a
  tie, so the f32 rollout cannot be its reference): it checks that the runtime steps the reduced graphs as the
  Python chain does;
- ``precision.error_vs_f32`` is the measured error against the f32 model: per graph, the max abs difference
  of every output (``logits`` for the fusion) from the f32 bundle's torch reference over its chained steps
  on the same inputs; over the reference rollout, token agreement free-running (the first step where the
  reduced rollout draws another token, and the fraction of identical tokens) and teacher-forced (at every
  step the reduced chain is fed the f32 rollout's previous tokens and draws with the same uniforms: the
  fraction of steps and of region tokens it draws as the f32 model did, and the max abs error of its guided
  logits against the f32 graphs' (onnxruntime, same inputs)).
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

if __name__ == "__main__" and not __package__:
    # run as a file (python export/quantize.py): run the package module, as `python -m export.quantize` from the
    # repository root does (the repository root instead of export/ first on the module path)
    import runpy
    sys.path[0] = str(Path(__file__).resolve().parents[1])
    runpy.run_module("export.quantize", run_name="__main__", alter_sys=True)
    raise SystemExit(0)

from livegesture import families  # noqa: E402
from livegesture.compare import diff  # noqa: E402
from livegesture.ort_chain import Chain, Streams, reference, token_mels  # noqa: E402
from livegesture.sampling import guide  # noqa: E402

PRECISIONS = ("int8", "f16", "bf16", "float16", "bfloat16")
# The stated bound of a reduced graph against the f32 torch reference vectors: the measured scaled error times
# this margin (room for the Rust runtime's onnxruntime and tract, which differ from Python's onnxruntime by
# ~1e-6), rounded up to one significant digit, and never below the f32 bound (docs/parity.md, 1e-5 scaled).
BOUND_MARGIN = 2.0
F32_BOUND = 1e-5
# The largest scaled error a reduced graph may have against the f32 torch reference vectors: far above what
# rounding the weights does (measured on the tiny test export, export/export.py --config tiny --random-seed 0,
# 2026-11-26: float16 <= 6.2e-4, int8 dynamic per tensor <= 2.2e-2; the manifest's
# checks.<graph>.reduced_vs_f32_torch_scaled), far below what a wrong graph does (a weight matrix scaled,
# transposed or from another graph). Over it, quantize refuses the bundle.
ERROR_LIMIT = {"float16": 0.02, "bfloat16": 0.1, "int8": 0.3}
# --precision -> the manifest's precision.weights (docs/bundle.md#forms-and-precision; the runtime's bundle::PRECISIONS)
WEIGHTS = {"int8": "int8", "f16": "float16", "float16": "float16", "bf16": "bfloat16", "bfloat16": "bfloat16"}
F16_MAX = float(np.finfo(np.float16).max)
BF16_MAX = 3.3895313892515355e38


def to_bf16_bits(a: np.ndarray) -> np.ndarray:
    """float32 -> bfloat16 bit patterns (uint16), round to nearest even (finite values)."""
    u = np.ascontiguousarray(a, dtype=np.float32).view(np.uint32).astype(np.uint64)
    return ((u + 0x7FFF + ((u >> 16) & 1)) >> 16).astype(np.uint16)


def bf16_bits_to_f32(b: np.ndarray) -> np.ndarray:
    return (b.astype(np.uint32) << 16).view(np.float32)


def reduced_tensor(a: np.ndarray, name: str, weights: str):
    """(TensorProto of ``a`` in the reduced type, the float32 values it stands for), or None when ``a`` has a value
    outside the reduced type's finite range (it then stays float32)."""
    from onnx import TensorProto, numpy_helper
    if not np.isfinite(a).all() or float(np.abs(a).max(initial=0.0)) > (F16_MAX if weights == "float16" else BF16_MAX):
        return None
    if weights == "float16":
        h = a.astype(np.float16)
        return numpy_helper.from_array(h, name), h.astype(np.float32)
    bits = to_bf16_bits(a)
    t = TensorProto()
    t.name, t.data_type = name, TensorProto.BFLOAT16
    t.dims.extend(a.shape)
    t.raw_data = bits.astype("<u2").tobytes()
    back = bf16_bits_to_f32(bits)
    # round to nearest even can carry a value past the largest finite bfloat16
    return (t, back) if np.isfinite(back).all() else None


def cast_weights(m, weights: str) -> dict:
    """Stores every float32 initializer and Constant tensor of more than one element as ``weights``
    (float16/bfloat16) followed by a Cast to float32 under its original name, in place. Returns counts:
    tensors reduced, tensors kept float32 (out of range), and the largest rounding error of a weight."""
    from onnx import TensorProto, helper, numpy_helper
    inits = list(m.graph.initializer)
    new_inits, head, kept, reduced, max_round = [], [], 0, 0, 0.0
    for i in inits:
        a = numpy_helper.to_array(i) if i.data_type == TensorProto.FLOAT else None
        r = reduced_tensor(a, i.name + "_" + weights, weights) if a is not None and a.size > 1 else None
        if r is None:
            kept += int(a is not None and a.size > 1)
            new_inits.append(i)
            continue
        t, back = r
        max_round = max(max_round, float(np.abs(back - a).max()))
        new_inits.append(t)
        head.append(helper.make_node("Cast", [t.name], [i.name], name=i.name + "_cast", to=TensorProto.FLOAT))
        reduced += 1
    nodes = []
    for n in m.graph.node:
        if n.op_type == "Constant" and len(n.attribute) == 1 and n.attribute[0].name == "value" \
                and n.attribute[0].t.data_type == TensorProto.FLOAT:
            a = numpy_helper.to_array(n.attribute[0].t)
            r = reduced_tensor(a, n.output[0] + "_" + weights, weights) if a.size > 1 else None
            if r is None:
                kept += int(a.size > 1)
            else:
                t, back = r
                max_round = max(max_round, float(np.abs(back - a).max()))
                nodes.append(helper.make_node("Constant", [], [t.name], name=(n.name or n.output[0]) + "_" + weights,
                                              value=t))
                nodes.append(helper.make_node("Cast", [t.name], [n.output[0]], name=(n.name or n.output[0]) + "_cast",
                                              to=TensorProto.FLOAT))
                reduced += 1
                continue
        nodes.append(n)
    del m.graph.initializer[:]
    m.graph.initializer.extend(new_inits)
    del m.graph.node[:]
    m.graph.node.extend(head + nodes)
    return {"reduced_tensors": reduced, "kept_float32_tensors": kept, "weight_rounding_max_abs": max_round}


def weight_only_int8(m):
    """Every MatMul/Gemm initializer weight -> int8 (symmetric, one scale per output channel) +
    DequantizeLinear to f32 in the graph; the product itself stays f32 (row-independent: no activation
    quantization, so a batch row never depends on the other rows)."""
    import onnx
    from onnx import helper, numpy_helper
    inits = {i.name: i for i in m.graph.initializer}
    new_nodes, n = [], 0
    for node in m.graph.node:
        if node.op_type in ("MatMul", "Gemm") and len(node.input) > 1 and node.input[1] in inits:
            w = numpy_helper.to_array(inits[node.input[1]]).astype(np.float32)
            trans_b = node.op_type == "Gemm" and any(a.name == "transB" and a.i == 1 for a in node.attribute)
            axis = 0 if trans_b else w.ndim - 1   # the output-channel axis of the weight
            red = tuple(i for i in range(w.ndim) if i != axis)
            scale = np.abs(w).max(axis=red) / 127.0
            scale = np.where(scale > 0, scale, 1.0).astype(np.float32)
            shp = [1] * w.ndim
            shp[axis] = -1
            q = np.clip(np.round(w / scale.reshape(shp)), -127, 127).astype(np.int8)
            base = node.input[1]
            m.graph.initializer.remove(inits[base])
            m.graph.initializer.extend([numpy_helper.from_array(q, base + "_int8"),
                                        numpy_helper.from_array(scale, base + "_scale"),
                                        numpy_helper.from_array(np.zeros_like(scale, dtype=np.int8), base + "_zp")])
            new_nodes.append(helper.make_node("DequantizeLinear", [base + "_int8", base + "_scale", base + "_zp"],
                                              [base], name=base + "_dq", axis=axis))
            n += 1
        new_nodes.append(node)
    del m.graph.node[:]
    m.graph.node.extend(new_nodes)
    return m


# onnxruntime's uint8 x int8 products on x86-64 without VNNI (vpmaddubsw) add two products in int16, saturating
# past 32767: with uint8 activations up to 255 the weights must stay within 64 (255 x 64 x 2 = 32640)
SATURATION_FREE_WEIGHT = 32767 // (2 * 255)


def saturating_weights(model) -> list[str]:
    """The ``MatMulInteger`` weight initializers of ``model`` (an onnx ModelProto) with a value beyond
    +-SATURATION_FREE_WEIGHT: products that saturate on a CPU without VNNI (the module docstring)."""
    from onnx import numpy_helper
    inits = {i.name: i for i in model.graph.initializer}
    bad = []
    for n in model.graph.node:
        if n.op_type == "MatMulInteger" and len(n.input) > 1 and n.input[1] in inits:
            w = numpy_helper.to_array(inits[n.input[1]])
            if w.dtype == np.int8 and int(np.abs(w.astype(np.int16)).max()) > SATURATION_FREE_WEIGHT:
                bad.append(n.input[1])
    return bad


def quantize_graph(src: Path, dst: Path, precision: str, per_channel: bool, activations: str = "dynamic") -> dict:
    """Writes the reduced graph; returns what was quantized."""
    import onnx
    from onnxruntime.quantization import QuantType, quantize_dynamic
    if precision not in WEIGHTS:
        raise ValueError(f"--precision {precision}: supported are {', '.join(PRECISIONS)}")
    m = onnx.load(str(src))
    inits = {i.name for i in m.graph.initializer}
    n_weights = sum(1 for n in m.graph.node if n.op_type in ("MatMul", "Gemm") and any(x in inits for x in n.input[1:2]))
    stats = {"nodes_f32": len(m.graph.node),
             "f32_initializer_bytes": sum(int(np.prod(i.dims)) * 4 for i in m.graph.initializer
                                          if i.data_type == onnx.TensorProto.FLOAT)}

    def save(q, tag: str) -> None:
        """The reduced graph keeps the f32 graph's metadata (livegesture.graph, ...) and says what it is."""
        if q is not m:
            del q.metadata_props[:]
            for p in m.metadata_props:
                q.metadata_props.add().CopyFrom(p)
        p = q.metadata_props.add()
        p.key, p.value = "livegesture.precision", tag
        q.producer_name = "livegesture-quantize"
        onnx.checker.check_model(q)
        onnx.save(q, str(dst))
        stats.update(nodes=len(q.graph.node), file_bytes_f32=src.stat().st_size, file_bytes=dst.stat().st_size)

    if WEIGHTS[precision] in ("float16", "bfloat16"):
        counts = cast_weights(m, WEIGHTS[precision])
        if counts["reduced_tensors"] == 0:
            raise RuntimeError(f"{src.name}: no float32 weight to store as {WEIGHTS[precision]}")
        save(m, WEIGHTS[precision])
        return {**counts, "quantized_products": 0, **stats}
    if activations not in ("dynamic", "f32"):
        raise ValueError(f"--activations {activations}: expected dynamic or f32")
    if activations == "f32":
        save(weight_only_int8(onnx.load(str(src))), precision)
        return {"quantized_products": n_weights, **stats}
    with tempfile.TemporaryDirectory() as td:
        quantize_dynamic(str(src), str(Path(td) / "q.onnx"), op_types_to_quantize=["MatMul", "Gemm"],
                         weight_type=QuantType.QInt8, per_channel=per_channel, reduce_range=True,
                         extra_options={"MatMulConstBOnly": True})
        q = onnx.load(str(Path(td) / "q.onnx"))
    bad = saturating_weights(q)
    if bad:
        raise RuntimeError(f"{src.name}: int8 weights beyond +-{SATURATION_FREE_WEIGHT} ({', '.join(bad[:3])}): their "
                           "products saturate on x86-64 without VNNI")
    save(q, precision)
    n_int = [n.op_type for n in q.graph.node].count("MatMulInteger")
    if n_int != n_weights:
        raise RuntimeError(f"{src.name}: {n_weights} weight products, but {n_int} were quantized")
    return {"quantized_products": n_weights, **stats}


def stated_bound(scaled_error: float) -> float:
    """The bound stated for a graph whose measured scaled error is ``scaled_error`` (see ``BOUND_MARGIN``)."""
    b = max(F32_BOUND, scaled_error * BOUND_MARGIN)
    e = np.floor(np.log10(b))
    return float(f"{np.ceil(b / 10 ** e * (1 - 1e-12)) * 10 ** e:.1g}")


def graph_reference(sess, spec: dict, ref: dict) -> tuple[dict, dict]:
    """Chains the reduced graph over the f32 reference's inputs; returns its outputs (same keys as the f32
    reference) and the error of each output (and last caches) against the f32 (torch) reference: ``err[name]``
    the max abs error, ``err["scaled"]`` the largest scaled error of any output or cache
    (``livegesture.compare``, NaN or Inf on either side: infinite)."""
    n_steps, batch = int(ref["n_steps"]), int(ref["batch"])
    out_names = [o.name for o in sess.get_outputs()]
    caches = {c["input"]: np.zeros([batch, *c["shape"][1:]], dtype=np.dtype(c["dtype"])) for c in spec["caches"]}
    new = {"n_steps": ref["n_steps"], "batch": ref["batch"]}
    err: dict[str, float] = {}
    scaled = 0.0
    for s in range(n_steps):
        feed = {i["name"]: ref[f"step{s}.input.{i['name']}"] for i in spec["inputs"]}
        for k, v in feed.items():
            new[f"step{s}.input.{k}"] = v
        res = dict(zip(out_names, sess.run(None, {**feed, **caches})))
        for o in spec["outputs"]:
            got = res[o["name"]]
            new[f"step{s}.output.{o['name']}"] = got
            e = diff(got, ref[f"step{s}.output.{o['name']}"]).max_abs   # NaN-safe: inf when not finite
            err[o["name"]] = max(err.get(o["name"], 0.0), e)

            scaled = max(scaled, diff(got, ref[f"step{s}.output.{o['name']}"]).scaled_error)
        if "phase" in feed:   # a ring graph (docs/bundle.md#ring-caches): its entries written at the phase
            p = int(feed["phase"][0])
            for c in spec["caches"]:
                if "output_shape" in c:
                    cache = caches[c["input"]].copy()
                    cache[..., p % cache.shape[-2], :] = res[c["output"]][..., 0, :]
                    res[c["output"]] = cache
        caches = {c["input"]: res[c["output"]] for c in spec["caches"]}
        if s == n_steps - 1:
            for c in spec["caches"]:
                got = res[c["output"]]
                new[f"step{s}.new_cache.{c['name']}"] = got
                if got.dtype.kind == "f":
                    e = diff(got, ref[f"step{s}.new_cache.{c['name']}"]).max_abs
                    err["caches (last step)"] = max(err.get("caches (last step)", 0.0), e)

                    scaled = max(scaled, diff(got, ref[f"step{s}.new_cache.{c['name']}"]).scaled_error)
    err["scaled"] = scaled
    return new, err


def rollout(chain: Chain, mels: np.ndarray, seed: int, n: int, forced: np.ndarray | None = None,
            f32: Chain | None = None) -> dict:
    """The rollout with the reduced graphs. ``forced``: the f32 rollout's tokens; each step then starts from
    the f32 rollout's previous tokens (teacher forcing), and with ``f32`` the f32 graphs run beside it on the
    same inputs, so the guided logits can be compared."""
    s = Streams(chain, 1, [seed], [0])
    sf = Streams(f32, 1, [seed], [0]) if f32 is not None else None
    tokens, frames, logit_err = [], [], 0.0
    for t in range(n):
        if forced is not None and t > 0:
            s.prev = forced[t - 1][None].copy()
            if sf is not None:
                sf.prev = forced[t - 1][None].copy()
        if sf is not None:
            sf.rngs[0].state = s.rngs[0].state   # the same uniform for both
        tok, fr = s.step(mels[t][None])
        if sf is not None:
            sf.step(mels[t][None])
            lq = chain.last_logits
            lf = f32.last_logits
            gq = guide(lq[0], lq[1], chain.guidance) if chain.guided else lq[0].astype(np.float64)
            gf = guide(lf[0], lf[1], f32.guidance) if f32.guided else lf[0].astype(np.float64)
            logit_err = max(logit_err, diff(gq, gf).max_abs)
        tokens.append(tok[0])
        frames.append(fr[0])
    out = {"tokens": np.stack(tokens).astype(np.int64)}
    for k in ("poses", "trans", "expressions", "foot_contact"):
        out[k] = np.concatenate([f[k] for f in frames]).astype(np.float32)
    out["guided_logits_max_abs"] = logit_err
    return out


class LoggingChain(Chain):
    """Chain that keeps the last fusion logits (for the teacher-forced comparison)."""

    def run(self, name, feed, caches):
        out = super().run(name, feed, caches)
        if name == "fusion":
            self.last_logits = out["logits"][:, :, :]
        return out


# long: one reduced-precision bundle in order (weights, activations, verification, manifest)
def build(src: Path, out: Path, precision: str, per_channel: bool, log=print, activations: str = "dynamic") -> dict:
    import onnxruntime as ort
    from .bundle_writer import export_provenance, file_table, sha256, staged_folder
    if precision not in WEIGHTS:
        raise ValueError(f"--precision {precision}: supported are {', '.join(PRECISIONS)}")
    weights = WEIGHTS[precision]
    cast = weights in ("float16", "bfloat16")
    manifest = json.loads((src / "manifest.json").read_text())
    if families.of_manifest(manifest) is not families.LIVEGESTURE:
        raise ValueError(f"{src}/manifest.json: family {manifest['family']}: only LiveGesture bundles are supported")
    if manifest.get("precision", {}).get("weights", "float32") != "float32":
        raise ValueError(f"{src}/manifest.json: precision.weights is {manifest['precision']['weights']}; "
                         "derive a reduced bundle from an f32 one")
    with staged_folder(out) as tmp:
        (tmp / "reference").mkdir()
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        per_graph, graph_info, scaled_err = {}, {}, {}
        for spec in manifest["graphs"]:
            t0 = time.time()
            info = quantize_graph(src / spec["file"], tmp / spec["file"], precision, per_channel, activations)
            sess = ort.InferenceSession(str(tmp / spec["file"]), opts, providers=["CPUExecutionProvider"])
            rel = spec.get("reference", f"reference/{spec['name']}.npz")
            ref = dict(np.load(src / rel))
            _, err = graph_reference(sess, spec, ref)
            # the reference vectors stay the f32 bundle's (torch): the reduced graph is checked against them
            shutil.copy2(src / rel, tmp / rel)
            scaled_err[spec["name"]] = err.pop("scaled")
            limit = ERROR_LIMIT[weights]
            if not scaled_err[spec["name"]] <= limit:
                raise RuntimeError(
                    f"graph '{spec['name']}': the {weights} graph differs from the f32 bundle's torch reference "
                    f"vectors by {scaled_err[spec['name']]:.3g} (scaled), over the {weights} limit {limit}: the "
                    "reduced graph is wrong, not rounded")
            per_graph[spec["name"]] = {k: err[k] for k in sorted(err)}
            graph_info[spec["name"]] = info
            what = (f"{info['reduced_tensors']} tensors {weights} ({info['kept_float32_tensors']} kept f32, weight "
                    f"rounding {info['weight_rounding_max_abs']:.2g})" if cast else f"{info['quantized_products']} products int8")
            log(f"  {spec['name']:<16} {what}, nodes {info['nodes_f32']} -> "
                f"{info['nodes']}, file {info['file_bytes_f32'] / 1e6:.2f} -> {info['file_bytes'] / 1e6:.2f} MB, "
                f"max abs vs f32 {max(err.values()):.3g} ({time.time() - t0:.1f}s)")
        for rel in ("reference/clip.wav", manifest["reference"].get("logmel", "reference/logmel.npy")):
            shutil.copy2(src / rel, tmp / rel)

        # the reference rollout with the reduced graphs (same clip, repeats, seed), and the token agreement
        t0 = time.time()
        f32 = LoggingChain(src)
        # the reduced chain reads the reduced graphs with the f32 manifest's graph table (same names/files)
        q = LoggingChain.__new__(LoggingChain)
        _init_chain_from(q, tmp, manifest)
        audio, seed, ref_tokens = reference(f32)
        mels = token_mels(f32, audio)
        n = min(len(ref_tokens), len(mels))
        ro = rollout(q, mels, seed, n)
        tf = rollout(q, mels, seed, n, forced=ref_tokens[:n], f32=f32)
        src_ro = np.load(src / manifest["reference"]["rollout"])
        np.savez_compressed(tmp / manifest["reference"]["rollout"], tokens=ro["tokens"], poses=ro["poses"],
                            trans=ro["trans"], expressions=ro["expressions"], foot_contact=ro["foot_contact"],
                            seed=src_ro["seed"], clip_repeats=src_ro["clip_repeats"])
        same = ro["tokens"] == ref_tokens[:n]
        diff_steps = np.nonzero(~same.all(1))[0]
        tf_same = tf["tokens"] == ref_tokens[:n]
        rollout_err = {
            "tokens": int(n),
            "free_running_identical_tokens": float(same.mean()),
            "free_running_first_differing_step": int(diff_steps[0]) if len(diff_steps) else None,
            "teacher_forced_identical_steps": float(tf_same.all(1).mean()),
            "teacher_forced_identical_tokens": float(tf_same.mean()),
            "teacher_forced_guided_logits_max_abs": tf["guided_logits_max_abs"],
        }
        log(f"  rollout          {n} tokens: free-running identical {rollout_err['free_running_identical_tokens']:.3f} "
            f"(first difference at step {rollout_err['free_running_first_differing_step']}), teacher-forced identical "
            f"tokens {rollout_err['teacher_forced_identical_tokens']:.4f}, guided logits max abs "
            f"{tf['guided_logits_max_abs']:.3g} ({time.time() - t0:.1f}s)")

        m = json.loads(json.dumps(manifest))
        m["precision"] = {
            "weights": weights,
            "method": ((f"weight storage only: every float32 initializer and Constant tensor of more than one element "
                        f"stored as {weights} (round to nearest even) + Cast to float32 under its original name (a "
                        f"tensor with a value outside the {weights} range stays float32); all arithmetic in float32, "
                        "as in the f32 graphs (both backends fold the Cast of a constant at load: the gain is the size "
                        "of the files, not speed)") if cast else
                       ("onnxruntime.quantization.quantize_dynamic: every MatMul/Gemm with an initializer weight as "
                        "DynamicQuantizeLinear (uint8 activations, one scale per tensor per step, i.e. shared by all "
                        "batch rows) + MatMulInteger (int8 weights, "
                        f"symmetric, {'per output channel' if per_channel else 'per tensor'}) + f32 scale and bias")
                       if activations == "dynamic" else
                       "weight-only: every MatMul/Gemm initializer weight as int8 (symmetric, per output channel) + "
                       "DequantizeLinear to f32 in the graph; f32 products (row-independent)"),
            "per_channel": per_channel if not cast else None,
            "activations": "float32" if cast else activations,
            "source": {"bundle": src.name, "manifest_sha256": sha256(src / "manifest.json"),
                       "config": manifest["model"].get("config_name"),
                       "training": manifest.get("provenance", {}).get("training", "trained checkpoint")},
            "reference": ("graph reference vectors: the f32 bundle's (torch on the f32 weights), checked with the bound "
                          "stated per graph in checks.<graph>.reduced_vs_f32_torch_bound (measured with onnxruntime "
                          f"{ort.__version__}, Python, CPU, x {BOUND_MARGIN}); reference rollout: onnxruntime "
                          f"{ort.__version__} (Python, CPU) on the reduced graphs, same clip and seed"),
            "graphs": graph_info,
            "error_vs_f32": {"graphs_max_abs": per_graph, "rollout": rollout_err,
                             "definition": ("graphs: max abs of every output (logits for the fusion) over the f32 "
                                            "bundle's chained reference steps, same inputs, against its torch outputs; "
                                            "rollout: see export/quantize.py")},
            "metrics": None,
        }
        m["reference"]["rollout_producer"] = "onnxruntime (Python), reduced graphs"
        for g, e in per_graph.items():
            m["checks"].setdefault(g, {})["reduced_vs_f32_max_abs"] = max(e.values())
            m["checks"][g]["reduced_vs_f32_torch_scaled"] = scaled_err[g]
            # stated once, from the measured scaled error: the checker scales it (livegesture parity judges
            # error <= bound x max(1, max|reference|)); stating it from the absolute error as well scaled it twice
            m["checks"][g]["reduced_vs_f32_torch_bound"] = stated_bound(scaled_err[g])
            m["checks"][g]["ort_vs_torch_max_abs_f32_bundle"] = m["checks"][g].pop("ort_vs_torch_max_abs", None)
        m["files"] = file_table(tmp)
        m["provenance"] = {**manifest.get("provenance", {}),
                           "reduced_precision": {**export_provenance(), "command": " ".join(sys.argv)}}
        with open(tmp / "manifest.json", "w") as f:
            json.dump(m, f, indent=1)
            f.write("\n")
        return m


def _init_chain_from(chain: Chain, folder: Path, manifest: dict):
    """A Chain over the graphs in ``folder`` described by ``manifest`` (the folder has no manifest yet)."""
    folder.joinpath("manifest.json").write_text(json.dumps(manifest))
    try:
        Chain.__init__(chain, folder)
    finally:
        folder.joinpath("manifest.json").unlink()


def record_metrics(bundle: Path, f32_eval: Path, reduced_eval: Path, command: str) -> dict:
    """Writes ``precision.metrics`` of a reduced bundle: the evaluation reports (``python -m livegesture.eval``
    JSON, as ``scripts/eval_bundle.sh`` writes them) of the f32 bundle and of this one, side by side (docs/bundle.md#forms-and-precision).
    The manifest is rewritten; the files table (graphs and reference vectors) is unchanged."""
    mpath = bundle / "manifest.json"
    m = json.loads(mpath.read_text())
    if m.get("precision", {}).get("weights", "float32") == "float32":
        raise ValueError(f"{mpath}: not a reduced-precision bundle (no precision.weights other than float32)")
    reports = {}
    for tag, path in (("float32", f32_eval), (m["precision"]["weights"], reduced_eval)):
        try:
            reports[tag] = json.loads(Path(path).read_text())
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: cannot read the evaluation report: {e}") from e
        if not isinstance(reports[tag], dict) or "generated" not in reports[tag]:
            raise ValueError(f"{path}: not a livegesture.eval report (no 'generated' section)")
    m["precision"]["metrics"] = {
        "command": command,
        "reports": {tag: str(path) for tag, path in (("float32", f32_eval),
                                                                   (m["precision"]["weights"], reduced_eval))},
        "generated": {tag: r["generated"] for tag, r in reports.items()},
        "ground_truth": next(iter(reports.values())).get("ground_truth"),
    }
    with open(mpath, "w") as f:
        json.dump(m, f, indent=1)
        f.write("\n")
    return m["precision"]["metrics"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    if argv is None:
        argv = sys.argv[1:]
    if "--record-metrics" in argv:
        mp = argparse.ArgumentParser(description="record the evaluation metrics beside f32 in a reduced bundle")
        mp.add_argument("--record-metrics", required=True, metavar="REDUCED_BUNDLE")
        mp.add_argument("--metrics-f32", required=True, help="eval.json of the f32 bundle")
        mp.add_argument("--metrics-reduced", required=True, help="eval.json of the reduced bundle")
        mp.add_argument("--metrics-command", required=True, help="the commands that made both reports")
        a = mp.parse_args(argv)
        try:
            met = record_metrics(Path(a.record_metrics), Path(a.metrics_f32), Path(a.metrics_reduced), a.metrics_command)
        except ValueError as e:
            print(f"quantize: {e}", file=sys.stderr)
            return 1
        print(json.dumps(met["generated"], indent=1))
        return 0
    ap.add_argument("--bundle", required=True, help="the f32 bundle")
    ap.add_argument("--precision", default="int8", choices=PRECISIONS)
    ap.add_argument("--per-channel", action="store_true", help="one weight scale per output channel (dynamic)")
    ap.add_argument("--activations", choices=("dynamic", "f32"), default="dynamic",
                    help="dynamic: uint8 activations quantized per tensor each step (MatMulInteger; fast on ort, but "
                         "batch rows share the scale); f32: weight-only int8, DequantizeLinear + f32 products")
    ap.add_argument("--out", required=True, help="reduced bundle folder to write (replaced atomically)")
    args = ap.parse_args(argv)
    src, out = Path(args.bundle).resolve(), Path(args.out).resolve()
    if src == out:
        print("quantize: --out must differ from --bundle (a reduced bundle never replaces the f32 one)", file=sys.stderr)
        return 2
    if not (src / "manifest.json").is_file():
        print(f"quantize: {src}/manifest.json: no such file", file=sys.stderr)
        return 2
    out.parent.mkdir(parents=True, exist_ok=True)
    print(f"quantizing {src} -> {out} ({args.precision})")
    try:
        build(src, out, args.precision, args.per_channel, activations=args.activations)
    except (ValueError, RuntimeError, KeyError) as e:
        print(f"quantize failed: {e}", file=sys.stderr)
        return 1
    print(f"ok: {out}/manifest.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())

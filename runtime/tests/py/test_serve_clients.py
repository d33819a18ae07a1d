"""Independent clients (docs/clients/, written against docs/serve.md alone) get frames equal to `generate`,
and refusals with reasons for bad parameters, malformed and oversize messages."""
import asyncio
import json
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest
import websockets

from livegesture.compare import assert_within

ROOT = pathlib.Path(__file__).resolve().parents[3]
CLIENTS = ROOT / "docs/clients"


def generate(binary, bundle, wav, out, seed):
    r = subprocess.run([str(binary), "generate", str(wav), "-o", str(out), "--seed", str(seed),
                        "--backend", "tract", "--bundle", str(bundle)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return np.load(out)


def compare(frames, ref, n_in, rate):
    """Frames cover the whole audio (ceil rule, the last partial token completed with silence) and equal
    generate's, every frame including the last partial token's, within 1e-4 (scaled, docs/parity.md)."""
    want = -(-n_in * 30 // rate)
    assert len(frames) == want, f"{len(frames)} frames, the audio needs {want}"
    assert [f["index"] for f in frames] == list(range(want))
    # generate covers the whole audio too (docs/output.md): no frame may be missing on either side
    assert len(ref["poses"]) == want, f"generate wrote {len(ref['poses'])} frames, the audio needs {want}"
    worst = None
    for k in ("poses", "expressions", "trans"):
        got = np.array([f[k] for f in frames], dtype=np.float32)
        d = assert_within(got, ref[k], 1e-4, f"client vs generate: '{k}'")
        worst = d if worst is None else worst.worst(d)
    return worst.max_abs


def test_the_comparison_fails_on_missing_frames_and_nan(binary, bundle, speech_wav, tmp_path):
    """compare() is strict: generate's own frames pass; a frame missing (the last partial token's), a moved
    value, or a NaN in either side fails."""
    wav, n, rate = speech_wav
    ref = dict(generate(binary, bundle, wav, tmp_path / "ref.npz", seed=7))
    frames = [{"index": i, "poses": ref["poses"][i].tolist(), "expressions": ref["expressions"][i].tolist(),
               "trans": ref["trans"][i].tolist()} for i in range(len(ref["poses"]))]
    assert compare(frames, ref, n, rate) == 0.0
    with pytest.raises(AssertionError, match="frames"):
        compare(frames[:-1], ref, n, rate)                  # the last frame (of the partial token) missing
    short = {**ref, "poses": ref["poses"][:-2], "expressions": ref["expressions"][:-2], "trans": ref["trans"][:-2]}
    with pytest.raises(AssertionError, match="generate wrote"):
        compare(frames, short, n, rate)                     # generate missing frames
    for k, v in (("poses", 1e-3), ("expressions", float("nan"))):
        bad = [dict(f) for f in frames]
        bad[-1] = {**bad[-1], k: list(bad[-1][k])}
        bad[-1][k][4] = bad[-1][k][4] + v
        with pytest.raises(AssertionError, match=k):
            compare(bad, ref, n, rate)
        bad_ref = {**ref, k: ref[k].copy()}
        bad_ref[k][-1, 4] += v
        with pytest.raises(AssertionError, match=k):
            compare(frames, bad_ref, n, rate)


def read_jsonl(path):
    return [json.loads(line) for line in pathlib.Path(path).read_text().splitlines() if line.strip()]


def test_python_client_frames_equal_generate(server, binary, bundle, speech_wav, tmp_path):
    wav, n, rate = speech_wav
    ref = generate(binary, bundle, wav, tmp_path / "ref.npz", seed=7)
    out = tmp_path / "py.jsonl"
    r = subprocess.run([sys.executable, str(CLIENTS / "serve_client.py"), server.url, str(wav), "--seed", "7",
                        "--out", str(out), "--chunk-ms", "37"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    compare(read_jsonl(out), ref, n, rate)
    # a different seed differs: the comparison can fail
    out2 = tmp_path / "py2.jsonl"
    r = subprocess.run([sys.executable, str(CLIENTS / "serve_client.py"), server.url, str(wav), "--seed", "8",
                        "--out", str(out2)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    with pytest.raises(AssertionError):
        compare(read_jsonl(out2), ref, n, rate)


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_javascript_client_frames_equal_generate(server, binary, bundle, speech_wav, tmp_path):
    wav, n, rate = speech_wav
    ref = generate(binary, bundle, wav, tmp_path / "ref.npz", seed=3)
    major = int(subprocess.run(["node", "--version"], capture_output=True, text=True).stdout.strip("v\n").split(".")[0])
    flags = [] if major >= 22 else ["--experimental-websocket"]
    r = subprocess.run(["node", *flags, str(CLIENTS / "serve_client.mjs"), server.url, str(wav), "3"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    compare([json.loads(line) for line in r.stdout.splitlines()], ref, n, rate)


async def _close_of(url, send):
    async with websockets.connect(url, max_size=None) as ws:
        ready = json.loads(await ws.recv())
        assert ready["type"] == "ready"
        await ws.send(send)
        try:
            while True:
                await ws.recv()
        except websockets.ConnectionClosed as e:
            return e.rcvd.code, e.rcvd.reason


async def _status_of(url):
    try:
        async with websockets.connect(url):
            return 101, ""
    except websockets.InvalidStatus as e:
        return e.response.status_code, e.response.body.decode()


def test_refusals_carry_reasons(server):
    base = server.url + "/v1/stream"
    for q, word in [("?rate=-1", "rate"), ("?format=mp3", "format"), ("?output=csv", "output"), ("?x=1", "x")]:
        status, body = asyncio.run(_status_of(base + q))
        assert status == 400 and word in body, (q, status, body)
    code, reason = asyncio.run(_close_of(base, "not json"))
    assert code == 1007 and "malformed" in reason
    code, reason = asyncio.run(_close_of(base, json.dumps({"type": "rewind"})))
    assert code == 1003 and "rewind" in reason
    code, reason = asyncio.run(_close_of(base, b"\0" * 70000))
    assert code == 1009 and "limit" in reason

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

ROOT = pathlib.Path(__file__).resolve().parents[3]
CLIENTS = ROOT / "docs/clients"


def generate(binary, bundle, wav, out, seed):
    r = subprocess.run([str(binary), "generate", str(wav), "-o", str(out), "--seed", str(seed),
                        "--backend", "tract", "--bundle", str(bundle)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return np.load(out)


def compare(frames, ref, n_in, rate):
    """Frames cover the whole audio (ceil rule) and equal generate's within 1e-4."""
    want = -(-n_in * 30 // rate)
    assert len(frames) == want
    assert [f["index"] for f in frames] == list(range(want))
    # generate writes every frame it makes (all of them once it also completes the last token)
    t = len(ref["poses"])
    assert want - 4 < t <= want
    poses = np.array([f["poses"] for f in frames[:t]], dtype=np.float32)
    expr = np.array([f["expressions"] for f in frames[:t]], dtype=np.float32)
    trans = np.array([f["trans"] for f in frames[:t]], dtype=np.float32)
    err = max(np.abs(poses - ref["poses"]).max(), np.abs(expr - ref["expressions"]).max(),
              np.abs(trans - ref["trans"]).max())
    assert err <= 1e-4, err
    return err


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

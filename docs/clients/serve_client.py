#!/usr/bin/env python3
"""Minimal `livegesture serve` client, written against docs/serve.md alone (nothing of the project).

Streams a 16-bit PCM WAV file to ws://HOST:PORT/v1/stream (optionally in real time), then sends
{"type":"end"} and writes every frame it receives as one JSON object per line.

    python serve_client.py ws://127.0.0.1:8765 speech.wav --seed 0 --out frames.jsonl [--realtime]

Needs the `websockets` package (pip install websockets).
"""
import argparse
import asyncio
import json
import sys
import time
import wave

import websockets


async def run(url, wav_path, seed, out_path, realtime, chunk_ms):
    with wave.open(wav_path, "rb") as w:
        if w.getsampwidth() != 2:
            sys.exit(f"{wav_path}: expected 16-bit PCM")
        rate, channels = w.getframerate(), w.getnchannels()
        pcm = w.readframes(w.getnframes())
    query = f"?rate={rate}&channels={channels}&format=s16le&seed={seed}&output=json"
    frames, done, latencies = [], None, []
    async with websockets.connect(url.rstrip("/") + "/v1/stream" + query, max_size=None) as ws:
        ready = json.loads(await ws.recv())
        assert ready["type"] == "ready", ready
        print(f"ready: model {ready['model']}, fps {ready['fps']}", file=sys.stderr)
        step = max(2 * channels, int(rate * chunk_ms / 1000) * 2 * channels)

        async def send():
            t0 = time.monotonic()
            for i in range(0, len(pcm), step):
                await ws.send(pcm[i:i + step])
                if realtime:  # pace the audio as a microphone would
                    ahead = (i + step) / (2 * channels * rate) - (time.monotonic() - t0)
                    if ahead > 0:
                        await asyncio.sleep(ahead)
            await ws.send(json.dumps({"type": "end"}))

        sender = asyncio.create_task(send())
        async for msg in ws:
            m = json.loads(msg)
            if m.get("type") == "done":
                done = m["frames"]
            elif "index" in m:
                frames.append(m)
        await sender
        code, reason = ws.close_code, ws.close_reason
    with open(out_path, "w") as f:
        for m in frames:
            f.write(json.dumps(m) + "\n")
    print(f"{len(frames)} frames (done says {done}); closed {code} {reason!r}", file=sys.stderr)
    return 0 if code == 1000 and done == len(frames) else 1


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("url", help="ws://HOST:PORT")
    ap.add_argument("wav")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="frames.jsonl")
    ap.add_argument("--realtime", action="store_true", help="send at the audio's own pace")
    ap.add_argument("--chunk-ms", type=float, default=20.0)
    a = ap.parse_args()
    sys.exit(asyncio.run(run(a.url, a.wav, a.seed, a.out, a.realtime, a.chunk_ms)))


if __name__ == "__main__":
    main()

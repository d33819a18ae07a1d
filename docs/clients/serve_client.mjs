// Minimal `livegesture serve` client in JavaScript, written against docs/serve.md alone.
// Works in a browser (WebSocket is built in) and in Node (>= 22, or 20 with --experimental-websocket):
//
//   node --experimental-websocket serve_client.mjs ws://127.0.0.1:8765 speech.wav [seed] > frames.jsonl
//
// Streams a 16-bit PCM WAV, sends {"type":"end"}, prints every frame as a JSON line on stdout.
import { readFileSync } from 'node:fs';

const [url, wavPath, seed = '0'] = process.argv.slice(2);
const wav = readFileSync(wavPath);

// the WAV header: find "fmt " and "data" chunks
let off = 12, rate = 16000, channels = 1, bits = 16, pcm = null;
while (off + 8 <= wav.length) {
  const id = wav.toString('ascii', off, off + 4), size = wav.readUInt32LE(off + 4);
  if (id === 'fmt ') { channels = wav.readUInt16LE(off + 10); rate = wav.readUInt32LE(off + 12); bits = wav.readUInt16LE(off + 22); }
  if (id === 'data') { pcm = wav.subarray(off + 8, off + 8 + size); break; }
  off += 8 + size + (size & 1);
}
if (!pcm || bits !== 16) { console.error(`${wavPath}: expected 16-bit PCM WAV`); process.exit(2); }

const ws = new WebSocket(`${url}/v1/stream?rate=${rate}&channels=${channels}&format=s16le&seed=${seed}&output=json`);
ws.binaryType = 'arraybuffer';
let frames = 0, done = null;
ws.onopen = () => {
  const step = Math.floor(rate / 50) * 2 * channels; // 20 ms messages
  for (let i = 0; i < pcm.length; i += step) ws.send(pcm.subarray(i, i + step));
  ws.send(JSON.stringify({ type: 'end' }));
};
ws.onmessage = (ev) => {
  const m = JSON.parse(ev.data);
  if (m.type === 'ready') console.error(`ready: model ${m.model}, fps ${m.fps}`);
  else if (m.type === 'done') done = m.frames;
  else if ('index' in m) { frames++; process.stdout.write(JSON.stringify(m) + '\n'); }
};
ws.onclose = (ev) => {
  console.error(`${frames} frames (done says ${done}); closed ${ev.code} ${ev.reason}`);
  process.exitCode = ev.code === 1000 && done === frames ? 0 : 1;
};
ws.onerror = () => { console.error('connection failed'); process.exitCode = 1; };

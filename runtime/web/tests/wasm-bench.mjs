// Benchmark of the WebAssembly runtime against native tract in one run (docs/wasm.md, BENCHMARKS.md):
//
//   node runtime/web/tests/wasm-bench.mjs --site target/web-static --bin target/release/livegesture \
//     --bundle models/default --wav models/default/reference/clip.wav --rounds 3 --out target/bench-wasm
//
// Per-token time: a whole WAV through one stream, native (`livegesture generate --backend tract`, one
// thread) and in chromium (window.livegestureTest.generate, one worker thread), interleaved A/B for
// --rounds rounds. Fixed costs (process start, bundle load, plan building) are removed by timing the
// first second of the same WAV too: per token = (t(whole) - t(1 s)) / (tokens(whole) - tokens(1 s)).
// Also: first-frame latency from the (fake) microphone, download size (wasm raw and gzipped, bundle
// graphs), WebAssembly memory per stream.
import { spawnSync } from 'node:child_process';
import { mkdirSync, readFileSync, statSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { gzipSync } from 'node:zlib';
import { launchChromium, openPage, serveStatic, wavLength } from './harness.mjs';

const args = {};
const argv = process.argv.slice(2);
for (let i = 0; i < argv.length; i += 2) args[argv[i].replace(/^--/, '')] = argv[i + 1];
for (const k of ['site', 'bin', 'bundle', 'wav', 'out']) if (!args[k]) { console.error(`wasm-bench.mjs: --${k} is required`); process.exit(2); }
const rounds = Number(args.rounds || 3);
mkdirSync(args.out, { recursive: true });
const lines = [];
const say = (s) => { console.log(s); lines.push(s); };

// the WAV and its first second, as files and bytes
const wav = readFileSync(args.wav);
const info = wavLength(wav);
if (info.channels !== 1 || info.bits !== 16) throw new Error(`${args.wav}: expected 16-bit mono PCM`);
const dataAt = wav.indexOf('data') + 8;
const shortSamples = info.rate; // one second
const short = Buffer.concat([wav.subarray(0, dataAt), wav.subarray(dataAt, dataAt + 2 * shortSamples)]);
short.writeUInt32LE(2 * shortSamples, dataAt - 4);
short.writeUInt32LE(short.length - 8, 4);
const shortPath = join(args.out, 'first-second.wav');
writeFileSync(shortPath, short);
const tokens = (samples) => Math.ceil(Math.ceil((samples * 30) / info.rate) / 4);
const tWhole = tokens(info.samples), tShort = tokens(shortSamples);
const seconds = info.samples / info.rate;

function native(path) {
  const t0 = process.hrtime.bigint();
  const r = spawnSync(args.bin, ['generate', path, '-o', join(args.out, 'native.npz'), '--backend', 'tract', '--bundle', args.bundle, '--seed', '7'], { encoding: 'utf8' });
  if (r.status !== 0) throw new Error(`native generate failed: ${r.stderr}`);
  return Number(process.hrtime.bigint() - t0) / 1e6;
}

const { origin, close } = await serveStatic(args.site);
const browser = await launchChromium(args.wav);
try {
  const { page } = await openPage(browser, origin, '?engine=wasm');
  await page.waitForFunction(() => window.lgState.status === 'idle' || window.lgState.error, null, { timeout: 180000 });
  const pageInfo = await page.evaluate(() => window.livegestureTest.info());
  const browserGen = (buf) => page.evaluate(async (b64) => {
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    return (await window.livegestureTest.generate(bytes.buffer, { seed: 7 })).ms;
  }, buf.toString('base64'));
  const res = { native: [], browser: [] };
  for (let r = 0; r < rounds; r++) {
    const nw = native(args.wav), ns = native(shortPath);
    const bw = await browserGen(wav), bs = await browserGen(short);
    res.native.push((nw - ns) / (tWhole - tShort));
    res.browser.push((bw - bs) / (tWhole - tShort));
    say(`round ${r + 1}: native whole ${nw.toFixed(0)} ms, first second ${ns.toFixed(0)} ms; chromium whole ${bw.toFixed(0)} ms, first second ${bs.toFixed(0)} ms`);
  }
  const med = (a) => [...a].sort((x, y) => x - y)[Math.floor(a.length / 2)];
  const n = med(res.native), b = med(res.browser);
  say(`per token (${tWhole - tShort} tokens, median of ${rounds} rounds): native tract ${n.toFixed(2)} ms, chromium wasm ${b.toFixed(2)} ms, ratio ${(b / n).toFixed(2)}`);
  say(`real-time factor (per token / 133.3 ms of audio): native ${(n / (4000 / 30)).toFixed(3)}, chromium ${(b / (4000 / 30)).toFixed(3)}`);
  say(`whole clip (${seconds.toFixed(1)} s) in chromium: ${med(res.browser.map((x) => x * (tWhole - tShort))).toFixed(0)} ms beyond the first second`);
  // memory per stream (a fresh page: wasm memory never shrinks)
  const { page: p2 } = await openPage(browser, origin, '?engine=wasm');
  await p2.waitForFunction(() => window.lgState.status === 'idle' || window.lgState.error, null, { timeout: 180000 });
  const mem = await p2.evaluate(() => window.livegestureTest.memory({ streams: 8 }));
  say(`memory: WebAssembly memory ${(mem.before / 2 ** 20).toFixed(1)} MiB with the model loaded and warmed up; ${mem.streams} streams (1 s pushed each) -> ${(mem.after / 2 ** 20).toFixed(1)} MiB: ${(mem.perStream / 2 ** 20).toFixed(2)} MiB per stream`);
  // first-frame latency from the microphone
  await p2.click('#mic');
  await p2.waitForFunction(() => window.lgState.frames >= 120 || window.lgState.error, null, { timeout: 120000 });
  const st = await p2.evaluate(() => ({ ...window.lgState }));
  say(`microphone: first token's latency ${st.firstLatencyMs?.toFixed(1)} ms, median token latency ${st.latencyMs?.toFixed(1)} ms (from posting the 20 ms AudioWorklet block that completes a token to its last frame on the page)`);
  await p2.click('#stop');
  const wasmBytes = readFileSync(join(args.site, 'wasm/livegesture_wasm_bg.wasm'));
  const glue = statSync(join(args.site, 'wasm/livegesture_wasm.js')).size;
  say(`download: livegesture_wasm_bg.wasm ${(wasmBytes.length / 1e6).toFixed(1)} MB (${(gzipSync(wasmBytes).length / 1e6).toFixed(1)} MB gzipped), glue ${(glue / 1e3).toFixed(0)} kB; bundle (manifest + graphs) ${(pageInfo.bytes / 1e6).toFixed(1)} MB, ${pageInfo.files} files; load + verify ${pageInfo.loadMs.toFixed(0)} ms, warm-up ${pageInfo.warmupMs.toFixed(0)} ms`);
} finally {
  await browser.close();
  close();
}
writeFileSync(join(args.out, 'bench.txt'), lines.join('\n') + '\n');

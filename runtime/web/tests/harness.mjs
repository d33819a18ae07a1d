// Shared by the WebAssembly browser tests and benchmark (wasm.mjs, wasm-bench.mjs): a static file
// server on the loopback address and Debian's chromium (never a downloaded browser).
import { createServer } from 'node:http';
import { readFileSync, statSync } from 'node:fs';
import { extname, join, normalize, resolve } from 'node:path';
import { chromium } from 'playwright-core';

const MIME = { '.html': 'text/html; charset=utf-8', '.js': 'text/javascript; charset=utf-8', '.mjs': 'text/javascript; charset=utf-8', '.wasm': 'application/wasm',
  '.json': 'application/json', '.wav': 'audio/wav' };

/** Serves `dir` on 127.0.0.1 (a free port); `served` lists the paths asked for. `isolate`: send the
 * cross-origin isolation headers (COOP/COEP) that SharedArrayBuffer, and so onnxruntime-web's threads, need. */
export async function serveStatic(dir, { isolate = false } = {}) {
  const site = resolve(dir);
  const served = [];
  const server = createServer((req, res) => {
    const path = normalize(decodeURIComponent(new URL(req.url, 'http://x').pathname)).replace(/^(\.\.[/\\])+/, '');
    let file = join(site, path);
    try { if (statSync(file).isDirectory()) file = join(file, 'index.html'); } catch (_) { /* 404 below */ }
    try {
      const body = readFileSync(file);
      served.push(path);
      const iso = isolate ? { 'cross-origin-opener-policy': 'same-origin', 'cross-origin-embedder-policy': 'require-corp' } : {};
      res.writeHead(200, { 'content-type': MIME[extname(file)] || 'application/octet-stream', 'cache-control': 'no-cache', ...iso });
      res.end(body);
    } catch (_) { res.writeHead(404); res.end('not found'); }
  });
  await new Promise((r) => server.listen(0, '127.0.0.1', r));
  return { origin: `http://127.0.0.1:${server.address().port}`, served, close: () => server.close() };
}

/** Headless chromium with a fake microphone playing `wav`; `extra`: more command-line flags. */
export function launchChromium(wav, extra = []) {
  return chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: [
      '--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-quic',
      '--no-first-run', '--disable-component-update', '--disable-sync',
      '--use-fake-ui-for-media-stream', '--use-fake-device-for-media-stream',
      `--use-file-for-fake-audio-capture=${resolve(wav)}`,
      '--enable-unsafe-swiftshader', '--autoplay-policy=no-user-gesture-required',
      ...extra,
    ],
  });
}

/** Opens `origin/query` and waits for the page and its test hook. */
export async function openPage(browser, origin, query) {
  const page = await browser.newPage({ viewport: { width: 1100, height: 700 } });
  const lines = [];
  page.on('console', (m) => lines.push(`${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => lines.push(`pageerror: ${e.message}`));
  const outside = [];
  page.on('request', (r) => { const u = r.url(); if (!u.startsWith(origin) && !u.startsWith('data:') && !u.startsWith('blob:')) outside.push(u); });
  await page.goto(`${origin}/${query}`, { timeout: 60000 });
  await page.waitForFunction(() => window.lgState && window.lgState.ready && window.livegestureTest, null, { timeout: 120000 });
  return { page, lines, outside };
}

/** Sample rate and samples per channel of a PCM WAV file. */
export function wavLength(buf) {
  let off = 12, rate = 0, channels = 1, bits = 16, samples = 0;
  while (off + 8 <= buf.length) {
    const id = buf.toString('ascii', off, off + 4), size = buf.readUInt32LE(off + 4);
    if (id === 'fmt ') { channels = buf.readUInt16LE(off + 10); rate = buf.readUInt32LE(off + 12); bits = buf.readUInt16LE(off + 22); }
    if (id === 'data') samples = size / (channels * (bits / 8));
    off += 8 + size + (size & 1);
  }
  return { rate, samples, channels, bits };
}

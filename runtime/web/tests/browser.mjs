// Browser test of the page served by `livegesture serve` (run by scripts/test.sh):
// Debian's chromium (never a downloaded browser) driven by playwright-core, with a fake microphone
// fed from a WAV file. Checks: the page connects, frames arrive, the skeleton's joints move, a
// screenshot PNG is written under target/ and is not blank; then the WAV-file mode streams a file;
// then avatar-checks.mjs (skinned figure, face panel, .glb in GLTFLoader, a VRM avatar following a WAV).
//
//   node runtime/web/tests/browser.mjs <livegesture binary> <bundle> <fake-mic.wav> <out-dir>
import { spawn } from 'node:child_process';
import { mkdirSync, writeFileSync } from 'node:fs';
import { join, resolve } from 'node:path';
import { chromium } from 'playwright-core';
import { avatarChecks } from './avatar-checks.mjs';

const [bin, bundle, wav, outDir] = process.argv.slice(2);
if (!outDir) { console.error('usage: browser.mjs BIN BUNDLE WAV OUT_DIR'); process.exit(2); }
mkdirSync(outDir, { recursive: true });

const fail = (msg) => { console.error(`browser test FAILED: ${msg}`); process.exitCode = 1; throw new Error(msg); };
const withTimeout = (p, ms, what) => Promise.race([p, new Promise((_, rej) => setTimeout(() => rej(new Error(`timeout: ${what}`)), ms))]);

const server = spawn(bin, ['serve', '--addr', '127.0.0.1:0', '--backend', 'tract', '--bundle', bundle], { stdio: ['ignore', 'ignore', 'pipe'] });
let log = '';
const addr = await withTimeout(new Promise((res, rej) => {
  server.stderr.on('data', (d) => {
    log += d;
    // the address only once it is whole: stderr arrives in chunks, and a chunk may end inside it
    const m = /listening on http:\/\/(\S+)\s/.exec(log);
    if (m) res(m[1]);
  });
  server.on('exit', (c) => rej(new Error(`serve exited ${c}: ${log}`)));
}), 60000, 'server start');
console.log(`server at ${addr}`);

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  headless: true,
  args: [
    '--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-quic',
    '--no-first-run', '--disable-component-update', '--disable-sync',
    '--use-fake-ui-for-media-stream', '--use-fake-device-for-media-stream',
    `--use-file-for-fake-audio-capture=${resolve(wav)}`,
    '--enable-unsafe-swiftshader', '--autoplay-policy=no-user-gesture-required',
  ],
});
let ok = false;
try {
  const page = await browser.newPage({ viewport: { width: 1100, height: 700 } });
  const consoleLines = [];
  page.on('console', (m) => consoleLines.push(`${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => consoleLines.push(`pageerror: ${e.message}`));
  // the page must not fetch anything from outside the server
  const outside = [];
  page.on('request', (r) => { if (!r.url().startsWith(`http://${addr}`) && !r.url().startsWith(`ws://${addr}`) && !r.url().startsWith('data:') && !r.url().startsWith('blob:')) outside.push(r.url()); });
  await page.goto(`http://${addr}/`, { timeout: 30000 });
  // generous: a loaded 2-core machine is slow to start swiftshader's WebGL
  await page.waitForFunction(() => window.lgState && window.lgState.ready, null, { timeout: 120000 })
    .catch(async () => fail(`page not ready within 120 s: ${JSON.stringify(await page.evaluate(() => window.lgState || null))}\n${consoleLines.join('\n')}`));
  // a plain `serve` has no WebAssembly runtime: "this browser" is not offered as a link, and says how
  const wasmEntry = await page.evaluate(() => { const e = document.getElementById('engine-wasm'); return e && { tag: e.tagName, text: e.textContent }; });
  if (!wasmEntry || wasmEntry.tag === 'A' || !/--web-dir/.test(wasmEntry.text)) fail(`plain serve offers the wasm engine it does not serve: ${JSON.stringify(wasmEntry)}`);
  await page.click('#mic');
  await page.waitForFunction(() => window.lgState.frames >= 90 || window.lgState.error, null, { timeout: 90000 })
    .catch(async () => fail(`no frames within 90 s: ${JSON.stringify(await page.evaluate(() => window.lgState))}\n${consoleLines.join('\n')}`));
  const live = await page.evaluate(() => ({ ...window.lgState }));
  console.log('live state:', JSON.stringify(live));
  if (live.error) fail(`page error: ${live.error}`);
  if (live.status !== 'live') fail(`status is ${live.status}, expected live`);
  if (!(live.moved > 0.01)) fail(`the joints did not move (max displacement ${live.moved} m)`);
  if (live.latencyMs === null) fail('no token latency shown');
  const shot = join(outDir, 'live.png');
  const png = await page.screenshot({ path: shot });
  // not blank: decode the PNG in the page and count pixels that differ from the background
  const stats = await page.evaluate(async (b64) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const c = document.createElement('canvas'); c.width = img.width; c.height = img.height;
    const g = c.getContext('2d'); g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    // the 3D view starts at x = 300 (the side panel's width); background #14161a
    let fg = 0, n = 0; const colours = new Set();
    for (let y = 0; y < c.height; y += 2) for (let x = 300; x < c.width; x += 2) {
      const i = 4 * (y * c.width + x); n++;
      if (Math.abs(d[i] - 0x14) + Math.abs(d[i + 1] - 0x16) + Math.abs(d[i + 2] - 0x1a) > 30) fg++;
      colours.add((d[i] >> 4) << 8 | (d[i + 1] >> 4) << 4 | (d[i + 2] >> 4));
    }
    return { fg, n, colours: colours.size, w: img.width, h: img.height };
  }, png.toString('base64'));
  console.log(`screenshot ${shot}: ${stats.w}x${stats.h}, ${stats.fg}/${stats.n} foreground samples in the 3D view, ${stats.colours} colours`);
  if (stats.fg < 200 || stats.colours < 4) fail('the screenshot of the 3D view is blank');
  await page.click('#stop');
  await page.waitForFunction(() => /^done/.test(window.lgState.status), null, { timeout: 30000 })
    .catch(async () => fail(`no done after stop: ${JSON.stringify(await page.evaluate(() => window.lgState))}`));
  // the talking head (docs/face.md): from a bundle with the face channel the figure wears the face mesh
  // and its morph weights follow the frames' arkit while the audio plays; then the face close-up of the
  // frame with the widest mouth (a real streamed frame, shown again) as face-closeup.png
  const fs = await page.evaluate(() => ({ channel: window.lgState.faceChannel, mesh: window.lgState.faceMesh, frames: window.lgState.faceFrames, min: window.lgState.faceJawMin, max: window.lgState.faceJawMax }));
  console.log('face:', JSON.stringify(fs));
  if (fs.channel) {
    if (!fs.mesh) fail('the bundle has the face channel but the page has no face mesh (/face.bin)');
    if (!(fs.frames >= 90)) fail(`only ${fs.frames} frames drove the face mesh`);
    if (!(fs.max - fs.min > 0.1)) fail(`the face's jawOpen weight did not change while the audio played (${fs.min} .. ${fs.max})`);
    await page.click('#camera');
    const widest = await page.evaluate(() => window.lgShowWidestMouth());
    await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
    const names = ['sil', 'PP', 'FF', 'TH', 'DD', 'kk', 'CH', 'SS', 'nn', 'RR', 'aa', 'E', 'ih', 'oh', 'ou'];
    const top = names[widest.visemes.indexOf(Math.max(...widest.visemes))];
    const shown = await page.evaluate(() => window.lgState.faceJaw);
    console.log(`face close-up: frame ${widest.index}, jawOpen ${widest.jawOpen.toFixed(3)} (mesh weight ${shown.toFixed(3)}), top viseme ${top}`);
    if (Math.abs(shown - widest.jawOpen) > 1e-6) fail(`the face mesh's jawOpen ${shown} is not the frame's ${widest.jawOpen}`);
    if (!['aa', 'E', 'ih', 'oh', 'ou'].includes(top)) fail(`the widest mouth is not on a vowel viseme (${top})`);
    const closeShot = join(outDir, 'face-closeup.png');
    await page.screenshot({ path: closeShot });
    await page.click('#camera');
    console.log(`face close-up screenshot: ${closeShot}`);
  }
  // file mode: the WAV streamed through the server at its own pace
  const before = await page.evaluate(() => window.lgState.frames);
  await page.setInputFiles('#wav', resolve(wav));
  await page.waitForFunction(() => window.lgState.status === 'live' && window.lgState.frames >= 30, null, { timeout: 60000 })
    .catch(async () => fail(`file mode gave no frames: ${JSON.stringify(await page.evaluate(() => window.lgState))}`));
  console.log(`file mode: frames arrive (${before} before, now ${await page.evaluate(() => window.lgState.frames)})`);
  // the figure, face panel, glTF in GLTFLoader, a VRM avatar following a WAV (avatar-checks.mjs)
  await avatarChecks(page, { bin, bundle, wav, outDir, fail });
  if (outside.length) fail(`the page fetched outside the server: ${outside.join(', ')}`);
  writeFileSync(join(outDir, 'console.log'), consoleLines.join('\n'));
  ok = true;
} finally {
  await browser.close();
  server.kill('SIGTERM');
  const code = await withTimeout(new Promise((res) => server.on('exit', res)), 20000, 'server exit');
  if (ok && code !== 0) { console.error(`serve exited with ${code}\n${log}`); process.exitCode = 1; }
}
console.log(ok ? 'browser test passed' : 'browser test failed');

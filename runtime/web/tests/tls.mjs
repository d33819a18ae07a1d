// The served page over https in Debian's chromium, with a token (run by scripts/test.sh; docs/deploy.md):
// a certificate made here (openssl, for localhost), `livegesture serve --tls-cert --tls-key
// --auth-token-file --allowed-origin`, chromium told to accept that one certificate (its public key's
// SHA-256, --ignore-certificate-errors-spki-list: any other certificate still fails). Checks:
//   - the page opened without a token, or with a wrong one in its token field, gets no session (401
//     before the upgrade, counted as `unauthorized` in /metrics) and says so; with the right one typed
//     in, a session;
//   - the page opened with ?token= is a secure context, its session goes over wss:// with the token and
//     receives frames from the fake microphone, the figure moves, and the session ends with `done`;
//   - a page of another origin, with the right token, is refused (403, `forbidden_origin`);
//   - the server exits 0 on SIGTERM.
//
//   node runtime/web/tests/tls.mjs <livegesture binary> <bundle> <fake-mic.wav> <out-dir>
import { execFileSync, spawn } from 'node:child_process';
import { createHash, X509Certificate } from 'node:crypto';
import { createServer } from 'node:http';
import { get } from 'node:https';
import { mkdirSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { launchChromium } from './harness.mjs';

const [bin, bundle, wav, outDir] = process.argv.slice(2);
if (!outDir) { console.error('usage: tls.mjs BIN BUNDLE WAV OUT_DIR'); process.exit(2); }
mkdirSync(outDir, { recursive: true });

const t0 = Date.now();
const fail = (msg) => { console.error(`tls browser test FAILED: ${msg}`); process.exitCode = 1; throw new Error(msg); };
// (the timer does not keep node alive once everything else is done)
const withTimeout = (p, ms, what) => Promise.race([p, new Promise((_, rej) => setTimeout(() => rej(new Error(`timeout: ${what}`)), ms).unref())]);

// the test certificate and the token
const dir = mkdtempSync(join(tmpdir(), 'livegesture-tls-'));
const cert = join(dir, 'cert.pem'), key = join(dir, 'key.pem'), tokenFile = join(dir, 'token');
execFileSync('openssl', ['req', '-x509', '-newkey', 'ec', '-pkeyopt', 'ec_paramgen_curve:prime256v1', '-nodes',
  '-days', '2', '-subj', '/CN=localhost', '-addext', 'subjectAltName=DNS:localhost,IP:127.0.0.1',
  '-keyout', key, '-out', cert], { stdio: ['ignore', 'ignore', 'pipe'] });
const certPem = readFileSync(cert);
const spki = createHash('sha256')
  .update(new X509Certificate(certPem).publicKey.export({ type: 'spki', format: 'der' })).digest('base64');
const TOKEN = `page-token-${process.pid}-0123456789`;
writeFileSync(tokenFile, `${TOKEN}\n`);

const server = spawn(bin, ['serve', '--addr', '127.0.0.1:0', '--backend', 'tract', '--bundle', bundle,
  '--tls-cert', cert, '--tls-key', key, '--auth-token-file', tokenFile,
  '--allowed-origin', 'https://app.example.org'], { stdio: ['ignore', 'ignore', 'pipe'] });
let log = '';
const addr = await withTimeout(new Promise((res, rej) => {
  server.stderr.on('data', (d) => {
    log += d;
    const m = /listening on https:\/\/(\S+)\s/.exec(log);
    if (m) res(m[1]);
  });
  server.on('exit', (c) => rej(new Error(`serve exited ${c}: ${log}`)));
}), 60000, 'server start');
const port = Number(addr.split(':').pop());
const origin = `https://localhost:${port}`;
console.log(`server at ${origin} (certificate made here, public key sha256 ${spki})`);

/** /metrics over https, the test certificate as the only trusted one. */
const metrics = () => new Promise((res, rej) => {
  get({ host: '127.0.0.1', port, path: '/metrics', servername: 'localhost', ca: certPem }, (r) => {
    let body = '';
    r.on('data', (d) => { body += d; });
    r.on('end', () => res(body));
  }).on('error', rej);
});
const refusals = async (reason) => {
  const m = new RegExp(`^livegesture_refusals_total\\{reason="${reason}"\\} (\\d+)$`, 'm').exec(await metrics());
  return m ? Number(m[1]) : 0;
};

// a page of another origin (plain http on another port), to open a session from there
const foreign = createServer((_, r) => { r.writeHead(200, { 'content-type': 'text/html' }); r.end('<!doctype html><title>other</title>'); });
await new Promise((r) => foreign.listen(0, '127.0.0.1', r));

const browser = await launchChromium(wav, [`--ignore-certificate-errors-spki-list=${spki}`]);
const lines = [];
/** Opens the served page with `query`, waits until it is ready; records its WebSocket URLs. */
async function open(query) {
  const page = await browser.newPage({ viewport: { width: 1100, height: 700 } });
  page.on('console', (m) => lines.push(`${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => lines.push(`pageerror: ${e.message}`));
  const sockets = [];
  page.on('websocket', (w) => sockets.push(w.url()));
  await page.goto(`${origin}/${query}`, { timeout: 60000 });
  await page.waitForFunction(() => window.lgState && window.lgState.ready, null, { timeout: 120000 })
    .catch(async () => fail(`page ${query} not ready within 120 s: ${JSON.stringify(await page.evaluate(() => window.lgState || null))}\n${lines.join('\n')}`));
  return { page, sockets };
}
const stateOf = (page) => page.evaluate(() => {
  const { status, frames, moved, error, latencyMs } = window.lgState;
  return { status, frames, moved, error, latencyMs, secure: window.isSecureContext, shown: document.getElementById('status').textContent };
});

/** Clicks the microphone button and waits for frames or a refusal; the page's state then. */
async function session(page, what, frames) {
  await page.evaluate(() => { window.lgState.error = null; });
  await page.click('#mic');
  await page.waitForFunction((n) => window.lgState.frames >= n || window.lgState.error, frames, { timeout: 90000 })
    .catch(async () => fail(`${what}: neither ${frames} frames nor a refusal within 90 s: ${JSON.stringify(await stateOf(page))}\n${lines.join('\n')}`));
  const s = await stateOf(page);
  console.log(`${what} (${((Date.now() - t0) / 1000).toFixed(1)} s):`, JSON.stringify({ status: s.shown, frames: s.frames, error: s.error, secure: s.secure }));
  return s;
}
const stop = async (page) => {
  await page.click('#stop');
  await page.waitForFunction(() => /^done/.test(window.lgState.status), null, { timeout: 30000 })
    .catch(async () => fail(`no done after stop: ${JSON.stringify(await stateOf(page))}`));
};
const refused = (s, what) => {
  if (s.frames !== 0 || s.error !== 'session refused' || !/^no session/.test(s.shown))
    fail(`${what}: expected a refused session, got ${JSON.stringify(s)}`);
};
const wssWithToken = (url) => url.startsWith(`wss://localhost:${port}/v1/stream?`) && new URL(url).searchParams.get('token') === TOKEN;

let ok = false;
try {
  // the page without a token: no session, said on the page, counted as unauthorized
  const a = await open('');
  refused(await session(a.page, 'without a token', 1), 'without a token');
  if ((await refusals('unauthorized')) !== 1) fail('the session without a token was not counted as unauthorized');
  // a wrong token typed into the field: refused too
  await a.page.fill('#token', 'not-the-token-0123456789');
  refused(await session(a.page, 'a wrong token', 1), 'a wrong token');
  if ((await refusals('unauthorized')) !== 2) fail('the session with a wrong token was not counted as unauthorized');
  // the right token typed into the field: a session
  await a.page.fill('#token', TOKEN);
  const typed = await session(a.page, 'the token typed in', 8);
  if (typed.error || typed.status !== 'live') fail(`the token typed in: no live session: ${JSON.stringify(typed)}`);
  if (!wssWithToken(a.sockets.at(-1) || '')) fail(`the session's WebSocket URL is ${a.sockets.at(-1)}, expected wss:// with the token`);
  await stop(a.page);
  await a.page.close();

  // the page opened with ?token=: a live session over wss, the figure moving
  const { page, sockets } = await open(`?token=${encodeURIComponent(TOKEN)}`);
  const live = await session(page, 'with ?token=', 30);
  if (live.error) fail(`page error with the token: ${live.error} (${live.shown})`);
  if (!live.secure) fail('the https page is not a secure context');
  if (live.status !== 'live') fail(`status is ${live.status}, expected live`);
  if (!(live.moved > 0.01)) fail(`the joints did not move (max displacement ${live.moved} m)`);
  if (!wssWithToken(sockets[0] || '')) fail(`the session's WebSocket URL is ${sockets[0]}, expected wss:// with the token`);
  await page.screenshot({ path: join(outDir, 'live-https.png') });
  await stop(page);
  await page.close();
  if ((await refusals('unauthorized')) !== 2) fail('a session with the token was counted as unauthorized');

  // another origin, with the token: 403 (its page may not open sessions)
  const other = await browser.newPage();
  await other.goto(`http://127.0.0.1:${foreign.address().port}/`);
  const opened = await other.evaluate((u) => new Promise((res) => {
    const w = new WebSocket(u);
    w.onopen = () => { w.close(); res(true); };
    w.onclose = () => res(false);
  }), `wss://localhost:${port}/v1/stream?token=${encodeURIComponent(TOKEN)}`);
  if (opened) fail('a page of another origin opened a session');
  const f = await refusals('forbidden_origin');
  if (f !== 1) fail(`livegesture_refusals_total{reason="forbidden_origin"} is ${f}, expected 1`);
  console.log(`another origin: refused (403) (${((Date.now() - t0) / 1000).toFixed(1)} s)`);
  writeFileSync(join(outDir, 'console.log'), lines.join('\n'));
  ok = true;
} finally {
  await browser.close();
  foreign.close();
  server.kill('SIGTERM');
  const code = await withTimeout(new Promise((res) => server.on('exit', res)), 20000, 'server exit');
  rmSync(dir, { recursive: true, force: true });
  if (ok && code !== 0) { console.error(`serve exited with ${code}\n${log}`); process.exitCode = 1; }
}
console.log(ok ? `tls browser test passed (${((Date.now() - t0) / 1000).toFixed(1)} s)` : 'tls browser test failed');

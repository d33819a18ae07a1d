// The page's second browser engine, onnxruntime-web (`?engine=ort-web`, docs/wasm.md), in Debian's
// chromium beside tract in WebAssembly (`?engine=wasm`): parity and speed, side by side.
//
//   node runtime/web/tests/ortweb.mjs --site target/web-static --out target/browser-ortweb \
//     --parity bundle/ --parity bundles/diffsheg/ --broken bundles/broken/:expert_hands \
//     [--bench models/default/reference/clip.wav --rounds 3 --threads 1,2 --forms canonical]
//     [--native target/release/livegesture --native-bundle models/default]
//     [--engine ort-web|wasm] [--json FILE --target NAME --bundle-name DIR]   (scripts/targets_providers.sh)
//
// Checks, each failing the run with a message:
//  1. parity of each --parity bundle on ort-web (window.livegestureTest.parity(): every graph vs the
//     torch reference vectors at ONNX Runtime's CPU bound, 1e-5 scaled; the whole seeded reference
//     rollout with identical tokens and frames within 1e-4): no FAIL line, some PASS lines;
//  2. each --broken bundle (one weight perturbed, sha256 fixed up) fails on ort-web, naming the graph;
//  3. with --parity bundle/ (the page's default bundle, which carries every form): the page (not `complete`)
//     downloads only the graphs of the form ort-web runs (the manifest's form for ort, docs/wasm.md) and makes
//     a session for each of them alone;
// and with --bench WAV, per-token time of the two engines interleaved in one run (the method of
// wasm-bench.mjs: a whole WAV and its first second through one stream, per token = the difference
// over the difference in tokens): tract-wasm (one thread: wasm32 has none), ort-web with each count of
// --threads (the page is served cross-origin isolated so that onnxruntime-web can start threads).
// With --native BIN, native tract joins every round, measured the same way (`BIN generate --backend
// tract` on --native-bundle, default the page's bundle folder, one thread), so one run gives native
// tract, tract-wasm and ort-web side by side (scripts/bench_browser.sh). --forms F1,F2 adds each engine on
// each named LiveGesture form (`?form=`, e.g. canonical: both engines on the same graphs) beside its own form.
import { spawnSync } from 'node:child_process';
import { mkdirSync, readFileSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { launchChromium, openPage as openPageAt, serveStatic, wavLength } from './harness.mjs';

const args = { parity: [], broken: [] };
const argv = process.argv.slice(2);
for (let i = 0; i < argv.length; i += 2) {
  const k = argv[i].replace(/^--/, ''), v = argv[i + 1];
  if (Array.isArray(args[k])) args[k].push(v); else args[k] = v;
}
for (const k of ['site', 'out']) if (!args[k]) { console.error(`ortweb.mjs: --${k} is required`); process.exit(2); }
if (!args.parity.length && !args.broken.length && !args.bench) { console.error('ortweb.mjs: nothing to do (--parity, --broken or --bench)'); process.exit(2); }
mkdirSync(args.out, { recursive: true });
const report = [];
const note = (s) => { console.log(s); report.push(s); };
let failures = 0;
const fail = (msg) => { failures++; console.error(`ort-web browser test FAILED: ${msg}`); report.push(`FAILED: ${msg}`); };

const { origin, close } = await serveStatic(args.site, { isolate: true });
const browser = await launchChromium(args.bench || join(args.site, 'bundle/reference/clip.wav'));
const openPage = (query) => openPageAt(browser, origin, query);
const engine = args.engine || 'ort-web';
if (!['ort-web', 'wasm'].includes(engine)) { console.error(`ortweb.mjs: --engine ${engine}: expected ort-web or wasm`); process.exit(2); }
const label = engine === 'ort-web' ? 'ort-web' : 'wasm tract';
const results = [];

try {
  // 1. parity of every bundle on ort-web
  for (const b of args.parity) {
    const { page, lines } = await openPage(`?engine=${engine}&bundle=${encodeURIComponent(b)}`);
    const t0 = Date.now();
    const r = await page.evaluate(() => window.livegestureTest.parity()).catch((e) => ({ error: String(e) }));
    const secs = ((Date.now() - t0) / 1000).toFixed(1);
    writeFileSync(join(args.out, `parity-${b.replace(/\W+/g, '_')}.txt`), (r.lines || [r.error]).join('\n') + '\n');
    results.push({ bundle: b, seconds: Number(secs), ...r });
    if (r.error) fail(`parity of ${b} on ${label}: ${r.error}\n${lines.join('\n')}`);
    else {
      note(`parity of ${b} on ${label} in chromium (${secs} s): ${r.passed} passed, ${r.failed} failed`);
      const worst = r.lines.filter((l) => l.includes(' output ') && l.includes('worst of'));
      for (const l of r.lines) if (l.startsWith('FAIL') || /rollout/.test(l)) note(`  ${l}`);
      for (const l of worst) report.push(`  ${l}`);
      if (r.failed !== 0 || r.passed < 3) fail(`parity of ${b} on ${label}: ${r.failed} failed, ${r.passed} passed`);
      if (!r.lines.some((l) => l.includes(`${label} vs`))) fail(`parity of ${b}: no line compares ${label} (did the page run another engine?)`);
    }
    await page.close();
  }

  // 2. a perturbed weight must fail on ort-web, naming the graph
  for (const spec of args.broken) {
    const [b, graph] = spec.split(':');
    const { page } = await openPage(`?engine=${engine}&bundle=${encodeURIComponent(b)}`);
    const r = await page.evaluate(() => window.livegestureTest.parity()).catch((e) => ({ error: String(e) }));
    const failedLines = (r.lines || []).filter((l) => l.startsWith('FAIL'));
    if (r.error) fail(`broken bundle ${b}: parity did not run on ${label}: ${r.error}`);
    else if (r.failed === 0) fail(`broken bundle ${b}: ${label} parity passed (${r.passed} lines) on a perturbed weight of ${graph}`);
    else if (!failedLines.some((l) => l.includes(`graph ${graph} `))) fail(`broken bundle ${b}: no FAIL line names graph ${graph}:\n${failedLines.join('\n')}`);
    else note(`perturbed ${graph} (${b}) on ${label}: parity fails as it must, ${r.failed} FAIL lines, e.g. ${failedLines.find((l) => l.includes(`graph ${graph} `))}`);
    await page.close();
  }

  // 3. the page downloads the graphs of ort's form only, and makes a session for each of them alone
  if (engine === 'ort-web' && args.parity.includes('bundle/')) {
    const manifest = JSON.parse(readFileSync(join(args.site, 'bundle', 'manifest.json'), 'utf8'));
    const form = (manifest.backend_forms || {}).ort;
    const files = new Set((manifest.graphs || []).map((g) => g.file));
    const allGraphs = Object.entries(manifest.files || {}).filter(([f]) => files.has(f)).reduce((n, [, e]) => n + (e.bytes || 0), 0);
    const { page, lines } = await openPage('?engine=ort-web');
    await page.waitForFunction(() => window.lgState.status === 'idle' || window.lgState.error, null, { timeout: 300000 });
    const err = await page.evaluate(() => window.lgState.error);
    if (err) fail(`ort-web page: ${err}\n${lines.join('\n')}`);
    else {
      const info = await page.evaluate(() => window.livegestureTest.info());
      note(`ort-web page: downloaded ${(info.bytes / 1e6).toFixed(1)} MB in ${info.files} files (form ${info.form}, ${info.sessions} sessions); the bundle's graphs are ${(allGraphs / 1e6).toFixed(1)} MB in ${files.size} files; ort's form is ${form}`);
      if (!form) fail('bundle/manifest.json names no form for ort (backend_forms.ort)');
      if (!(info.bytes < allGraphs / 2)) fail(`the ort-web page downloaded ${info.bytes} bytes of the ${allGraphs} of every graph: expected only those of ${form}`);
      if (!(info.sessions >= 2 && info.sessions === info.files - 1)) fail(`the ort-web page made ${info.sessions} sessions for ${info.files - 1} graph files`);
    }
    await page.close();
  }

  // 4. speed, interleaved
  if (args.bench) {
    const rounds = Number(args.rounds || 3);
    const threads = String(args.threads || '1').split(',').map(Number);
    const wav = readFileSync(args.bench);
    const info = wavLength(wav);
    if (info.channels !== 1 || info.bits !== 16) throw new Error(`${args.bench}: expected 16-bit mono PCM`);
    const dataAt = wav.indexOf('data') + 8;
    const shortSamples = info.rate;
    const short = Buffer.concat([wav.subarray(0, dataAt), wav.subarray(dataAt, dataAt + 2 * shortSamples)]);
    short.writeUInt32LE(2 * shortSamples, dataAt - 4);
    short.writeUInt32LE(short.length - 8, 4);
    const tokens = (samples) => Math.ceil(Math.ceil((samples * 30) / info.rate) / 4);
    const dTok = tokens(info.samples) - tokens(shortSamples);
    const engines = [{ name: 'tract-wasm, 1 thread', query: '?engine=wasm' },
      ...threads.map((t) => ({ name: `ort-web, ${t} thread${t > 1 ? 's' : ''}`, query: `?engine=ort-web&threads=${t}` }))];
    // each engine again on each named form (?form=): the same graphs on both
    for (const f of String(args.forms || '').split(',').filter(Boolean)) {
      engines.push({ name: `tract-wasm, 1 thread, form ${f}`, query: `?engine=wasm&form=${f}` },
        { name: `ort-web, 1 thread, form ${f}`, query: `?engine=ort-web&threads=1&form=${f}` });
    }
    if (args.native) {
      // native tract through the CLI: the same WAV files, the same seed, one thread
      const bundleDir = args['native-bundle'] || join(args.site, 'bundle');
      const wavPath = join(args.out, 'bench-whole.wav'), shortPath = join(args.out, 'bench-first-second.wav');
      writeFileSync(wavPath, wav); writeFileSync(shortPath, short);
      const run = (path) => {
        const t0 = process.hrtime.bigint();
        const r = spawnSync(args.native, ['generate', path, '-o', join(args.out, 'native.npz'), '--backend', 'tract', '--bundle', bundleDir, '--seed', '7'], { encoding: 'utf8' });
        if (r.status !== 0) throw new Error(`native tract: ${args.native} generate ${path} failed (exit ${r.status}): ${r.stderr}`);
        return Number(process.hrtime.bigint() - t0) / 1e6;
      };
      engines.push({ name: 'native tract, 1 thread', native: { whole: () => run(wavPath), short: () => run(shortPath) } });
    }
    for (const e of engines) {
      if (e.native) { e.perToken = []; e.graphPerToken = []; continue; }
      e.page = (await openPage(e.query)).page;
      await e.page.waitForFunction(() => window.lgState.status === 'idle' || window.lgState.error, null, { timeout: 300000 });
      const err = await e.page.evaluate(() => window.lgState.error);
      if (err) throw new Error(`${e.name}: ${err}`);
      e.info = await e.page.evaluate(() => window.livegestureTest.info());
      e.perToken = []; e.graphPerToken = [];
    }
    const gen = (page, buf) => page.evaluate(async (b64) => {
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      const r = await window.livegestureTest.generate(bytes.buffer, { seed: 7 });
      return { ms: r.ms, graphMs: r.graphMs, frames: r.frames };
    }, buf.toString('base64'));
    for (let r = 0; r < rounds; r++) {
      const parts = [];
      for (const e of engines) {
        const w = e.native ? { ms: e.native.whole() } : await gen(e.page, wav);
        const s = e.native ? { ms: e.native.short() } : await gen(e.page, short);
        e.perToken.push((w.ms - s.ms) / dTok);
        if (w.graphMs !== undefined) e.graphPerToken.push((w.graphMs - s.graphMs) / dTok);
        parts.push(`${e.name} ${w.ms.toFixed(0)} / ${s.ms.toFixed(0)} ms`);
      }
      note(`round ${r + 1} (whole clip / first second): ${parts.join('; ')}`);
    }
    const med = (a) => [...a].sort((x, y) => x - y)[Math.floor(a.length / 2)];
    const base = med(engines[0].perToken);
    for (const e of engines) {
      const m = med(e.perToken);
      const g = e.graphPerToken.length ? `, of which onnxruntime-web session.run ${med(e.graphPerToken).toFixed(2)} ms` : '';
      note(`per token (${dTok} tokens, median of ${rounds} rounds): ${e.name} ${m.toFixed(2)} ms${g}; vs tract-wasm x${(m / base).toFixed(2)}; real-time factor ${(m / (4000 / 30)).toFixed(3)}`);
    }
    const nat = engines.find((e) => e.native);
    if (nat) note(`tract-wasm / native tract: x${(base / med(nat.perToken)).toFixed(2)} (medians); per round: ${engines[0].perToken.map((b, i) => (b / nat.perToken[i]).toFixed(2)).join(', ')}`);
    for (const e of engines.filter((x) => x.name.startsWith('ort-web'))) note(`${e.name} / tract-wasm per round: ${e.perToken.map((m, i) => (m / engines[0].perToken[i]).toFixed(2)).join(', ')}`);
    note(`ort-web: onnxruntime-web ${engines[1] ? engines[1].info.ortVersion : '?'}, page cross-origin isolated`);
  }
} catch (e) {
  fail(String(e && e.stack ? e.stack : e));
} finally {
  await browser.close();
  close();
}
writeFileSync(join(args.out, 'report.txt'), report.join('\n') + '\n');
if (args.json) {
  // the target file of scripts/targets_providers.sh (one bundle)
  const r = results[0] || {};
  writeFileSync(args.json, JSON.stringify({
    target: args.target || `browser-${engine}`, bundle: args['bundle-name'] || r.bundle, engine: label, browser: 'chromium',
    passed: failures === 0 && results.length > 0, comparisons_passed: r.passed ?? 0, comparisons_failed: r.failed ?? 0,
    seconds: r.seconds, error: r.error, lines: r.lines || [], failures: report.filter((l) => l.startsWith('FAILED')),
  }, null, 1) + '\n');
}
if (failures) { console.error(`${failures} failure(s); report in ${args.out}/report.txt`); process.exit(1); }
console.log(`ort-web browser tests passed; report in ${args.out}/report.txt`);

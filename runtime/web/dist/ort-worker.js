// Web Worker of the page's second browser engine, `?engine=ort-web` (docs/wasm.md, "ONNX Runtime Web"):
// the LiveGesture runtime in WebAssembly (wasm/, the same module as worker.js: bundle checks, streaming
// logic, log-mel frontend, sampler, frame assembly, parity) with its step graphs run by onnxruntime-web
// (ort/, its WebAssembly CPU backend) instead of tract. Same requests and replies as worker.js, plus
// `threads` in `load` (ONNX Runtime Web's intra-op threads; more than 1 needs a cross-origin isolated
// page) and `graphMs` (time spent in onnxruntime-web) in every frames reply.
//
// The runtime calls its graphs synchronously and onnxruntime-web answers with a Promise: the two are
// joined with WebAssembly JSPI (bindings/wasm/src/ortweb.rs): the import lgOrtRun is wrapped in
// WebAssembly.Suspending and the exports that reach it are called through WebAssembly.promising. One
// request runs at a time (a suspended call must not be entered again).
import * as ort from './ort/ort.wasm.min.mjs';
import {
  initSync, BundleFiles, filesToLoad, lastPanic, simd, ortweb_load, ortweb_stage_pcm, ortweb_stage_wav, ortweb_take,
  ortweb_reset, ortweb_close,
} from './wasm/livegesture_wasm.js';

let raw = null; // the module's exports (numbers-only calls go straight to them)
let P = null; // the exports that may suspend, through WebAssembly.promising
const sessions = new Map(); // graph name -> ort.InferenceSession
let graphMs = 0;
let info = null;

function init() {
  if (typeof WebAssembly.Suspending !== 'function' || typeof WebAssembly.promising !== 'function') {
    throw new Error('the ort-web engine needs WebAssembly JSPI (WebAssembly.Suspending, Chromium 137 or newer); use ?engine=wasm');
  }
  return (async () => {
    const module = await WebAssembly.compileStreaming(fetch(new URL('./wasm/livegesture_wasm_bg.wasm', import.meta.url)));
    // wrap the graph import in WebAssembly.Suspending as the glue instantiates the module
    const Real = WebAssembly.Instance;
    let wrapped = 0;
    WebAssembly.Instance = function (m, imports) {
      for (const ns of Object.values(imports)) {
        for (const k of Object.keys(ns)) if (k.startsWith('__wbg_lgOrtRun_')) { ns[k] = new WebAssembly.Suspending(ns[k]); wrapped++; }
      }
      return new Real(m, imports);
    };
    try { raw = initSync({ module }); } finally { WebAssembly.Instance = Real; }
    if (wrapped !== 1) throw new Error(`ort-web: expected one lgOrtRun import in the wasm module, found ${wrapped}`);
    P = {};
    for (const k of ['ortweb_stream', 'ortweb_push', 'ortweb_finish', 'ortweb_generate', 'ortweb_parity']) {
      if (typeof raw[k] !== 'function') throw new Error(`ort-web: the wasm module has no export ${k} (rebuild it: scripts/build_wasm.sh)`);
      P[k] = WebAssembly.promising(raw[k]);
    }
  })();
}

// the graphs, for the module: [name, dtype, dims, data] in -> [[dims, data], ...] out, or an error string
globalThis.lgOrtRun = async (graph, inputs) => {
  try {
    const s = sessions.get(graph);
    if (!s) return `no ONNX Runtime Web session for graph '${graph}'`;
    const feeds = {};
    for (const [name, dtype, dims, data] of inputs) feeds[name] = new ort.Tensor(dtype, data, dims);
    const t0 = performance.now();
    const out = await s.run(feeds);
    graphMs += performance.now() - t0;
    return s.outputNames.map((n) => [Array.from(out[n].dims), out[n].data]);
  } catch (e) {
    return `onnxruntime-web: ${e && e.message ? e.message : e}`;
  }
};

async function fetchBytes(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  return new Uint8Array(await r.arrayBuffer());
}

async function load({ bundleUrl, files, complete, threads = 1, form }) {
  const t0 = performance.now();
  if (!Number.isInteger(threads) || threads < 1) throw new Error(`threads is ${threads}; expected an integer >= 1`);
  if (threads > 1 && !self.crossOriginIsolated) throw new Error(`threads ${threads}: onnxruntime-web needs a cross-origin isolated page (COOP/COEP headers) for more than 1 thread`);
  if (info) throw new Error('ort-web: a model is already loaded in this worker (start another)');
  ort.env.wasm.wasmPaths = new URL('./ort/', import.meta.url).href;
  ort.env.wasm.numThreads = threads;
  ort.env.wasm.proxy = false;
  const base = new URL(bundleUrl.endsWith('/') ? bundleUrl : `${bundleUrl}/`, self.location.href);
  const given = files || {};
  const manifestBytes = given['manifest.json'] ? new Uint8Array(given['manifest.json']) : await fetchBytes(new URL('manifest.json', base));
  const manifest = JSON.parse(new TextDecoder().decode(manifestBytes));
  // complete: every listed file (parity checks every graph against its reference vectors); else only
  // the graphs of the form onnxruntime-web runs (ort's, or `form`), its decoders and the face graph
  const want = complete ? Object.keys(manifest.files || {}) : filesToLoad(manifestBytes, 'ort-web', form);
  const got = {};
  const queue = [...want];
  await Promise.all(Array.from({ length: 4 }, async () => {
    while (queue.length) {
      const rel = queue.shift();
      got[rel] = given[rel] ? new Uint8Array(given[rel]) : await fetchBytes(new URL(rel, base));
    }
  }));
  const bf = new BundleFiles();
  bf.add('manifest.json', manifestBytes);
  let bytes = manifestBytes.length;
  for (const rel of want) { bf.add(rel, got[rel]); bytes += got[rel].length; }
  // the runtime checks every file's sha256 and the graphs' names before any session is made
  const m = ortweb_load(base.href.replace(/\/$/, ''), bf, !!complete, form);
  for (const [name, file] of m.graphs) {
    sessions.set(name, await ort.InferenceSession.create(got[file], {
      executionProviders: ['wasm'], graphOptimizationLevel: 'all', intraOpNumThreads: threads,
    }));
  }
  info = { family: m.family, fps: m.fps, precision: m.precision, simd: simd(), bytes, files: want.length + 1,
    form: form || 'auto', sessions: sessions.size,
    loadMs: performance.now() - t0, engine: 'ort-web', threads, ortVersion: ort.env.versions.web };
  return info;
}

function framesOut(f, ms, gms) {
  const out = {
    count: f.count, index: new Float64Array(f.index), poses: new Float32Array(f.poses),
    trans: new Float32Array(f.trans), expressions: new Float32Array(f.expressions),
    // the face channel (docs/face.md): undefined from a bundle without one
    arkit: f.arkit && new Float32Array(f.arkit), visemes: f.visemes && new Float32Array(f.visemes),
    footContact: new Float32Array(f.footContact), ms, graphMs: gms,
  };
  f.free();
  return out;
}
const transfers = (r) => (r && r.poses ? [r.index.buffer, r.poses.buffer, r.trans.buffer, r.expressions.buffer, r.footContact.buffer, ...(r.arkit ? [r.arkit.buffer, r.visemes.buffer] : [])] : []);

/** Runs a suspending export and takes its result (its error thrown). */
async function suspend(name, ...args) {
  if (!info) throw new Error('no model loaded');
  const g0 = graphMs, t0 = performance.now();
  await P[name](...args);
  const ms = performance.now() - t0;
  return { value: ortweb_take(), ms, graphMs: graphMs - g0 };
}

const ops = {
  load,
  async stream({ seed = 0, guidance }) {
    const r = await suspend('ortweb_stream', seed, guidance ?? NaN);
    return { stream: r.value };
  },
  async push({ stream, pcm, sampleRate }) {
    ortweb_stage_pcm(pcm);
    const r = await suspend('ortweb_push', stream, sampleRate);
    return framesOut(r.value, r.ms, r.graphMs);
  },
  async finish({ stream }) {
    const r = await suspend('ortweb_finish', stream);
    return framesOut(r.value, r.ms, r.graphMs);
  },
  reset({ stream }) { ortweb_reset(stream); return {}; },
  close({ stream }) { ortweb_close(stream); return {}; },
  async generate({ wav, seed = 0, guidance }) {
    ortweb_stage_wav(new Uint8Array(wav));
    const r = await suspend('ortweb_generate', seed, guidance ?? NaN);
    return framesOut(r.value, r.ms, r.graphMs);
  },
  async parity() {
    const r = await suspend('ortweb_parity');
    return JSON.parse(r.value);
  },
  memory() { return { bytes: raw ? raw.memory.buffer.byteLength : 0 }; },
};

let ready = null;
let queue = Promise.resolve();
async function handle(data) {
  const { id, op } = data;
  try {
    if (!ready) ready = init();
    await ready;
    if (!ops[op]) throw new Error(`unknown op '${op}'`);
    const r = await ops[op](data);
    self.postMessage({ id, ok: true, result: r }, transfers(r));
  } catch (err) {
    let message = err && err.message ? err.message : String(err);
    let panic = null;
    try { panic = raw ? lastPanic() : null; } catch (_) { /* the instance is gone */ }
    if (panic) message = `the WebAssembly runtime panicked (reload the page): ${panic}`;
    self.postMessage({ id, ok: false, error: message });
  }
}
// one request at a time: a call suspended in a graph must not be entered again
self.onmessage = (e) => { queue = queue.then(() => handle(e.data)); };

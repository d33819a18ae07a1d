// Web Worker: the LiveGesture runtime compiled to WebAssembly (bindings/wasm, docs/wasm.md), so the
// page never blocks. Requests are {id, op, ...}; every reply carries the request's id and either the
// result or {error}. The wasm module (wasm-bindgen, --target web) sits beside this file in wasm/.
//
//   load     {bundleUrl, files?, complete?}  -> {family, fps, precision, bytes, files, loadMs}
//            (complete: every file the manifest lists; else only the graphs tract runs)
//   stream   {seed, guidance?}               -> {stream}                 (a new stream's id)
//   push     {stream, pcm, sampleRate}       -> frames                   (Float32Array in, transferred)
//   finish   {stream}                        -> frames
//   reset    {stream}                        -> {}
//   close    {stream}                        -> {}
//   generate {wav, seed, guidance?}          -> frames of a whole WAV file
//   parity   {}                              -> {passed, failed, lines}
// frames = {count, index: Float64Array, poses, trans, expressions, footContact: Float32Array, ms}
import init, { BundleFiles, Model, filesToLoad, lastPanic, simd } from './wasm/livegesture_wasm.js';

let ready = null;
let model = null;
const streams = new Map();
let nextStream = 1;

function framesOut(f, ms) {
  const out = {
    count: f.count, index: new Float64Array(f.index), poses: new Float32Array(f.poses),
    trans: new Float32Array(f.trans), expressions: new Float32Array(f.expressions),
    // the face channel (docs/face.md): undefined from a bundle without one
    arkit: f.arkit && new Float32Array(f.arkit), visemes: f.visemes && new Float32Array(f.visemes),
    footContact: new Float32Array(f.footContact), ms,
  };
  f.free();
  return out;
}
const transfers = (r) => (r && r.poses ? [r.index.buffer, r.poses.buffer, r.trans.buffer, r.expressions.buffer, r.footContact.buffer, ...(r.arkit ? [r.arkit.buffer, r.visemes.buffer] : [])] : []);

async function fetchBytes(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  return new Uint8Array(await r.arrayBuffer());
}

async function load({ bundleUrl, files, complete, form }) {
  const t0 = performance.now();
  const base = new URL(bundleUrl.endsWith('/') ? bundleUrl : `${bundleUrl}/`, self.location.href);
  const given = files || {};
  const manifestBytes = given['manifest.json'] ? new Uint8Array(given['manifest.json']) : await fetchBytes(new URL('manifest.json', base));
  const manifest = JSON.parse(new TextDecoder().decode(manifestBytes));
  // complete: every listed file (parity needs the reference vectors); else only the graphs tract
  // runs (its form or `form`, decoders and face graph: about a third of a bundle with every form)
  const want = complete ? Object.keys(manifest.files || {}) : filesToLoad(manifestBytes, 'wasm', form);
  const bf = new BundleFiles();
  bf.add('manifest.json', manifestBytes);
  let bytes = manifestBytes.length;
  // a few downloads at a time
  const queue = [...want];
  const got = {};
  await Promise.all(Array.from({ length: 4 }, async () => {
    while (queue.length) {
      const rel = queue.shift();
      got[rel] = given[rel] ? new Uint8Array(given[rel]) : await fetchBytes(new URL(rel, base));
    }
  }));
  for (const rel of want) { bf.add(rel, got[rel]); bytes += got[rel].length; }
  for (const s of streams.values()) s.free();
  streams.clear();
  if (model) model.free();
  model = Model.load(base.href.replace(/\/$/, ''), bf, !!complete, form);
  return { family: model.family, fps: model.fps, precision: model.precision, simd: simd(), bytes, files: want.length + 1, form: form || 'auto', loadMs: performance.now() - t0 };
}

function stream(id) {
  const s = streams.get(id);
  if (!s) throw new Error(`no stream ${id}`);
  return s;
}

const ops = {
  load,
  stream({ seed = 0, guidance }) {
    if (!model) throw new Error('no model loaded');
    const id = nextStream++;
    streams.set(id, model.stream(seed, guidance ?? undefined));
    return { stream: id };
  },
  push({ stream: id, pcm, sampleRate }) {
    const t0 = performance.now();
    const f = stream(id).push(pcm, sampleRate);
    return framesOut(f, performance.now() - t0);
  },
  finish({ stream: id }) {
    const t0 = performance.now();
    return framesOut(stream(id).finish(), performance.now() - t0);
  },
  reset({ stream: id }) { stream(id).reset(); return {}; },
  close({ stream: id }) { const s = streams.get(id); if (s) { s.free(); streams.delete(id); } return {}; },
  generate({ wav, seed = 0, guidance }) {
    if (!model) throw new Error('no model loaded');
    const t0 = performance.now();
    const f = model.generate(new Uint8Array(wav), seed, guidance ?? undefined);
    return framesOut(f, performance.now() - t0);
  },
  parity() {
    if (!model) throw new Error('no model loaded');
    return JSON.parse(model.parity());
  },
  memory() {
    return { bytes: ready && wasmMemory ? wasmMemory.buffer.byteLength : 0 };
  },
};

let wasmMemory = null;
self.onmessage = async (e) => {
  const { id, op } = e.data;
  try {
    if (!ready) ready = init({ module_or_path: new URL('./wasm/livegesture_wasm_bg.wasm', import.meta.url) }).then((w) => { wasmMemory = w.memory; });
    await ready;
    if (!ops[op]) throw new Error(`unknown op '${op}'`);
    const r = await ops[op](e.data);
    self.postMessage({ id, ok: true, result: r }, transfers(r));
  } catch (err) {
    let message = err && err.message ? err.message : String(err);
    let panic = null;
    try { panic = lastPanic(); } catch (_) { /* the instance is gone */ }
    if (panic) message = `the WebAssembly runtime panicked (reload the page): ${panic}`;
    self.postMessage({ id, ok: false, error: message });
  }
};

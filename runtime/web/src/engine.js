// The LiveGesture runtime in this browser (docs/wasm.md): the Rust runtime compiled to WebAssembly,
// running in a Web Worker (public/worker.js), with the streaming API of the Rust library:
//
//   const model = await loadModel({ bundleUrl: 'bundle/' });      // sha256 of every file checked
//   const s = await model.stream({ seed: 7, guidance: 1.25 });
//   const frames = await s.push(float32Pcm, 48000);              // any rate, any chunk size
//   const rest = await s.finish();                               // ceil(duration x 30) frames in all
//   await s.reset();
//   const whole = await model.generate(wavArrayBuffer, { seed: 7 });
//
// Frames are {count, index, poses (n x 165), trans (n x 3), expressions (n x 100), footContact (n x 4)},
// row-major typed arrays.

/** Which engine the page runs: `?engine=wasm` this browser (tract in WebAssembly), `?engine=ort-web`
 * this browser with the graphs on onnxruntime-web (ort-worker.js), `?engine=server` the server;
 * without the parameter, the page's `<meta name="livegesture-engine">` (the static build sets `wasm`:
 * no server there), else the server. */
export function engineFromUrl(href = location.href) {
  const meta = document.querySelector('meta[name="livegesture-engine"]');
  const e = new URL(href).searchParams.get('engine') || (meta && meta.content) || 'server';
  return e === 'wasm' || e === 'ort-web' ? e : 'server';
}

/** Where the page finds the bundle in wasm mode: `?bundle=URL`, else `bundle/` beside the page. */
export function bundleFromUrl(href = location.href) {
  return new URL(href).searchParams.get('bundle') || 'bundle/';
}

class Rpc {
  constructor(workerUrl) {
    this.worker = new Worker(workerUrl, { type: 'module' });
    this.pending = new Map();
    this.next = 1;
    this.worker.onmessage = (e) => {
      const p = this.pending.get(e.data.id);
      if (!p) return;
      this.pending.delete(e.data.id);
      if (e.data.ok) p.resolve(e.data.result); else p.reject(new Error(e.data.error));
    };
    this.worker.onerror = (e) => {
      const err = new Error(`worker: ${e.message || 'failed to start'}`);
      for (const p of this.pending.values()) p.reject(err);
      this.pending.clear();
    };
  }

  call(op, args = {}, transfer = []) {
    const id = this.next++;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject });
      this.worker.postMessage({ id, op, ...args }, transfer);
    });
  }
}

/** One stream of a model: its own state in the worker. */
export class WasmStream {
  constructor(rpc, id) { this.rpc = rpc; this.id = id; }
  /** Mono PCM at `sampleRate` Hz: a Float32Array in [-1, 1] or an Int16Array (scaled by 1/32768);
   * resolves to the frames it completes. */
  push(pcm, sampleRate) {
    const copy = pcm instanceof Int16Array ? Float32Array.from(pcm, (v) => v / 32768) : new Float32Array(pcm);
    return this.rpc.call('push', { stream: this.id, pcm: copy, sampleRate }, [copy.buffer]);
  }
  /** Ends the stream; the remaining frames (the stream then covers its whole input). */
  finish() { return this.rpc.call('finish', { stream: this.id }); }
  /** Back to a cold start with the same seed and guidance. */
  reset() { return this.rpc.call('reset', { stream: this.id }); }
  /** Frees the stream in the worker. */
  close() { return this.rpc.call('close', { stream: this.id }); }
}

/** A bundle loaded in a worker. */
export class WasmModel {
  constructor(rpc, info) { this.rpc = rpc; Object.assign(this, info); }
  /** A new stream with `seed` and `guidance` (undefined: the bundle's default). */
  async stream({ seed = 0, guidance } = {}) {
    const r = await this.rpc.call('stream', { seed, guidance });
    return new WasmStream(this.rpc, r.stream);
  }
  /** A whole WAV file (ArrayBuffer) through a fresh stream. */
  generate(wav, { seed = 0, guidance } = {}) {
    const copy = wav.slice(0);
    return this.rpc.call('generate', { wav: copy, seed, guidance }, [copy]);
  }
  /** Every graph against its reference vectors and the reference rollout: {passed, failed, lines}
   * (the model must have been loaded with `complete: true`). */
  parity() { return this.rpc.call('parity'); }
  /** The worker's WebAssembly memory in bytes. */
  async memoryBytes() { return (await this.rpc.call('memory')).bytes; }
  terminate() { this.rpc.worker.terminate(); }
}

/**
 * Starts a worker and loads a bundle into it: `bundleUrl` (a folder with manifest.json), or `files`
 * ({path: ArrayBuffer}, which may hold all of it). `complete`: also load the files that only parity
 * needs (reference vectors); graphs and manifest are always verified against their sha256.
 * `engine`: 'wasm' (tract, worker.js) or 'ort-web' (onnxruntime-web, ort-worker.js, with `threads`).
 * `form`: the LiveGesture graph form (undefined: the engine's own; only its graphs are downloaded).
 */
export async function loadModel({ bundleUrl = 'bundle/', files, complete = false, workerUrl, engine = 'wasm', threads = 1, form } = {}) {
  const worker = engine === 'ort-web' ? 'ort-worker.js' : 'worker.js';
  const rpc = new Rpc(workerUrl || new URL(worker, document.baseURI));
  const info = await rpc.call('load', { bundleUrl: new URL(bundleUrl, document.baseURI).href, files, complete, form, ...(engine === 'ort-web' ? { threads } : {}) });
  return new WasmModel(rpc, info);
}

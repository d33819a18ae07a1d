// The page's "this browser" engine (`/?engine=wasm`, docs/wasm.md): microphone -> AudioWorklet ->
// worker (the runtime in WebAssembly) -> frames -> avatar, with no server doing inference; and the
// test hook `window.livegestureTest` (generate a whole WAV, run the parity checks).
import { bundleFromUrl, engineFromUrl, loadModel } from './engine.js';

const params = () => new URL(location.href).searchParams;

/** The in-browser engine's options: `?engine=ort-web` runs the graphs on onnxruntime-web with
 * `?threads=N` intra-op threads (default 1), else tract in WebAssembly; `?form=NAME` (canonical,
 * fused, attention, fused_ring, attention_ring; default the engine's own: tract's for wasm, ort's for
 * ort-web) picks the LiveGesture graph form (docs/bundle.md#forms-and-precision). */
function engineOptions() {
  const engine = engineFromUrl() === 'ort-web' ? 'ort-web' : 'wasm';
  const form = params().get('form') || undefined;
  return engine === 'ort-web' ? { engine, form, threads: Number(params().get('threads') || 1) } : { engine, form };
}

/** The engine's name on the page. */
export function engineLabel() {
  const o = engineOptions();
  const form = o.form ? `, form ${o.form}` : '';
  return o.engine === 'ort-web' ? `onnxruntime-web, ${o.threads} thread${o.threads > 1 ? 's' : ''}${form}` : `wasm tract${form}`;
}

let modelPromise = null;

/** Loads the bundle (graphs and manifest only) into a worker once, and warms it up. */
export function wasmModel(onStatus = () => {}) {
  if (!modelPromise) {
    modelPromise = (async () => {
      onStatus('loading model');
      const model = await loadModel({ bundleUrl: bundleFromUrl(), ...engineOptions() });
      // warm-up: the first runs build tract's plans and let the JS engine optimise the module
      onStatus('warming up');
      const t0 = performance.now();
      const s = await model.stream({ seed: 0 });
      await s.push(new Float32Array(16000 * 2), 16000);
      await s.close();
      model.warmupMs = performance.now() - t0;
      return model;
    })();
  }
  return modelPromise;
}

/**
 * A live session on the wasm engine with the callbacks of the server session:
 * onReady(label), onFrame(frame), onDone(count), onError(message).
 */
export class WasmSession {
  constructor(rate, { onReady, onFrame, onDone, onError }) {
    this.rate = rate;
    this.cb = { onReady, onFrame, onDone, onError };
    this.stream = null;
    this.waiting = []; // audio pushed before the stream exists
    this.results = Promise.resolve(); // frames are emitted in push order
    this.frames = 0;
    this.failed = false;
    this.open = (async () => {
      const model = await wasmModel();
      const seed = Number(params().get('seed') || 0);
      const g = params().get('guidance');
      this.stream = await model.stream({ seed, guidance: g === null ? undefined : Number(g) });
      onReady(`${model.family}, ${model.precision} (${engineLabel()}, this browser)`);
      for (const pcm of this.waiting) this.track(this.stream.push(pcm, this.rate));
      this.waiting = [];
    })().catch((e) => this.fail(e));
  }

  fail(e) {
    if (this.failed) return;
    this.failed = true;
    this.cb.onError(e && e.message ? e.message : String(e));
  }

  // the worker answers in order; pushes are posted at once (never waiting for the previous answer)
  track(p) {
    this.results = this.results.then(() => p).then((f) => this.emit(f)).catch((e) => this.fail(e));
  }

  emit(f) {
    for (let i = 0; i < f.count; i++) {
      this.frames++;
      this.cb.onFrame({
        index: f.index[i], time_s: f.index[i] / 30,
        poses: f.poses.subarray(165 * i, 165 * i + 165),
        trans: f.trans.subarray(3 * i, 3 * i + 3),
        expressions: f.expressions.subarray(100 * i, 100 * i + 100),
        arkit: f.arkit ? f.arkit.subarray(52 * i, 52 * i + 52) : undefined,
        visemes: f.visemes ? f.visemes.subarray(15 * i, 15 * i + 15) : undefined,
      });
    }
  }

  /** Pushes mono samples (in order; frames come back through onFrame). */
  send(f32) {
    if (this.failed) return;
    const pcm = new Float32Array(f32);
    if (this.stream) this.track(this.stream.push(pcm, this.rate));
    else this.waiting.push(pcm);
  }

  /** Finishes the stream: the last frames, then onDone. */
  async end() {
    await this.open;
    if (!this.stream || this.failed) return;
    this.track(this.stream.finish());
    await this.results;
    if (this.failed) return;
    await this.stream.close();
    this.cb.onDone(this.frames);
  }
}

/** `window.livegestureTest` (docs/wasm.md): for tests and for users' own checks. */
export function installTestHook() {
  window.livegestureTest = {
    async generate(wavBytes, { seed = 0, guidance } = {}) {
      const model = await wasmModel();
      const f = await model.generate(wavBytes, { seed, guidance });
      return { frames: f.count, poses: f.poses, expressions: f.expressions, trans: f.trans, arkit: f.arkit, visemes: f.visemes, ms: f.ms, graphMs: f.graphMs };
    },
    async parity() {
      // a second worker with the whole bundle (reference vectors included)
      const model = await loadModel({ bundleUrl: bundleFromUrl(), complete: true, ...engineOptions() });
      try {
        return await model.parity();
      } finally {
        model.terminate();
      }
    },
    /** Memory of `streams` live streams: the worker's WebAssembly memory before and after opening
     * them and pushing one second of audio into each (the memory never shrinks; measure on a fresh page). */
    async memory({ streams = 8 } = {}) {
      const model = await wasmModel();
      const before = await model.memoryBytes();
      const open = [];
      const noise = new Float32Array(16000).map((_, i) => 0.1 * Math.sin(i * 0.05));
      for (let i = 0; i < streams; i++) { const s = await model.stream({ seed: i }); await s.push(noise, 16000); open.push(s); }
      const after = await model.memoryBytes();
      for (const s of open) await s.close();
      return { streams, before, after, perStream: (after - before) / streams };
    },
    async info() {
      const model = await wasmModel();
      return { family: model.family, precision: model.precision, simd: model.simd, bytes: model.bytes, files: model.files,
        loadMs: model.loadMs, warmupMs: model.warmupMs, memoryBytes: await model.memoryBytes(),
        engine: model.engine || 'wasm', threads: model.threads || 1, ortVersion: model.ortVersion, form: model.form,
        sessions: model.sessions };
    },
  };
}

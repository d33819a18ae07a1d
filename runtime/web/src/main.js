// LiveGesture browser page: microphone (getUserMedia + AudioWorklet) or a WAV file -> WebSocket
// (/v1/stream, docs/serve.md) -> live 3D figure; or a generated .npz / .bvh / .glb with its audio.
// The skeleton (names, parents, rest offsets) comes from the server's /skeleton.json, the Rust mirror
// of python/livegesture/skeleton.py. The figure (figure.js), a dropped VRM avatar (vrm.js, retarget.js,
// avatarui.js) and the face panel (facepanel.js) live in their own modules; docs/avatars.md.
import * as THREE from 'three';
import { createFK } from './fk.js';
import { createFigure } from './figure.js';
import { createFacePanel } from './facepanel.js';
import { setupAvatarControls } from './avatarui.js';
import { loadGltfMotion } from './gltfmotion.js';
import { engineFromUrl } from './engine.js';
import { WasmSession, engineLabel, installTestHook, wasmModel } from './wasm-page.js';
import { loadFaceMesh, applyArkit, FACE_OFFSET, JAW_OPEN } from './facemesh.js';

const $ = (id) => document.getElementById(id);
const N = 55;
// binary records (docs/output.md): 1104 bytes (version 1, body), 1372 (version 2, body and face)
const RECORD = 1104, RECORD_FACE = 1372;
// `?engine=wasm` (tract) or `?engine=ort-web` (onnxruntime-web): the runtime runs in this browser
// (wasm-page.js), else on the server (WebSocket)
const ENGINE = engineFromUrl();

// state the browser test reads (runtime/web/tests/browser.mjs)
const state = (window.lgState = {
  status: 'idle', frames: 0, lastIndex: -1, moved: 0, latencyMs: null, error: null, webgl: false,
  engine: ENGINE, firstLatencyMs: null,
});

let SK = null; // { names, parents, offsets }
let first = null; // joint positions of the first frame shown (to measure movement)

// ------------------------------------------------------------------------------------------ view

const canvas = $('c');
let renderer = null, scene, camera, ctx2d = null;
let fk = null, figure = null, face = null, avatar = null, P = null, lastShown = null;
let faceMesh = null; // the talking head (facemesh.js) on the figure's head joint
let closeUp = false; // the camera: whole figure, or the face close-up
let widestMouth = null; // the streamed frame with the widest-open jaw (a test hook shows it again)
const headPos = new THREE.Vector3(), camGoal = new THREE.Vector3();
let lastRender = performance.now();

function initView() {
  try {
    renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    state.webgl = true;
  } catch (e) {
    renderer = null;
    ctx2d = canvas.getContext('2d');
    console.warn('WebGL unavailable, drawing in 2D:', e.message);
  }
  scene = new THREE.Scene();
  scene.background = new THREE.Color(0x14161a);
  camera = new THREE.PerspectiveCamera(35, 1, 0.05, 50);
  camera.position.set(1.1, 1.25, 3.2);
  camera.lookAt(0, 0.9, 0);
  scene.add(new THREE.HemisphereLight(0xddeeff, 0x202020, 2.0));
  const dl = new THREE.DirectionalLight(0xffffff, 1.5);
  dl.position.set(2, 4, 3);
  scene.add(dl);
  const grid = new THREE.GridHelper(4, 16, 0x445066, 0x2a303a);
  scene.add(grid);
  const resize = () => {
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (renderer) renderer.setSize(w, h, false);
    else { canvas.width = w; canvas.height = h; }
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
  };
  window.addEventListener('resize', resize);
  resize();
}

function render() {
  const now = performance.now();
  const dt = Math.min(0.1, (now - lastRender) / 1000);
  lastRender = now;
  if (avatar) avatar.update(dt);
  aimCamera();
  if (renderer) {
    renderer.render(scene, camera);
  } else if (ctx2d && SK && P) {
    const w = canvas.width, h = canvas.height;
    ctx2d.fillStyle = '#14161a'; ctx2d.fillRect(0, 0, w, h);
    const pr = (v) => { const q = v.clone().project(camera); return [(q.x + 1) / 2 * w, (1 - q.y) / 2 * h]; };
    ctx2d.strokeStyle = '#9fc3ff'; ctx2d.lineWidth = 2;
    for (let j = 1; j < N; j++) {
      const [x0, y0] = pr(P[SK.parents[j]]), [x1, y1] = pr(P[j]);
      ctx2d.beginPath(); ctx2d.moveTo(x0, y0); ctx2d.lineTo(x1, y1); ctx2d.stroke();
    }
    ctx2d.fillStyle = '#f0a030';
    for (let j = 0; j < N; j++) { const [x, y] = pr(P[j]); ctx2d.fillRect(x - 3, y - 3, 6, 6); }
  }
  requestAnimationFrame(render);
}

// the face close-up follows the head (the avatar's when it is shown, else the figure's)
function aimCamera() {
  if (!closeUp) return;
  const head = avatar && avatar.vrm.scene.visible ? avatar.vrm.humanoid.getNormalizedBoneNode('head') : figure?.bones[15];
  if (!head) return;
  head.updateWorldMatrix(true, false);
  head.getWorldPosition(headPos);
  headPos.y += FACE_OFFSET[1];
  camGoal.set(headPos.x + 0.12, headPos.y + 0.03, headPos.z + 0.62);
  camera.position.copy(camGoal);
  camera.lookAt(headPos);
}

function setCloseUp(on) {
  closeUp = on;
  state.closeUp = on;
  $('camera').textContent = on ? 'Whole figure' : 'Face close-up';
  if (!on) { camera.position.set(1.1, 1.25, 3.2); camera.lookAt(0, 0.9, 0); }
}

// ------------------------------------------------------------------------------------------ frames

function showFrame(f) {
  const pos = fk.solve(f.poses, f.trans).P;
  P = pos;
  if (!first) first = pos.map((v) => v.clone());
  else {
    let m = 0;
    for (let j = 0; j < N; j++) m = Math.max(m, pos[j].distanceTo(first[j]));
    state.moved = Math.max(state.moved, m);
  }
  figure.setPose(f.poses, f.trans, pos);
  if (avatar) avatar.apply(f.poses, f.trans, f);
  if (faceMesh) {
    applyArkit(faceMesh, f.arkit);
    // what the browser test reads: the face mesh's jawOpen weight now, and its range so far
    const jaw = faceMesh.morphTargetInfluences[JAW_OPEN];
    state.faceJaw = jaw;
    if (f.arkit) {
      state.faceFrames = (state.faceFrames || 0) + 1;
      state.faceJawMin = Math.min(state.faceJawMin ?? jaw, jaw);
      if (!(jaw <= state.faceJawMax) && f !== widestMouth) {
        // the frame with the widest mouth so far, kept for the close-up screenshot (lgShowWidestMouth)
        const c = (a) => a && Float32Array.from(a);
        widestMouth = { index: f.index, time_s: f.time_s, poses: c(f.poses), trans: c(f.trans), expressions: c(f.expressions), arkit: c(f.arkit), visemes: c(f.visemes) };
      }
      state.faceJawMax = Math.max(state.faceJawMax ?? jaw, jaw);
    }
  }
  face.update(f);
  lastShown = f;
  state.lastFrame = {
    index: f.index, poses: Array.from(f.poses), trans: Array.from(f.trans),
    arkit: f.arkit && Array.from(f.arkit), visemes: f.visemes && Array.from(f.visemes),
  };
  $('mtime').textContent = `${f.time_s.toFixed(2)} s`;
}

function decodeRecord(buf) {
  const dv = new DataView(buf);
  const f32 = (off, n) => { const a = new Float32Array(n); for (let i = 0; i < n; i++) a[i] = dv.getFloat32(off + 4 * i, true); return a; };
  return {
    index: Number(dv.getBigUint64(0, true)),
    time_s: dv.getFloat64(8, true),
    poses: f32(16, 165), trans: f32(676, 3), expressions: f32(688, 100),
    // version 2: the face channel after the body
    arkit: buf.byteLength === RECORD_FACE ? f32(1104, 52) : undefined,
    visemes: buf.byteLength === RECORD_FACE ? f32(1312, 15) : undefined,
  };
}

function setStatus(s, kind = s) {
  state.status = s;
  $('status').textContent = s;
  $('status').dataset.state = kind;
}

// ------------------------------------------------------------------------------------------ live session

let ws = null, sentSamples = 0, sentLog = [], rate = 16000, latencies = [];
let stopSource = null;
let wasm = null; // the WasmSession in wasm mode

function onFrame(f) {
  state.frames++; state.lastIndex = f.index;
  $('frames').textContent = state.frames;
  if (f.index % 4 === 3) tokenLatency(f.index);
  showFrame(f);
}

function openSession(inputRate) {
  rate = inputRate;
  sentSamples = 0; sentLog = []; latencies = []; first = null;
  state.frames = 0; state.moved = 0; state.firstLatencyMs = null;
  if (ENGINE !== 'server') {
    setStatus('connecting');
    wasm = new WasmSession(rate, {
      onReady: (label) => { setStatus('live'); $('model').textContent = label; },
      onFrame,
      onDone: (n) => setStatus(`done: ${n} frames`, 'idle'),
      onError: (m) => { state.error = m; setStatus(`error: ${m}`, 'error'); stopInput(); },
    });
    return;
  }
  const proto = location.protocol === 'https:' ? 'wss' : 'ws';
  // a server with --auth-token-file wants the token; browsers cannot set Authorization on a
  // WebSocket, so it goes in the `token` query parameter (docs/deploy.md#who-may-connect)
  const token = $('token').value.trim();
  const auth = token ? `&token=${encodeURIComponent(token)}` : '';
  ws = new WebSocket(`${proto}://${location.host}/v1/stream?rate=${Math.round(rate)}&channels=1&format=f32le&output=binary${auth}`);
  ws.binaryType = 'arraybuffer';
  let opened = false;
  setStatus('connecting');
  ws.onopen = () => { opened = true; setStatus('connected'); };
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') {
      const m = JSON.parse(ev.data);
      if (m.type === 'ready') { setStatus('live'); state.faceChannel = !!m.face; $('model').textContent = `${m.model} (${m.backend})`; }
      else if (m.type === 'done') setStatus(`done: ${m.frames} frames`, 'idle');
      return;
    }
    if (ev.data.byteLength !== RECORD && ev.data.byteLength !== RECORD_FACE) return;
    onFrame(decodeRecord(ev.data));
  };
  ws.onclose = (ev) => {
    // refused before the upgrade (401 token, 403 origin, 429, 503): browsers only report 1006
    if (!opened) {
      state.error = 'session refused';
      setStatus(token ? 'no session: refused or unreachable (wrong token? at capacity?)'
        : 'no session: refused or unreachable (does the server need a token? add ?token=... to the address)', 'error');
    } else if (state.status === 'live' || state.status === 'connected' || state.status === 'connecting')
      setStatus(`closed ${ev.code}${ev.reason ? ': ' + ev.reason : ''}`, ev.code === 1000 ? 'idle' : 'error');
    stopInput();
  };
  ws.onerror = () => { if (opened) { state.error = 'websocket error'; setStatus('connection error', 'error'); } };
}

// latency: from sending the audio that completes token t to receiving its last frame
function tokenLatency(index) {
  const need = (index + 1) / 30; // seconds of audio the token needs
  while (sentLog.length && sentLog[0].upTo < need) sentLog.shift();
  if (!sentLog.length) return;
  latencies.push(performance.now() - sentLog[0].t);
  if (state.firstLatencyMs === null) state.firstLatencyMs = latencies[0];
  if (latencies.length > 40) latencies.shift();
  const s = [...latencies].sort((a, b) => a - b);
  state.latencyMs = s[Math.floor(s.length / 2)];
  $('latency').textContent = `${state.latencyMs.toFixed(0)} ms (median of ${s.length})`;
}

function sendSamples(f32) {
  if (wasm) wasm.send(f32);
  else if (!ws || ws.readyState !== WebSocket.OPEN) return;
  else ws.send(f32.buffer.slice(f32.byteOffset, f32.byteOffset + f32.byteLength));
  sentSamples += f32.length;
  sentLog.push({ t: performance.now(), upTo: sentSamples / rate });
}

function endSession() {
  if (wasm) { wasm.end(); wasm = null; }
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({ type: 'end' }));
  stopInput();
}

function stopInput() {
  if (stopSource) { const s = stopSource; stopSource = null; s(); }
  $('mic').disabled = false; $('stop').disabled = true;
}

let audioCtx = null;
async function context() {
  if (!audioCtx) {
    audioCtx = new AudioContext();
    await audioCtx.audioWorklet.addModule(new URL('worklet.js', document.baseURI));
  }
  if (audioCtx.state === 'suspended') await audioCtx.resume();
  return audioCtx;
}

async function startMic() {
  try {
    $('mic').disabled = true; $('stop').disabled = false;
    const ctx = await context();
    const media = await navigator.mediaDevices.getUserMedia({
      audio: { channelCount: 1, echoCancellation: false, noiseSuppression: false, autoGainControl: false },
    });
    const src = ctx.createMediaStreamSource(media);
    const node = new AudioWorkletNode(ctx, 'lg-capture');
    const mute = ctx.createGain(); mute.gain.value = 0;
    src.connect(node); node.connect(mute); mute.connect(ctx.destination);
    node.port.onmessage = (e) => sendSamples(e.data);
    stopSource = () => { node.port.onmessage = null; src.disconnect(); node.disconnect(); media.getTracks().forEach((t) => t.stop()); };
    openSession(ctx.sampleRate);
  } catch (e) {
    state.error = String(e); setStatus(`microphone: ${e.message || e}`, 'error'); stopInput();
  }
}

async function playWav(file) {
  try {
    const ctx = await context();
    const buf = await ctx.decodeAudioData(await file.arrayBuffer());
    const mono = new Float32Array(buf.length);
    for (let c = 0; c < buf.numberOfChannels; c++) {
      const d = buf.getChannelData(c);
      for (let i = 0; i < d.length; i++) mono[i] += d[i] / buf.numberOfChannels;
    }
    openSession(buf.sampleRate);
    await new Promise((res) => { const t = setInterval(() => { if (state.status === 'live') { clearInterval(t); res(); } }, 10); });
    const src = ctx.createBufferSource(); src.buffer = buf; src.connect(ctx.destination);
    const t0 = ctx.currentTime; src.start();
    let sent = 0;
    const timer = setInterval(() => {
      const upTo = Math.min(mono.length, Math.floor((ctx.currentTime - t0) * buf.sampleRate));
      if (upTo > sent) { sendSamples(mono.subarray(sent, upTo)); sent = upTo; }
      if (sent >= mono.length) { clearInterval(timer); endSession(); }
    }, 20);
    $('mic').disabled = true; $('stop').disabled = false;
    stopSource = () => { clearInterval(timer); try { src.stop(); } catch (_) { /* already stopped */ } };
  } catch (e) {
    state.error = String(e); setStatus(`file: ${e.message || e}`, 'error');
  }
}

// ------------------------------------------------------------------------------------------ file viewer

async function inflateRaw(bytes) {
  const s = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate-raw'));
  return new Uint8Array(await new Response(s).arrayBuffer());
}

async function readZip(buf) {
  const dv = new DataView(buf), out = {};
  let off = 0;
  while (off + 30 <= buf.byteLength && dv.getUint32(off, true) === 0x04034b50) {
    const method = dv.getUint16(off + 8, true);
    let csize = dv.getUint32(off + 18, true);
    const nlen = dv.getUint16(off + 26, true), xlen = dv.getUint16(off + 28, true);
    const name = new TextDecoder().decode(new Uint8Array(buf, off + 30, nlen));
    const start = off + 30 + nlen + xlen;
    if (csize === 0xffffffff) throw new Error('zip64 .npz files are not supported here');
    const data = new Uint8Array(buf, start, csize);
    out[name] = method === 0 ? data.slice() : method === 8 ? await inflateRaw(data) : null;
    if (out[name] === null) throw new Error(`${name}: unsupported zip compression ${method}`);
    off = start + csize;
  }
  return out;
}

function readNpy(bytes) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const major = bytes[6];
  const hlen = major === 1 ? dv.getUint16(8, true) : dv.getUint32(8, true);
  const hstart = major === 1 ? 10 : 12;
  const header = new TextDecoder().decode(bytes.subarray(hstart, hstart + hlen));
  const descr = /'descr':\s*'([^']+)'/.exec(header)[1];
  const shape = /'shape':\s*\(([^)]*)\)/.exec(header)[1].split(',').filter((s) => s.trim()).map(Number);
  const data = bytes.slice(hstart + hlen);
  const arr = descr === '<f4' ? new Float32Array(data.buffer) : descr === '<f8' ? new Float64Array(data.buffer) : null;
  if (!arr) throw new Error(`unsupported dtype ${descr}`);
  return { shape, data: arr };
}

async function loadNpz(file) {
  const z = await readZip(await file.arrayBuffer());
  const get = (k) => { if (!z[`${k}.npy`]) throw new Error(`${file.name}: no '${k}' array`); return readNpy(z[`${k}.npy`]); };
  const poses = get('poses'), trans = get('trans'), expr = get('expressions');
  // the face channel where the file has it (docs/face.md)
  const arkit = z['arkit.npy'] && z['visemes.npy'] ? get('arkit') : null, vis = arkit && get('visemes');
  const T = poses.shape[0];
  return Array.from({ length: T }, (_, t) => ({
    index: t, time_s: t / 30,
    poses: poses.data.subarray(165 * t, 165 * t + 165),
    trans: trans.data.subarray(3 * t, 3 * t + 3),
    expressions: expr.data.subarray(100 * t, 100 * t + 100),
    arkit: arkit ? arkit.data.subarray(52 * t, 52 * t + 52) : undefined,
    visemes: vis ? vis.data.subarray(15 * t, 15 * t + 15) : undefined,
  }));
}

// BVH written by `livegesture generate -o x.bvh` (or any BVH on the same joint names; centimetres)
async function loadBvh(file) {
  const text = await file.text();
  const [head, motion] = text.split(/^MOTION\s*$/m);
  const joints = [];
  const re = /(ROOT|JOINT)\s+(\S+)[\s\S]*?CHANNELS\s+(\d+)\s+([^\n]+)/g;
  let m;
  while ((m = re.exec(head))) joints.push({ name: m[2], channels: m[4].trim().split(/\s+/) });
  const lines = motion.trim().split('\n');
  const frameTime = parseFloat(lines[1].split(':')[1]);
  const idx = joints.map((j) => SK.names.indexOf(j.name));
  const frames = [];
  const q = new THREE.Quaternion(), e = new THREE.Euler();
  for (let t = 0; t + 2 < lines.length; t++) {
    const v = lines[t + 2].trim().split(/\s+/).map(Number);
    const poses = new Float32Array(165), trans = new Float32Array(3);
    let k = 0;
    joints.forEach((j, ji) => {
      const ang = {};
      for (const c of j.channels) {
        const x = v[k++];
        if (c.endsWith('position')) trans['XYZ'.indexOf(c[0])] = x / 100 - SK.offsets[0]['XYZ'.indexOf(c[0])];
        else ang[c[0]] = (x * Math.PI) / 180;
      }
      const order = j.channels.filter((c) => c.endsWith('rotation')).map((c) => c[0]).join('');
      e.set(ang.X || 0, ang.Y || 0, ang.Z || 0, order);
      q.setFromEuler(e);
      const s = Math.sqrt(Math.max(0, 1 - q.w * q.w));
      const a = 2 * Math.acos(Math.min(1, Math.max(-1, q.w)));
      const jj = idx[ji];
      if (jj >= 0 && s > 1e-9) { poses[3 * jj] = (q.x / s) * a; poses[3 * jj + 1] = (q.y / s) * a; poses[3 * jj + 2] = (q.z / s) * a; }
    });
    frames.push({ index: t, time_s: t * frameTime, poses, trans, expressions: new Float32Array(100) });
  }
  return frames;
}

let fileFrames = null;
async function loadMotion(file) {
  try {
    const ext = file.name.toLowerCase().split('.').pop();
    fileFrames = ext === 'bvh' ? await loadBvh(file)
      : ext === 'glb' || ext === 'gltf' ? await loadGltfMotion(await file.arrayBuffer(), SK, file.name)
        : await loadNpz(file);
    state.fileFrames = fileFrames.length;
    state.loadedFile = file.name;
    setStatus(`file: ${fileFrames.length} frames`, 'idle');
    first = null; state.moved = 0;
    showFrame(fileFrames[0]);
    $('playFile').disabled = false;
  } catch (e) {
    state.error = String(e); setStatus(`file: ${e.message || e}`, 'error');
  }
}

function playFile() {
  if (!fileFrames) return;
  const audioFile = $('motionAudio').files[0];
  let audio = null;
  if (audioFile) { audio = new Audio(URL.createObjectURL(audioFile)); audio.play(); }
  const t0 = performance.now();
  const tick = () => {
    const t = audio ? audio.currentTime : (performance.now() - t0) / 1000;
    const i = Math.min(fileFrames.length - 1, Math.floor(t * 30));
    showFrame(fileFrames[i]);
    state.frames = i + 1;
    $('frames').textContent = `${i + 1} / ${fileFrames.length}`;
    if (i < fileFrames.length - 1 && !(audio && audio.ended)) requestAnimationFrame(tick);
  };
  tick();
}

// ------------------------------------------------------------------------------------------ start

async function main() {
  initView();
  SK = await (await fetch(new URL('skeleton.json', document.baseURI))).json();
  fk = createFK(SK);
  // the talking head: the runtime's face mesh, worn on the figure's head joint
  faceMesh = await loadFaceMesh(new URL('face.bin', document.baseURI));
  figure = createFigure(scene, SK, { wearsFace: !!faceMesh });
  face = createFacePanel($('face'), state);
  if (faceMesh) {
    faceMesh.position.set(...FACE_OFFSET);
    figure.bones[15].add(faceMesh);
  }
  state.faceMesh = !!faceMesh;
  $('camera').onclick = () => setCloseUp(!closeUp);
  // for the browser test's close-up screenshot: show again the frame with the widest mouth so far;
  // returns its index, jawOpen and viseme weights
  window.lgShowWidestMouth = () => {
    if (!widestMouth) return null;
    showFrame(widestMouth);
    return { index: widestMouth.index, jawOpen: widestMouth.arkit[JAW_OPEN], visemes: Array.from(widestMouth.visemes) };
  };
  setupAvatarControls({
    scene, SK, figure, state, setStatus, showFrame,
    setAvatar: (a) => { avatar = a; },
    lastFrame: () => lastShown,
    onMotionFile: loadMotion,
    onWav: playWav,
  });
  window.lgFileFrame = (i) => (fileFrames && fileFrames[i] ? { poses: Array.from(fileFrames[i].poses), trans: Array.from(fileFrames[i].trans) } : null);
  showFrame({ index: 0, time_s: 0, poses: new Float32Array(165), trans: new Float32Array(3), expressions: new Float32Array(100) });
  first = null;
  render();
  // `?token=...` in the page's address fills the token field (docs/deploy.md#who-may-connect)
  $('token').value = new URL(location.href).searchParams.get('token') || '';
  $('mic').onclick = startMic;
  $('stop').onclick = endSession;
  $('wav').onchange = (e) => e.target.files[0] && playWav(e.target.files[0]);
  $('motion').onchange = (e) => e.target.files[0] && loadMotion(e.target.files[0]);
  $('playFile').onclick = playFile;
  // the browser engines need the WebAssembly runtime beside the page (the static build, or `serve
  // --web-dir`); a plain `livegesture serve` has none: say how to get it rather than offer a dead end
  const wasmServed = await fetch('wasm/livegesture_wasm.js', { method: 'HEAD', cache: 'no-store' })
    .then((r) => r.ok, () => false);
  if (!wasmServed) {
    const how = 'not served here: build it with scripts/build_web_static.sh and run livegesture serve --web-dir target/web-static (docs/wasm.md)';
    for (const [id, label] of [['engine-wasm', 'this browser'], ['engine-ort-web', 'this browser, onnxruntime-web']]) {
      $(id).replaceWith(Object.assign(document.createElement('span'), { id, title: how, textContent: `${label} (${how})` }));
    }
  }
  if (ENGINE !== 'server' && !wasmServed) {
    state.error = 'the WebAssembly engine is not served here';
    setStatus(`engine "${engineLabel()}": the WebAssembly runtime is not served here; run livegesture serve --web-dir target/web-static (docs/wasm.md)`, 'error');
  } else if (ENGINE !== 'server') {
    installTestHook();
    $('model').textContent = 'loading (this browser)';
    wasmModel((s) => setStatus(s, 'idle')).then(
      (m) => { $('model').textContent = `${m.family}, ${m.precision} (${engineLabel()}, this browser)`; setStatus('idle'); },
      (e) => { state.error = String(e); setStatus(`model: ${e.message || e}`, 'error'); });
  }
  state.ready = true;
}

main().catch((e) => { state.error = String(e); setStatus(`error: ${e.message || e}`, 'error'); });

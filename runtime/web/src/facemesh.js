// The talking head: ICT-FaceKit's face region (MIT licence; runtime/assets/face/, docs/face.md) as a
// three.js mesh with the 52 ARKit morph targets, driven per frame by the face channel's `arkit`
// weights. The asset is the one compiled into the runtime (`LGFACE01`, runtime/src/face/mesh.rs):
// the server serves it at /face.bin; the static WebAssembly site carries a copy (build_web_static.sh).
import * as THREE from 'three';

/** The ARKit name of weight 17 (the test's check of the mouth). */
export const JAW_OPEN = 17;
/** The face mesh's offset from the head joint, metres (as in the glTF output: FACE_OFFSET). */
export const FACE_OFFSET = [0.0, 0.07, 0.045];

function f16(h) {
  const s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 0x1f, m = h & 0x3ff;
  if (e === 0) return s * m * 2 ** -24;
  if (e === 31) return m ? NaN : s * Infinity;
  return s * (1 + m / 1024) * 2 ** (e - 15);
}

/** Parses an `LGFACE01` asset: { positions (n*3), triangles (t*3), targets: [[indices, deltas]] x 52 }. */
export function parseFaceMesh(buf) {
  const dv = new DataView(buf);
  const magic = new TextDecoder().decode(new Uint8Array(buf, 0, 8));
  if (magic !== 'LGFACE01') throw new Error(`face mesh: bad magic ${JSON.stringify(magic)}, expected LGFACE01`);
  const n = dv.getUint32(8, true), t = dv.getUint32(12, true), k = dv.getUint32(16, true);
  if (k !== 52) throw new Error(`face mesh: ${k} targets, expected 52`);
  let at = 20;
  const need = (bytes, what) => { if (at + bytes > buf.byteLength) throw new Error(`face mesh: truncated in ${what}`); };
  need(12 * n, 'positions');
  const positions = new Float32Array(3 * n);
  for (let i = 0; i < 3 * n; i++) positions[i] = dv.getFloat32(at + 4 * i, true);
  at += 12 * n;
  need(6 * t, 'triangles');
  const triangles = new Uint16Array(3 * t);
  for (let i = 0; i < 3 * t; i++) triangles[i] = dv.getUint16(at + 2 * i, true);
  at += 6 * t;
  const targets = [];
  for (let j = 0; j < k; j++) {
    need(4, `target ${j}`);
    const c = dv.getUint32(at, true); at += 4;
    need(8 * c, `target ${j}`);
    const idx = new Uint16Array(c), d = new Float32Array(3 * c);
    for (let i = 0; i < c; i++) idx[i] = dv.getUint16(at + 2 * i, true);
    at += 2 * c;
    for (let i = 0; i < 3 * c; i++) d[i] = f16(dv.getUint16(at + 2 * i, true));
    at += 6 * c;
    targets.push([idx, d]);
  }
  if (at !== buf.byteLength) throw new Error(`face mesh: ${buf.byteLength - at} trailing bytes`);
  return { positions, triangles, targets };
}

/** The face as a THREE.Mesh with 52 relative morph targets (dense; about 6 MB of GPU memory). */
export function createFaceMesh(parsed) {
  const { positions, triangles, targets } = parsed;
  const n = positions.length / 3;
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(positions, 3));
  g.setIndex(new THREE.BufferAttribute(triangles, 1));
  g.morphAttributes.position = targets.map(([idx, d]) => {
    const dense = new Float32Array(3 * n);
    for (let i = 0; i < idx.length; i++) {
      dense[3 * idx[i]] = d[3 * i]; dense[3 * idx[i] + 1] = d[3 * i + 1]; dense[3 * idx[i] + 2] = d[3 * i + 2];
    }
    return new THREE.BufferAttribute(dense, 3);
  });
  g.morphTargetsRelative = true;
  g.computeVertexNormals();
  const mesh = new THREE.Mesh(g, new THREE.MeshStandardMaterial({ color: 0xe0b48c, roughness: 0.6, side: THREE.DoubleSide }));
  mesh.name = 'face';
  mesh.frustumCulled = false;
  mesh.morphTargetInfluences = new Array(52).fill(0);
  // the face region has eye openings but no eyes: an eyeball behind each, at the centre of the
  // eyelid (the vertices its blink shape moves more than half its most: eyeBlinkLeft 0, eyeBlinkRight 7),
  // set back by about its radius
  for (const t of [0, 7]) {
    const [idx, d] = targets[t];
    const mag = Array.from(idx, (_, i) => Math.hypot(d[3 * i], d[3 * i + 1], d[3 * i + 2]));
    const top = Math.max(0, ...mag);
    if (!(top > 0)) continue;
    const c = new THREE.Vector3();
    let m = 0;
    for (let i = 0; i < idx.length; i++) {
      if (mag[i] <= 0.5 * top) continue;
      c.add(new THREE.Vector3(positions[3 * idx[i]], positions[3 * idx[i] + 1], positions[3 * idx[i] + 2]));
      m++;
    }
    c.divideScalar(m);
    const eye = new THREE.Mesh(new THREE.SphereGeometry(0.0125, 20, 14), new THREE.MeshStandardMaterial({ color: 0xf4f4f0, roughness: 0.3 }));
    const iris = new THREE.Mesh(new THREE.SphereGeometry(0.0055, 14, 10), new THREE.MeshStandardMaterial({ color: 0x3a2a1c, roughness: 0.3 }));
    iris.position.set(0, 0, 0.0112);
    iris.scale.set(1, 1, 0.4);
    eye.add(iris);
    eye.position.set(c.x, c.y, c.z - 0.011);
    eye.name = t === 0 ? 'eyeLeft' : 'eyeRight';
    mesh.add(eye);
  }
  return mesh;
}

/** Fetches the face mesh at `url`; null (and a console line) where there is none. */
export async function loadFaceMesh(url) {
  try {
    const r = await fetch(url);
    if (!r.ok) { console.warn(`no face mesh at ${url} (${r.status})`); return null; }
    return createFaceMesh(parseFaceMesh(await r.arrayBuffer()));
  } catch (e) {
    console.warn(`face mesh: ${e.message || e}`);
    return null;
  }
}

/** Sets the mesh's 52 morph weights from a frame's `arkit` (none: all 0). */
export function applyArkit(mesh, arkit) {
  const w = mesh.morphTargetInfluences;
  for (let i = 0; i < 52; i++) w[i] = arkit ? arkit[i] : 0;
}

// VRM expressions from the face channel (docs/face.md): the five vowels from the visemes (a viseme
// of a consonant lends part of its weight to the vowel whose mouth it resembles), blinks from ARKit's
// eyeBlinkLeft (0) / eyeBlinkRight (7).
const VISEME = { sil: 0, PP: 1, FF: 2, TH: 3, DD: 4, kk: 5, CH: 6, SS: 7, nn: 8, RR: 9, aa: 10, E: 11, ih: 12, oh: 13, ou: 14 };
export const VRM_FROM_VISEMES = {
  aa: { aa: 1, DD: 0.3, kk: 0.3, nn: 0.3 },
  ee: { E: 1, SS: 0.5, TH: 0.5 },
  ih: { ih: 1, FF: 0.3 },
  oh: { oh: 1, RR: 0.5 },
  ou: { ou: 1, CH: 0.5 },
};

/** { aa, ih, ou, ee, oh, blinkLeft, blinkRight } in [0, 1] from a frame's visemes and arkit. */
export function vrmExpressions(visemes, arkit) {
  const out = {};
  for (const [name, mix] of Object.entries(VRM_FROM_VISEMES)) {
    let v = 0;
    for (const [vis, w] of Object.entries(mix)) v += w * visemes[VISEME[vis]];
    out[name] = Math.min(1, Math.max(0, v));
  }
  out.blinkLeft = arkit[0];
  out.blinkRight = arkit[7];
  return out;
}

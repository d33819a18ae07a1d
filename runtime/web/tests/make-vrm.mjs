// A small VRM 1.0 humanoid built here, for the tests (no downloaded asset): a .glb whose JSON carries
// the VRMC_vrm extension (meta, humanoid, an `aa` expression bound to a morph target of a face mesh).
//
// - Its rest pose is a T-pose facing +Z, with proportions unlike the project's skeleton (longer arms,
//   straight spine, no upperChest bone: the retargeting must fold that joint), all fingers.
// - Every bone node has its own non-identity rest rotation (with translations that keep the T-pose),
//   as exported avatars often have, so only retargeting through the normalized bones poses it right.
//
//   import { makeTestVrm, TEST_VRM_REST } from './make-vrm.mjs'; writeFileSync('t.vrm', makeTestVrm());
import { Quaternion, Vector3 } from 'three';

const L = {
  hips: [0, 1.0, 0], spine: [0, 1.1, 0.01], chest: [0, 1.26, 0], neck: [0, 1.5, -0.01], head: [0, 1.6, 0],
  leftShoulder: [0.03, 1.45, 0], leftUpperArm: [0.17, 1.45, 0], leftLowerArm: [0.46, 1.45, 0], leftHand: [0.73, 1.45, 0],
  leftIndexProximal: [0.81, 1.45, 0.025], leftIndexIntermediate: [0.85, 1.45, 0.025], leftIndexDistal: [0.88, 1.45, 0.025],
  leftMiddleProximal: [0.815, 1.45, 0.0], leftMiddleIntermediate: [0.857, 1.45, 0.0], leftMiddleDistal: [0.89, 1.45, 0.0],
  leftRingProximal: [0.81, 1.45, -0.02], leftRingIntermediate: [0.848, 1.45, -0.02], leftRingDistal: [0.878, 1.45, -0.02],
  leftLittleProximal: [0.8, 1.45, -0.04], leftLittleIntermediate: [0.83, 1.45, -0.04], leftLittleDistal: [0.855, 1.45, -0.04],
  leftThumbMetacarpal: [0.75, 1.44, 0.03], leftThumbProximal: [0.78, 1.44, 0.055], leftThumbDistal: [0.8, 1.44, 0.07],
  leftUpperLeg: [0.09, 0.95, 0], leftLowerLeg: [0.09, 0.52, 0.01], leftFoot: [0.09, 0.08, -0.02], leftToes: [0.09, 0.02, 0.11],
};
/** World rest positions of the test VRM's bones (metres, +Z forward, its left at +X). */
export const TEST_VRM_REST = { ...L };
for (const [k, v] of Object.entries(L)) if (k.startsWith('left')) TEST_VRM_REST[`right${k.slice(4)}`] = [-v[0], v[1], v[2]];

const PARENT = { hips: null, spine: 'hips', chest: 'spine', neck: 'chest', head: 'neck' };
for (const S of ['left', 'right']) {
  Object.assign(PARENT, {
    [`${S}UpperLeg`]: 'hips', [`${S}LowerLeg`]: `${S}UpperLeg`, [`${S}Foot`]: `${S}LowerLeg`, [`${S}Toes`]: `${S}Foot`,
    [`${S}Shoulder`]: 'chest', [`${S}UpperArm`]: `${S}Shoulder`, [`${S}LowerArm`]: `${S}UpperArm`, [`${S}Hand`]: `${S}LowerArm`,
  });
  for (const f of ['Thumb', 'Index', 'Middle', 'Ring', 'Little']) {
    const [a, b, c] = f === 'Thumb' ? ['Metacarpal', 'Proximal', 'Distal'] : ['Proximal', 'Intermediate', 'Distal'];
    Object.assign(PARENT, { [`${S}${f}${a}`]: `${S}Hand`, [`${S}${f}${b}`]: `${S}${f}${a}`, [`${S}${f}${c}`]: `${S}${f}${b}` });
  }
}

/** The .vrm (GLB) bytes of the test humanoid. */
export function makeTestVrm() {
  const names = Object.keys(PARENT);
  const idx = Object.fromEntries(names.map((n, i) => [n, i]));
  // deterministic "random" rest rotations
  let seed = 7;
  const rnd = () => { seed = (seed * 1103515245 + 12345) % 2147483648; return seed / 2147483648 * 2 - 1; };
  const worldRot = {};
  const nodes = names.map((name) => {
    const q = new Quaternion().setFromAxisAngle(new Vector3(rnd(), rnd(), rnd()).normalize(), rnd() * 1.2);
    const p = PARENT[name];
    const wp = new Vector3(...TEST_VRM_REST[name]);
    let t, local;
    if (!p) { worldRot[name] = q.clone(); t = wp; local = q; } else {
      worldRot[name] = worldRot[p].clone().multiply(q);
      const d = wp.clone().sub(new Vector3(...TEST_VRM_REST[p]));
      t = d.applyQuaternion(worldRot[p].clone().invert());
      local = q;
    }
    return { name, translation: t.toArray(), rotation: local.toArray() };
  });
  for (const name of names) {
    const kids = names.filter((n) => PARENT[n] === name).map((n) => idx[n]);
    if (kids.length) nodes[idx[name]].children = kids;
  }
  // a face mesh on the head: a quad whose one morph target opens a "mouth" (moves two vertices down)
  const faceNode = nodes.length;
  const headRot = worldRot.head.clone().invert();
  const local = (v) => new Vector3(...v).applyQuaternion(headRot).toArray();
  const pos = [[-0.03, 0.0, 0.09], [0.03, 0.0, 0.09], [0.03, -0.02, 0.09], [-0.03, -0.02, 0.09]].map(local).flat();
  const morph = [[0, 0, 0], [0, 0, 0], [0, -0.03, 0], [0, -0.03, 0]].map(local).flat();
  nodes.push({ name: 'face', mesh: 0 });
  nodes[idx.head].children = [...(nodes[idx.head].children || []), faceNode];
  const f32 = (a) => Buffer.from(new Float32Array(a).buffer);
  const indices = Buffer.from(new Uint16Array([0, 1, 2, 0, 2, 3]).buffer);
  const bin = Buffer.concat([f32(pos), f32(morph), indices]);
  const minmax = (a) => [0, 1, 2].map((k) => a.filter((_, i) => i % 3 === k)).map((c) => [Math.min(...c), Math.max(...c)]);
  const mm = minmax(pos), mmm = minmax(morph);
  const humanBones = Object.fromEntries(names.map((n) => [n, { node: idx[n] }]));
  const doc = {
    asset: { version: '2.0', generator: 'livegesture tests (make-vrm.mjs)' },
    scene: 0,
    scenes: [{ nodes: [idx.hips] }],
    nodes,
    meshes: [{ name: 'face', primitives: [{ attributes: { POSITION: 0 }, indices: 2, targets: [{ POSITION: 1 }] }], weights: [0] }],
    accessors: [
      { bufferView: 0, componentType: 5126, count: 4, type: 'VEC3', min: mm.map((x) => x[0]), max: mm.map((x) => x[1]) },
      { bufferView: 1, componentType: 5126, count: 4, type: 'VEC3', min: mmm.map((x) => x[0]), max: mmm.map((x) => x[1]) },
      { bufferView: 2, componentType: 5123, count: 6, type: 'SCALAR' },
    ],
    bufferViews: [
      { buffer: 0, byteOffset: 0, byteLength: 48 },
      { buffer: 0, byteOffset: 48, byteLength: 48 },
      { buffer: 0, byteOffset: 96, byteLength: 12 },
    ],
    buffers: [{ byteLength: bin.length }],
    extensionsUsed: ['VRMC_vrm'],
    extensions: {
      VRMC_vrm: {
        specVersion: '1.0',
        meta: {
          name: 'livegesture test humanoid', version: '1', authors: ['livegesture tests'],
          licenseUrl: 'https://vrm.dev/licenses/1.0/', avatarPermission: 'everyone', commercialUsage: 'corporation',
          allowExcessivelyViolentUsage: false, allowExcessivelySexualUsage: false, allowPoliticalOrReligiousUsage: false,
          allowAntisocialOrHateUsage: false, creditNotation: 'unnecessary', allowRedistribution: true, modification: 'allowModificationRedistribution',
        },
        humanoid: { humanBones },
        // the five vowels and the blinks the face channel drives (all on the one morph target)
        expressions: { preset: Object.fromEntries(['aa', 'ih', 'ou', 'ee', 'oh', 'blinkLeft', 'blinkRight'].map((n) =>
          [n, { morphTargetBinds: [{ node: faceNode, index: 0, weight: 1.0 }], isBinary: false }])) },
      },
    },
  };
  let js = Buffer.from(JSON.stringify(doc));
  js = Buffer.concat([js, Buffer.alloc((4 - (js.length % 4)) % 4, 0x20)]);
  const binPadded = Buffer.concat([bin, Buffer.alloc((4 - (bin.length % 4)) % 4, 0)]);
  const header = Buffer.alloc(12);
  header.write('glTF', 0); header.writeUInt32LE(2, 4); header.writeUInt32LE(12 + 8 + js.length + 8 + binPadded.length, 8);
  const jh = Buffer.alloc(8); jh.writeUInt32LE(js.length, 0); jh.write('JSON', 4);
  const bh = Buffer.alloc(8); bh.writeUInt32LE(binPadded.length, 0); bh.write('BIN\0', 4);
  return Buffer.concat([header, jh, js, bh, binPadded]);
}

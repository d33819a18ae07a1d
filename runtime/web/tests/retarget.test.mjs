// Tests of the SMPL-X -> VRM retargeting (runtime/web/src/retarget.js), run with `node --test` in
// runtime/web (scripts/test.sh). The skeleton is tests/skeleton.json, the page's /skeleton.json (the
// browser test checks that the two agree); the avatar is the test humanoid of make-vrm.mjs.
//
// The property checked: posed by the retargeting, every avatar bone that has a mapped child points where
// the SMPL-X bone points (world directions, forward kinematics on both sides), whatever the avatar's
// rest proportions, missing bones, or VRM version.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { Quaternion, Vector3 } from 'three';
import { createRetarget, MAIN_CHILD, SMPLX_TO_VRM, VRM_PARENT, jawToAa, aaToQuat, JAW_OPEN_FULL } from '../src/retarget.js';
import { TEST_VRM_REST } from './make-vrm.mjs';
import { diff } from './compare.mjs';

const SK = JSON.parse(readFileSync(new URL('./skeleton.json', import.meta.url)));
const N = SK.names.length;
const J = Object.fromEntries(SK.names.map((n, j) => [n, j]));

function smplFK(poses, trans) {
  const G = [], P = [];
  for (let j = 0; j < N; j++) {
    const q = aaToQuat(poses[3 * j], poses[3 * j + 1], poses[3 * j + 2]);
    const o = new Vector3(...SK.offsets[j]);
    const p = SK.parents[j];
    if (p < 0) { G.push(q); P.push(o.add(new Vector3(...trans))); } else {
      G.push(G[p].clone().multiply(q));
      P.push(P[p].clone().add(o.applyQuaternion(G[p])));
    }
  }
  return { G, P };
}

// the avatar's normalized rig posed with local rotations `rot` and hips offset: world positions
function vrmFK(rest, rot, hipsOffset) {
  const has = (b) => b in rest;
  const W = {}, P = {};
  for (const b of Object.keys(VRM_PARENT)) {
    if (!has(b)) continue;
    let p = VRM_PARENT[b];
    while (p && !has(p)) p = VRM_PARENT[p];
    const q = rot[b] || new Quaternion();
    if (!p) { W[b] = q.clone(); P[b] = new Vector3(...rest[b]).add(hipsOffset); } else {
      W[b] = W[p].clone().multiply(q);
      P[b] = P[p].clone().add(new Vector3(...rest[b]).sub(new Vector3(...rest[p])).applyQuaternion(W[p]));
    }
  }
  return P;
}

// [smpl joint, its main child, vrm bone, vrm child] for every bone the avatar has with its main child
// (a bone's direction is what the retargeting keeps; across a missing bone, or towards a side branch,
// directions differ by the avatar's own rest geometry)
function pairs(rest) {
  const out = [];
  for (let p = 0; p < N; p++) {
    const c = MAIN_CHILD[SK.names[p]];
    const bp = SMPLX_TO_VRM[SK.names[p]], bc = SMPLX_TO_VRM[c];
    if (c && bp in rest && bc in rest) out.push([p, J[c], bp, bc]);
  }
  return out;
}

function randomPoses(seed, scale = 0.6) {
  const poses = new Float32Array(165);
  let s = seed;
  for (let i = 3; i < 165; i++) { s = (s * 16807) % 2147483647; poses[i] = ((s / 2147483647) * 2 - 1) * scale; }
  poses[0] = 0.2; poses[1] = -0.4; poses[2] = 0.1;
  return poses;
}

// the worst angle (radians) between SMPL-X and avatar bone directions; `turn` maps avatar frame -> project frame.
// Every angle goes through compare.mjs (absolute): a NaN direction makes `worst` infinite (an `a > worst`
// fold skipped it and reported the rest as the worst).
function worstDirection(rest, result, poses, trans, turn = (v) => v) {
  const { P } = smplFK(poses, trans);
  const V = vrmFK(rest, result.rotations, result.hipsOffset);
  const angles = [], names = [];
  for (const [p, c, bp, bc] of pairs(rest)) {
    const ds = P[c].clone().sub(P[p]).normalize();
    const dv = turn(V[bc].clone().sub(V[bp])).normalize();
    angles.push(ds.angleTo(dv));
    names.push(`${SK.names[p]}->${SK.names[c]} / ${bp}->${bc}`);
  }
  const d = diff(angles, angles.map(() => 0), { absolute: true });
  return { worst: d.maxAbs, at: `${names[d.index]} (${d})`, n: angles.length, d };
}

const smplRest = () => {
  const R = [];
  for (let j = 0; j < N; j++) {
    const o = new Vector3(...SK.offsets[j]);
    R.push(SK.parents[j] < 0 ? o : o.add(R[SK.parents[j]]));
  }
  const rest = {};
  for (let j = 0; j < N; j++) if (SMPLX_TO_VRM[SK.names[j]]) rest[SMPLX_TO_VRM[SK.names[j]]] = R[j].toArray();
  return rest;
};

test('every SMPL-X body and finger joint but jaw and eyes maps to a distinct VRM bone', () => {
  const mapped = SK.names.filter((n) => SMPLX_TO_VRM[n]);
  assert.equal(mapped.length, 55 - 3);
  assert.deepEqual(SK.names.filter((n) => !SMPLX_TO_VRM[n]), ['jaw', 'left_eye_smplhf', 'right_eye_smplhf']);
  assert.equal(new Set(mapped.map((n) => SMPLX_TO_VRM[n])).size, mapped.length);
  for (const n of mapped) assert.ok(SMPLX_TO_VRM[n] in VRM_PARENT, `${SMPLX_TO_VRM[n]} is a VRM humanoid bone`);
  assert.equal(SMPLX_TO_VRM.left_thumb1, 'leftThumbMetacarpal');
  assert.equal(SMPLX_TO_VRM.right_pinky3, 'rightLittleDistal');
});

test('an avatar shaped like the skeleton: the rest pose stays the rest pose, poses copy through', () => {
  const rest = smplRest();
  const rt = createRetarget(SK, rest);
  const r0 = rt.apply(new Float32Array(165), [0, 0, 0]);
  for (const [b, q] of Object.entries(r0.rotations)) assert.ok(Math.abs(Math.abs(q.w) - 1) < 1e-9, `${b} not at rest: ${q.toArray()}`);
  assert.ok(r0.hipsOffset.length() < 1e-12);
  const poses = randomPoses(3);
  const r = rt.apply(poses, [0.1, -0.05, 0.2]);
  // same shape: each local rotation is the joint's own axis-angle
  for (const [j, name] of SK.names.entries()) {
    const b = SMPLX_TO_VRM[name];
    if (!b) continue;
    const want = aaToQuat(poses[3 * j], poses[3 * j + 1], poses[3 * j + 2]);
    assert.ok(Math.abs(Math.abs(want.dot(r.rotations[b])) - 1) < 1e-6, `${name} -> ${b}`);
  }
  assert.deepEqual(r.hipsOffset.toArray().map((x) => +x.toFixed(6)), [0.1, -0.05, 0.2]);
});

test('VRM 1.0 avatar of other proportions, no upperChest: bones point where the SMPL-X bones point', () => {
  const rt = createRetarget(SK, TEST_VRM_REST, { metaVersion: '1.0' });
  assert.ok(!rt.bones.includes('upperChest'));
  for (const seed of [1, 2, 3, 4, 5]) {
    const poses = randomPoses(seed);
    const r = rt.apply(poses, [0.05, 0.02, -0.1]);
    const { worst, at, n } = worstDirection(TEST_VRM_REST, r, poses, [0.05, 0.02, -0.1]);
    assert.ok(n >= 34, `${n} bone pairs compared`);
    assert.ok(worst < 1e-4, `seed ${seed}: ${(worst * 180 / Math.PI).toFixed(4)} deg at ${at}`);
  }
  // the hips follow the pelvis, scaled by hips height over pelvis height
  const r = rt.apply(new Float32Array(165), [0.1, 0, 0]);
  assert.ok(Math.abs(r.hipsOffset.x - 0.1 * (1.0 / 0.95)) < 1e-9);
});

test('the check fails a naive retargeting that copies local rotations (rest-pose differences ignored)', () => {
  const poses = randomPoses(9);
  const naive = { rotations: {}, hipsOffset: new Vector3() };
  for (const [j, name] of SK.names.entries()) if (SMPLX_TO_VRM[name]) naive.rotations[SMPLX_TO_VRM[name]] = aaToQuat(poses[3 * j], poses[3 * j + 1], poses[3 * j + 2]);
  const { worst, d } = worstDirection(TEST_VRM_REST, naive, poses, [0, 0, 0]);
  assert.ok(d.problem === null && worst > 0.02, `naive retargeting off by only ${worst} rad`);
});

test('the check fails a retargeting with a NaN rotation (issue 38: the old `a > worst` fold passed it)', () => {
  const rt = createRetarget(SK, TEST_VRM_REST, { metaVersion: '1.0' });
  const poses = randomPoses(1);
  const r = rt.apply(poses, [0, 0, 0]);
  const bone = Object.keys(r.rotations).find((b) => b.startsWith('leftLower'));
  r.rotations[bone] = r.rotations[bone].clone().set(NaN, NaN, NaN, NaN);
  const { worst, d } = worstDirection(TEST_VRM_REST, r, poses, [0, 0, 0]);
  // the old fold (`if (a > worst) worst = a`) skips NaN angles: it reported 0 for [0, NaN, 0]
  assert.equal([0, NaN, 0].reduce((w, a) => (a > w ? a : w), 0), 0);
  assert.ok(!(worst < 1e-4), `a NaN rotation passed: ${worst}`);
  assert.match(String(d), /non-finite/);
});

test('VRM 0.x (facing -Z): the same motion, turned half about Y', () => {
  const rest0 = Object.fromEntries(Object.entries(TEST_VRM_REST).map(([b, p]) => [b, [-p[0], p[1], -p[2]]]));
  const rt = createRetarget(SK, rest0, { metaVersion: '0' });
  const turn = (v) => new Vector3(-v.x, v.y, -v.z);
  for (const seed of [11, 12]) {
    const poses = randomPoses(seed);
    const r = rt.apply(poses, [0.03, 0, 0.04]);
    const { worst, at } = worstDirection(rest0, r, poses, [0.03, 0, 0.04], turn);
    assert.ok(worst < 1e-4, `seed ${seed}: ${worst} at ${at}`);
    // and read as 1.0 (no turn) it is wrong: the check sees the axis difference
    const wrong = worstDirection(rest0, r, poses, [0.03, 0, 0.04]);
    assert.ok(wrong.worst > 0.05);
  }
  const r = rt.apply(new Float32Array(165), [0.1, 0, 0.2]);
  assert.ok(r.hipsOffset.x < 0 && r.hipsOffset.z < 0);
});

test('jaw -> aa: closed 0, opening up to JAW_OPEN_FULL, clamped', () => {
  const p = new Float32Array(165);
  assert.equal(jawToAa(p), 0);
  p[66] = JAW_OPEN_FULL / 2; assert.ok(Math.abs(jawToAa(p) - 0.5) < 1e-6);
  p[66] = 1; assert.equal(jawToAa(p), 1);
  p[66] = -0.2; assert.equal(jawToAa(p), 0);
});

test('an avatar without hips is refused', () => {
  const rest = { ...TEST_VRM_REST };
  delete rest.hips;
  assert.throws(() => createRetarget(SK, rest), /no hips/);
});

// Retargeting the project's SMPL-X skeleton (55 joints, axis-angle per joint, rest T-pose, Y up, body
// facing +Z, the character's left at +X) onto a VRM humanoid (0.x or 1.0) through three-vrm's
// *normalized* human bones, whose rest rotations are all the identity (docs/avatars.md).
//
// - Joints map to VRM humanoid bones by name (SMPLX_TO_VRM): body, neck and head, shoulders, arms,
//   legs, feet and toes, and all fingers (SMPL-X thumb1..3 -> VRM thumbMetacarpal/Proximal/Distal;
//   three-vrm names VRM 0.x thumbs the same way). The jaw drives the `aa` expression (jawToAa), not a
//   bone; the eyes stay with the avatar (its look-at and blinks).
// - Rest-pose differences: each mapped bone gets a constant correction Rc, the shortest rotation that
//   turns the VRM bone's rest direction (bone -> its main child) into the SMPL-X one. The VRM bone's
//   world rotation is G_smplx(j) * Rc, so every bone points where the SMPL-X bone points.
// - Hierarchy differences: local rotations come from world rotations, L(b) = G(parent(b))^-1 G(b), over
//   the bones the avatar has; a missing optional bone (upperChest, a finger) folds into its neighbours.
// - Axis differences: VRM 1.0 faces +Z as the project does; VRM 0.x faces -Z, so its rotations are the
//   project's turned half about Y (quaternion x and z negated) and so is the hips offset.
// - The root: the hips move by the pelvis's translation scaled by hips height / pelvis height.
//
// Pure math over three.js types: no scene, no DOM (runtime/web/tests/retarget.test.mjs runs it in node).
import { Quaternion, Vector3 } from 'three';

export const SMPLX_TO_VRM = {
  pelvis: 'hips',
  left_hip: 'leftUpperLeg', right_hip: 'rightUpperLeg',
  spine1: 'spine',
  left_knee: 'leftLowerLeg', right_knee: 'rightLowerLeg',
  spine2: 'chest',
  left_ankle: 'leftFoot', right_ankle: 'rightFoot',
  spine3: 'upperChest',
  left_foot: 'leftToes', right_foot: 'rightToes',
  neck: 'neck',
  left_collar: 'leftShoulder', right_collar: 'rightShoulder',
  head: 'head',
  left_shoulder: 'leftUpperArm', right_shoulder: 'rightUpperArm',
  left_elbow: 'leftLowerArm', right_elbow: 'rightLowerArm',
  left_wrist: 'leftHand', right_wrist: 'rightHand',
};
for (const side of ['left', 'right']) {
  const S = side;
  for (const [smpl, vrm] of [['index', 'Index'], ['middle', 'Middle'], ['ring', 'Ring'], ['pinky', 'Little']]) {
    SMPLX_TO_VRM[`${side}_${smpl}1`] = `${S}${vrm}Proximal`;
    SMPLX_TO_VRM[`${side}_${smpl}2`] = `${S}${vrm}Intermediate`;
    SMPLX_TO_VRM[`${side}_${smpl}3`] = `${S}${vrm}Distal`;
  }
  SMPLX_TO_VRM[`${side}_thumb1`] = `${S}ThumbMetacarpal`;
  SMPLX_TO_VRM[`${side}_thumb2`] = `${S}ThumbProximal`;
  SMPLX_TO_VRM[`${side}_thumb3`] = `${S}ThumbDistal`;
}

// The VRM 1.0 humanoid hierarchy (vrm-specification, VRMC_vrm-1.0/humanoid.md), for the bones mapped above.
export const VRM_PARENT = {
  hips: null, spine: 'hips', chest: 'spine', upperChest: 'chest', neck: 'upperChest', head: 'neck',
};
for (const S of ['left', 'right']) {
  Object.assign(VRM_PARENT, {
    [`${S}UpperLeg`]: 'hips', [`${S}LowerLeg`]: `${S}UpperLeg`, [`${S}Foot`]: `${S}LowerLeg`, [`${S}Toes`]: `${S}Foot`,
    [`${S}Shoulder`]: 'upperChest', [`${S}UpperArm`]: `${S}Shoulder`, [`${S}LowerArm`]: `${S}UpperArm`,
    [`${S}Hand`]: `${S}LowerArm`,
  });
  for (const f of ['Thumb', 'Index', 'Middle', 'Ring', 'Little']) {
    const [a, b, c] = f === 'Thumb' ? ['Metacarpal', 'Proximal', 'Distal'] : ['Proximal', 'Intermediate', 'Distal'];
    Object.assign(VRM_PARENT, { [`${S}${f}${a}`]: `${S}Hand`, [`${S}${f}${b}`]: `${S}${f}${a}`, [`${S}${f}${c}`]: `${S}${f}${b}` });
  }
}

// Each SMPL-X joint's main child: the direction a bone points in (none: no correction for that bone).
export const MAIN_CHILD = {
  spine1: 'spine2', spine2: 'spine3', spine3: 'neck', neck: 'head',
};
for (const s of ['left', 'right']) {
  Object.assign(MAIN_CHILD, {
    [`${s}_hip`]: `${s}_knee`, [`${s}_knee`]: `${s}_ankle`, [`${s}_ankle`]: `${s}_foot`,
    [`${s}_collar`]: `${s}_shoulder`, [`${s}_shoulder`]: `${s}_elbow`, [`${s}_elbow`]: `${s}_wrist`,
    [`${s}_wrist`]: `${s}_middle1`,
  });
  for (const f of ['index', 'middle', 'ring', 'pinky', 'thumb']) {
    Object.assign(MAIN_CHILD, { [`${s}_${f}1`]: `${s}_${f}2`, [`${s}_${f}2`]: `${s}_${f}3` });
  }
}

/** Full `aa` (mouth open) at this jaw opening, radians about the jaw's X axis. */
export const JAW_OPEN_FULL = 0.3;

/** The `aa` expression weight, 0..1, of a frame's jaw (SMPL-X joint 22; opening is +X rotation). */
export function jawToAa(poses) {
  const x = poses[66];
  return Math.min(1, Math.max(0, x / JAW_OPEN_FULL));
}

/** Jaw opening angle in radians (rotation about the jaw's X axis, >= 0 when open) of a frame. */
export function jawOpening(poses) {
  return poses[66];
}

const tmpAxis = new Vector3();
/** Axis-angle (x, y, z) -> quaternion. */
export function aaToQuat(x, y, z, out = new Quaternion()) {
  const a = Math.hypot(x, y, z);
  if (a < 1e-12) return out.set(0, 0, 0, 1);
  return out.setFromAxisAngle(tmpAxis.set(x / a, y / a, z / a), a);
}

/**
 * Builds the retargeting of `skeleton` ({names, parents, offsets}: the page's /skeleton.json) onto a VRM
 * whose normalized human bones rest at `restPositions` ({vrmBoneName: [x, y, z]} in the model's own frame,
 * metres). `metaVersion` is '0' for VRM 0.x (facing -Z), '1' for VRM 1.0.
 *
 * Returns { bones, corrections, apply(poses, trans) } where apply gives
 * { rotations: {vrmBoneName: Quaternion (local, normalized bone)}, hipsOffset: Vector3, aa }.
 */
export function createRetarget(skeleton, restPositions, { metaVersion = '1' } = {}) {
  const { names, parents, offsets } = skeleton;
  const n = names.length;
  const index = Object.fromEntries(names.map((nm, j) => [nm, j]));
  const vrm0 = String(metaVersion).startsWith('0');
  // rest positions in the project's frame (+Z forward)
  const rest = {};
  for (const [b, p] of Object.entries(restPositions)) rest[b] = vrm0 ? new Vector3(-p[0], p[1], -p[2]) : new Vector3(p[0], p[1], p[2]);
  const has = (b) => b in rest;

  // SMPL-X rest joint positions
  const R = [];
  for (let j = 0; j < n; j++) {
    const o = new Vector3(...offsets[j]);
    R.push(parents[j] < 0 ? o : o.add(R[parents[j]]));
  }

  // the mapped joints the avatar has, in joint order (parents before children)
  const mapped = [];
  for (let j = 0; j < n; j++) {
    const b = SMPLX_TO_VRM[names[j]];
    if (b && has(b)) mapped.push([j, b]);
  }
  if (!mapped.some(([, b]) => b === 'hips')) throw new Error('retarget: the VRM has no hips bone');

  // rest-pose corrections: VRM rest direction -> SMPL-X rest direction
  const corrections = {};
  for (const [j, b] of mapped) {
    const q = new Quaternion();
    let c = MAIN_CHILD[names[j]];
    while (c && !has(SMPLX_TO_VRM[c])) c = MAIN_CHILD[c]; // the first descendant the avatar has
    if (c) {
      const ds = R[index[c]].clone().sub(R[j]);
      const dv = rest[SMPLX_TO_VRM[c]].clone().sub(rest[b]);
      if (ds.lengthSq() > 1e-12 && dv.lengthSq() > 1e-12) q.setFromUnitVectors(dv.normalize(), ds.normalize());
    }
    corrections[b] = q;
  }

  // the nearest present ancestor of each present bone
  const parentOf = {};
  for (const b of Object.keys(rest)) {
    let p = VRM_PARENT[b];
    while (p && !has(p)) p = VRM_PARENT[p];
    parentOf[b] = p || null;
  }
  const order = Object.keys(VRM_PARENT).filter(has); // VRM_PARENT lists parents first
  const jointOf = Object.fromEntries(mapped.map(([j, b]) => [b, j]));

  const hipsHeight = rest.hips.y;
  const pelvisHeight = offsets[0][1];
  const scale = pelvisHeight > 1e-6 && hipsHeight > 1e-6 ? hipsHeight / pelvisHeight : 1;

  const G = Array.from({ length: n }, () => new Quaternion());
  const local = new Quaternion();
  const Gv = {};
  for (const b of order) Gv[b] = new Quaternion();
  const inv = new Quaternion();

  function apply(poses, trans) {
    for (let j = 0; j < n; j++) {
      aaToQuat(poses[3 * j], poses[3 * j + 1], poses[3 * j + 2], local);
      if (parents[j] < 0) G[j].copy(local);
      else G[j].copy(G[parents[j]]).multiply(local);
    }
    const rotations = {};
    for (const b of order) {
      const p = parentOf[b];
      if (b in jointOf) Gv[b].copy(G[jointOf[b]]).multiply(corrections[b]);
      else Gv[b].copy(p ? Gv[p] : new Quaternion()); // unmapped: keeps its rest relative to the parent
      const q = p ? inv.copy(Gv[p]).invert().multiply(Gv[b]) : inv.copy(Gv[b]);
      const out = q.clone();
      if (vrm0) { out.x = -out.x; out.z = -out.z; }
      rotations[b] = out;
    }
    const hipsOffset = new Vector3(trans[0], trans[1], trans[2]).multiplyScalar(scale);
    if (vrm0) { hipsOffset.x = -hipsOffset.x; hipsOffset.z = -hipsOffset.z; }
    return { rotations, hipsOffset, aa: jawToAa(poses) };
  }

  return { bones: mapped.map(([, b]) => b), corrections, scale, apply };
}

// The page's figure: a skinned humanoid built here from the project's own skeleton (/skeleton.json;
// no downloaded or licensed asset) and, as an option, the ball-and-stick skeleton.
//
// The skinned figure is one THREE.SkinnedMesh: a bone per joint (rest offsets from the skeleton, rest
// rotations identity, so a frame's axis-angle is each bone's local rotation as is), over procedural
// geometry: capsules for limbs, fingers and neck, ellipsoids for pelvis, torso and head, each vertex
// bound to its joint and blended into the next joint near the end of a limb. The head has eyes and a
// lower jaw bound to the `jaw` joint in front of a dark mouth, so the mouth opens with the jaw.
import * as THREE from 'three';

const COLORS = {
  suit: 0x4a6a9c, skin: 0xe3b591, hair: 0x3a2a20, shoe: 0x2a2b30, mouth: 0x3a0f14, lip: 0xb8655f,
  eye: 0xf4f4ef, pupil: 0x1c1c22,
};

// geometry accumulated from parts, each vertex with up to two joints
class Parts {
  constructor() { this.pos = []; this.nrm = []; this.col = []; this.si = []; this.sw = []; this.idx = []; }

  // geo: a BufferGeometry in its own frame; m: Matrix4 to the rest pose; weights(v) -> [[j, w], ...]
  add(geo, m, color, weights) {
    const g = geo.index ? geo : geo.toNonIndexed();
    const base = this.pos.length / 3;
    const p = g.attributes.position, nn = g.attributes.normal;
    const nm = new THREE.Matrix3().getNormalMatrix(m);
    const c = new THREE.Color(color);
    const v = new THREE.Vector3(), n = new THREE.Vector3();
    for (let i = 0; i < p.count; i++) {
      v.fromBufferAttribute(p, i).applyMatrix4(m);
      n.fromBufferAttribute(nn, i).applyMatrix3(nm).normalize();
      this.pos.push(v.x, v.y, v.z); this.nrm.push(n.x, n.y, n.z); this.col.push(c.r, c.g, c.b);
      const w = weights(v);
      for (let k = 0; k < 4; k++) { this.si.push(w[k] ? w[k][0] : 0); this.sw.push(w[k] ? w[k][1] : 0); }
    }
    if (g.index) for (let i = 0; i < g.index.count; i++) this.idx.push(base + g.index.getX(i));
    else for (let i = 0; i < p.count; i++) this.idx.push(base + i);
  }

  geometry() {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.Float32BufferAttribute(this.pos, 3));
    g.setAttribute('normal', new THREE.Float32BufferAttribute(this.nrm, 3));
    g.setAttribute('color', new THREE.Float32BufferAttribute(this.col, 3));
    g.setAttribute('skinIndex', new THREE.Uint16BufferAttribute(this.si, 4));
    g.setAttribute('skinWeight', new THREE.Float32BufferAttribute(this.sw, 4));
    g.setIndex(this.idx);
    return g;
  }
}

// a frame whose Y axis runs from a to b, X kept across (side) and Z the remaining axis
function segmentMatrix(a, b, sx = 1, sz = 1) {
  const d = b.clone().sub(a);
  const len = d.length();
  const y = d.normalize();
  const ref = Math.abs(y.y) < 0.9 ? new THREE.Vector3(0, 1, 0) : new THREE.Vector3(0, 0, 1);
  const x = new THREE.Vector3().crossVectors(y, ref).normalize();
  const z = new THREE.Vector3().crossVectors(x, y);
  if (Math.abs(y.y) >= 0.9) { x.set(1, 0, 0); z.crossVectors(x, y).normalize(); x.crossVectors(y, z); }
  const m = new THREE.Matrix4().makeBasis(x.multiplyScalar(sx), y, z.multiplyScalar(sz));
  m.setPosition(a.clone().add(b).multiplyScalar(0.5));
  return { m, len };
}

const smooth = (e0, e1, x) => { const t = Math.min(1, Math.max(0, (x - e0) / (e1 - e0))); return t * t * (3 - 2 * t); };

/**
 * Builds the figure under `parent` for skeleton SK ({names, parents, offsets}). With `wearsFace` (the
 * talking head of facemesh.js goes on the head joint) the head is the skull and hair only, set back
 * so that the face mesh is in front: no eyes, mouth or jaw of its own.
 * Returns { setPose(poses, trans, P), setMode('skinned' | 'sticks'), mode, mesh, bones }.
 */
export function createFigure(parent, SK, { wearsFace = false } = {}) {
  const n = SK.names.length;
  const J = Object.fromEntries(SK.names.map((nm, j) => [nm, j]));
  const R = [];
  for (let j = 0; j < n; j++) {
    const o = new THREE.Vector3(...SK.offsets[j]);
    R.push(SK.parents[j] < 0 ? o : o.add(R[SK.parents[j]]));
  }
  const at = (name, dx = 0, dy = 0, dz = 0) => R[J[name]].clone().add(new THREE.Vector3(dx, dy, dz));
  const parts = new Parts();

  // a capsule from a to b of radius r (flattened by sx, sz), on joint j, blending into joint `to` near b
  const capsule = (a, b, r, j, color, { to = null, sx = 1, sz = 1 } = {}) => {
    const { m, len } = segmentMatrix(a, b, sx, sz);
    const geo = new THREE.CapsuleGeometry(r, Math.max(len, 1e-3), 4, 14);
    const ab = b.clone().sub(a);
    const l2 = Math.max(ab.lengthSq(), 1e-9);
    parts.add(geo, m, color, (v) => {
      if (to === null) return [[j, 1]];
      const t = v.clone().sub(a).dot(ab) / l2;
      const w = 0.5 * smooth(0.75, 1.1, t);
      return [[j, 1 - w], [to, w]];
    });
  };
  const ellipsoid = (c, rx, ry, rz, j, color, seg = 20) => {
    const m = new THREE.Matrix4().makeScale(rx, ry, rz).setPosition(c);
    parts.add(new THREE.SphereGeometry(1, seg, Math.round(seg * 0.7)), m, color, () => [[j, 1]]);
  };

  // legs and feet
  for (const s of ['left', 'right']) {
    capsule(at(`${s}_hip`), at(`${s}_knee`), 0.062, J[`${s}_hip`], COLORS.suit, { to: J[`${s}_knee`] });
    capsule(at(`${s}_knee`), at(`${s}_ankle`), 0.05, J[`${s}_knee`], COLORS.suit, { to: J[`${s}_ankle`] });
    capsule(at(`${s}_ankle`, 0, -0.03, -0.03), at(`${s}_foot`, 0, -0.02, 0), 0.04, J[`${s}_ankle`], COLORS.shoe, { sx: 1.1, sz: 0.7 });
    capsule(at(`${s}_foot`, 0, -0.02, 0), at(`${s}_foot`, 0, -0.025, 0.06), 0.035, J[`${s}_foot`], COLORS.shoe, { sx: 1.2, sz: 0.75 });
  }
  // pelvis and torso: flattened capsules up the spine, each blending into the next joint
  ellipsoid(at('pelvis', 0, -0.01, -0.01), 0.155, 0.1, 0.1, J.pelvis, COLORS.suit);
  capsule(at('pelvis', 0, 0.0, -0.005), at('spine1'), 0.095, J.pelvis, COLORS.suit, { to: J.spine1, sx: 1.5 });
  capsule(at('spine1'), at('spine2'), 0.095, J.spine1, COLORS.suit, { to: J.spine2, sx: 1.45 });
  capsule(at('spine2'), at('spine3'), 0.1, J.spine2, COLORS.suit, { to: J.spine3, sx: 1.5 });
  capsule(at('spine3', 0, 0, -0.005), at('neck', 0, -0.045, -0.01), 0.11, J.spine3, COLORS.suit, { sx: 1.55 });
  // neck, collars, arms
  capsule(at('neck', 0, -0.02, 0), at('head'), 0.045, J.neck, COLORS.skin, { to: J.head });
  for (const s of ['left', 'right']) {
    capsule(at(`${s}_collar`), at(`${s}_shoulder`), 0.05, J[`${s}_collar`], COLORS.suit, { to: J[`${s}_shoulder`] });
    capsule(at(`${s}_shoulder`), at(`${s}_elbow`), 0.045, J[`${s}_shoulder`], COLORS.suit, { to: J[`${s}_elbow`] });
    capsule(at(`${s}_elbow`), at(`${s}_wrist`), 0.037, J[`${s}_elbow`], COLORS.skin, { to: J[`${s}_wrist`] });
    // palm: wrist to the middle knuckle, flat (wide across the fingers, thin through the palm)
    capsule(at(`${s}_wrist`), at(`${s}_middle1`), 0.028, J[`${s}_wrist`], COLORS.skin, { sx: 1.5, sz: 0.55 });
    for (const f of ['index', 'middle', 'ring', 'pinky', 'thumb']) {
      const j1 = J[`${s}_${f}1`], j2 = J[`${s}_${f}2`], j3 = J[`${s}_${f}3`];
      const tip = R[j3].clone().add(R[j3].clone().sub(R[j2]).multiplyScalar(0.8));
      const r = f === 'thumb' ? 0.011 : f === 'pinky' ? 0.0075 : 0.009;
      capsule(R[j1], R[j2], r, j1, COLORS.skin);
      capsule(R[j2], R[j3], r * 0.93, j2, COLORS.skin);
      capsule(R[j3], tip, r * 0.86, j3, COLORS.skin);
    }
  }
  // head: skull and hair on the head joint; eyes on the eye joints; a dark mouth on the head with a
  // lower jaw on the jaw joint in front of it, which swings down as the jaw opens
  const H = at('head', 0, 0.085, wearsFace ? -0.045 : 0.0);
  ellipsoid(H, 0.085, 0.105, 0.1, J.head, COLORS.skin, 28);
  ellipsoid(H.clone().add(new THREE.Vector3(0, 0.035, -0.022)), 0.09, 0.088, 0.097, J.head, COLORS.hair, 24);
  if (!wearsFace) for (const s of ['left', 'right']) {
    const e = at(`${s}_eye_smplhf`, 0, 0, 0.012);
    ellipsoid(e, 0.014, 0.014, 0.012, J[`${s}_eye_smplhf`], COLORS.eye, 14);
    ellipsoid(e.clone().add(new THREE.Vector3(0, 0, 0.01)), 0.006, 0.006, 0.004, J[`${s}_eye_smplhf`], COLORS.pupil, 10);
  }
  if (!wearsFace) {
    ellipsoid(at('jaw', 0, 0.008, 0.062), 0.04, 0.017, 0.035, J.head, COLORS.mouth, 18);
    ellipsoid(at('jaw', 0, -0.022, 0.035), 0.058, 0.034, 0.062, J.jaw, COLORS.skin, 22);
    ellipsoid(at('jaw', 0, -0.006, 0.085), 0.03, 0.008, 0.014, J.jaw, COLORS.lip, 12);
  }

  const bones = SK.names.map((name) => { const b = new THREE.Bone(); b.name = name; return b; });
  for (let j = 0; j < n; j++) {
    bones[j].position.set(...SK.offsets[j]);
    if (SK.parents[j] >= 0) bones[SK.parents[j]].add(bones[j]);
  }
  const material = new THREE.MeshStandardMaterial({ vertexColors: true, roughness: 0.7, metalness: 0.0 });
  const mesh = new THREE.SkinnedMesh(parts.geometry(), material);
  mesh.name = 'livegesture-figure';
  mesh.add(bones[0]);
  mesh.bind(new THREE.Skeleton(bones));
  mesh.frustumCulled = false;
  parent.add(mesh);

  // ball-and-stick
  const sticks = new THREE.Group();
  const jointMesh = new THREE.InstancedMesh(
    new THREE.SphereGeometry(0.018, 12, 8), new THREE.MeshStandardMaterial({ color: 0xf0a030, roughness: 0.5 }), n);
  const boneGeom = new THREE.BufferGeometry();
  boneGeom.setAttribute('position', new THREE.BufferAttribute(new Float32Array((n - 1) * 6), 3));
  sticks.add(jointMesh, new THREE.LineSegments(boneGeom, new THREE.LineBasicMaterial({ color: 0x9fc3ff })));
  sticks.visible = false;
  parent.add(sticks);

  const q = new THREE.Quaternion(), axis = new THREE.Vector3(), m4 = new THREE.Matrix4();
  const figure = {
    mode: 'skinned', mesh, bones, sticks,
    setMode(mode) {
      figure.mode = mode;
      mesh.visible = mode === 'skinned';
      sticks.visible = mode === 'sticks';
    },
    // poses (165 axis-angle), trans (3), P (joint positions from fk.js, for the sticks)
    setPose(poses, trans, P) {
      for (let j = 0; j < n; j++) {
        const x = poses[3 * j], y = poses[3 * j + 1], z = poses[3 * j + 2];
        const a = Math.hypot(x, y, z);
        if (a < 1e-12) q.set(0, 0, 0, 1); else q.setFromAxisAngle(axis.set(x / a, y / a, z / a), a);
        bones[j].quaternion.copy(q);
      }
      const o = SK.offsets[0];
      bones[0].position.set(trans[0] + o[0], trans[1] + o[1], trans[2] + o[2]);
      for (let j = 0; j < n; j++) {
        const s = j >= 25 ? 0.45 : j === 22 ? 0.8 : 1;
        m4.makeScale(s, s, s).setPosition(P[j]);
        jointMesh.setMatrixAt(j, m4);
      }
      jointMesh.instanceMatrix.needsUpdate = true;
      const a = boneGeom.attributes.position.array;
      let k = 0;
      for (let j = 1; j < n; j++) {
        const p = P[SK.parents[j]], c = P[j];
        a[k++] = p.x; a[k++] = p.y; a[k++] = p.z; a[k++] = c.x; a[k++] = c.y; a[k++] = c.z;
      }
      boneGeom.attributes.position.needsUpdate = true;
      boneGeom.computeBoundingSphere();
    },
  };
  return figure;
}

// A glTF motion (`livegesture generate -o x.glb` / `.gltf`, or any glTF animating nodes named as the
// project's joints) read with three.js GLTFLoader and turned back into frames (axis-angle per joint,
// the pelvis's translation minus its rest offset), one frame per keyframe of the first animation.
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';

export async function loadGltfMotion(bytes, SK, name = 'motion.glb') {
  const gltf = await new GLTFLoader().parseAsync(bytes, '');
  const anim = gltf.animations[0];
  if (!anim) throw new Error(`${name}: the glTF file has no animation`);
  const index = Object.fromEntries(SK.names.map((n, j) => [n, j]));
  let times = null;
  const rot = {}, pos = {};
  for (const t of anim.tracks) {
    const dot = t.name.lastIndexOf('.');
    const node = t.name.slice(0, dot), prop = t.name.slice(dot + 1);
    if (!(node in index)) continue;
    if (prop === 'quaternion') rot[index[node]] = t.values;
    else if (prop === 'position' && index[node] === 0) pos[0] = t.values;
    else continue;
    if (!times || t.times.length > times.length) times = t.times;
  }
  if (!times || !Object.keys(rot).length) throw new Error(`${name}: no rotation track on a joint named as the project's (pelvis, ...)`);
  const T = times.length;
  const o = SK.offsets[0];
  const frames = [];
  for (let k = 0; k < T; k++) {
    const poses = new Float32Array(165), trans = new Float32Array(3);
    for (const [j, v] of Object.entries(rot)) {
      if (v.length !== 4 * T) throw new Error(`${name}: joint ${SK.names[j]} has ${v.length / 4} keys, expected ${T}`);
      let [x, y, z, w] = [v[4 * k], v[4 * k + 1], v[4 * k + 2], v[4 * k + 3]];
      if (w < 0) { x = -x; y = -y; z = -z; w = -w; }
      const s = Math.hypot(x, y, z);
      const a = 2 * Math.atan2(s, w);
      const f = s > 1e-9 ? a / s : 2;
      poses[3 * j] = x * f; poses[3 * j + 1] = y * f; poses[3 * j + 2] = z * f;
    }
    if (pos[0]) for (let c = 0; c < 3; c++) trans[c] = pos[0][3 * k + c] - o[c];
    frames.push({ index: k, time_s: times[k], poses, trans, expressions: new Float32Array(100) });
  }
  return frames;
}

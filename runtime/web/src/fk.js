// Forward kinematics on the project's skeleton (/skeleton.json: names, parents, rest offsets in metres,
// the Rust mirror of python/livegesture/skeleton.py): a frame's 55 axis-angle rotations (each relative
// to its parent; the root's global) and its translation -> joint positions and world rotations.
import * as THREE from 'three';
import { aaToQuat } from './retarget.js';

export const N_JOINTS = 55;

export function createFK(SK) {
  const n = SK.names.length;
  const G = Array.from({ length: n }, () => new THREE.Quaternion());
  const P = Array.from({ length: n }, () => new THREE.Vector3());
  const q = new THREE.Quaternion();
  const v = new THREE.Vector3();
  // poses: 165 axis-angle values, trans: 3 -> { P: positions (m), G: world rotations }
  function solve(poses, trans) {
    for (let j = 0; j < n; j++) {
      aaToQuat(poses[3 * j], poses[3 * j + 1], poses[3 * j + 2], q);
      const p = SK.parents[j];
      const o = SK.offsets[j];
      if (p < 0) {
        G[j].copy(q);
        P[j].set(trans[0] + o[0], trans[1] + o[1], trans[2] + o[2]);
      } else {
        G[j].copy(G[p]).multiply(q);
        v.set(o[0], o[1], o[2]).applyQuaternion(G[p]);
        P[j].copy(P[p]).add(v);
      }
    }
    return { P, G };
  }
  return { solve, P, G };
}

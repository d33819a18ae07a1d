// A user's VRM avatar (0.x or 1.0, read by @pixiv/three-vrm) following the motion: each frame is
// retargeted from the project's skeleton to the avatar's normalized human bones (retarget.js). With the
// face channel (docs/face.md) the visemes drive the expressions `aa, ih, ou, ee, oh` and ARKit's
// eyeBlinkLeft/Right drive `blinkLeft`/`blinkRight` (facemesh.js vrmExpressions); without it the jaw
// opening drives `aa`. Look-at and spring bones stay the avatar's own.
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { VRMLoaderPlugin, VRMUtils } from '@pixiv/three-vrm';
import { createRetarget, VRM_PARENT } from './retarget.js';
import { vrmExpressions } from './facemesh.js';

/** Loads a .vrm from its bytes into `scene`; rejects with a message naming what is missing. */
export async function loadVrm(bytes, SK, scene, name = 'avatar.vrm') {
  const loader = new GLTFLoader();
  loader.register((parser) => new VRMLoaderPlugin(parser));
  let gltf;
  try {
    gltf = await loader.parseAsync(bytes, '');
  } catch (e) {
    throw new Error(`${name}: not a readable glTF/VRM file (${e.message || e})`);
  }
  const vrm = gltf.userData.vrm;
  if (!vrm || !vrm.humanoid) throw new Error(`${name}: no VRM humanoid (expected the VRMC_vrm or VRM extension)`);
  VRMUtils.rotateVRM0(vrm); // VRM 0.x faces -Z: turn the scene to face the camera as 1.0 does
  vrm.scene.traverse((o) => { o.frustumCulled = false; });
  scene.add(vrm.scene);
  vrm.humanoid.resetNormalizedPose();
  vrm.scene.updateMatrixWorld(true);
  const rest = {};
  const v = new THREE.Vector3();
  for (const bone of Object.keys(VRM_PARENT)) {
    const node = vrm.humanoid.getNormalizedBoneNode(bone);
    if (!node) continue;
    node.getWorldPosition(v);
    vrm.scene.worldToLocal(v);
    rest[bone] = v.toArray();
  }
  const metaVersion = String(vrm.meta?.metaVersion ?? '1');
  const rt = createRetarget(SK, rest, { metaVersion });
  const hips = vrm.humanoid.getNormalizedBoneNode('hips');
  const hipsRest = hips.position.clone();
  const nodes = Object.fromEntries(rt.bones.map((b) => [b, vrm.humanoid.getNormalizedBoneNode(b)]));
  const hasAa = !!vrm.expressionManager?.getExpression('aa');
  const has = (name) => !!vrm.expressionManager?.getExpression(name);
  return {
    vrm, metaVersion, bones: rt.bones, hasAa,
    title: vrm.meta?.name || vrm.meta?.title || name,
    aa: 0,
    expressions: null, // the expression values of the last frame with the face channel
    // one frame: the pose on the normalized bones, copied to the avatar's own bones at once; the
    // face from `face.visemes` and `face.arkit` where the frame has them
    apply(poses, trans, face) {
      const r = rt.apply(poses, trans);
      for (const [b, q] of Object.entries(r.rotations)) if (nodes[b]) nodes[b].quaternion.copy(q);
      hips.position.copy(hipsRest).add(r.hipsOffset);
      if (face && face.visemes && face.arkit) {
        const ex = vrmExpressions(face.visemes, face.arkit);
        for (const [name, v] of Object.entries(ex)) if (has(name)) vrm.expressionManager.setValue(name, v);
        this.expressions = ex;
        this.aa = ex.aa;
      } else {
        if (hasAa) vrm.expressionManager.setValue('aa', r.aa);
        this.aa = r.aa;
      }
      vrm.humanoid.update();
      vrm.expressionManager?.update();
      vrm.scene.updateMatrixWorld(true);
    },
    // per rendered frame: the avatar's own animation (spring bones, look-at, its expressions)
    update(dt) { vrm.update(dt); },
    dispose() { scene.remove(vrm.scene); VRMUtils.deepDispose(vrm.scene); },
  };
}

// The page's figure and avatar controls: the view (skinned figure, ball-and-stick skeleton, or a VRM
// avatar), the VRM file input, and dropping files on the page (.vrm: the avatar; .npz/.bvh/.glb/.gltf:
// a motion to view; .wav: played through the server). window.lgAvatar is what the browser test reads.
import * as THREE from 'three';
import { loadVrm } from './vrm.js';

const $ = (id) => document.getElementById(id);

/**
 * ctx: { scene, SK, figure, state, setAvatar(a), lastFrame() -> frame|null, showFrame(frame),
 *        onMotionFile(file), onWav(file), setStatus(text, kind) }
 */
export function setupAvatarControls(ctx) {
  const { scene, SK, figure, state } = ctx;
  let avatar = null;
  const sel = $('viewMode');
  const vrmOption = sel.querySelector('option[value=vrm]');
  state.view = sel.value;
  state.avatar = { loaded: false, error: null };

  function setView(mode) {
    state.view = mode;
    sel.value = mode;
    figure.setMode(mode === 'vrm' ? 'none' : mode);
    if (avatar) avatar.vrm.scene.visible = mode === 'vrm';
  }
  sel.onchange = () => setView(sel.value);

  async function loadAvatar(file) {
    try {
      state.avatar = { loaded: false, loading: file.name, error: null };
      const a = await loadVrm(await file.arrayBuffer(), SK, scene, file.name);
      if (avatar) avatar.dispose();
      avatar = a;
      ctx.setAvatar(a);
      vrmOption.disabled = false;
      vrmOption.textContent = `avatar: ${a.title}`;
      setView('vrm');
      const f = ctx.lastFrame();
      if (f) ctx.showFrame(f);
      state.avatar = { loaded: true, title: a.title, metaVersion: a.metaVersion, bones: a.bones.length, aaExpression: a.hasAa, error: null };
      $('avatarInfo').textContent = `${a.title} (VRM ${a.metaVersion.startsWith('0') ? '0.x' : '1.0'}, ${a.bones.length} bones driven${a.hasAa ? ', aa' : ', no aa expression'})`;
    } catch (e) {
      state.avatar = { loaded: false, error: String(e.message || e) };
      $('avatarInfo').textContent = `${e.message || e}`;
      ctx.setStatus(`avatar: ${e.message || e}`, 'error');
    }
  }
  $('vrm').onchange = (e) => e.target.files[0] && loadAvatar(e.target.files[0]);

  // drop anywhere on the page
  document.addEventListener('dragover', (e) => { e.preventDefault(); });
  document.addEventListener('drop', (e) => {
    e.preventDefault();
    for (const file of e.dataTransfer?.files || []) {
      const ext = file.name.toLowerCase().split('.').pop();
      if (ext === 'vrm') loadAvatar(file);
      else if (['npz', 'bvh', 'glb', 'gltf'].includes(ext)) ctx.onMotionFile(file);
      else if (ext === 'wav') ctx.onWav(file);
      else ctx.setStatus(`${file.name}: drop a .vrm avatar, a motion (.npz, .bvh, .glb, .gltf) or a .wav`, 'error');
    }
  });

  const v = new THREE.Vector3();
  window.lgAvatar = {
    loadFile: loadAvatar,
    // world positions of the avatar's own (raw) human bones, and its current `aa` weight
    pose(names) {
      if (!avatar) return null;
      const out = {};
      for (const b of names) {
        const node = avatar.vrm.humanoid.getRawBoneNode(b);
        if (node) out[b] = node.getWorldPosition(v).toArray();
      }
      const em = avatar.vrm.expressionManager;
      const expressions = Object.fromEntries(['aa', 'ih', 'ou', 'ee', 'oh', 'blinkLeft', 'blinkRight'].map((n) => [n, em?.getValue(n) ?? null]));
      return { bones: out, aa: em?.getValue('aa') ?? null, expressions, frame: window.lgState.lastFrame };
    },
  };
  return { setView };
}

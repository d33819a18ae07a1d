// The browser test's checks of the figure, the face panel, glTF loading and VRM avatars (called by
// runtime/web/tests/browser.mjs on the served page; docs/avatars.md):
//   1. the page's /skeleton.json is tests/skeleton.json (which the node tests of retarget.js use);
//   2. the default view is the skinned figure: screenshot serve-page.png (docs/serve-page.png), which
//      covers far more of the view than the ball-and-stick option does; the face panel shows the mouth;
//   3. `generate -o m.glb` and `-o m.npz` of the same audio: the .glb read by three.js GLTFLoader in the
//      page holds the npz's frames and rotations;
//   4. a VRM 1.0 humanoid built by the test (make-vrm.mjs) loaded in the page follows a WAV played through
//      the server: its own bones point where the skeleton's bones point, frame by frame (forward
//      kinematics here, in node), and its expressions follow the face channel: `aa, ih, ou, ee, oh`
//      from the visemes, `blinkLeft`/`blinkRight` from ARKit's blinks (facemesh.js vrmExpressions;
//      from a bundle without the face channel, `aa` follows the jaw).
import { execFileSync } from 'node:child_process';
import { readFileSync, writeFileSync } from 'node:fs';
import { join, resolve } from 'node:path';
import { Quaternion, Vector3 } from 'three';
import { makeTestVrm } from './make-vrm.mjs';
import { diff } from './compare.mjs';
import { vrmExpressions } from '../src/facemesh.js';

const FIXTURE = JSON.parse(readFileSync(new URL('./skeleton.json', import.meta.url)));

// foreground samples of a screenshot's 3D view (x >= 300), background #14161a
async function foreground(page, png) {
  return page.evaluate(async (b64) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const c = document.createElement('canvas'); c.width = img.width; c.height = img.height;
    const g = c.getContext('2d'); g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    let fg = 0;
    for (let y = 0; y < c.height; y += 2) for (let x = 300; x < c.width; x += 2) {
      const i = 4 * (y * c.width + x);
      if (Math.abs(d[i] - 0x14) + Math.abs(d[i + 1] - 0x16) + Math.abs(d[i + 2] - 0x1a) > 30) fg++;
    }
    return fg;
  }, png.toString('base64'));
}

function aaQuat(x, y, z) {
  const a = Math.hypot(x, y, z);
  return a < 1e-12 ? new Quaternion() : new Quaternion().setFromAxisAngle(new Vector3(x / a, y / a, z / a), a);
}

function fk(SK, poses, trans) {
  const G = [], P = [];
  for (let j = 0; j < SK.names.length; j++) {
    const q = aaQuat(poses[3 * j], poses[3 * j + 1], poses[3 * j + 2]);
    const o = new Vector3(...SK.offsets[j]);
    const p = SK.parents[j];
    if (p < 0) { G.push(q); P.push(o.add(new Vector3(...trans))); } else {
      G.push(G[p].clone().multiply(q));
      P.push(P[p].clone().add(o.applyQuaternion(G[p])));
    }
  }
  return P;
}

// skeleton bone (joint -> child) and the test avatar's bone that must point the same way
const BONE_PAIRS = [
  ['left_shoulder', 'left_elbow', 'leftUpperArm', 'leftLowerArm'],
  ['left_elbow', 'left_wrist', 'leftLowerArm', 'leftHand'],
  ['right_shoulder', 'right_elbow', 'rightUpperArm', 'rightLowerArm'],
  ['right_elbow', 'right_wrist', 'rightLowerArm', 'rightHand'],
  ['left_collar', 'left_shoulder', 'leftShoulder', 'leftUpperArm'],
  ['neck', 'head', 'neck', 'head'],
  ['spine1', 'spine2', 'spine', 'chest'],
  ['left_hip', 'left_knee', 'leftUpperLeg', 'leftLowerLeg'],
  ['right_knee', 'right_ankle', 'rightLowerLeg', 'rightFoot'],
  ['left_wrist', 'left_middle1', 'leftHand', 'leftMiddleProximal'],
  ['left_index1', 'left_index2', 'leftIndexProximal', 'leftIndexIntermediate'],
  ['right_thumb1', 'right_thumb2', 'rightThumbMetacarpal', 'rightThumbProximal'],
  ['right_pinky2', 'right_pinky3', 'rightLittleIntermediate', 'rightLittleDistal'],
];

export async function avatarChecks(page, { bin, bundle, wav, outDir, fail }) {
  // end a session still streaming
  if (await page.evaluate(() => !document.getElementById('stop').disabled)) {
    await page.click('#stop');
    await page.waitForFunction(() => !/^(live|connected|connecting)$/.test(window.lgState.status), null, { timeout: 30000 })
      .catch(async () => fail(`the session did not end: ${JSON.stringify(await page.evaluate(() => window.lgState))}`));
  }
  // 1. the skeleton
  const SK = await page.evaluate(async () => (await fetch('/skeleton.json')).json());
  const same = SK.names.join() === FIXTURE.names.join() && SK.parents.join() === FIXTURE.parents.join()
    && SK.offsets.every((o, j) => o.every((v, k) => Math.abs(v - FIXTURE.offsets[j][k]) < 1e-9));
  if (!same) fail('the served /skeleton.json differs from runtime/web/tests/skeleton.json (regenerate the fixture)');

  // 2. the figure: skinned by default, larger on screen than the sticks; the face panel
  const view = await page.evaluate(() => window.lgState.view);
  if (view !== 'skinned') fail(`the default view is ${view}, expected the skinned figure`);
  const shot = join(outDir, 'serve-page.png');
  const skinned = await foreground(page, await page.screenshot({ path: shot }));
  await page.selectOption('#viewMode', 'sticks');
  await page.waitForTimeout(300);
  const sticks = await foreground(page, await page.screenshot({ path: join(outDir, 'sticks.png') }));
  await page.selectOption('#viewMode', 'skinned');
  console.log(`figure: skinned view ${skinned} foreground samples, ball-and-stick ${sticks} (screenshot ${shot})`);
  if (!(skinned > 2 * sticks)) fail(`the skinned figure covers ${skinned} samples, not clearly more than the sticks (${sticks})`);
  const face = await page.evaluate(() => ({ mouth: window.lgState.mouthOpening, n: (window.lgState.expressions || []).length, text: document.getElementById('mouthv').textContent }));
  console.log(`face panel: mouth ${face.text}, ${face.n} expression values as data`);
  if (typeof face.mouth !== 'number' || face.n !== 100 || !/%$/.test(face.text)) fail(`face panel: ${JSON.stringify(face)}`);

  // 3. glTF: the .glb of the same audio as the .npz, read by GLTFLoader in the page
  const gen = (out) => execFileSync(bin, ['generate', wav, '-o', out, '--seed', '5', '--backend', 'tract', '--bundle', bundle], { stdio: ['ignore', 'ignore', 'pipe'] });
  const npz = resolve(join(outDir, 'motion.npz')), glb = resolve(join(outDir, 'motion.glb'));
  gen(npz); gen(glb);
  const readFile = async (path) => {
    await page.setInputFiles('#motion', path);
    await page.waitForFunction((n) => window.lgState.loadedFile === n, path.split('/').pop(), { timeout: 30000 })
      .catch(async () => fail(`${path}: not loaded by the viewer: ${JSON.stringify(await page.evaluate(() => window.lgState))}`));
    const n = await page.evaluate(() => window.lgState.fileFrames);
    const at = [0, 1, Math.floor(n / 2), n - 1];
    return { n, at, frames: await page.evaluate((ix) => ix.map((i) => window.lgFileFrame(i)), at) };
  };
  const a = await readFile(npz), b = await readFile(glb);
  if (a.n !== b.n) fail(`the .glb holds ${b.n} frames, the .npz ${a.n}`);
  // compare.mjs: a NaN or a missing value fails (Math.max and `worst < 1e-5` on NaN did not)
  const rotErr = [], transA = [], transB = [];
  for (let k = 0; k < a.at.length; k++) {
    for (let j = 0; j < 55; j++) {
      const qa = aaQuat(...a.frames[k].poses.slice(3 * j, 3 * j + 3)), qb = aaQuat(...b.frames[k].poses.slice(3 * j, 3 * j + 3));
      rotErr.push(1 - Math.abs(qa.dot(qb)));
    }
    transA.push(...a.frames[k].trans); transB.push(...b.frames[k].trans);
  }
  const dRot = diff(rotErr, rotErr.map(() => 0), { absolute: true });
  const dTrans = diff(transB, transA);
  console.log(`glTF in the browser: GLTFLoader read ${b.n} frames from ${glb}; vs the npz at frames ${a.at}: rotations (1 - |q.q'|) ${dRot}; translation ${dTrans}`);
  if (!dRot.within(1e-5) || !dTrans.within(1e-5)) fail(`the .glb read by GLTFLoader differs from the npz: rotations ${dRot}; translation ${dTrans}`);

  // 4. a VRM 1.0 avatar made here follows a WAV played through the server
  const vrmPath = join(outDir, 'test-humanoid.vrm');
  writeFileSync(vrmPath, makeTestVrm());
  await page.setInputFiles('#vrm', resolve(vrmPath));
  await page.waitForFunction(() => window.lgState.avatar && (window.lgState.avatar.loaded || window.lgState.avatar.error), null, { timeout: 30000 })
    .catch(async () => fail(`the VRM did not load: ${JSON.stringify(await page.evaluate(() => window.lgState.avatar))}`));
  const av = await page.evaluate(() => window.lgState.avatar);
  console.log('VRM:', JSON.stringify(av));
  if (!av.loaded || av.error) fail(`the VRM was refused: ${av.error}`);
  if (!av.aaExpression) fail('the VRM loaded without its aa expression');
  if (await page.evaluate(() => window.lgState.view) !== 'vrm') fail('the view did not switch to the avatar');
  await page.setInputFiles('#wav', []); // the same file again fires no change event otherwise
  await page.setInputFiles('#wav', resolve(wav));
  await page.waitForFunction(() => window.lgState.status === 'live' && window.lgState.frames >= 10, null, { timeout: 60000 })
    .catch(async () => fail(`no frames for the avatar: ${JSON.stringify(await page.evaluate(() => window.lgState))}`));
  const vrmBones = [...new Set(BONE_PAIRS.flatMap((p) => [p[2], p[3]]))];
  const samples = [];
  for (let i = 0; i < 8; i++) {
    samples.push(await page.evaluate((names) => window.lgAvatar.pose(names), vrmBones));
    await page.waitForTimeout(250);
  }
  // every angle and jaw error through compare.mjs: NaN fails (`ang > worstAngle` and `> 0.01` skipped it)
  const angles = [], where = [], aaGot = [], aaWant = [];
  let faceFrames = 0;
  const dirs = [];
  for (const s of samples) {
    if (!s || !s.frame) { fail('no frame or avatar pose to compare'); continue; }
    const P = fk(SK, s.frame.poses, s.frame.trans);
    const idx = Object.fromEntries(SK.names.map((n, j) => [n, j]));
    const d = [];
    for (const [p, c, bp, bc] of BONE_PAIRS) {
      const ds = P[idx[c]].clone().sub(P[idx[p]]).normalize();
      const dv = new Vector3(...s.bones[bc]).sub(new Vector3(...s.bones[bp])).normalize();
      angles.push(ds.angleTo(dv));
      where.push(`${p}->${c} vs ${bp}->${bc} at frame ${s.frame.index}`);
      d.push(dv);
    }
    dirs.push(d);
    if (s.frame.visemes) {
      // every expression the face channel drives, against the table applied here
      const want = vrmExpressions(s.frame.visemes, s.frame.arkit);
      for (const [n, v] of Object.entries(want)) { aaGot.push(s.expressions[n]); aaWant.push(v); }
      faceFrames++;
    } else {
      aaGot.push(s.aa);
      aaWant.push(Math.min(1, Math.max(0, s.frame.poses[66] / 0.3)));
    }
  }
  const dAngle = diff(angles, angles.map(() => 0), { absolute: true });
  const dAa = diff(aaGot, aaWant, { absolute: true });
  // the avatar moves: its bone directions change between the samples
  const movedAll = [];
  for (let k = 1; k < dirs.length; k++) for (let i = 0; i < BONE_PAIRS.length; i++) movedAll.push(dirs[k][i].angleTo(dirs[0][i]));
  const moved = movedAll.length && movedAll.every(Number.isFinite) ? Math.max(...movedAll) : NaN;
  const aas = samples.map((s) => Number(s && s.aa).toFixed(3));
  console.log(`VRM follows the motion: ${samples.length} samples, bone direction error (rad) ${dAngle} (${where[dAngle.index] || '-'}), ` +
    `avatar bones turned up to ${(moved * 180 / Math.PI).toFixed(1)} deg, aa ${aas.join(' ')} (error ${dAa})`);
  if (!dAngle.within(0.01)) fail(`the avatar's bones do not point where the skeleton's do: ${dAngle} at ${where[dAngle.index]}`);
  if (!dAa.within(1e-4)) fail(`the avatar's expressions do not follow the face channel (or aa the jaw): ${dAa}`);
  const hasFace = await page.evaluate(() => window.lgState.faceChannel);
  if (hasFace && faceFrames !== samples.length) fail(`${samples.length - faceFrames} of ${samples.length} avatar samples had no face channel`);
  console.log(`VRM expressions from the face channel on ${faceFrames}/${samples.length} samples`);
  if (!(moved >= 0.02)) fail(`the avatar did not move (bone directions changed by ${moved} rad)`);
  await page.screenshot({ path: join(outDir, 'vrm.png') });
}

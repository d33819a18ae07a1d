// The Khronos glTF validator (npm `gltf-validator`) over files written by `livegesture generate -o x.glb`
// / `x.gltf` (run by scripts/test.sh). Passes when every file has no error and no warning; infos and
// hints are printed. A self-check first: a copy of the first file with a deliberately wrong accessor
// bound must be reported as an error, so a validator that reports nothing fails this test.
//
//   node runtime/web/tests/gltf-validate.mjs FILE.glb [FILE.gltf ...]
import { readFileSync } from 'node:fs';
import { basename } from 'node:path';
import validator from 'gltf-validator';

const files = process.argv.slice(2);
if (!files.length) { console.error('usage: gltf-validate.mjs FILE.glb [FILE.gltf ...]'); process.exit(2); }

async function validate(bytes, name) {
  return validator.validateBytes(new Uint8Array(bytes), {
    uri: name,
    maxIssues: 50,
    externalResourceFunction: (uri) => Promise.reject(new Error(`${name}: external resource ${uri} (none expected)`)),
  });
}

function summary(r) {
  const i = r.issues;
  return `${i.numErrors} errors, ${i.numWarnings} warnings, ${i.numInfos} infos, ${i.numHints} hints`;
}

// the .glb with its JSON chunk edited by `edit`
function editGlb(bytes, edit) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (dv.getUint32(0, true) !== 0x46546c67) throw new Error('not a .glb (no glTF magic)');
  const jlen = dv.getUint32(12, true);
  const doc = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jlen)));
  edit(doc);
  let js = new TextEncoder().encode(JSON.stringify(doc));
  const pad = (4 - (js.length % 4)) % 4;
  js = Uint8Array.from([...js, ...Array(pad).fill(0x20)]);
  const rest = bytes.subarray(20 + jlen);
  const out = new Uint8Array(20 + js.length + rest.length);
  out.set(bytes.subarray(0, 20));
  out.set(js, 20);
  out.set(rest, 20 + js.length);
  const ov = new DataView(out.buffer);
  ov.setUint32(8, out.length, true);
  ov.setUint32(12, js.length, true);
  return out;
}

let failed = false;
const glb = files.find((f) => f.toLowerCase().endsWith('.glb'));
if (glb) {
  const broken = editGlb(readFileSync(glb), (doc) => {
    const input = doc.animations[0].samplers[0].input;
    doc.accessors[input].max = [doc.accessors[input].max[0] + 1]; // a keyframe time bound that is wrong
  });
  const r = await validate(broken, `broken-${basename(glb)}`);
  if (r.issues.numErrors === 0) {
    console.error(`self-check FAILED: a .glb with a wrong accessor bound passed the validator (${summary(r)})`);
    failed = true;
  } else {
    console.log(`self-check: a deliberately broken copy of ${basename(glb)} is refused (${summary(r)}: ${r.issues.messages[0].code})`);
  }
}

for (const f of files) {
  const r = await validate(readFileSync(f), basename(f));
  const info = r.info || {};
  console.log(`${f}: ${summary(r)}; ${info.animationCount} animation, ${info.totalVertexCount} vertices, ${info.maxInfluences} influences, generator ${info.generator}`);
  for (const m of r.issues.messages) {
    const level = ['error', 'warning', 'info', 'hint'][m.severity];
    console.log(`  ${level} ${m.code} ${m.pointer || ''}: ${m.message}`);
  }
  if (r.issues.numErrors > 0 || r.issues.numWarnings > 0) failed = true;
  if (!(info.animationCount >= 1)) { console.error(`${f}: no animation`); failed = true; }
}
if (failed) { console.error('glTF validation FAILED'); process.exit(1); }
console.log('glTF validation passed');

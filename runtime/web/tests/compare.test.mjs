// node --test: the web tests' comparison (compare.mjs) fails on NaN, Inf, empty input and shape or
// length mismatch, and where the old hand-rolled checks passed them (issue 38: both outcomes shown).
import test from 'node:test';
import assert from 'node:assert/strict';
import { diff, assertWithin, exact } from './compare.mjs';

const ref = [0.5, -1.25, 40.0, 3.0];

test('equal and slightly different values pass, the bound scales with the reference', () => {
  assert.ok(diff(ref, ref).within(0));
  const near = ref.slice(); near[2] += 3e-3; // 3e-3 absolute at magnitude 40: 7.5e-5 scaled
  assert.ok(diff(near, ref).within(1e-4));
  assert.ok(!diff(near, ref, { absolute: true }).within(1e-4));
  const far = ref.slice(); far[0] += 2e-4;
  assert.ok(!diff(far, ref.map((x) => x / 40)).within(1e-4));
});

test('NaN or Inf on either side fails any bound, where Math.max and > comparisons passed it', () => {
  for (const bad of [NaN, Infinity, -Infinity]) {
    for (const side of ['got', 'ref']) {
      const a = ref.slice(), b = ref.slice();
      (side === 'got' ? a : b)[1] = bad;
      // the old patterns: Math.max(worst, |a - b|) is NaN, and `NaN > bound` is false
      const old = a.reduce((w, x, i) => Math.max(w, Math.abs(x - b[i])), 0);
      if (Number.isNaN(bad)) assert.ok(!(old > 1e-3), `premise: the old check passed NaN in ${side}`);
      const d = diff(a, b);
      assert.ok(!d.within(Number.MAX_VALUE), `${bad} in ${side} passed`);
      assert.match(String(d), /non-finite/);
      assert.throws(() => assertWithin(a, b, 1, 'x'), /non-finite/);
    }
  }
});

test('empty input, length and shape mismatch fail', () => {
  assert.ok(!diff([], []).within(1));
  assert.match(String(diff([], [])), /nothing compared/);
  assert.ok(!diff(ref.slice(0, 3), ref).within(1));
  assert.match(String(diff(ref.slice(0, 3), ref)), /lengths differ/);
  const d = diff(ref, ref, { shape: [2, 2], refShape: [4, 1] });
  assert.ok(!d.within(1));
  assert.match(String(d), /shapes differ/);
  assert.ok(diff(ref, ref, { shape: [2, 2], refShape: [2, 2] }).within(0));
});

test('integers are compared exactly', () => {
  assert.doesNotThrow(() => exact([1, 2, 3], [1, 2, 3], 'tokens'));
  assert.throws(() => exact([1, 2, 4], [1, 2, 3], 'tokens'), /tokens/);
  assert.throws(() => exact([], [], 'tokens'), /nothing compared/);
});

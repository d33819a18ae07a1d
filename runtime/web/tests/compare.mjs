// The one comparison of the web tests (issue 38): the JavaScript equivalent of the shared helpers
// (runtime/src/compare.rs, python/livegesture/compare.py). A comparison fails, whatever the bound, when
// a value is NaN or Inf on either side, nothing is compared, the lengths or the shapes differ; otherwise
// it passes when max|got - ref| <= bound x scale, scale = max(1, max|ref|) over the reference (docs/parity.md).
// `{ absolute: true }` judges at scale 1 (angles, unit-free errors).
//
//   import { diff, assertWithin } from './compare.mjs';
//   const d = diff(got, want, { shape: [T, 165], refShape: [T, 165] });
//   if (!d.within(1e-4)) fail(`poses: ${d}`);

/** Compares two array-likes of numbers element by element (see the module comment). */
export function diff(got, ref, { shape, refShape, absolute = false } = {}) {
  const g = got ?? [], r = ref ?? [];
  const n = Math.min(g.length, r.length);
  let scale = 1, maxAbs = 0, index = -1, nonfinite = null;
  for (let i = 0; i < n; i++) {
    const a = Number(g[i]), b = Number(r[i]);
    const fa = Number.isFinite(a), fb = Number.isFinite(b);
    if (!(fa && fb)) {
      if (nonfinite === null) {
        nonfinite = !fa && !fb ? `both sides at [${i}]: got ${a}, reference ${b}`
          : !fa ? `got[${i}] = ${a} (reference ${b})` : `reference[${i}] = ${b} (got ${a})`;
        index = i;
      }
      continue;
    }
    if (!absolute) scale = Math.max(scale, Math.abs(b));
    const d = Math.abs(a - b);
    if (nonfinite === null && (index < 0 || d > maxAbs)) { maxAbs = d; index = i; }
  }
  let problem = null;
  if (shape !== undefined || refShape !== undefined) {
    const s = JSON.stringify(shape ?? null), rs = JSON.stringify(refShape ?? null);
    if (s !== rs) problem = `shapes differ: got ${s}, reference ${rs}`;
  }
  if (!problem && g.length !== r.length) problem = `lengths differ: got ${g.length} values, reference ${r.length}`;
  if (!problem && nonfinite) problem = `non-finite value: ${nonfinite}`;
  if (!problem && n === 0) problem = 'nothing compared (both sides empty)';
  if (problem) maxAbs = Infinity;
  return {
    maxAbs, scale, index, compared: n, problem,
    scaledError: maxAbs / scale,
    within(bound) { return this.problem === null && this.maxAbs <= bound * this.scale; },
    toString() {
      if (this.problem) return `${this.problem} (${this.compared} compared)`;
      return `max |got - reference| = ${this.maxAbs.toExponential(3)} (scale ${this.scale.toFixed(4)}, ${this.compared} compared) at index ${this.index}: got ${g[this.index]}, reference ${r[this.index]}`;
    },
  };
}

/** Throws naming `what`, the error, the bound and the scale unless `got` is within `bound` of `ref`. */
export function assertWithin(got, ref, bound, what, opts = {}) {
  const d = diff(got, ref, opts);
  if (!d.within(bound)) throw new Error(`${what}: ${d}; bound ${bound} x scale ${d.scale}`);
  return d;
}

/** Integer tensors (tokens, indices): identical, same length, something compared. */
export function exact(got, ref, what) {
  const d = diff(got, ref);
  if (!d.within(0)) throw new Error(`${what}: ${d}`);
  for (let i = 0; i < got.length; i++) {
    if (!Number.isInteger(Number(got[i])) || Number(got[i]) !== Number(ref[i])) throw new Error(`${what}: [${i}] ${got[i]} vs ${ref[i]}`);
  }
  return d;
}

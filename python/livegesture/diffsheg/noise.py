"""Portable Gaussian noise for DiffSHEG sampling. Owned numerics: the Rust runtime reproduces this bit for bit.

Every normal is a pure function of (seed, index), so a stream's PRNG position is one integer, the number of
normals drawn so far (``noise_position`` in the manifest), and numpy can draw a whole block at once.

Uniforms (``livegesture.sampling.SplitMix64``, counter form). The n-th 64-bit draw (n = 0, 1, ...) of the
stream with seed ``s`` is::

    z = (s + (n + 1) * 0x9E3779B97F4A7C15) mod 2^64
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9  mod 2^64
    z = (z ^ (z >> 27)) * 0x94D049BB133111EB  mod 2^64
    u64(n) = z ^ (z >> 31)
    f64(n) = (u64(n) >> 11) * 2^-53                     uniform in [0, 1), exact

(identical to ``SplitMix64(s)``'s n-th ``next_u64``/``next_f64``).

Normal k (k = 0, 1, ...) uses draws 2k and 2k+1 (Box-Muller, cosine branch only), in IEEE float64::

    u1 = f64(2k); u2 = f64(2k + 1)
    r  = sqrt(-2.0 * ln_01(1.0 - u1))                   1 - u1 is in [2^-53, 1], so r is finite
    z  = r * cos_2pi(u2)
    normal(k) = float32(z)                              round to nearest even

``sqrt`` is IEEE's (correctly rounded everywhere). ``ln_01`` and ``cos_2pi`` are NOT the C library's (whose
last bit differs between libms and numpy's SIMD loops): they are the fixed polynomials below, evaluated
with separate multiplies and adds in exactly the written order (no fused multiply-add):

``ln_01(x)``, x in [2^-53, 1]::

    (m, e) = frexp(x)                     x = m * 2^e, m in [0.5, 1), exact (bit manipulation)
    if m < SQRT_HALF: m = m * 2.0; e = e - 1          m now in [SQRT_HALF, 2 * SQRT_HALF)
    s = (m - 1.0) / (m + 1.0); w = s * s
    p = C[12]; for j = 11 down to 0: p = p * w + C[j]          C[j] = 1.0 / (2j + 1)  (f64 division)
    ln = float64(e) * LN2 + (2.0 * s) * p

with SQRT_HALF = 0.7071067811865476 (0x3FE6A09E667F3BCD) and LN2 = 0.6931471805599453 (0x3FE62E42FEFA39EF).

``cos_2pi(u)``, u in [0, 1) (octant reduction, all steps exact up to the polynomial)::

    v = 8.0 * u; o = floor(v) (0..7); r = v - o                 r in [0, 1), exact
    if o is even: q = o / 2;       a = r * PI_4;          sign_s = +1
    else:         q = (o + 1) / 2; a = (1.0 - r) * PI_4;  sign_s = -1
    w = a * a
    c = CC[9]; for j = 8 down to 0: c = c * w + CC[j]            CC[j] = (-1)^j / (2j)!
    s = SC[9]; for j = 8 down to 0: s = s * w + SC[j]            SC[j] = (-1)^j / (2j+1)!
    s = s * a                                                    (once, after the loop)
    if sign_s < 0: s = -s                                        (exact negation)
    cos_2pi = [c, -s, -c, s][q mod 4]

with PI_4 = 0.7853981633974483 (0x3FE921FB54442D18); the factorials are accumulated in f64
(``f = 1.0; f = f * n`` for n = 1, 2, ...) and each coefficient is ``sign * (1.0 / f)``.
Both polynomials are accurate to a few units in the last place of float64, far below the float32 cast.

Draw order is the sampler's business (``livegesture.diffsheg.foppas``); a block of ``count`` normals starting
at position ``p`` is ``normal(p) .. normal(p + count - 1)``, laid out row-major into the tensor it fills.
"""
from __future__ import annotations

import math

import numpy as np

from ..sampling import GOLDEN, MASK64, SplitMix64

SQRT_HALF = 0.7071067811865476
LN2 = 0.6931471805599453
PI_4 = 0.7853981633974483
assert SQRT_HALF.hex() == "0x1.6a09e667f3bcdp-1" and LN2.hex() == "0x1.62e42fefa39efp-1"
assert PI_4.hex() == "0x1.921fb54442d18p-1"

LN_COEF = [1.0 / (2 * j + 1) for j in range(13)]


def _taylor_coefs():
    fact, facts = 1.0, [1.0]
    for n in range(1, 20):
        fact = fact * n
        facts.append(fact)
    cos_c = [(-1.0 if j % 2 else 1.0) * (1.0 / facts[2 * j]) for j in range(10)]
    sin_c = [(-1.0 if j % 2 else 1.0) * (1.0 / facts[2 * j + 1]) for j in range(10)]
    return cos_c, sin_c


COS_COEF, SIN_COEF = _taylor_coefs()


# ----------------------------------------------------------------------------- scalar reference

def ln_01(x: float) -> float:
    m, e = math.frexp(x)
    if m < SQRT_HALF:
        m = m * 2.0
        e = e - 1
    s = (m - 1.0) / (m + 1.0)
    w = s * s
    p = LN_COEF[12]
    for j in range(11, -1, -1):
        p = p * w + LN_COEF[j]
    return float(e) * LN2 + (2.0 * s) * p


def cos_2pi(u: float) -> float:
    v = 8.0 * u
    o = int(math.floor(v))
    r = v - o
    if o % 2 == 0:
        q, a, sign = o // 2, r * PI_4, 1.0
    else:
        q, a, sign = (o + 1) // 2, (1.0 - r) * PI_4, -1.0
    w = a * a
    c = COS_COEF[9]
    for j in range(8, -1, -1):
        c = c * w + COS_COEF[j]
    s = SIN_COEF[9]
    for j in range(8, -1, -1):
        s = s * w + SIN_COEF[j]
    s = sign * (s * a)
    return (c, -s, -c, s)[q % 4]


def normal_scalar(seed: int, k: int) -> np.float32:
    """Normal k of the stream with this seed (the scalar definition; slow, for tests)."""
    g = SplitMix64((int(seed) + 2 * int(k) * GOLDEN) & MASK64)   # state before draw 2k
    u1, u2 = g.next_f64(), g.next_f64()
    r = math.sqrt(-2.0 * ln_01(1.0 - u1))
    return np.float32(r * cos_2pi(u2))


# ----------------------------------------------------------------------------- vectorised (numpy)

def _u64(seed: int, n: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        z = np.uint64(int(seed) & MASK64) + (n + np.uint64(1)) * np.uint64(GOLDEN)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def _f64(u: np.ndarray) -> np.ndarray:
    return (u >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def ln_01_vec(x: np.ndarray) -> np.ndarray:
    m, e = np.frexp(x)
    low = m < SQRT_HALF
    m[low] *= 2.0
    e[low] -= 1
    s = (m - 1.0) / (m + 1.0)
    w = s * s
    p = np.full_like(s, LN_COEF[12])
    for j in range(11, -1, -1):     # in-place Horner: the same IEEE operations as the scalar loop
        p *= w
        p += LN_COEF[j]
    s *= 2.0
    p *= s
    out = e.astype(np.float64)
    out *= LN2
    out += p
    return out


def cos_2pi_vec(u: np.ndarray) -> np.ndarray:
    v = 8.0 * u
    o = np.floor(v)
    r = v - o
    o = o.astype(np.int64)
    odd = (o & 1) == 1
    q = ((o + odd) >> 1) & 3
    a = np.where(odd, 1.0 - r, r)
    a *= PI_4
    w = a * a
    c = np.full_like(a, COS_COEF[9])
    sn = np.full_like(a, SIN_COEF[9])
    for j in range(8, -1, -1):
        c *= w
        c += COS_COEF[j]
        sn *= w
        sn += SIN_COEF[j]
    sn *= a
    np.negative(sn, out=sn, where=odd)
    # [c, -s, -c, s][q]: the sine for odd q, negated for q = 1 and 2
    out = np.where((q & 1) == 1, sn, c)
    np.negative(out, out=out, where=(q == 1) | (q == 2))
    return out


def normals(seed: int, position: int, count: int) -> np.ndarray:
    """Normals ``position .. position + count - 1`` of the stream with this seed, float32 (count,)."""
    if count < 0 or position < 0:
        raise ValueError(f"noise: position {position} and count {count} must be >= 0")
    k = np.arange(count, dtype=np.uint64) + np.uint64(position)
    u1 = _f64(_u64(seed, 2 * k))
    u2 = _f64(_u64(seed, 2 * k + np.uint64(1)))
    r = np.sqrt(-2.0 * ln_01_vec(1.0 - u1))
    return (r * cos_2pi_vec(u2)).astype(np.float32)


class NoiseStream:
    """A stream's Gaussian noise: ``take(shape)`` returns the next normals row-major and advances
    ``position`` (the PRNG state carried between windows)."""

    def __init__(self, seed: int, position: int = 0):
        self.seed, self.position = int(seed), int(position)

    def take(self, shape) -> np.ndarray:
        n = int(np.prod(shape))
        out = normals(self.seed, self.position, n).reshape(shape)
        self.position += n
        return out

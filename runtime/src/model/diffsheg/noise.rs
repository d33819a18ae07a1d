//! Portable Gaussian noise for DiffSHEG sampling, bit-identical to `python/livegesture/diffsheg/noise.py`
//! (the normative definition; the manifest's `noise.definition` holds its text).
//!
//! Every normal is a pure function of `(seed, index)`, so a stream's PRNG state is one integer, the
//! number of normals drawn so far (`noise_position`).
//!
//! - Uniforms: the counter form of SplitMix64 ([`crate::sampling::SplitMix64`]): draw `n` of seed `s` is
//!   the mix of `s + (n + 1) * 0x9E3779B97F4A7C15`, `f64 = (u64 >> 11) * 2^-53`.
//! - Normal `k` (Box-Muller, cosine branch, IEEE f64): `u1 = f64(2k)`, `u2 = f64(2k + 1)`,
//!   `r = sqrt(-2 * ln_01(1 - u1))`, `z = r * cos_2pi(u2)`, rounded to f32 (nearest even).
//! - `ln_01` and `cos_2pi` are the project's own polynomials ([`ln_01`], [`cos_2pi`]), not libm's: a
//!   fixed Horner order with separate multiplies and adds (Rust never fuses `a * b + c` on its own).

use crate::sampling::SplitMix64;

const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;
/// `0x3FE6A09E667F3BCD` = 0.7071067811865476.
const SQRT_HALF: f64 = std::f64::consts::FRAC_1_SQRT_2;
/// `0x3FE62E42FEFA39EF` = 0.6931471805599453.
const LN2: f64 = std::f64::consts::LN_2;
/// `0x3FE921FB54442D18` = 0.7853981633974483.
const PI_4: f64 = std::f64::consts::FRAC_PI_4;

/// `1 / (2j + 1)` for j = 0..12 (f64 division), the atanh series of [`ln_01`].
fn ln_coefs() -> &'static [f64; 13] {
    static C: std::sync::OnceLock<[f64; 13]> = std::sync::OnceLock::new();
    C.get_or_init(|| std::array::from_fn(|j| 1.0 / (2 * j + 1) as f64))
}

/// Taylor coefficients `(-1)^j / (2j)!` (cosine) and `(-1)^j / (2j+1)!` (sine), j = 0..9, with the
/// factorials accumulated in f64 (`f = f * n`).
fn taylor_coefs() -> &'static ([f64; 10], [f64; 10]) {
    static C: std::sync::OnceLock<([f64; 10], [f64; 10])> = std::sync::OnceLock::new();
    C.get_or_init(|| {
        let mut facts = [1.0f64; 20];
        let mut f = 1.0f64;
        for (n, slot) in facts.iter_mut().enumerate().skip(1) {
            f *= n as f64;
            *slot = f;
        }
        let sign = |j: usize| if j % 2 == 1 { -1.0 } else { 1.0 };
        (
            std::array::from_fn(|j| sign(j) * (1.0 / facts[2 * j])),
            std::array::from_fn(|j| sign(j) * (1.0 / facts[2 * j + 1])),
        )
    })
}

/// `(m, e)` with `x = m * 2^e`, `m` in `[0.5, 1)`, for a positive normal `x` (exact, bit manipulation).
fn frexp(x: f64) -> (f64, i32) {
    let bits = x.to_bits();
    let exp = ((bits >> 52) & 0x7ff) as i32;
    let m = f64::from_bits((bits & !(0x7ffu64 << 52)) | (1022u64 << 52));
    (m, exp - 1022)
}

/// The natural log for `x` in `[2^-53, 1]`: frexp reduction, then `2 s * sum(w^j / (2j+1))` with
/// `s = (m - 1) / (m + 1)`, `w = s^2`, 13 terms in Horner order.
pub fn ln_01(x: f64) -> f64 {
    debug_assert!((f64::EPSILON / 2.0..=1.0).contains(&x));
    let (mut m, mut e) = frexp(x);
    if m < SQRT_HALF {
        m *= 2.0;
        e -= 1;
    }
    let s = (m - 1.0) / (m + 1.0);
    let w = s * s;
    let c = ln_coefs();
    let mut p = c[12];
    for j in (0..12).rev() {
        p = p * w + c[j];
    }
    e as f64 * LN2 + (2.0 * s) * p
}

/// `cos(2 pi u)` for `u` in `[0, 1)`: octant reduction, then 10-term Taylor series of cos and sin.
pub fn cos_2pi(u: f64) -> f64 {
    let v = 8.0 * u;
    let of = v.floor();
    let r = v - of;
    let o = of as i64;
    let (q, a, negate) = if o % 2 == 0 {
        (o / 2, r * PI_4, false)
    } else {
        ((o + 1) / 2, (1.0 - r) * PI_4, true)
    };
    let w = a * a;
    let (cc, sc) = taylor_coefs();
    let mut c = cc[9];
    for j in (0..9).rev() {
        c = c * w + cc[j];
    }
    let mut s = sc[9];
    for j in (0..9).rev() {
        s = s * w + sc[j];
    }
    s *= a;
    if negate {
        s = -s;
    }
    match q.rem_euclid(4) {
        0 => c,
        1 => -s,
        2 => -c,
        _ => s,
    }
}

/// Uniform draw `n` of the stream with `seed`, in `[0, 1)`.
fn uniform(seed: u64, n: u64) -> f64 {
    SplitMix64::new(seed.wrapping_add(n.wrapping_mul(GOLDEN))).next_f64()
}

/// Normal `k` of the stream with `seed`.
pub fn normal(seed: u64, k: u64) -> f32 {
    let u1 = uniform(seed, 2 * k);
    let u2 = uniform(seed, 2 * k + 1);
    let r = (-2.0 * ln_01(1.0 - u1)).sqrt();
    (r * cos_2pi(u2)) as f32
}

/// Fills `out` with normals `position .. position + out.len() - 1`.
pub fn fill_normals(seed: u64, position: u64, out: &mut [f32]) {
    for (i, o) in out.iter_mut().enumerate() {
        *o = normal(seed, position + i as u64);
    }
}

/// A stream's noise: the seed and the number of normals drawn so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NoiseStream {
    /// The stream's seed.
    pub seed: u64,
    /// Normals drawn so far (`noise_position` in the manifest's `foppas.state`).
    pub position: u64,
}

impl NoiseStream {
    /// A stream at position 0.
    pub fn new(seed: u64) -> Self {
        Self { seed, position: 0 }
    }

    /// The next `count` normals (row-major into whatever tensor they fill); advances the position.
    pub fn take(&mut self, count: usize) -> Vec<f32> {
        let mut v = vec![0f32; count];
        self.take_into(&mut v);
        v
    }

    /// Like [`NoiseStream::take`], into `out`.
    pub fn take_into(&mut self, out: &mut [f32]) {
        fill_normals(self.seed, self.position, out);
        self.position += out.len() as u64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sha2::{Digest, Sha256};

    fn digest(v: &[f32]) -> String {
        let mut h = Sha256::new();
        for x in v {
            h.update(x.to_le_bytes());
        }
        hex::encode(h.finalize())
    }

    #[test]
    fn pinned_values_of_the_contract() {
        // docs/bundle.md: seed 0 gives -0x1.e247d2p+0, 0x1.d2241cp-3, -0x1.c5813ap-3, 0x1.55aeaep-4
        let got: Vec<u32> = NoiseStream::new(0)
            .take(4)
            .iter()
            .map(|x| x.to_bits())
            .collect();
        assert_eq!(got, [0xbff123e9, 0x3e69120e, 0xbe62c09d, 0x3daad757]);
    }

    #[test]
    fn polynomials_match_python_bit_for_bit() {
        // values printed by python/livegesture/diffsheg/noise.py (ln_01, cos_2pi)
        assert_eq!(ln_01(2f64.powi(-53)).to_bits(), 0xc0425e4f7b2737fa);
        assert_eq!(ln_01(0.3).to_bits(), 0xbff34378fcbda720);
        assert_eq!(ln_01(1.0).to_bits(), 0);
        assert_eq!(cos_2pi(0.37).to_bits(), 0xbfe5e7cf55112013);
        assert_eq!(cos_2pi(0.999).to_bits(), 0x3fefffd69aa0b99d);
        assert_eq!(cos_2pi(0.0).to_bits(), 0x3ff0000000000000);
        assert_eq!(cos_2pi(0.5625).to_bits(), 0xbfed906bcf328d46);
        assert_eq!(SQRT_HALF.to_bits(), 0x3FE6A09E667F3BCD);
        assert_eq!(LN2.to_bits(), 0x3FE62E42FEFA39EF);
        assert_eq!(PI_4.to_bits(), 0x3FE921FB54442D18);
    }

    /// Long runs against `livegesture.diffsheg.noise.normals(seed, position, count)`: sha256 of the
    /// little-endian f32 bytes, and the first, middle and last values (generated with the Python
    /// reference at commit b4cf56f).
    #[test]
    fn long_runs_match_python_bit_for_bit() {
        let cases: [(u64, u64, usize, &str, [u32; 3]); 4] = [
            (
                0,
                0,
                1_000_000,
                "a4d24905c4884a613f8a4e706d0d710cfa8216b61e0518604c4d9d23d23b09cc",
                [0xbff123e9, 0x3fc77776, 0xc00106d3],
            ),
            (
                1234,
                10200,
                64600,
                "9ab74bb014cb5222a979fbd8aba03980d46807f1686b0cf3080e57b5ad82a1bc",
                [0x3e8d317e, 0xbf944c79, 0xbf4874ae],
            ),
            (
                u64::MAX,
                (1 << 40) + 3,
                200_000,
                "d3f67af1118e57aa3e6c0011600b23e09d090858f7115288d5ffb9456bc6fd67",
                [0xbf7da300, 0xbf14b77a, 0x3f03a26a],
            ),
            (
                42,
                123_456_789,
                300_001,
                "ca91755020c08e2c7f19d20a48c17e8c7d0eb85ccf0e500ffe6b70329c2a51f5",
                [0xbdadbe91, 0xbce6c574, 0x3eb9c37e],
            ),
        ];
        for (seed, pos, count, sha, picks) in cases {
            let mut s = NoiseStream {
                seed,
                position: pos,
            };
            let v = s.take(count);
            assert_eq!(s.position, pos + count as u64);
            let got = [v[0], v[count / 2], v[count - 1]].map(f32::to_bits);
            assert_eq!(got, picks, "seed {seed} position {pos}");
            assert_eq!(digest(&v), sha, "seed {seed} position {pos} count {count}");
        }
    }

    #[test]
    fn blocks_concatenate_and_a_changed_bit_changes_the_digest() {
        let mut a = NoiseStream::new(7);
        let mut v = a.take(10);
        v.extend(a.take(7));
        assert_eq!(v, NoiseStream::new(7).take(17));
        let d = digest(&v);
        v[3] = f32::from_bits(v[3].to_bits() ^ 1);
        assert_ne!(digest(&v), d);
    }
}

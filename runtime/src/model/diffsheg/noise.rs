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
///
/// Bit-identical to [`normal`] element by element: the same IEEE operations in the same order, only
/// computed [`LANES`] normals at a time so the compiler can keep them in vector registers (every
/// operation is an exactly rounded IEEE one, and Rust never contracts `a * b + c`, so a lane computes
/// what the scalar code computes). On x86-64 the block kernel is compiled a second and third time with
/// AVX2 and AVX-512 enabled and picked at run time; elsewhere (WebAssembly, aarch64) the portable one
/// runs. `fast_path_equals_the_definition` holds it to [`normal`].
pub fn fill_normals(seed: u64, position: u64, out: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512dq") {
            // SAFETY: the CPU has the features the function is compiled for (checked just above).
            return unsafe { fill_normals_avx512(seed, position, out) };
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: as above.
            return unsafe { fill_normals_avx2(seed, position, out) };
        }
    }
    fill_normals_portable(seed, position, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq,avx512vl,avx2")]
unsafe fn fill_normals_avx512(seed: u64, position: u64, out: &mut [f32]) {
    fill_normals_portable(seed, position, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn fill_normals_avx2(seed: u64, position: u64, out: &mut [f32]) {
    fill_normals_portable(seed, position, out)
}

/// Normals computed together by the block kernel of [`fill_normals`].
pub const LANES: usize = 8;

#[inline(always)]
fn fill_normals_portable(seed: u64, position: u64, out: &mut [f32]) {
    let lc = ln_coefs();
    let (cc, sc) = taylor_coefs();
    let mut chunks = out.chunks_exact_mut(LANES);
    let mut k = position;
    for block in &mut chunks {
        normals_block(
            seed,
            k,
            lc,
            cc,
            sc,
            block.try_into().expect("LANES-sized chunk"),
        );
        k = k.wrapping_add(LANES as u64);
    }
    for (i, o) in chunks.into_remainder().iter_mut().enumerate() {
        *o = normal(seed, k.wrapping_add(i as u64));
    }
}

/// `mix(seed + (n + 1) * GOLDEN) >> 11` as f64 times 2^-53: [`uniform`] without the generator struct.
#[inline(always)]
fn uniform_bits(seed: u64, n: u64) -> f64 {
    let mut z = seed.wrapping_add(n.wrapping_add(1).wrapping_mul(GOLDEN));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
}

/// Normals `k0 .. k0 + LANES - 1`: [`normal`], [`ln_01`] and [`cos_2pi`] written lane by lane.
// index loops over several fixed-size arrays: the form the vectoriser turns into lane-wise code
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn normals_block(
    seed: u64,
    k0: u64,
    lc: &[f64; 13],
    cc: &[f64; 10],
    sc: &[f64; 10],
    out: &mut [f32; LANES],
) {
    let mut x = [0f64; LANES];
    let mut u2 = [0f64; LANES];
    for i in 0..LANES {
        let k = k0.wrapping_add(i as u64);
        x[i] = 1.0 - uniform_bits(seed, k.wrapping_mul(2));
        u2[i] = uniform_bits(seed, k.wrapping_mul(2).wrapping_add(1));
    }
    // ln_01(x): frexp, the sqrt(1/2) fold, atanh series
    let mut s = [0f64; LANES];
    let mut e = [0f64; LANES];
    for i in 0..LANES {
        let bits = x[i].to_bits();
        let ex = ((bits >> 52) & 0x7ff) as i32 - 1022;
        let m = f64::from_bits((bits & !(0x7ffu64 << 52)) | (1022u64 << 52));
        let fold = m < SQRT_HALF;
        let m = if fold { m * 2.0 } else { m };
        e[i] = (if fold { ex - 1 } else { ex }) as f64;
        s[i] = (m - 1.0) / (m + 1.0);
    }
    let mut w = [0f64; LANES];
    let mut p = [lc[12]; LANES];
    for i in 0..LANES {
        w[i] = s[i] * s[i];
    }
    for j in (0..12).rev() {
        for i in 0..LANES {
            p[i] = p[i] * w[i] + lc[j];
        }
    }
    let mut r = [0f64; LANES];
    for i in 0..LANES {
        let ln = e[i] * LN2 + (2.0 * s[i]) * p[i];
        r[i] = (-2.0 * ln).sqrt();
    }
    // cos_2pi(u2): octant reduction, Taylor series of cos and sin, quadrant select
    let mut a = [0f64; LANES];
    let mut q = [0i32; LANES];
    let mut neg = [false; LANES];
    for i in 0..LANES {
        let v = 8.0 * u2[i];
        let of = v.floor();
        let rr = v - of;
        let o = of as i32;
        let odd = o & 1 == 1;
        q[i] = if odd { (o + 1) / 2 } else { o / 2 };
        a[i] = if odd { (1.0 - rr) * PI_4 } else { rr * PI_4 };
        neg[i] = odd;
    }
    let mut aw = [0f64; LANES];
    for i in 0..LANES {
        aw[i] = a[i] * a[i];
    }
    let mut c = [cc[9]; LANES];
    let mut sn = [sc[9]; LANES];
    for j in (0..9).rev() {
        for i in 0..LANES {
            c[i] = c[i] * aw[i] + cc[j];
            sn[i] = sn[i] * aw[i] + sc[j];
        }
    }
    for i in 0..LANES {
        let mut si = sn[i] * a[i];
        if neg[i] {
            si = -si;
        }
        let quad = q[i] & 3;
        let base = if quad & 1 == 1 { si } else { c[i] };
        let cos = if quad == 1 || quad == 2 { -base } else { base };
        out[i] = (r[i] * cos) as f32;
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

    /// The block kernel of `fill_normals` (whichever the CPU picks) against the scalar definition
    /// `normal`, on every offset within a block and across seeds and positions that wrap.
    #[test]
    fn fast_path_equals_the_definition() {
        for (seed, pos) in [
            (0u64, 0u64),
            (1, 3),
            (u64::MAX, (1 << 62) - 40),
            (0x9E37_79B9_7F4A_7C15, 1 << 61),
            (42, 123_456_789),
        ] {
            for len in [0usize, 1, 7, 8, 9, 63, 200_003] {
                let mut v = vec![0f32; len];
                fill_normals(seed, pos, &mut v);
                for (i, x) in v.iter().enumerate() {
                    let want = normal(seed, pos.wrapping_add(i as u64));
                    assert_eq!(
                        x.to_bits(),
                        want.to_bits(),
                        "seed {seed} position {pos} + {i}"
                    );
                }
            }
        }
        // the portable kernel too (the one WebAssembly and aarch64 run), whatever this CPU picks
        let mut v = vec![0f32; 50_001];
        fill_normals_portable(5, 77, &mut v);
        for (i, x) in v.iter().enumerate() {
            assert_eq!(
                x.to_bits(),
                normal(5, 77 + i as u64).to_bits(),
                "portable + {i}"
            );
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

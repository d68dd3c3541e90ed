//! Eight Gaussians between memory, one Gaussian after another, and lanes, one field per
//! vector: loads that split `[8, 3]` and `[8, 4]` row-major blocks into their columns, and the
//! 8 × 8 transpose that turns eight field vectors into eight 8-word records.
//!
//! Written lane by lane these compile to one scalar load or store per value plus a
//! store-to-load stall per vector (a third of the projection's time in `perf`); [`Avx2`] does
//! them with in-register shuffles. An implementation is a value (a token): an [`Avx2`] exists
//! only on a CPU with AVX2 ([`Avx2::detect`]), so its safe methods never run AVX2 code where it
//! would fault. The kernels use [`Avx2`] in their AVX2 versions (`multiversion`'s
//! `match_target!`) and [`Plain`] elsewhere; the tests check one against the other.
#![allow(clippy::needless_range_loop)]

use super::lanes::LANES;

/// Moving eight values per field between rows and lanes.
pub trait Transpose: Copy {
    /// Columns of a row-major `[8, 3]` block: `out[c][l] = block[3 l + c]`.
    fn columns3(self, block: &[f32; 3 * LANES]) -> [[f32; LANES]; 3];
    /// Columns of a row-major `[8, 4]` block: `out[c][l] = block[4 l + c]`.
    fn columns4(self, block: &[f32; 4 * LANES]) -> [[f32; LANES]; 4];
    /// The transpose: `out[l][f] = fields[f][l]`.
    fn transpose8(self, fields: &[[f32; LANES]; 8]) -> [[f32; LANES]; 8];
}

/// Plain loops (any target).
#[derive(Debug, Clone, Copy)]
pub struct Plain;

impl Transpose for Plain {
    #[inline(always)]
    fn columns3(self, block: &[f32; 3 * LANES]) -> [[f32; LANES]; 3] {
        let mut out = [[0.0; LANES]; 3];
        for l in 0..LANES {
            for c in 0..3 {
                out[c][l] = block[3 * l + c];
            }
        }
        out
    }

    #[inline(always)]
    fn columns4(self, block: &[f32; 4 * LANES]) -> [[f32; LANES]; 4] {
        let mut out = [[0.0; LANES]; 4];
        for l in 0..LANES {
            for c in 0..4 {
                out[c][l] = block[4 * l + c];
            }
        }
        out
    }

    #[inline(always)]
    fn transpose8(self, fields: &[[f32; LANES]; 8]) -> [[f32; LANES]; 8] {
        let mut out = [[0.0; LANES]; 8];
        for l in 0..LANES {
            for f in 0..8 {
                out[l][f] = fields[f][l];
            }
        }
        out
    }
}

/// AVX2 shuffles: a token that exists only on CPUs with AVX2.
#[cfg(target_arch = "x86_64")]
#[derive(Debug, Clone, Copy)]
pub struct Avx2 {
    _proof: (),
}

#[cfg(target_arch = "x86_64")]
impl Avx2 {
    /// The token, on a CPU with AVX2.
    pub fn detect() -> Option<Self> {
        std::arch::is_x86_feature_detected!("avx2").then_some(Self { _proof: () })
    }
}

#[cfg(target_arch = "x86_64")]
impl Transpose for Avx2 {
    #[inline(always)]
    fn columns3(self, block: &[f32; 3 * LANES]) -> [[f32; LANES]; 3] {
        // SAFETY: an `Avx2` exists only where the CPU has AVX2 (`Avx2::detect`).
        unsafe { avx2::columns3(block) }
    }

    #[inline(always)]
    fn columns4(self, block: &[f32; 4 * LANES]) -> [[f32; LANES]; 4] {
        // SAFETY: as in `columns3`.
        unsafe { avx2::columns4(block) }
    }

    #[inline(always)]
    fn transpose8(self, fields: &[[f32; LANES]; 8]) -> [[f32; LANES]; 8] {
        // SAFETY: as in `columns3`.
        unsafe { avx2::transpose8(fields) }
    }
}

/// The AVX2 bodies: functions that carry the target feature, so that they inline into callers
/// that enable it.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::LANES;
    use std::arch::x86_64::*;

    #[inline]
    #[target_feature(enable = "avx2")]
    fn load(v: &[f32; LANES]) -> __m256 {
        // SAFETY: `v` holds eight f32s.
        unsafe { _mm256_loadu_ps(v.as_ptr()) }
    }

    /// The `K` vectors of eight values of `block`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn parts<const N: usize, const K: usize>(block: &[f32; N]) -> [__m256; K] {
        debug_assert_eq!(N, K * LANES);
        let mut out = [_mm256_setzero_ps(); K];
        for (k, v) in out.iter_mut().enumerate() {
            *v = load(block[LANES * k..LANES * (k + 1)].try_into().expect("8 values"));
        }
        out
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    fn store(v: __m256) -> [f32; LANES] {
        let mut out = [0.0; LANES];
        // SAFETY: `out` holds eight f32s.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        out
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    fn indices(i: [i32; LANES]) -> __m256i {
        _mm256_setr_epi32(i[0], i[1], i[2], i[3], i[4], i[5], i[6], i[7])
    }

    /// Rows `g0 … g7` of three values lie in three vectors as
    /// `[x0 y0 z0 x1 y1 z1 x2 y2] [z2 x3 y3 z3 x4 y4 z4 x5] [y5 z5 x6 y6 z6 x7 y7 z7]`. For each
    /// column the positions it occupies in the three vectors are disjoint, so two blends put
    /// all eight of its values into one vector and one permute sorts them.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub fn columns3(block: &[f32; 3 * LANES]) -> [[f32; LANES]; 3] {
        let [m0, m1, m2] = parts(block);
        // x: m0 at 0, 3, 6; m1 at 1, 4, 7; m2 at 2, 5.
        let x = _mm256_blend_ps::<0b0010_0100>(_mm256_blend_ps::<0b1001_0010>(m0, m1), m2);
        let x = _mm256_permutevar8x32_ps(x, indices([0, 3, 6, 1, 4, 7, 2, 5]));
        // y: m0 at 1, 4, 7; m1 at 2, 5; m2 at 0, 3, 6.
        let y = _mm256_blend_ps::<0b0100_1001>(_mm256_blend_ps::<0b0010_0100>(m0, m1), m2);
        let y = _mm256_permutevar8x32_ps(y, indices([1, 4, 7, 2, 5, 0, 3, 6]));
        // z: m0 at 2, 5; m1 at 0, 3, 6; m2 at 1, 4, 7.
        let z = _mm256_blend_ps::<0b1001_0010>(_mm256_blend_ps::<0b0100_1001>(m0, m1), m2);
        let z = _mm256_permutevar8x32_ps(z, indices([2, 5, 0, 3, 6, 1, 4, 7]));
        [store(x), store(y), store(z)]
    }

    /// Rows of four values, two per vector: interleave pairs of vectors twice (lanes come out
    /// in the order 0, 2, 4, 6, 1, 3, 5, 7), then one permute per column.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub fn columns4(block: &[f32; 4 * LANES]) -> [[f32; LANES]; 4] {
        let [r0, r1, r2, r3] = parts(block);
        let t0 = _mm256_castps_pd(_mm256_unpacklo_ps(r0, r1));
        let t1 = _mm256_castps_pd(_mm256_unpackhi_ps(r0, r1));
        let t2 = _mm256_castps_pd(_mm256_unpacklo_ps(r2, r3));
        let t3 = _mm256_castps_pd(_mm256_unpackhi_ps(r2, r3));
        let order = indices([0, 4, 1, 5, 2, 6, 3, 7]);
        [
            store(_mm256_permutevar8x32_ps(_mm256_castpd_ps(_mm256_unpacklo_pd(t0, t2)), order)),
            store(_mm256_permutevar8x32_ps(_mm256_castpd_ps(_mm256_unpackhi_pd(t0, t2)), order)),
            store(_mm256_permutevar8x32_ps(_mm256_castpd_ps(_mm256_unpacklo_pd(t1, t3)), order)),
            store(_mm256_permutevar8x32_ps(_mm256_castpd_ps(_mm256_unpackhi_pd(t1, t3)), order)),
        ]
    }

    /// The usual 8 × 8 transpose: interleave pairs, then quadruples, then swap 128-bit halves.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub fn transpose8(fields: &[[f32; LANES]; 8]) -> [[f32; LANES]; 8] {
        let r: [__m256; 8] = parts::<64, 8>(fields.as_flattened().try_into().expect("64 values"));
        let t = [
            _mm256_unpacklo_ps(r[0], r[1]),
            _mm256_unpackhi_ps(r[0], r[1]),
            _mm256_unpacklo_ps(r[2], r[3]),
            _mm256_unpackhi_ps(r[2], r[3]),
            _mm256_unpacklo_ps(r[4], r[5]),
            _mm256_unpackhi_ps(r[4], r[5]),
            _mm256_unpacklo_ps(r[6], r[7]),
            _mm256_unpackhi_ps(r[6], r[7]),
        ];
        let s = [
            _mm256_shuffle_ps::<0x44>(t[0], t[2]),
            _mm256_shuffle_ps::<0xEE>(t[0], t[2]),
            _mm256_shuffle_ps::<0x44>(t[1], t[3]),
            _mm256_shuffle_ps::<0xEE>(t[1], t[3]),
            _mm256_shuffle_ps::<0x44>(t[4], t[6]),
            _mm256_shuffle_ps::<0xEE>(t[4], t[6]),
            _mm256_shuffle_ps::<0x44>(t[5], t[7]),
            _mm256_shuffle_ps::<0xEE>(t[5], t[7]),
        ];
        [
            store(_mm256_permute2f128_ps::<0x20>(s[0], s[4])),
            store(_mm256_permute2f128_ps::<0x20>(s[1], s[5])),
            store(_mm256_permute2f128_ps::<0x20>(s[2], s[6])),
            store(_mm256_permute2f128_ps::<0x20>(s[3], s[7])),
            store(_mm256_permute2f128_ps::<0x31>(s[0], s[4])),
            store(_mm256_permute2f128_ps::<0x31>(s[1], s[5])),
            store(_mm256_permute2f128_ps::<0x31>(s[2], s[6])),
            store(_mm256_permute2f128_ps::<0x31>(s[3], s[7])),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block<const N: usize>() -> [f32; N] {
        std::array::from_fn(|i| i as f32 * 1.5 - 7.0)
    }

    #[test]
    fn plain_moves_each_value_where_the_docs_say() {
        let b3 = block::<24>();
        let c3 = Plain.columns3(&b3);
        assert_eq!((c3[1][2], c3[2][7]), (b3[7], b3[23]));
        let b4 = block::<32>();
        let c4 = Plain.columns4(&b4);
        assert_eq!((c4[0][1], c4[3][6]), (b4[4], b4[27]));
        let fields: [[f32; 8]; 8] = std::array::from_fn(|f| std::array::from_fn(|l| (10 * f + l) as f32));
        let t = Plain.transpose8(&fields);
        assert_eq!((t[2][5], t[7][0]), (52.0, 7.0));
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_equals_plain() {
        let Some(avx2) = Avx2::detect() else {
            eprintln!("skipping the AVX2 check: this CPU has no AVX2");
            return;
        };
        let b3 = block::<24>();
        assert_eq!(avx2.columns3(&b3), Plain.columns3(&b3));
        let b4 = block::<32>();
        assert_eq!(avx2.columns4(&b4), Plain.columns4(&b4));
        let fields: [[f32; 8]; 8] = std::array::from_fn(|f| std::array::from_fn(|l| (10 * f + l) as f32));
        assert_eq!(avx2.transpose8(&fields), Plain.transpose8(&fields));
    }
}

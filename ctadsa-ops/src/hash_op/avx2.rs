//! AVX2 versions of the hash encoding's forward kernels: eight points per block, one vector lane
//! per point, the table reads as gathers. Every value is computed with the same operations in
//! the same order as the scalar kernels of [`super::level`] (no fused multiply-adds), so the
//! results are the same bit for bit (`tests::avx2_kernels_equal_the_scalar_kernels`); points
//! after the last whole block go through the scalar kernels.
//!
//! Only called after `is_x86_feature_detected!` found AVX2 and FMA (`cpu.rs`).
#![cfg(target_arch = "x86_64")]

use std::arch::x86_64::*;

use super::config::{HASH_P1, HASH_P2};
use super::level::{Level, encode_level_jacobian_scalar, encode_level_scalar};

/// Points per block.
const LANES: usize = 8;

/// Corner rows (table rows, the level's first row included), per-axis factors and axis scales
/// of eight points: what `cpu::corner_rows` gives each point.
struct Block {
    /// Corner `k` = `x + 2y + 4z`.
    rows: [__m256i; 8],
    /// `[1 − frac_d, frac_d]` per axis `d`.
    a: [[__m256; 2]; 3],
    /// `∂frac_d/∂u_d`: the resolution, 0 where the point was clamped.
    s: [__m256; 3],
}

/// The corners of the eight points of `u` (`[24]`, point-major).
#[target_feature(enable = "avx2,fma")]
fn block(lv: &Level, mask: i64, u: &[f32]) -> Block {
    assert!(u.len() >= 3 * LANES);
    let res = _mm256_set1_ps(lv.res);
    let zero = _mm256_setzero_ps();
    let top = _mm256_set1_ps(1.0 - 1e-6);
    let stride3 = _mm256_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21);
    let one_i = _mm256_set1_epi32(1);
    let factor = if lv.dense { [1, lv.r1, lv.r1 * lv.r1] } else { [1, HASH_P1, HASH_P2] };
    let mut a = [[zero; 2]; 3];
    let mut s = [zero; 3];
    let mut term = [[_mm256_setzero_si256(); 2]; 3];
    for d in 0..3 {
        // SAFETY: lanes read u[3·l + d] for l < 8, inside the 24 values asserted above.
        let v = unsafe { _mm256_i32gather_ps::<4>(u.as_ptr().add(d), stride3) };
        let c = _mm256_min_ps(_mm256_max_ps(v, zero), top);
        s[d] = _mm256_and_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(c, v), res);
        let p = _mm256_mul_ps(c, res);
        let f = _mm256_floor_ps(p);
        let cell = _mm256_cvttps_epi32(f);
        let frac = _mm256_sub_ps(p, f);
        a[d] = [_mm256_sub_ps(_mm256_set1_ps(1.0), frac), frac];
        // Cells are below 2¹² and the factors below 2¹⁹, so every term fits in i32.
        let fd = _mm256_set1_epi32(factor[d] as i32);
        term[d] = [_mm256_mullo_epi32(cell, fd), _mm256_mullo_epi32(_mm256_add_epi32(cell, one_i), fd)];
    }
    let base = _mm256_set1_epi32(lv.base as i32);
    let mask = _mm256_set1_epi32(mask as i32);
    let rows = std::array::from_fn(|k| {
        let (tx, ty, tz) = (term[0][k & 1], term[1][(k >> 1) & 1], term[2][k >> 2]);
        let idx = if lv.dense {
            _mm256_add_epi32(_mm256_add_epi32(tx, ty), tz)
        } else {
            _mm256_and_si256(_mm256_xor_si256(_mm256_xor_si256(tx, ty), tz), mask)
        };
        _mm256_add_epi32(base, idx)
    });
    Block { rows, a, s }
}

/// The trilinear weights `a[0][x]·a[1][y]·a[2][z]` of the eight corners.
#[target_feature(enable = "avx2,fma")]
fn weights(a: &[[__m256; 2]; 3]) -> [__m256; 8] {
    std::array::from_fn(|k| _mm256_mul_ps(_mm256_mul_ps(a[0][k & 1], a[1][(k >> 1) & 1]), a[2][k >> 2]))
}

/// One feature's corner values, read from `t` (the feature's `[R]` table).
#[target_feature(enable = "avx2,fma")]
fn corner_values(t: &[f32], rows: &[__m256i; 8]) -> [__m256; 8] {
    std::array::from_fn(|k| {
        // SAFETY: corner rows are below the table's row count `R = t.len()` (cells clamped to
        // the grid, dense indices below (r+1)³ and hashed ones masked to the level's rows).
        unsafe { _mm256_i32gather_ps::<4>(t.as_ptr(), rows[k]) }
    })
}

/// `Σ_k w[k]·v[k]` in corner order, as `cpu::dot8`.
#[target_feature(enable = "avx2,fma")]
fn dot8(w: &[__m256; 8], v: &[__m256; 8]) -> __m256 {
    let mut sum = _mm256_mul_ps(w[0], v[0]);
    for k in 1..8 {
        sum = _mm256_add_ps(sum, _mm256_mul_ps(w[k], v[k]));
    }
    sum
}

/// The blocks of `u` (`[8·3]` each, whole blocks only), with their index and corners.
#[target_feature(enable = "avx2,fma")]
fn for_each_block(level: &Level, mask: i64, u: &[f32], mut body: impl FnMut(usize, &Block)) {
    for (i, ub) in u.chunks_exact(3 * LANES).enumerate() {
        body(i, &block(level, mask, ub));
    }
}

fn lanes(v: __m256) -> [f32; LANES] {
    // SAFETY: `__m256` and `[f32; 8]` have the same size, and every bit pattern is valid for both.
    unsafe { std::mem::transmute::<__m256, [f32; LANES]>(v) }
}

/// `cpu::encode_level`, eight points at a time.
#[target_feature(enable = "avx2,fma")]
pub(super) fn encode_level(level: &Level, mask: i64, u: &[f32], tables: &[f32], stride: usize, f_n: usize) -> Vec<f32> {
    let n = u.len() / 3;
    let whole = n / LANES * LANES;
    let mut o = vec![0.0f32; n * f_n];
    for_each_block(level, mask, &u[..3 * whole], |i, b| {
        let ob = &mut o[i * LANES * f_n..(i + 1) * LANES * f_n];
        let w = weights(&b.a);
        for f in 0..f_n {
            let value = lanes(dot8(&w, &corner_values(&tables[f * stride..(f + 1) * stride], &b.rows)));
            for (l, v) in value.iter().enumerate() {
                ob[l * f_n + f] = *v;
            }
        }
    });
    let tail = encode_level_scalar(level, mask, &u[3 * whole..], tables, stride, f_n);
    o[whole * f_n..].copy_from_slice(&tail);
    o
}

/// `cpu::encode_level_jacobian`, eight points at a time.
#[target_feature(enable = "avx2,fma")]
pub(super) fn encode_level_jacobian(
    level: &Level,
    mask: i64,
    u: &[f32],
    tables: &[f32],
    stride: usize,
    f_n: usize,
    jac: &mut [f32],
) -> Vec<f32> {
    let n = u.len() / 3;
    let whole = n / LANES * LANES;
    let mut o = vec![0.0f32; n * f_n];
    for_each_block(level, mask, &u[..3 * whole], |i, b| {
        let ob = &mut o[i * LANES * f_n..(i + 1) * LANES * f_n];
        let jb = &mut jac[i * LANES * f_n * 3..(i + 1) * LANES * f_n * 3];
        let w = weights(&b.a);
        let (a, s) = (&b.a, &b.s);
        // Edge weights as in the scalar kernel: along x the factors of y and z, and so on.
        let edge = |d0: usize, d1: usize, d: usize| -> [__m256; 4] {
            std::array::from_fn(|e| _mm256_mul_ps(_mm256_mul_ps(a[d0][e & 1], a[d1][e >> 1]), s[d]))
        };
        let (ex, ey, ez) = (edge(1, 2, 0), edge(0, 2, 1), edge(0, 1, 2));
        for f in 0..f_n {
            let v = corner_values(&tables[f * stride..(f + 1) * stride], &b.rows);
            let value = lanes(dot8(&w, &v));
            let (mut jx, mut jy, mut jz) = (_mm256_setzero_ps(), _mm256_setzero_ps(), _mm256_setzero_ps());
            for e in 0..4 {
                let (p, q) = (e & 1, e >> 1);
                jx = _mm256_add_ps(jx, _mm256_mul_ps(ex[e], _mm256_sub_ps(v[2 * e + 1], v[2 * e])));
                jy = _mm256_add_ps(jy, _mm256_mul_ps(ey[e], _mm256_sub_ps(v[p + 4 * q + 2], v[p + 4 * q])));
                jz = _mm256_add_ps(jz, _mm256_mul_ps(ez[e], _mm256_sub_ps(v[p + 2 * q + 4], v[p + 2 * q])));
            }
            let (jx, jy, jz) = (lanes(jx), lanes(jy), lanes(jz));
            for l in 0..LANES {
                ob[l * f_n + f] = value[l];
                let j = (l * f_n + f) * 3;
                jb[j..j + 3].copy_from_slice(&[jx[l], jy[l], jz[l]]);
            }
        }
    });
    let tail =
        encode_level_jacobian_scalar(level, mask, &u[3 * whole..], tables, stride, f_n, &mut jac[whole * f_n * 3..]);
    o[whole * f_n..].copy_from_slice(&tail);
    o
}

#[cfg(test)]
mod tests {
    use super::super::level::{Level, levels};
    use super::*;
    use crate::hash_op::HashGridConfig;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Every level kernel against its scalar version on the same inputs, bit for bit: dense and
    /// hashed levels, points outside `[0, 1]³` (clamped) and a point count that leaves a tail.
    #[test]
    fn avx2_kernels_equal_the_scalar_kernels() {
        if !(is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")) {
            assert!(
                !std::env::var("CTADSA_REQUIRE_AVX2").is_ok_and(|v| v == "1"),
                "CTADSA_REQUIRE_AVX2=1 but this CPU has no AVX2 + FMA"
            );
            eprintln!("skipped: this CPU has no AVX2 + FMA, so the AVX2 kernels never run here");
            return;
        }
        let c = HashGridConfig {
            levels: 6,
            features: 2,
            log2_table: 10,
            base_resolution: 4.0,
            growth: 1.8,
            ..Default::default()
        };
        let lv: Vec<Level> = levels(&c);
        assert!(lv.iter().any(|l| l.dense) && lv.iter().any(|l| !l.dense));
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let n = 1003;
        let u: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-0.05f32..1.05)).collect();
        let tables: Vec<f32> = (0..c.features * c.rows()).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let (stride, f_n, mask) = (c.rows(), c.features, c.table_size() - 1);
        for (l, level) in lv.iter().enumerate() {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            let fast = unsafe { encode_level(level, mask, &u, &tables, stride, f_n) };
            assert_eq!(fast, encode_level_scalar(level, mask, &u, &tables, stride, f_n), "encode, level {l}");
            let (mut jac_fast, mut jac_slow) = (vec![0.0; n * f_n * 3], vec![0.0; n * f_n * 3]);
            // SAFETY: as above.
            let fast = unsafe { encode_level_jacobian(level, mask, &u, &tables, stride, f_n, &mut jac_fast) };
            let slow = encode_level_jacobian_scalar(level, mask, &u, &tables, stride, f_n, &mut jac_slow);
            assert_eq!((fast, jac_fast), (slow, jac_slow), "encode with Jacobian, level {l}");
        }
    }
}

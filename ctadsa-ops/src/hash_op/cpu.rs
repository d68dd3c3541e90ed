//! CPU kernels of the hash encoding (host slices): forward, and backward to the positions and
//! the tables. The table gradient is a scatter-add with one task per level (deterministic).

use std::mem::MaybeUninit;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::config::HashGridConfig;
use super::level::{
    Level, corner_rows, corner_weights, corners, encode_level_jacobian_scalar, encode_level_scalar, levels,
};
use crate::par_buffer::zeroed;

/// The table gradient `[F · R]` (rows `stride` per feature) split per level into that level's
/// per-feature row slices, in feature order: what one level's task may write.
fn split_by_level<'a>(lv: &[Level], stride: usize, grad_tables: &'a mut [f32]) -> Vec<Vec<&'a mut [f32]>> {
    let mut by_level: Vec<Vec<&mut [f32]>> = lv.iter().map(|_| Vec::new()).collect();
    for feature in grad_tables.chunks_mut(stride) {
        let mut rest = feature;
        for (l, level) in lv.iter().enumerate() {
            let (rows, tail) = rest.split_at_mut(level.rows);
            by_level[l].push(rows);
            rest = tail;
        }
    }
    by_level
}

/// Encodes `u` (`[N·3]`) with `tables` (`[F · R]`, feature-major): `[N · L·F]`.
///
/// Level-major: one task per level reads that level's `F × T` table slice for every point, so
/// the slice (4 MB at T = 2¹⁹) stays in cache while the points' corners hit it; a point-major
/// loop would walk all levels' tables (67 MB) for every point and miss on nearly every corner.
pub fn encode(c: &HashGridConfig, u: &[f32], tables: &[f32]) -> Vec<f32> {
    let lv = levels(c);
    let (l_n, f_n) = (c.levels, c.features);
    let stride = c.rows();
    let mask = c.table_size() - 1;
    let n = u.len() / 3;
    // [L][N·F], then transposed to [N][L·F].
    let by_level: Vec<Vec<f32>> =
        lv.par_iter().map(|level| encode_level(level, mask, u, tables, stride, f_n)).collect();
    let mut out = vec![0.0f32; n * l_n * f_n];
    out.par_chunks_mut(l_n * f_n).enumerate().for_each(|(i, o)| {
        for (l, level) in by_level.iter().enumerate() {
            o[l * f_n..(l + 1) * f_n].copy_from_slice(&level[i * f_n..(i + 1) * f_n]);
        }
    });
    out
}

/// Gradients of `Σ grad · encode(u, tables)` with respect to `u` (`[N·3]`) and `tables`
/// (written into `grad_tables`, `[F · R]`, which must be zero on entry).
///
/// One task per level (level-major, as [`encode`]): it scatters the level's table gradient —
/// a level's rows have no other writer, so there are no atomics and each entry sums its points in
/// index order, the same result for any thread count — and collects the level's share of the
/// position gradient, which is then summed over levels in level order per point.
pub fn encode_backward_into(
    c: &HashGridConfig,
    u: &[f32],
    tables: &[f32],
    grad: &[f32],
    grad_tables: &mut [f32],
) -> Vec<f32> {
    let lv = levels(c);
    let l_n = c.levels;
    let stride = c.rows();
    let mask = c.table_size() - 1;
    let n = u.len() / 3;
    let by_level = split_by_level(&lv, stride, grad_tables);
    let grad_u_by_level: Vec<Vec<f32>> = by_level
        .into_par_iter()
        .zip(lv.par_iter())
        .enumerate()
        .map(|(l, (mut features, level))| backward_level(level, l, mask, u, tables, stride, grad, l_n, &mut features))
        .collect();
    let mut grad_u = vec![0.0f32; 3 * n];
    grad_u.par_chunks_mut(3).enumerate().for_each(|(i, gu)| {
        for level in &grad_u_by_level {
            for d in 0..3 {
                gu[d] += level[3 * i + d];
            }
        }
    });
    grad_u
}

/// One level of [`encode`]: `[N·F]` (the AVX2 kernel where the CPU has AVX2 and FMA).
fn encode_level(level: &Level, mask: i64, u: &[f32], tables: &[f32], stride: usize, f_n: usize) -> Vec<f32> {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 and FMA.
        return unsafe { super::avx2::encode_level(level, mask, u, tables, stride, f_n) };
    }
    encode_level_scalar(level, mask, u, tables, stride, f_n)
}

/// Whether the CPU runs the AVX2 kernels (AVX2 and FMA).
#[cfg(target_arch = "x86_64")]
fn has_avx2() -> bool {
    is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
}

/// One level of [`encode_backward_into`]: scatters into the level's per-feature gradient
/// slices `features` and returns the level's share of `∂/∂u` (`[N·3]`).
#[allow(clippy::too_many_arguments)]
#[multiversion::multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn backward_level(
    level: &Level,
    l: usize,
    mask: i64,
    u: &[f32],
    tables: &[f32],
    stride: usize,
    grad: &[f32],
    l_n: usize,
    features: &mut [&mut [f32]],
) -> Vec<f32> {
    let n = u.len() / 3;
    let f_n = features.len();
    let mut gu = vec![0.0f32; 3 * n];
    for (i, gui) in gu.chunks_exact_mut(3).enumerate() {
        let (rows, w, dw) = corners(level, mask, [u[3 * i], u[3 * i + 1], u[3 * i + 2]]);
        let g = &grad[(i * l_n + l) * f_n..(i * l_n + l + 1) * f_n];
        for k in 0..8 {
            // ∂/∂u of Σ_f g_f · t_f[row]: the corner's value along the gradient, once per corner.
            let mut v = 0.0f32;
            for (f, slice) in features.iter_mut().enumerate() {
                slice[rows[k] - level.base] += w[k] * g[f];
                v += g[f] * tables[f * stride + rows[k]];
            }
            for d in 0..3 {
                gui[d] += dw[k][d] * v;
            }
        }
    }
    gu
}

/// [`encode`] and the encoding's Jacobian with respect to `u`, for training: the Jacobian is
/// level-major, `[L · N·F·3]` (level `l`, point `i`, feature `f`, axis `d` at
/// `((l·N + i)·F + f)·3 + d`), so that [`encode_backward_from_jacobian_into`] reads no table:
/// the backward's table reads cost as much as its scatter, and the forward has the corner values
/// at hand already.
pub fn encode_with_jacobian(c: &HashGridConfig, u: &[f32], tables: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let mut jacobian = zeroed(c.levels * (u.len() / 3) * c.features * 3);
    let out = encode_with_jacobian_into(c, u, tables, &mut jacobian);
    (out, jacobian)
}

/// [`encode_with_jacobian`] writing the Jacobian into `jacobian` (`[L · N·F·3]`), every element
/// of which it overwrites (so a reused buffer need not be cleared first); returns the encoding.
pub fn encode_with_jacobian_into(c: &HashGridConfig, u: &[f32], tables: &[f32], jacobian: &mut [f32]) -> Vec<f32> {
    let lv = levels(c);
    let (l_n, f_n) = (c.levels, c.features);
    let stride = c.rows();
    let mask = c.table_size() - 1;
    let n = u.len() / 3;
    assert_eq!(jacobian.len(), l_n * n * f_n * 3, "Jacobian buffer of the wrong length");
    // Per level, [chunk][chunk points · F]: a level's points in chunks, so that the thread that
    // finishes its levels first takes over part of another's instead of waiting for it.
    let by_level: Vec<Vec<Vec<f32>>> = jacobian
        .par_chunks_mut((n * f_n * 3).max(1))
        .zip(lv.par_iter())
        .map(|(jac, level)| {
            u.par_chunks(3 * POINT_CHUNK)
                .zip(jac.par_chunks_mut(POINT_CHUNK * f_n * 3))
                .map(|(u, jac)| encode_level_jacobian(level, mask, u, tables, stride, f_n, jac))
                .collect()
        })
        .collect();
    // Every element is written below, so the buffer is not cleared first.
    let mut out: Vec<f32> = Vec::with_capacity(n * l_n * f_n);
    if l_n * f_n > 0 {
        out.spare_capacity_mut()[..n * l_n * f_n].par_chunks_mut(l_n * f_n).enumerate().for_each(|(i, o)| {
            let (chunk, at) = (i / POINT_CHUNK, i % POINT_CHUNK);
            for (l, level) in by_level.iter().enumerate() {
                write_features(&mut o[l * f_n..(l + 1) * f_n], &level[chunk][at * f_n..(at + 1) * f_n]);
            }
        });
    }
    // SAFETY: the capacity is `n · L·F`, split above into the `n` rows of `L·F` values, each of
    // which gets its `F` values from every one of the `L` levels.
    unsafe { out.set_len(n * l_n * f_n) };
    out
}

/// Copies one point's features of one level (`src`) into its place in the encoding (`dst`, as
/// long): two features, every shipped configuration, as two moves rather than a `memcpy` call.
#[inline(always)]
fn write_features(dst: &mut [MaybeUninit<f32>], src: &[f32]) {
    if let ([d0, d1], [s0, s1]) = (&mut *dst, src) {
        *d0 = MaybeUninit::new(*s0);
        *d1 = MaybeUninit::new(*s1);
        return;
    }
    dst.iter_mut().zip(src).for_each(|(d, &s)| *d = MaybeUninit::new(s));
}

/// Points per task of [`encode_with_jacobian`] (a multiple of the AVX2 kernels' block of 8).
const POINT_CHUNK: usize = 8192;

/// Runs `work(l, slot)` once for every level `l` of `lv`, one level per task, the levels with the
/// most rows first, each thread of the pool taking the next level when it is done with one
/// (longest-first list scheduling): the dense levels are cheap, the hashed ones cost about the
/// same, and splitting them evenly by count left one thread idle for up to a level's time.
/// A level is worked on by one thread from start to end, so what it computes does not depend
/// on the schedule.
fn for_each_level_costliest_first<T: Send>(lv: &[Level], slots: Vec<T>, work: impl Fn(usize, T) + Sync) {
    let mut order: Vec<usize> = (0..lv.len()).collect();
    order.sort_by_key(|&l| std::cmp::Reverse(lv[l].rows));
    let slots: Vec<Mutex<Option<T>>> = slots.into_iter().map(|s| Mutex::new(Some(s))).collect();
    let next = AtomicUsize::new(0);
    (0..rayon::current_num_threads()).into_par_iter().with_max_len(1).for_each(|_| {
        while let Some(&l) = order.get(next.fetch_add(1, Ordering::Relaxed)) {
            if let Some(slot) = slots[l].lock().ok().and_then(|mut s| s.take()) {
                work(l, slot);
            }
        }
    });
}

/// The gradients of [`encode_backward_into`] from the Jacobian of [`encode_with_jacobian`]
/// (`[L · N·F·3]`) instead of the tables: the same table gradient, bit for bit (the same
/// level-major scatter), and `∂/∂u` as `Σ_l Σ_f grad · J` (the same sum as the table-reading
/// path up to rounding: it groups the corners per feature first).
pub fn encode_backward_from_jacobian_into(
    c: &HashGridConfig,
    u: &[f32],
    jacobian: &[f32],
    grad: &[f32],
    grad_tables: &mut [f32],
) -> Vec<f32> {
    let lv = levels(c);
    let (l_n, f_n) = (c.levels, c.features);
    let mask = c.table_size() - 1;
    let n = u.len() / 3;
    let by_level = split_by_level(&lv, c.rows(), grad_tables);
    let scatter = || {
        for_each_level_costliest_first(&lv, by_level, |l, mut features| {
            scatter_level(&lv[l], l, mask, u, grad, l_n, &mut features)
        })
    };
    // The position gradient needs no table: it fills the time a thread would otherwise wait
    // for the other's last level.
    let position = || {
        let mut grad_u = zeroed(3 * n);
        grad_u.par_chunks_mut(3).enumerate().for_each(|(i, gu)| {
            for l in 0..l_n {
                let g = &grad[(i * l_n + l) * f_n..(i * l_n + l + 1) * f_n];
                let j = &jacobian[(l * n + i) * f_n * 3..(l * n + i + 1) * f_n * 3];
                let mut level_part = [0.0f32; 3];
                for (f, gf) in g.iter().enumerate() {
                    for d in 0..3 {
                        level_part[d] += gf * j[3 * f + d];
                    }
                }
                for d in 0..3 {
                    gu[d] += level_part[d];
                }
            }
        });
        grad_u
    };
    rayon::join(scatter, position).1
}

/// One level of [`encode_with_jacobian`]: returns the encoding `[N·F]` and writes `∂/∂u` per
/// feature into `jac` (`[N·F·3]`). Per axis the derivative is the corner differences along that
/// axis weighted by the other two axes' factors (the sum of the corner weights' derivatives
/// times the corners, grouped by edge).
fn encode_level_jacobian(
    level: &Level,
    mask: i64,
    u: &[f32],
    tables: &[f32],
    stride: usize,
    f_n: usize,
    jac: &mut [f32],
) -> Vec<f32> {
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 and FMA.
        return unsafe { super::avx2::encode_level_jacobian(level, mask, u, tables, stride, f_n, jac) };
    }
    encode_level_jacobian_scalar(level, mask, u, tables, stride, f_n, jac)
}

/// One level's table-gradient scatter of [`encode_backward_from_jacobian_into`] (no table
/// reads): the same additions, in the same order, as [`backward_level`]'s.
fn scatter_level(level: &Level, l: usize, mask: i64, u: &[f32], grad: &[f32], l_n: usize, features: &mut [&mut [f32]]) {
    if let [first, second] = features {
        return scatter_level_two_features(level, l, mask, u, grad, l_n, first, second);
    }
    scatter_level_scalar(level, l, mask, u, grad, l_n, features)
}

/// [`scatter_level_scalar`] for two features per level (every shipped configuration), with both
/// features' slices at hand in the corner loop: the same additions in the same order. It is the
/// fastest of the variants measured (126k Gaussian centres of a BraVa paper run, table 2¹⁹ × 16,
/// scatter and position gradient: 32–34 ms on 2 threads against 44–49 for an AVX2 version that
/// computed eight points' corners at a time and then made their additions; on one thread 64–67
/// ms against 78–83 for the generic loop over the feature slices and 90–99 for the AVX2 version;
/// prefetching the rows for writing gained nothing).
#[allow(clippy::too_many_arguments)]
#[multiversion::multiversion(targets("x86_64+sse4.1"))]
fn scatter_level_two_features(
    level: &Level,
    l: usize,
    mask: i64,
    u: &[f32],
    grad: &[f32],
    l_n: usize,
    first: &mut [f32],
    second: &mut [f32],
) {
    for (i, p) in u.chunks_exact(3).enumerate() {
        let (rows, a, _) = corner_rows(level, mask, [p[0], p[1], p[2]]);
        let w = corner_weights(&a);
        let (g0, g1) = (grad[(i * l_n + l) * 2], grad[(i * l_n + l) * 2 + 1]);
        for k in 0..8 {
            let row = rows[k] - level.base;
            first[row] += w[k] * g0;
            second[row] += w[k] * g1;
        }
    }
}

/// [`scatter_level`], one point at a time, for any number of features; the two-feature
/// kernel's oracle.
#[multiversion::multiversion(targets("x86_64+sse4.1"))]
pub(super) fn scatter_level_scalar(
    level: &Level,
    l: usize,
    mask: i64,
    u: &[f32],
    grad: &[f32],
    l_n: usize,
    features: &mut [&mut [f32]],
) {
    let n = u.len() / 3;
    let f_n = features.len();
    for i in 0..n {
        let (rows, w, _) = corners(level, mask, [u[3 * i], u[3 * i + 1], u[3 * i + 2]]);
        let g = &grad[(i * l_n + l) * f_n..(i * l_n + l + 1) * f_n];
        for k in 0..8 {
            for (f, slice) in features.iter_mut().enumerate() {
                slice[rows[k] - level.base] += w[k] * g[f];
            }
        }
    }
}

/// [`encode_backward_into`] with a fresh table gradient: `(∂/∂u, ∂/∂tables)`.
pub fn encode_backward(c: &HashGridConfig, u: &[f32], tables: &[f32], grad: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let mut grad_t = vec![0.0f32; tables.len()];
    let grad_u = encode_backward_into(c, u, tables, grad, &mut grad_t);
    (grad_u, grad_t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The table gradient as one sequential scatter over points (the obvious loop).
    fn table_grad_sequential(c: &HashGridConfig, u: &[f32], grad: &[f32]) -> Vec<f32> {
        let lv = levels(c);
        let (l_n, f_n) = (c.levels, c.features);
        let stride = c.rows();
        let mask = c.table_size() - 1;
        let mut out = vec![0.0f32; f_n * stride];
        for i in 0..u.len() / 3 {
            let p = [u[3 * i], u[3 * i + 1], u[3 * i + 2]];
            for (l, level) in lv.iter().enumerate() {
                let (rows, w, _) = corners(level, mask, p);
                for f in 0..f_n {
                    let g = grad[(i * l_n + l) * f_n + f];
                    for k in 0..8 {
                        out[f * stride + rows[k]] += w[k] * g;
                    }
                }
            }
        }
        out
    }

    #[test]
    fn jacobian_path_gives_the_table_reading_gradients() {
        let c = HashGridConfig {
            levels: 6,
            features: 2,
            log2_table: 10,
            base_resolution: 4.0,
            growth: 1.8,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        // More than two of the forward's point chunks, the last one partial.
        let n = 2 * POINT_CHUNK + 1003;
        let u: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-0.05f32..1.05)).collect();
        let tables: Vec<f32> = (0..c.features * c.rows()).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let grad: Vec<f32> = (0..n * c.levels * c.features).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let (out, jacobian) = encode_with_jacobian(&c, &u, &tables);
        assert_eq!(out, encode(&c, &u, &tables));
        let (gu_reading, gt_reading) = encode_backward(&c, &u, &tables, &grad);
        let mut gt = vec![0.0f32; tables.len()];
        let gu = encode_backward_from_jacobian_into(&c, &u, &jacobian, &grad, &mut gt);
        assert_eq!(gt, gt_reading);
        let scale = gu_reading.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let worst = gu.iter().zip(&gu_reading).fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(scale > 1.0 && worst <= 1e-5 * scale, "position gradients differ by {worst} (scale {scale})");
    }

    /// The two-feature scatter against the generic one, per level (dense and hashed, clamped
    /// points), bit for bit.
    #[test]
    fn two_feature_scatter_equals_the_generic_scatter_bit_for_bit() {
        let c = HashGridConfig {
            levels: 6,
            features: 2,
            log2_table: 10,
            base_resolution: 4.0,
            growth: 1.8,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let n = 4001;
        let u: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-0.05f32..1.05)).collect();
        let grad: Vec<f32> = (0..n * c.levels * 2).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let mask = c.table_size() - 1;
        for (l, level) in levels(&c).iter().enumerate() {
            let (mut fast, mut slow) = (vec![vec![0.0f32; level.rows]; 2], vec![vec![0.0f32; level.rows]; 2]);
            let [f0, f1] = &mut fast[..] else { unreachable!() };
            scatter_level_two_features(level, l, mask, &u, &grad, c.levels, f0, f1);
            let mut slices: Vec<&mut [f32]> = slow.iter_mut().map(|v| v.as_mut_slice()).collect();
            scatter_level_scalar(level, l, mask, &u, &grad, c.levels, &mut slices);
            assert_eq!(fast, slow, "level {l}");
        }
    }

    /// The forward overwrites every element of a reused Jacobian buffer (one full of NaN here).
    #[test]
    fn jacobian_into_a_used_buffer_overwrites_all_of_it() {
        let c = HashGridConfig {
            levels: 6,
            features: 2,
            log2_table: 10,
            base_resolution: 4.0,
            growth: 1.8,
            ..Default::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let n = POINT_CHUNK + 1001;
        let u: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-0.05f32..1.05)).collect();
        let tables: Vec<f32> = (0..c.features * c.rows()).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let (out, jacobian) = encode_with_jacobian(&c, &u, &tables);
        let mut used = vec![f32::NAN; jacobian.len()];
        assert_eq!(encode_with_jacobian_into(&c, &u, &tables, &mut used), out);
        assert_eq!(used, jacobian);
    }

    #[test]
    fn level_parallel_table_gradient_equals_the_sequential_scatter_bit_for_bit() {
        let c = HashGridConfig {
            levels: 6,
            features: 2,
            log2_table: 10,
            base_resolution: 4.0,
            growth: 1.8,
            ..Default::default()
        };
        assert!((0..c.levels).any(|l| c.dense(l)) && (0..c.levels).any(|l| !c.dense(l)));
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 5000;
        // Some points outside [0, 1]³ exercise the clamping.
        let u: Vec<f32> = (0..3 * n).map(|_| rng.random_range(-0.05f32..1.05)).collect();
        let tables: Vec<f32> = (0..c.features * c.rows()).map(|_| rng.random()).collect();
        let grad: Vec<f32> = (0..n * c.levels * c.features).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let (_, parallel) = encode_backward(&c, &u, &tables, &grad);
        assert_eq!(parallel, table_grad_sequential(&c, &u, &grad));
    }
}

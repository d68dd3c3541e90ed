//! One level of the encoding, the scalar way: the level's constants, a point's corner rows and
//! trilinear weights (prefetched a few points ahead), and the scalar level kernels — the AVX2
//! kernels' oracle and tail.

use super::config::{HASH_P1, HASH_P2, HashGridConfig};

/// Per-level constants.
#[derive(Debug, Clone, Copy)]
pub(super) struct Level {
    pub(super) res: f32,
    pub(super) r1: i64,
    pub(super) dense: bool,
    /// First row and row count of the level in the table.
    pub(super) base: usize,
    pub(super) rows: usize,
}

pub(super) fn levels(c: &HashGridConfig) -> Vec<Level> {
    (0..c.levels)
        .map(|l| Level {
            res: c.resolution(l) as f32,
            r1: c.resolution(l) + 1,
            dense: c.dense(l),
            base: c.level_offset(l),
            rows: c.level_rows(l),
        })
        .collect()
}

/// Corner table rows of a point at one level (corner `k` = `x + 2y + 4z`), the per-axis
/// trilinear factors `a[d] = [1 − frac_d, frac_d]`, and per axis `∂frac_d/∂u_d` (the resolution,
/// zero where the point was clamped).
#[inline(always)]
pub(super) fn corner_rows(lv: &Level, mask: i64, u: [f32; 3]) -> ([usize; 8], [[f32; 2]; 3], [f32; 3]) {
    let mut inside = [1.0f32; 3];
    let mut frac = [0.0f32; 3];
    let mut cell = [0i64; 3];
    for d in 0..3 {
        let v = u[d];
        let c = v.clamp(0.0, 1.0 - 1e-6);
        if c != v {
            inside[d] = 0.0;
        }
        let p = c * lv.res;
        let f = p.floor();
        cell[d] = f as i64;
        frac[d] = p - f;
    }
    // Per axis, the two corner offsets' index terms; a corner's index combines one per axis.
    let hash = [1i64, HASH_P1, HASH_P2];
    let dense_stride = [1i64, lv.r1, lv.r1 * lv.r1];
    let term: [[i64; 2]; 3] = std::array::from_fn(|d| {
        let c = [cell[d], cell[d] + 1];
        if lv.dense { c.map(|v| v * dense_stride[d]) } else { c.map(|v| v.wrapping_mul(hash[d])) }
    });
    let mut rows = [0usize; 8];
    for (k, row) in rows.iter_mut().enumerate() {
        let (x, y, z) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
        let idx =
            if lv.dense { term[0][x] + term[1][y] + term[2][z] } else { (term[0][x] ^ term[1][y] ^ term[2][z]) & mask };
        *row = lv.base + idx as usize;
    }
    let a: [[f32; 2]; 3] = std::array::from_fn(|d| [1.0 - frac[d], frac[d]]);
    (rows, a, std::array::from_fn(|d| lv.res * inside[d]))
}

/// The 8 trilinear corner weights (corner `k` = `x + 2y + 4z`) from the per-axis factors of
/// [`corner_rows`]: `a[0][x] · a[1][y] · a[2][z]`, in that order (every path multiplies the
/// same way, so their results agree bit for bit).
#[inline(always)]
pub(super) fn corner_weights(a: &[[f32; 2]; 3]) -> [f32; 8] {
    std::array::from_fn(|k| a[0][k & 1] * a[1][(k >> 1) & 1] * a[2][k >> 2])
}

/// `Σ_k w[k]·v[k]`, summed in corner order from the first product (the AVX2 kernels sum the
/// same way).
#[inline(always)]
pub(super) fn dot8(w: &[f32; 8], v: &[f32; 8]) -> f32 {
    let mut sum = w[0] * v[0];
    for k in 1..8 {
        sum += w[k] * v[k];
    }
    sum
}

/// How many points ahead the level loops compute corner rows and prefetch them: a point's 8·F
/// table reads are random, and waiting for each in turn would leave the core idle.
pub(super) const AHEAD: usize = 8;

/// Asks the CPU to bring `slice[i]` into cache (a hint: no effect on results, no fault).
#[inline(always)]
pub(super) fn prefetch(slice: &[f32], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v) = slice.get(i) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: the pointer comes from a live reference; a prefetch reads nothing observable
        // and cannot fault.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(std::ptr::from_ref(v).cast::<i8>()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (slice, i);
}

/// Corner rows, per-axis factors and axis scales of one point ([`corner_rows`]).
pub(super) type CornerRows = ([usize; 8], [[f32; 2]; 3], [f32; 3]);

/// [`corner_rows`] of every point of `u` (`[N·3]`), handed out in order while the rows of the
/// point [`AHEAD`] places later are being prefetched (by the caller's `fetch(row)`).
pub(super) struct CornerPipeline<'a> {
    level: &'a Level,
    mask: i64,
    u: &'a [f32],
    ring: [CornerRows; AHEAD],
}

impl<'a> CornerPipeline<'a> {
    pub(super) fn new(level: &'a Level, mask: i64, u: &'a [f32], mut fetch: impl FnMut(usize)) -> Self {
        let mut pipe = Self { level, mask, u, ring: [([0; 8], [[0.0; 2]; 3], [0.0; 3]); AHEAD] };
        for i in 0..AHEAD.min(u.len() / 3) {
            pipe.fill(i, &mut fetch);
        }
        pipe
    }

    #[inline(always)]
    fn fill(&mut self, i: usize, fetch: &mut impl FnMut(usize)) {
        let u = self.u;
        let entry = corner_rows(self.level, self.mask, [u[3 * i], u[3 * i + 1], u[3 * i + 2]]);
        entry.0.iter().for_each(|&row| fetch(row));
        self.ring[i % AHEAD] = entry;
    }

    /// Point `i`'s corners (points must be asked for in order, from 0).
    #[inline(always)]
    pub(super) fn take(&mut self, i: usize, mut fetch: impl FnMut(usize)) -> CornerRows {
        let entry = self.ring[i % AHEAD];
        if i + AHEAD < self.u.len() / 3 {
            self.fill(i + AHEAD, &mut fetch);
        }
        entry
    }
}

/// Corner table rows and trilinear weights of a point at one level, and the weight derivatives
/// with respect to the point (zero where the point was clamped).
#[inline(always)]
pub(super) fn corners(lv: &Level, mask: i64, u: [f32; 3]) -> ([usize; 8], [f32; 8], [[f32; 3]; 8]) {
    let (rows, a, s) = corner_rows(lv, mask, u);
    const SIGN: [f32; 2] = [-1.0, 1.0];
    let dw = std::array::from_fn(|k| {
        let (x, y, z) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
        [SIGN[x] * a[1][y] * a[2][z] * s[0], a[0][x] * SIGN[y] * a[2][z] * s[1], a[0][x] * a[1][y] * SIGN[z] * s[2]]
    });
    (rows, corner_weights(&a), dw)
}

/// [`encode_level`], one point at a time (compiled for SSE 4.1 where the CPU has it); the
/// AVX2 kernel's oracle and tail.
#[multiversion::multiversion(targets("x86_64+sse4.1"))]
pub(super) fn encode_level_scalar(
    level: &Level,
    mask: i64,
    u: &[f32],
    tables: &[f32],
    stride: usize,
    f_n: usize,
) -> Vec<f32> {
    let n = u.len() / 3;
    let mut o = vec![0.0f32; n * f_n];
    let fetch = |row: usize| (0..f_n).for_each(|f| prefetch(tables, f * stride + row));
    let mut pipe = CornerPipeline::new(level, mask, u, fetch);
    for (i, oi) in o.chunks_exact_mut(f_n).enumerate() {
        let (rows, a, _) = pipe.take(i, fetch);
        let w = corner_weights(&a);
        for (f, v) in oi.iter_mut().enumerate() {
            let t = &tables[f * stride..(f + 1) * stride];
            *v = dot8(&w, &std::array::from_fn(|k| t[rows[k]]));
        }
    }
    o
}

/// [`encode_level_jacobian`], one point at a time; the AVX2 kernel's oracle and tail.
#[multiversion::multiversion(targets("x86_64+sse4.1"))]
pub(super) fn encode_level_jacobian_scalar(
    level: &Level,
    mask: i64,
    u: &[f32],
    tables: &[f32],
    stride: usize,
    f_n: usize,
    jac: &mut [f32],
) -> Vec<f32> {
    let n = u.len() / 3;
    let mut o = vec![0.0f32; n * f_n];
    let fetch = |row: usize| (0..f_n).for_each(|f| prefetch(tables, f * stride + row));
    let mut pipe = CornerPipeline::new(level, mask, u, fetch);
    for (i, (oi, ji)) in o.chunks_exact_mut(f_n).zip(jac.chunks_exact_mut(f_n * 3)).enumerate() {
        let (rows, a, s) = pipe.take(i, fetch);
        let w = corner_weights(&a);
        // Edge e along x joins corners 2e and 2e + 1 (y = e & 1, z = e >> 1); along y corners
        // p + 4q and p + 4q + 2 (x = p, z = q); along z corners p + 2q and p + 2q + 4 (x = p,
        // y = q), with p = e & 1, q = e >> 1. Each edge's weight is the other two axes' factors.
        let ex: [f32; 4] = std::array::from_fn(|e| a[1][e & 1] * a[2][e >> 1] * s[0]);
        let ey: [f32; 4] = std::array::from_fn(|e| a[0][e & 1] * a[2][e >> 1] * s[1]);
        let ez: [f32; 4] = std::array::from_fn(|e| a[0][e & 1] * a[1][e >> 1] * s[2]);
        // All features' corners first (up to 8 features), so that their loads overlap.
        let mut corner_values = [[0.0f32; 8]; 8];
        for (f, v) in corner_values.iter_mut().enumerate().take(f_n) {
            let t = &tables[f * stride..(f + 1) * stride];
            *v = std::array::from_fn(|k| t[rows[k]]);
        }
        for (f, v) in corner_values.iter().enumerate().take(f_n) {
            oi[f] = dot8(&w, v);
            let (mut jx, mut jy, mut jz) = (0.0f32, 0.0f32, 0.0f32);
            for e in 0..4 {
                let (p, q) = (e & 1, e >> 1);
                jx += ex[e] * (v[2 * e + 1] - v[2 * e]);
                jy += ey[e] * (v[p + 4 * q + 2] - v[p + 4 * q]);
                jz += ez[e] * (v[p + 2 * q + 4] - v[p + 2 * q]);
            }
            ji[3 * f..3 * f + 3].copy_from_slice(&[jx, jy, jz]);
        }
    }
    o
}

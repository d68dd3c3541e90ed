//! The forward pass's record of one Gaussian in one view: what its pixel loop reads, in one
//! 64-byte cache line, and [`project_splats`], which writes them eight at a time.
//!
//! Unlike [`Projected`](super::math::Projected) (the backward's record) it keeps no pixel
//! coordinates of the centre: a pixel's normalised coordinates `(x, y)` come from the pixel
//! alone, and the offsets from the centre are `dx = x − x0`, `dy = y − y0`.

use bytemuck::{Pod, Zeroable};
use multiversion::target::match_target;

use super::host::HostGaussians;
use super::lanes::{F8, LANES, M8};
use super::math::RowEval;
use super::project::{Inputs, load, project8};
use super::transpose::{self, Transpose};
use crate::view_params::ViewParams;

/// One Gaussian in one view for the forward pixel loop (see [`super::math`] for the symbols).
#[repr(C, align(64))]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct Splat {
    /// Projected centre in normalised image coordinates (`w_x`, `w_y`).
    pub x0: f32,
    pub y0: f32,
    /// Camera-frame precision entries used per pixel: `Q_xx, Q_xy, Q_yy` (1/mm²).
    pub q_xx: f32,
    pub q_xy: f32,
    pub q_yy: f32,
    /// `g = Q w` (x, y components) and `α_w = wᵀ Q w`.
    pub g_x: f32,
    pub g_y: f32,
    pub alpha_w: f32,
    /// The conic `C = μ_z² α_w Σ₂⁻¹` (`xx, xy, yy`).
    pub c_xx: f32,
    pub c_xy: f32,
    pub c_yy: f32,
    /// `ρ √(2π)`.
    pub amp: f32,
    /// `k²`, or `+∞` for an unbounded footprint (as [`Projected::cut`](super::math::Projected)).
    pub cut: f32,
    /// Inclusive column range of the footprint's box, packed by [`pack_range`].
    pub cols: u32,
    /// Inclusive row range, packed by [`pack_range`].
    pub rows: u32,
    /// Unused: pads the record to 16 words.
    pub padding: u32,
}

/// Image sides up to this many pixels fit the packed ranges.
pub const MAX_SIDE_PX: u32 = 1 << 16;
const _: () = assert!(crate::geometry::MAX_DETECTOR_PX <= MAX_SIDE_PX, "views must fit the packed ranges");

/// The packed empty range (first 1, last 0): culled Gaussians have it in both `cols` and
/// `rows`.
pub const EMPTY_RANGE: u32 = 1;

/// Packs the inclusive range `[first, last]` (each `< 2¹⁶`) as `first | last << 16`.
#[inline(always)]
pub fn pack_range(first: u32, last: u32) -> u32 {
    first | (last << 16)
}

/// Unpacks [`pack_range`].
#[inline(always)]
fn unpack_range(packed: u32) -> (i32, i32) {
    ((packed & 0xffff) as i32, (packed >> 16) as i32)
}

impl Splat {
    /// Inclusive column range of the footprint's box (empty if first > last).
    #[inline(always)]
    pub fn col_range(&self) -> (i32, i32) {
        unpack_range(self.cols)
    }

    /// Inclusive row range of the footprint's box (empty if first > last).
    #[inline(always)]
    pub fn row_range(&self) -> (i32, i32) {
        unpack_range(self.rows)
    }

    /// Whether a pixel with `N = quad` and `α = alpha` sees the Gaussian (as
    /// [`Projected::sees`](super::math::Projected::sees)).
    #[inline(always)]
    pub fn sees(&self, quad: f32, alpha: f32) -> bool {
        quad <= self.cut * alpha
    }

    /// Coefficients of image row `row` (as
    /// [`Projected::row_eval`](super::math::Projected::row_eval), with `dy` taken from the
    /// row's normalised coordinate).
    #[inline(always)]
    pub fn row_eval(&self, row: i32, vp: &ViewParams) -> RowEval {
        let yn = (row as f32 - vp.cy) * vp.inv_fy;
        let dy = yn - self.y0;
        RowEval {
            dy,
            yn,
            a0: dy.mul_add(self.q_yy.mul_add(dy, 2.0 * self.g_y), self.alpha_w),
            a1: 2.0 * self.q_xy.mul_add(dy, self.g_x),
            a2: self.q_xx,
            n0: self.c_yy * dy * dy,
            n1: 2.0 * self.c_xy * dy,
            n2: self.c_xx,
            r0: yn.mul_add(yn, 1.0),
        }
    }
}

/// Loads Gaussians `first..first + LANES` (all present) with the block transposes of `T`.
#[inline(always)]
fn load_full<T: Transpose>(t: T, g: &HostGaussians, first: usize) -> Inputs {
    let block3 = |a: &[f32]| -> [F8; 3] {
        t.columns3(a[3 * first..3 * (first + LANES)].try_into().expect("a whole batch")).map(F8)
    };
    let quat = t.columns4(g.rotations[4 * first..4 * (first + LANES)].try_into().expect("a whole batch"));
    let density: [f32; LANES] = g.densities[first..first + LANES].try_into().expect("a whole batch");
    Inputs { mean: block3(g.means), scale: block3(g.scales), quat: quat.map(F8), density: F8(density) }
}

/// Packs the box ranges of a batch (lanes whose Gaussian is culled get [`EMPTY_RANGE`]).
#[inline(always)]
fn pack_ranges(first: F8, last: F8, valid: M8) -> F8 {
    // Whole numbers in [0, 2¹⁶) (clipped to the image): adding 2²³ puts them in the low
    // mantissa bits, a conversion that vectorises (`as u32` saturates lane by lane). Culled
    // lanes may hold anything (even NaN): wrapping, and masked out below.
    const TWO_23: f32 = 8_388_608.0;
    let bits = |v: f32| (v + TWO_23).to_bits().wrapping_sub(TWO_23.to_bits()) & 0xffff;
    let mut out = [0.0; LANES];
    for (l, (out, mask)) in out.iter_mut().zip(valid.bits()).enumerate() {
        let packed = pack_range(bits(first.0[l]), bits(last.0[l]));
        *out = f32::from_bits((packed & mask) | (EMPTY_RANGE & !mask));
    }
    F8(out)
}

/// The fields of a batch's [`Splat`] records, one lane array per field in record order.
type SplatFields = [[f32; LANES]; 16];

/// Loads and projects Gaussians `start..start + count` (`count ≤ LANES`) and packs their
/// [`Splat`] fields.
#[inline(always)]
fn splat_fields<T: Transpose>(
    t: T,
    g: &HostGaussians,
    start: usize,
    count: usize,
    vp: &ViewParams,
    k_sigma: f32,
    fields: &mut SplatFields,
) {
    let x = if count == LANES { load_full(t, g, start) } else { load(g, start, count) };
    let o = project8(&x, vp, k_sigma);
    let cols = pack_ranges(o.col_min, o.col_max, o.valid);
    let rows = pack_ranges(o.row_min, o.row_max, o.valid);
    let order = [
        o.x0,
        o.y0,
        o.q[0],
        o.q[1],
        o.q[3],
        o.g_x,
        o.g_y,
        o.alpha_w,
        o.c_xx,
        o.c_xy,
        o.c_yy,
        o.amp,
        o.cut,
        cols,
        rows,
        F8::splat(0.0),
    ];
    for (field, v) in fields.iter_mut().zip(order) {
        *field = v.0;
    }
}

/// Projects Gaussians `first..first + out.len()` of `g` into view `vp` with a k-σ footprint,
/// as the forward pass's [`Splat`] records (culled Gaussians, as in
/// [`project_range`](super::project::project_range), get empty ranges). The view's sides must
/// be at most [`MAX_SIDE_PX`].
#[multiversion::multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
pub fn project_splats(g: &HostGaussians, first: usize, vp: &ViewParams, k_sigma: f32, out: &mut [Splat]) {
    /// Loads and maths, out of line: inlined together with the record stores, LLVM vectorised
    /// much of the maths four lanes (or three components) at a time instead of eight.
    #[multiversion::inherit_target]
    #[inline(never)]
    fn batch<T: Transpose>(
        t: T,
        g: &HostGaussians,
        start: usize,
        count: usize,
        vp: &ViewParams,
        k_sigma: f32,
        fields: &mut SplatFields,
    ) {
        splat_fields(t, g, start, count, vp, k_sigma, fields);
    }
    match_target! {
        "x86_64+avx2" => match transpose::Avx2::detect() {
            Some(avx2) => store_splats(avx2, g, first, vp, k_sigma, out, batch::<transpose::Avx2>),
            None => store_splats(transpose::Plain, g, first, vp, k_sigma, out, batch::<transpose::Plain>),
        },
        _ => store_splats(transpose::Plain, g, first, vp, k_sigma, out, batch::<transpose::Plain>),
    }
}

/// The batch loop of [`project_splats`]: `batch` fills the fields, `t` transposes them into
/// records.
#[inline(always)]
fn store_splats<T: Transpose>(
    t: T,
    g: &HostGaussians,
    first: usize,
    vp: &ViewParams,
    k_sigma: f32,
    out: &mut [Splat],
    batch: fn(T, &HostGaussians, usize, usize, &ViewParams, f32, &mut SplatFields),
) {
    let mut fields = [[0.0; LANES]; 16];
    for (b, out) in out.chunks_mut(LANES).enumerate() {
        batch(t, g, first + b * LANES, out.len(), vp, k_sigma, &mut fields);
        let lo = t.transpose8(fields[..8].try_into().expect("8 fields"));
        let hi = t.transpose8(fields[8..].try_into().expect("8 fields"));
        for (l, splat) in out.iter_mut().enumerate() {
            *splat = bytemuck::cast([lo[l], hi[l]]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::project::project_range;
    use crate::cpu::project::tests::{INVALID, scene};

    #[test]
    fn record_is_one_cache_line_and_ranges_round_trip() {
        assert_eq!(std::mem::size_of::<Splat>(), 64);
        assert_eq!(std::mem::align_of::<Splat>(), 64);
        let s = Splat { cols: pack_range(3, MAX_SIDE_PX - 1), rows: EMPTY_RANGE, ..Splat::default() };
        assert_eq!(s.col_range(), (3, MAX_SIDE_PX as i32 - 1));
        let (first, last) = s.row_range();
        assert!(first > last, "the empty range is empty");
    }

    /// The forward's records hold the same numbers as the backward's, for whole batches and
    /// the last partial one, with the dispatched moves (AVX2 on this CPU) and the plain ones
    /// (what CPUs without AVX2 run).
    #[test]
    fn splats_equal_projections() {
        let ([means, scales, rotations, densities], vp) = scene();
        let n = densities.len();
        let g = HostGaussians { means: &means, scales: &scales, rotations: &rotations, densities: &densities };
        let mut projected = vec![None; n];
        project_range(&g, 0, &vp, 3.0, &mut projected, None);
        let mut dispatched = vec![Splat::default(); n];
        project_splats(&g, 0, &vp, 3.0, &mut dispatched);
        fn plain_batch(
            t: transpose::Plain,
            g: &HostGaussians,
            s: usize,
            c: usize,
            vp: &ViewParams,
            k: f32,
            f: &mut SplatFields,
        ) {
            splat_fields(t, g, s, c, vp, k, f);
        }
        let mut plain = vec![Splat::default(); n];
        store_splats(transpose::Plain, &g, 0, &vp, 3.0, &mut plain, plain_batch);
        for (i, (s, p)) in dispatched.iter().chain(&plain).zip(projected.iter().cycle()).enumerate() {
            let i = i % n;
            let Some(p) = p else {
                assert!(INVALID.contains(&i), "Gaussian {i} culled");
                assert_eq!((s.cols, s.rows), (EMPTY_RANGE, EMPTY_RANGE), "Gaussian {i}");
                continue;
            };
            let expect = Splat {
                x0: p.x0,
                y0: p.y0,
                q_xx: p.q_xx,
                q_xy: p.q_xy,
                q_yy: p.q_yy,
                g_x: p.g_x,
                g_y: p.g_y,
                alpha_w: p.alpha_w,
                c_xx: p.c_xx,
                c_xy: p.c_xy,
                c_yy: p.c_yy,
                amp: p.amp,
                cut: p.cut,
                cols: pack_range(p.col_min as u32, p.col_max as u32),
                rows: pack_range(p.row_min as u32, p.row_max as u32),
                padding: 0,
            };
            assert_eq!(*s, expect, "Gaussian {i}");
        }
    }
}

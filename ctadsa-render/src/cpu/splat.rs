//! The forward pass's record of one Gaussian in one view: what its pixel loop reads, in one
//! 64-byte cache line (written eight at a time by [`super::project::project_splats`]).
//!
//! Unlike [`Projected`](super::math::Projected) (the backward's record) it keeps no pixel
//! coordinates of the centre: a pixel's normalised coordinates `(x, y)` come from the pixel
//! alone, and the offsets from the centre are `dx = x − x0`, `dy = y − y0`.

use bytemuck::{Pod, Zeroable};

use super::math::RowEval;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_is_one_cache_line_and_ranges_round_trip() {
        assert_eq!(std::mem::size_of::<Splat>(), 64);
        assert_eq!(std::mem::align_of::<Splat>(), 64);
        let s = Splat { cols: pack_range(3, MAX_SIDE_PX - 1), rows: EMPTY_RANGE, ..Splat::default() };
        assert_eq!(s.col_range(), (3, MAX_SIDE_PX as i32 - 1));
        let (first, last) = s.row_range();
        assert!(first > last, "the empty range is empty");
    }
}

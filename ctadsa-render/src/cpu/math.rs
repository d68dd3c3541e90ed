//! Per-Gaussian, per-view set-up of the exact cone-beam line integral (f32), shared by the CPU
//! forward, backward and pair-counting kernels. The CubeCL kernels mirror these formulas.
//!
//! Camera frame: source at the origin, `z` along the principal ray. A pixel `(u, v)` has the
//! unnormalised ray `ũ = (x, y, 1)` with `x = (u − c_x)/f_x`, `y = (v − c_y)/f_y`. For a Gaussian
//! with camera-frame centre `μ` and precision `Q`, write `w = μ/μ_z` (the ray through the centre),
//! `Δ = ũ − w = (dx, dy, 0)`. Then (xray-splatting.md §3b)
//!
//! `I = ρ √(2π) · sqrt(|ũ|² / α) · exp(−½ N/α)`, with `α = ũᵀQũ` and `N = ΔᵀCΔ`,
//!
//! where `C = μ_z² α_w Σ₂⁻¹`, `α_w = wᵀQw` and `Σ₂ = PΣPᵀ` is the covariance projected along `w`
//! onto the plane `z = 0` (`P = [[1, 0, −w_x], [0, 1, −w_y]]`). Computing `C` from `Σ` (not from
//! `Q`) keeps it free of cancellation for disc-like Gaussians. The footprint
//! `{c = N/α ≤ k²}` is exactly the image of the k-σ ellipsoid: the conic
//! `F(Δ) = N − k²α ≤ 0`.

use crate::view_params::ViewParams;

/// √(2π).
pub const SQRT_2PI: f32 = 2.506_628_3;
/// Scales are clamped to this range (mm) before use so that `1/s²` and `s²` stay finite in f32.
pub const SCALE_MIN_MM: f32 = 1e-4;
/// Upper clamp for scales (mm).
pub const SCALE_MAX_MM: f32 = 1e5;

/// Rotation matrix (row-major `[r00, r01, r02, r10, …]`) of the unit quaternion `q̂ = q/|q|`,
/// `q = (w, x, y, z)`. Returns `None` for a zero or non-finite quaternion.
#[inline]
pub fn quat_to_mat(q: [f32; 4]) -> Option<([f32; 9], [f32; 4], f32)> {
    let n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    if !(n2.is_finite() && n2 > 1e-24) {
        return None;
    }
    let n = n2.sqrt();
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    let r = [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    ];
    Some((r, [w, x, y, z], n))
}

/// Symmetric 3 × 3 matrix stored as `[xx, xy, xz, yy, yz, zz]`.
pub type Sym3 = [f32; 6];

/// `M diag(d) Mᵀ` for a row-major 3 × 3 `M`.
#[inline]
pub fn sandwich_diag(m: &[f32; 9], d: [f32; 3]) -> Sym3 {
    let e = |i: usize, j: usize| {
        m[3 * i] * d[0] * m[3 * j] + m[3 * i + 1] * d[1] * m[3 * j + 1] + m[3 * i + 2] * d[2] * m[3 * j + 2]
    };
    [e(0, 0), e(0, 1), e(0, 2), e(1, 1), e(1, 2), e(2, 2)]
}

/// The clamped scales of a Gaussian and whether each component was inside the clamp range
/// (outside it the gradient is zero); `None` for a non-positive or non-finite scale.
#[inline]
pub fn clamp_scales(s: [f32; 3]) -> Option<([f32; 3], [bool; 3])> {
    if !s.iter().all(|v| v.is_finite() && *v > 0.0) {
        return None;
    }
    let c = s.map(|v| v.clamp(SCALE_MIN_MM, SCALE_MAX_MM));
    let inside = [0, 1, 2].map(|k| s[k] >= SCALE_MIN_MM && s[k] <= SCALE_MAX_MM);
    Some((c, inside))
}

/// Everything the pixel loops need to evaluate one Gaussian in one view (computed by
/// [`super::project::project_range`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct Projected {
    /// Projected centre in pixels.
    pub u0: f32,
    pub v0: f32,
    /// Projected centre in normalised image coordinates (`w_x`, `w_y`).
    pub x0: f32,
    pub y0: f32,
    /// Depth of the centre (mm).
    pub mu_z: f32,
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
    /// `k²` for a bounded footprint, `+∞` where the k-σ ellipsoid reaches the source plane
    /// (every pixel is evaluated, no cut-off; branch-free [`Projected::sees`]).
    pub cut: f32,
    /// Inclusive pixel bounding box of the footprint (the exact box of the k-σ ellipsoid's
    /// image), clipped to the image; empty if `col_min > col_max` or `row_min > row_max`. The
    /// pixels inside it that see the Gaussian are those where [`Projected::sees`] holds.
    pub col_min: i32,
    pub col_max: i32,
    pub row_min: i32,
    pub row_max: i32,
}

impl Projected {
    /// Whether a pixel with `N = quad` and `α = alpha` sees the Gaussian: its ray passes within
    /// `k` Mahalanobis units (`N/α ≤ k²`), or the footprint is unbounded.
    #[inline(always)]
    pub fn sees(&self, quad: f32, alpha: f32) -> bool {
        quad <= self.cut * alpha
    }

    /// Per-row coefficients for evaluating pixels of row `row` (see [`RowEval`]).
    #[inline]
    pub fn row_eval(&self, row: i32, vp: &ViewParams) -> RowEval {
        let dy = (row as f32 - self.v0) * vp.inv_fy;
        let yn = self.y0 + dy;
        RowEval {
            dy,
            yn,
            a0: self.alpha_w + 2.0 * self.g_y * dy + self.q_yy * dy * dy,
            a1: 2.0 * (self.g_x + self.q_xy * dy),
            a2: self.q_xx,
            n0: self.c_yy * dy * dy,
            n1: 2.0 * self.c_xy * dy,
            n2: self.c_xx,
            r0: 1.0 + yn * yn,
        }
    }
}

/// Coefficients of one image row: with `dx` the normalised column offset from the centre,
/// `α = a0 + dx (a1 + dx a2)`, `N = n0 + dx (n1 + dx n2)`, `|ũ|² = r0 + (x0 + dx)²`.
#[derive(Debug, Clone, Copy)]
pub struct RowEval {
    pub dy: f32,
    pub yn: f32,
    pub a0: f32,
    pub a1: f32,
    pub a2: f32,
    pub n0: f32,
    pub n1: f32,
    pub n2: f32,
    pub r0: f32,
}

impl RowEval {
    /// `α = ũᵀQũ` at normalised column offset `dx`.
    #[inline(always)]
    pub fn alpha(&self, dx: f32) -> f32 {
        dx.mul_add(dx.mul_add(self.a2, self.a1), self.a0)
    }

    /// `N = ΔᵀCΔ` at normalised column offset `dx`.
    #[inline(always)]
    pub fn quad(&self, dx: f32) -> f32 {
        dx.mul_add(dx.mul_add(self.n2, self.n1), self.n0)
    }

    /// `|ũ|²` for the normalised column `xn = x0 + dx`.
    #[inline(always)]
    pub fn ray_len2(&self, xn: f32) -> f32 {
        xn.mul_add(xn, self.r0)
    }
}

/// Camera-frame quantities a backward pass needs beyond [`Projected`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Frame {
    /// `M = R_view · R_gaussian` (row-major): Gaussian axes in camera coordinates.
    pub m: [f32; 9],
    /// Camera-frame precision (full).
    pub q: Sym3,
    /// Camera-frame centre (mm).
    pub mu: [f32; 3],
}

/// `exp(x)` for `x ≤ 0`, written so that loops over it vectorise (no libm call): range reduction
/// `x = n ln2 + r`, a degree-6 polynomial for `e^r` on `|r| ≤ ln2/2` (relative error < 2e-7),
/// and the exponent added in the float's bits. Returns 0 below −87.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Round to nearest with the 1.5·2²³ trick (vectorises; `round()` is a libm call on x86-64).
    const ROUND: f32 = 12_582_912.0;
    let x = x.max(-87.0);
    let n = x.mul_add(LOG2E, ROUND) - ROUND;
    let r = (-n).mul_add(LN2_LO, (-n).mul_add(LN2_HI, x));
    // Horner with fused multiply-adds (one instruction per step in the FMA kernels).
    let p = (1.0f32 / 720.0).mul_add(r, 1.0 / 120.0);
    let p = p.mul_add(r, 1.0 / 24.0);
    let p = p.mul_add(r, 1.0 / 6.0);
    let p = p.mul_add(r, 0.5);
    let p = p.mul_add(r, 1.0);
    let p = p.mul_add(r, 1.0);
    // 2ⁿ from the float's bits without a float → int conversion (which would not vectorise):
    // n + 127 + 1.5·2²³ holds n + 127 ∈ [1, 127] in its low mantissa bits; shifting by 23
    // moves them into the exponent field and drops the rest.
    let bits = (n + (ROUND + 127.0)).to_bits() << 23;
    let v = p * f32::from_bits(bits);
    if x <= -87.0 { 0.0 } else { v }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_neg_matches_libm() {
        let mut worst = 0.0f64;
        let mut x = -86.0f32;
        while x <= 0.0 {
            let e = (x as f64).exp();
            let rel = ((exp_neg(x) as f64 - e) / e).abs();
            worst = worst.max(rel);
            x += 0.0137;
        }
        assert!(worst < 4e-7, "worst relative error {worst}");
        assert_eq!(exp_neg(-200.0), 0.0);
        assert_eq!(exp_neg(0.0), 1.0);
    }

    #[test]
    fn quaternion_gives_rotation() {
        let (r, _, n) = quat_to_mat([2.0, 0.0, 0.0, 2.0]).unwrap();
        assert!((n - 8f32.sqrt()).abs() < 1e-6);
        // 90° about z: x → y.
        let expect = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        for (a, b) in r.iter().zip(expect) {
            assert!((a - b).abs() < 1e-6, "{r:?}");
        }
        assert!(quat_to_mat([0.0; 4]).is_none());
        assert!(quat_to_mat([f32::NAN, 0.0, 0.0, 1.0]).is_none());
    }
}

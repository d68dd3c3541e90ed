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

/// Row-major product `a · b` of 3 × 3 matrices.
#[inline]
pub fn matmul3(a: &[f32; 9], b: &[f32; 9]) -> [f32; 9] {
    let mut out = [0.0; 9];
    for i in 0..3 {
        for j in 0..3 {
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
        }
    }
    out
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

/// Everything the pixel loops need to evaluate one Gaussian in one view.
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
    /// `k²`, and whether the footprint is bounded (false: the k-σ ellipsoid reaches the source
    /// plane, every pixel is evaluated, no cut-off).
    pub k2: f32,
    pub bounded: bool,
    /// `k²` for a bounded footprint, `+∞` otherwise (branch-free [`Projected::sees`]).
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
    /// Whether the footprint covers at least one pixel.
    #[inline]
    pub fn visible(&self) -> bool {
        self.col_min <= self.col_max && self.row_min <= self.row_max
    }

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

/// Camera-frame quantities a backward pass needs beyond [`Projected`].
#[derive(Debug, Clone, Copy)]
pub struct Frame {
    /// `M = R_view · R_gaussian` (row-major): Gaussian axes in camera coordinates.
    pub m: [f32; 9],
    /// Camera-frame precision (full).
    pub q: Sym3,
    /// Camera-frame centre (mm).
    pub mu: [f32; 3],
}

/// Projects Gaussian `(mean, scale, quat, density)` (world mm) into view `vp` with a k-σ
/// footprint. Returns `None` when the Gaussian is invalid (non-finite, zero quaternion),
/// behind the source, or does not touch the image.
#[inline(always)]
pub fn project(
    mean: [f32; 3],
    scale: [f32; 3],
    quat: [f32; 4],
    density: f32,
    vp: &ViewParams,
    k_sigma: f32,
) -> Option<(Projected, Frame)> {
    if !(density.is_finite() && mean.iter().all(|v| v.is_finite())) {
        return None;
    }
    let (s, _) = clamp_scales(scale)?;
    let (rot, _, _) = quat_to_mat(quat)?;
    let r = &vp.rotation;
    let mu = [
        r[0] * mean[0] + r[1] * mean[1] + r[2] * mean[2] + vp.translation[0],
        r[3] * mean[0] + r[4] * mean[1] + r[5] * mean[2] + vp.translation[1],
        r[6] * mean[0] + r[7] * mean[1] + r[8] * mean[2] + vp.translation[2],
    ];
    if !(mu[2] > 0.0) {
        return None;
    }
    let m = matmul3(r, &rot);
    let q = sandwich_diag(&m, s.map(|v| 1.0 / (v * v)));
    let sig = sandwich_diag(&m, s.map(|v| v * v));
    let proj = setup(mu, &q, &sig, density, vp, k_sigma)?;
    Some((proj, Frame { m, q, mu }))
}

/// The view-independent part of [`project`] once the camera-frame centre, precision and
/// covariance are known.
#[inline(always)]
fn setup(mu: [f32; 3], q: &Sym3, sig: &Sym3, density: f32, vp: &ViewParams, k_sigma: f32) -> Option<Projected> {
    let [qxx, qxy, qxz, qyy, qyz, qzz] = *q;
    let [sxx, sxy, sxz, syy, syz, szz] = *sig;
    let x0 = mu[0] / mu[2];
    let y0 = mu[1] / mu[2];
    let g_x = qxx * x0 + qxy * y0 + qxz;
    let g_y = qxy * x0 + qyy * y0 + qyz;
    let g_z = qxz * x0 + qyz * y0 + qzz;
    let alpha_w = x0 * g_x + y0 * g_y + g_z;
    // Σ₂ = P Σ Pᵀ, P = [[1, 0, −x0], [0, 1, −y0]].
    let s00 = sxx - 2.0 * x0 * sxz + x0 * x0 * szz;
    let s01 = sxy - x0 * syz - y0 * sxz + x0 * y0 * szz;
    let s11 = syy - 2.0 * y0 * syz + y0 * y0 * szz;
    let det = s00 * s11 - s01 * s01;
    if !(det > 0.0 && det.is_finite() && alpha_w > 0.0) {
        return None;
    }
    let scale = mu[2] * mu[2] * alpha_w / det;
    let (c_xx, c_xy, c_yy) = (scale * s11, -scale * s01, scale * s00);
    let k2 = k_sigma * k_sigma;
    let u0 = vp.fx * x0 + vp.cx;
    let v0 = vp.fy * y0 + vp.cy;
    let mut p = Projected {
        u0,
        v0,
        x0,
        y0,
        mu_z: mu[2],
        q_xx: qxx,
        q_xy: qxy,
        q_yy: qyy,
        g_x,
        g_y,
        alpha_w,
        c_xx,
        c_xy,
        c_yy,
        amp: density * SQRT_2PI,
        k2,
        bounded: true,
        cut: k2,
        col_min: 0,
        col_max: vp.width as i32 - 1,
        row_min: 0,
        row_max: vp.height as i32 - 1,
    };
    // Footprint conic F = Δᵀ A Δ + 2 bᵀΔ + c with A = C − k² Q₂, b = −k² g, c = −k² α_w.
    let (a_xx, a_xy, a_yy) = (c_xx - k2 * qxx, c_xy - k2 * qxy, c_yy - k2 * qyy);
    let det_a = a_xx * a_yy - a_xy * a_xy;
    if !(a_xx > 0.0 && det_a > 0.0) {
        // The k-σ ellipsoid reaches the source plane: unbounded footprint, every pixel.
        p.bounded = false;
        p.cut = f32::INFINITY;
        return Some(p);
    }
    let (b_x, b_y) = (-k2 * g_x, -k2 * g_y);
    let (i_xx, i_xy, i_yy) = (a_yy / det_a, -a_xy / det_a, a_xx / det_a);
    let (pc_x, pc_y) = (-(i_xx * b_x + i_xy * b_y), -(i_xy * b_x + i_yy * b_y));
    let f_min = -k2 * alpha_w + (b_x * pc_x + b_y * pc_y);
    if !(f_min < 0.0) {
        return None;
    }
    let (hx, hy) = ((-f_min * i_xx).sqrt(), (-f_min * i_yy).sqrt());
    let col_lo = (u0 + (pc_x - hx) * vp.fx).ceil();
    let col_hi = (u0 + (pc_x + hx) * vp.fx).floor();
    let row_lo = (v0 + (pc_y - hy) * vp.fy).ceil();
    let row_hi = (v0 + (pc_y + hy) * vp.fy).floor();
    if !(col_lo.is_finite() && col_hi.is_finite() && row_lo.is_finite() && row_hi.is_finite()) {
        return None;
    }
    p.col_min = col_lo.max(0.0) as i32;
    p.col_max = col_hi.min(vp.width as f32 - 1.0) as i32;
    p.row_min = row_lo.max(0.0) as i32;
    p.row_max = row_hi.min(vp.height as f32 - 1.0) as i32;
    p.visible().then_some(p)
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
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0 / 720.0;
    let p = p * r + 1.0 / 120.0;
    let p = p * r + 1.0 / 24.0;
    let p = p * r + 1.0 / 6.0;
    let p = p * r + 0.5;
    let p = p * r + 1.0;
    let p = p * r + 1.0;
    let bits = ((n as i32).wrapping_add(127) as u32) << 23;
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

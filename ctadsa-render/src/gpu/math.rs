//! CubeCL device functions mirroring `cpu::math`: quaternion to rotation, camera-frame
//! precision and covariance, the per-view set-up of the exact line integral, row spans of the
//! k-σ footprint, and the chain rule from `∂L/∂Q` to scales and quaternions.
//! Formulas and names follow `cpu::math` line by line; the CPU code is the reference.
// CubeCL kernels: `RangeInclusive::contains` is not available inside `#[cube]` functions.
#![allow(clippy::manual_range_contains)]

use burn_cubecl::cubecl;
use cubecl::prelude::*;

/// Number of f32 per packed view (`crate::VIEW_PARAMS_LEN`).
pub const VIEW_LEN: usize = 20;
/// √(2π).
pub const SQRT_2PI: f32 = 2.506_628_3;
/// Pixels by which [`row_columns`] widens a row's span on each side.
pub const SPAN_MARGIN_PX: f32 = 2.0;

/// Row-major 3 × 3 matrix.
#[derive(CubeType, Clone, Copy)]
pub struct Mat3 {
    pub m00: f32,
    pub m01: f32,
    pub m02: f32,
    pub m10: f32,
    pub m11: f32,
    pub m12: f32,
    pub m20: f32,
    pub m21: f32,
    pub m22: f32,
}

/// Symmetric 3 × 3 matrix.
#[derive(CubeType, Clone, Copy)]
pub struct Sym3 {
    pub xx: f32,
    pub xy: f32,
    pub xz: f32,
    pub yy: f32,
    pub yz: f32,
    pub zz: f32,
}

/// One Gaussian in one view (see `cpu::math::Projected` and `cpu::math::Frame`).
#[derive(CubeType, Clone, Copy)]
pub struct Proj {
    pub u0: f32,
    pub v0: f32,
    pub x0: f32,
    pub y0: f32,
    pub mu_z: f32,
    pub q: Sym3,
    pub g_x: f32,
    pub g_y: f32,
    pub alpha_w: f32,
    pub c_xx: f32,
    pub c_xy: f32,
    pub c_yy: f32,
    pub k2: f32,
    /// 1: bounded footprint; 0: every pixel.
    pub bounded: u32,
    /// 1: visible in the image.
    pub valid: u32,
    pub col_min: u32,
    pub col_max: u32,
    pub row_min: u32,
    pub row_max: u32,
}

/// The view constants.
#[derive(CubeType, Clone, Copy)]
pub struct View {
    pub r: Mat3,
    pub t_x: f32,
    pub t_y: f32,
    pub t_z: f32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub inv_fx: f32,
    pub inv_fy: f32,
    pub width: u32,
    pub height: u32,
}

/// Finite check on the bits (WGSL may assume that NaN and ∞ do not occur, so `is_nan` can be
/// folded away by a shader compiler; the exponent bits cannot).
#[cube]
pub fn finite(x: f32) -> bool {
    (x.to_bits() & 0x7F80_0000u32) != 0x7F80_0000u32
}

#[cube]
pub fn load_view(views: &Tensor<f32>, v: usize) -> View {
    let b = v * VIEW_LEN;
    View {
        r: Mat3 {
            m00: views[b],
            m01: views[b + 1],
            m02: views[b + 2],
            m10: views[b + 3],
            m11: views[b + 4],
            m12: views[b + 5],
            m20: views[b + 6],
            m21: views[b + 7],
            m22: views[b + 8],
        },
        t_x: views[b + 9],
        t_y: views[b + 10],
        t_z: views[b + 11],
        fx: views[b + 12],
        fy: views[b + 13],
        cx: views[b + 14],
        cy: views[b + 15],
        inv_fx: views[b + 16],
        inv_fy: views[b + 17],
        width: u32::cast_from(views[b + 18]),
        height: u32::cast_from(views[b + 19]),
    }
}

/// Rotation of the normalised quaternion `(w, x, y, z)`.
#[cube]
pub fn quat_to_mat(w: f32, x: f32, y: f32, z: f32) -> Mat3 {
    Mat3 {
        m00: 1.0 - 2.0 * (y * y + z * z),
        m01: 2.0 * (x * y - w * z),
        m02: 2.0 * (x * z + w * y),
        m10: 2.0 * (x * y + w * z),
        m11: 1.0 - 2.0 * (x * x + z * z),
        m12: 2.0 * (y * z - w * x),
        m20: 2.0 * (x * z - w * y),
        m21: 2.0 * (y * z + w * x),
        m22: 1.0 - 2.0 * (x * x + y * y),
    }
}

#[cube]
pub fn matmul(a: &Mat3, b: &Mat3) -> Mat3 {
    Mat3 {
        m00: a.m00 * b.m00 + a.m01 * b.m10 + a.m02 * b.m20,
        m01: a.m00 * b.m01 + a.m01 * b.m11 + a.m02 * b.m21,
        m02: a.m00 * b.m02 + a.m01 * b.m12 + a.m02 * b.m22,
        m10: a.m10 * b.m00 + a.m11 * b.m10 + a.m12 * b.m20,
        m11: a.m10 * b.m01 + a.m11 * b.m11 + a.m12 * b.m21,
        m12: a.m10 * b.m02 + a.m11 * b.m12 + a.m12 * b.m22,
        m20: a.m20 * b.m00 + a.m21 * b.m10 + a.m22 * b.m20,
        m21: a.m20 * b.m01 + a.m21 * b.m11 + a.m22 * b.m21,
        m22: a.m20 * b.m02 + a.m21 * b.m12 + a.m22 * b.m22,
    }
}

/// `M diag(d) Mᵀ`.
#[cube]
pub fn sandwich_diag(m: &Mat3, d0: f32, d1: f32, d2: f32) -> Sym3 {
    Sym3 {
        xx: m.m00 * d0 * m.m00 + m.m01 * d1 * m.m01 + m.m02 * d2 * m.m02,
        xy: m.m00 * d0 * m.m10 + m.m01 * d1 * m.m11 + m.m02 * d2 * m.m12,
        xz: m.m00 * d0 * m.m20 + m.m01 * d1 * m.m21 + m.m02 * d2 * m.m22,
        yy: m.m10 * d0 * m.m10 + m.m11 * d1 * m.m11 + m.m12 * d2 * m.m12,
        yz: m.m10 * d0 * m.m20 + m.m11 * d1 * m.m21 + m.m12 * d2 * m.m22,
        zz: m.m20 * d0 * m.m20 + m.m21 * d1 * m.m21 + m.m22 * d2 * m.m22,
    }
}

/// The Gaussian's parameters after the validity checks of `cpu::math::project`.
#[derive(CubeType, Clone, Copy)]
pub struct Params {
    pub mx: f32,
    pub my: f32,
    pub mz: f32,
    pub s0: f32,
    pub s1: f32,
    pub s2: f32,
    /// 1 where the raw scale was inside the clamp range.
    pub in0: f32,
    pub in1: f32,
    pub in2: f32,
    pub qw: f32,
    pub qx: f32,
    pub qy: f32,
    pub qz: f32,
    pub qnorm: f32,
    pub density: f32,
    pub valid: u32,
}

#[cube]
fn clamp_scale(s: f32) -> f32 {
    f32::clamp(s, 1e-4, 1e5)
}

#[cube]
fn inside_scale(s: f32) -> f32 {
    let mut r = 0.0f32;
    if s >= 1e-4 && s <= 1e5 {
        r = 1.0;
    }
    r
}

#[cube]
pub fn load_params(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    i: usize,
) -> Params {
    let mx = means[3 * i];
    let my = means[3 * i + 1];
    let mz = means[3 * i + 2];
    let rs0 = scales[3 * i];
    let rs1 = scales[3 * i + 1];
    let rs2 = scales[3 * i + 2];
    let rw = rotations[4 * i];
    let rx = rotations[4 * i + 1];
    let ry = rotations[4 * i + 2];
    let rz = rotations[4 * i + 3];
    let density = densities[i];
    let n2 = rw * rw + rx * rx + ry * ry + rz * rz;
    let mut valid = 1u32;
    if !(finite(mx) && finite(my) && finite(mz) && finite(density)) {
        valid = 0u32;
    }
    if !(finite(rs0) && finite(rs1) && finite(rs2) && rs0 > 0.0 && rs1 > 0.0 && rs2 > 0.0) {
        valid = 0u32;
    }
    if !(finite(n2) && n2 > 1e-24) {
        valid = 0u32;
    }
    let mut qnorm = 1.0f32;
    if valid == 1u32 {
        qnorm = f32::sqrt(n2);
    }
    Params {
        mx,
        my,
        mz,
        s0: clamp_scale(rs0),
        s1: clamp_scale(rs1),
        s2: clamp_scale(rs2),
        in0: inside_scale(rs0),
        in1: inside_scale(rs1),
        in2: inside_scale(rs2),
        qw: rw / qnorm,
        qx: rx / qnorm,
        qy: ry / qnorm,
        qz: rz / qnorm,
        qnorm,
        density,
        valid,
    }
}

/// `cpu::math::project` for Gaussian parameters `p` in view `vw`.
#[cube]
pub fn project(p: &Params, vw: &View, k_sigma: f32) -> Proj {
    let mu_x = vw.r.m00 * p.mx + vw.r.m01 * p.my + vw.r.m02 * p.mz + vw.t_x;
    let mu_y = vw.r.m10 * p.mx + vw.r.m11 * p.my + vw.r.m12 * p.mz + vw.t_y;
    let mu_z = vw.r.m20 * p.mx + vw.r.m21 * p.my + vw.r.m22 * p.mz + vw.t_z;
    let rot = quat_to_mat(p.qw, p.qx, p.qy, p.qz);
    let m = matmul(&vw.r, &rot);
    let q = sandwich_diag(&m, 1.0 / (p.s0 * p.s0), 1.0 / (p.s1 * p.s1), 1.0 / (p.s2 * p.s2));
    let sig = sandwich_diag(&m, p.s0 * p.s0, p.s1 * p.s1, p.s2 * p.s2);
    let mut valid = p.valid;
    let mut z = mu_z;
    if !(mu_z > 0.0) {
        valid = 0u32;
        z = 1.0;
    }
    let x0 = mu_x / z;
    let y0 = mu_y / z;
    let g_x = q.xx * x0 + q.xy * y0 + q.xz;
    let g_y = q.xy * x0 + q.yy * y0 + q.yz;
    let g_z = q.xz * x0 + q.yz * y0 + q.zz;
    let alpha_w = x0 * g_x + y0 * g_y + g_z;
    let s00 = sig.xx - 2.0 * x0 * sig.xz + x0 * x0 * sig.zz;
    let s01 = sig.xy - x0 * sig.yz - y0 * sig.xz + x0 * y0 * sig.zz;
    let s11 = sig.yy - 2.0 * y0 * sig.yz + y0 * y0 * sig.zz;
    let det = s00 * s11 - s01 * s01;
    if !(det > 0.0 && finite(det) && alpha_w > 0.0) {
        valid = 0u32;
    }
    let scale = z * z * alpha_w / det;
    let c_xx = scale * s11;
    let c_xy = -scale * s01;
    let c_yy = scale * s00;
    let k2 = k_sigma * k_sigma;
    let u0 = vw.fx * x0 + vw.cx;
    let v0 = vw.fy * y0 + vw.cy;
    let wf = f32::cast_from(vw.width);
    let hf = f32::cast_from(vw.height);
    let a_xx = c_xx - k2 * q.xx;
    let a_xy = c_xy - k2 * q.xy;
    let a_yy = c_yy - k2 * q.yy;
    let det_a = a_xx * a_yy - a_xy * a_xy;
    let mut bounded = 1u32;
    let mut col_lo = 0.0f32;
    let mut col_hi = wf - 1.0;
    let mut row_lo = 0.0f32;
    let mut row_hi = hf - 1.0;
    if !(a_xx > 0.0 && det_a > 0.0) {
        bounded = 0u32;
    } else {
        let b_x = -k2 * g_x;
        let b_y = -k2 * g_y;
        let i_xx = a_yy / det_a;
        let i_xy = -a_xy / det_a;
        let i_yy = a_xx / det_a;
        let pc_x = -(i_xx * b_x + i_xy * b_y);
        let pc_y = -(i_xy * b_x + i_yy * b_y);
        let f_min = -k2 * alpha_w + (b_x * pc_x + b_y * pc_y);
        if !(f_min < 0.0) {
            valid = 0u32;
        } else {
            let hx = f32::sqrt(-f_min * i_xx);
            let hy = f32::sqrt(-f_min * i_yy);
            col_lo = f32::ceil(u0 + (pc_x - hx) * vw.fx);
            col_hi = f32::floor(u0 + (pc_x + hx) * vw.fx);
            row_lo = f32::ceil(v0 + (pc_y - hy) * vw.fy);
            row_hi = f32::floor(v0 + (pc_y + hy) * vw.fy);
            if !(finite(col_lo) && finite(col_hi) && finite(row_lo) && finite(row_hi)) {
                valid = 0u32;
            }
            col_lo = f32::max(col_lo, 0.0);
            col_hi = f32::min(col_hi, wf - 1.0);
            row_lo = f32::max(row_lo, 0.0);
            row_hi = f32::min(row_hi, hf - 1.0);
            if !(col_lo <= col_hi && row_lo <= row_hi) {
                valid = 0u32;
            }
        }
    }
    if valid == 0u32 {
        col_lo = 0.0;
        col_hi = 0.0;
        row_lo = 0.0;
        row_hi = 0.0;
    }
    Proj {
        u0,
        v0,
        x0,
        y0,
        mu_z: z,
        q,
        g_x,
        g_y,
        alpha_w,
        c_xx,
        c_xy,
        c_yy,
        k2,
        bounded,
        valid,
        col_min: u32::cast_from(col_lo),
        col_max: u32::cast_from(col_hi),
        row_min: u32::cast_from(row_lo),
        row_max: u32::cast_from(row_hi),
    }
}

/// Row coefficients `(dy, yn, a0, a1, n0, n1, r0)` (`cpu::math::Projected::row_eval`;
/// `a2 = Q_xx`, `n2 = C_xx`).
#[derive(CubeType, Clone, Copy)]
pub struct RowEval {
    pub dy: f32,
    pub yn: f32,
    pub a0: f32,
    pub a1: f32,
    pub n0: f32,
    pub n1: f32,
    pub r0: f32,
}

#[cube]
pub fn row_eval(pr: &Proj, vw: &View, row: u32) -> RowEval {
    let dy = (f32::cast_from(row) - pr.v0) * vw.inv_fy;
    let yn = pr.y0 + dy;
    RowEval {
        dy,
        yn,
        a0: pr.alpha_w + 2.0 * pr.g_y * dy + pr.q.yy * dy * dy,
        a1: 2.0 * (pr.g_x + pr.q.xy * dy),
        n0: pr.c_yy * dy * dy,
        n1: 2.0 * pr.c_xy * dy,
        r0: 1.0 + yn * yn,
    }
}

/// Columns (inclusive; empty when the first exceeds the last) of row `re` whose rays may meet
/// the k-σ ellipsoid: the roots of the row's quadratic `N − k²α ≤ 0` in `dx`, widened by
/// [`SPAN_MARGIN_PX`] against rounding and cut to the footprint's box. A superset of the
/// pixels [`unit_value`] sees; every column of the box for unbounded footprints.
#[cube]
pub fn row_columns(pr: &Proj, re: &RowEval, vw: &View) -> (u32, u32) {
    let mut first = pr.col_min;
    let mut last = pr.col_max;
    if pr.bounded == 1u32 {
        // a > 0 for bounded footprints (`project`).
        let a = pr.c_xx - pr.k2 * pr.q.xx;
        let b = re.n1 - pr.k2 * re.a1;
        let c = re.n0 - pr.k2 * re.a0;
        let root = f32::sqrt(f32::max(b * b - 4.0 * a * c, 0.0));
        let lo = pr.u0 + (-b - root) / (2.0 * a) * vw.fx - SPAN_MARGIN_PX;
        let hi = pr.u0 + (-b + root) / (2.0 * a) * vw.fx + SPAN_MARGIN_PX;
        let box_lo = f32::cast_from(pr.col_min);
        let box_hi = f32::cast_from(pr.col_max);
        // Comparisons first: a NaN bound keeps the box.
        if lo > box_lo {
            first = u32::cast_from(f32::ceil(f32::min(lo, box_hi + 1.0)));
        }
        if hi < box_hi {
            last = u32::cast_from(f32::floor(f32::max(hi, box_lo)));
        }
    }
    (first, last)
}

/// `I/ρ` at normalised column offset `dx`: `√(2π) sqrt(|ũ|²/α) exp(−½ N/α)` — 0 when the
/// pixel's ray misses the k-σ ellipsoid (`N > k²α`, bounded footprints; `cpu::math::Projected::sees`)
/// — and `1/α`.
#[cube]
pub fn unit_value(pr: &Proj, re: &RowEval, dx: f32) -> (f32, f32) {
    let alpha = re.a0 + dx * (re.a1 + dx * pr.q.xx);
    let quad = re.n0 + dx * (re.n1 + dx * pr.c_xx);
    let xn = pr.x0 + dx;
    let r2 = re.r0 + xn * xn;
    let inv_a = 1.0 / alpha;
    let value = SQRT_2PI * f32::sqrt(r2 * inv_a) * f32::exp(quad * inv_a * -0.5f32);
    let sees = pr.bounded == 0u32 || quad <= pr.k2 * alpha;
    (select(sees, value, 0.0f32), inv_a)
}

//! CPU backward pass, Gaussian-major: each Gaussian walks its own footprint in every view and
//! sums its gradient from the upstream image gradient. No two threads write the same value, and
//! each Gaussian's sums run in a fixed pixel order, so the result is deterministic.
//!
//! Per pixel, with `I` the pixel's term, `g = ∂L/∂I`, `e = μ_z (Δ − β ũ)` the offset from the
//! centre to the Mahalanobis-closest point of the ray (`β = (Qũ)·Δ / α`), xray-splatting.md §3:
//! `∂I/∂ρ = I/ρ`, `∂I/∂μ = I Q e`, `∂I/∂Q = −½ I (ũũᵀ/α + e eᵀ)`.

use rayon::prelude::*;

use super::host::HostGaussians;
use super::math::{Frame, Projected, SQRT_2PI, Sym3, clamp_scales, exp_neg, quat_to_mat};
use super::project::project_range;
use crate::view_params::ViewParams;

/// Gradients of a scalar loss with respect to the render inputs (row-major, like the inputs),
/// plus the densification statistic.
#[derive(Debug, Clone, Default)]
pub struct HostGrads {
    pub means: Vec<f32>,
    pub scales: Vec<f32>,
    pub rotations: Vec<f32>,
    pub densities: Vec<f32>,
    /// `[N·2]`: per Gaussian, the sum over views of the norm of `∂L/∂(projected centre)` in NDC
    /// units (pixels × half the image size), and the number of views whose image it touched.
    pub screen_stats: Vec<f32>,
}

/// Sums over one view's footprint, in the camera frame.
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    /// `Σ g I/ρ`.
    unit: f32,
    /// `Σ g I e` (mm).
    e: [f32; 3],
    /// `Σ g I (ũũᵀ/α + eeᵀ)`, symmetric.
    m: Sym3,
}

/// Lanes per inner-loop chunk; the arrays below vectorise.
const LANES: usize = 8;

#[inline(always)]
fn row_sums(
    p: &Projected,
    vp: &ViewParams,
    row: i32,
    c0: i32,
    c1: i32,
    grad_row: &[f32],
    acc: &mut [[f32; LANES]; 10],
) {
    let re = p.row_eval(row, vp);
    let dy = re.dy;
    let yn = re.yn;
    let mu_z = p.mu_z;
    let density = p.amp * (1.0 / SQRT_2PI);
    let n = (c1 - c0 + 1) as usize;
    let mut j = 0;
    let lane_col: [f32; LANES] = std::array::from_fn(|l| l as f32);
    while j < n {
        let take = (n - j).min(LANES);
        let first = (c0 as usize + j) as f32;
        let start = c0 as usize + j;
        // A whole-chunk load where the row allows it (one vector load, no `memcpy` call);
        // lanes past the span get weight 0.
        let mut g_lane = [0.0f32; LANES];
        match grad_row.get(start..start + LANES) {
            Some(whole) => g_lane.copy_from_slice(whole),
            None => g_lane[..take].copy_from_slice(&grad_row[start..start + take]),
        }
        let live: [bool; LANES] = std::array::from_fn(|l| l < take);
        for l in 0..LANES {
            let g = g_lane[l];
            let dx = (first + lane_col[l] - p.u0) * vp.inv_fx;
            let alpha = re.alpha(dx);
            let quad = re.quad(dx);
            let xn = p.x0 + dx;
            let r2 = re.ray_len2(xn);
            let inv_a = 1.0 / alpha;
            let unit = SQRT_2PI * (r2 * inv_a).sqrt() * exp_neg(-0.5 * quad * inv_a);
            let g = if live[l] & p.sees(quad, alpha) { g } else { 0.0 };
            let gu = g * unit;
            let gi = gu * density;
            // β = (Qũ)·Δ / α, Qũ = g_w + Q Δ.
            let qu_x = p.q_xy.mul_add(dy, p.q_xx.mul_add(dx, p.g_x));
            let qu_y = p.q_yy.mul_add(dy, p.q_xy.mul_add(dx, p.g_y));
            let beta = qu_y.mul_add(dy, qu_x * dx) * inv_a;
            let ex = mu_z * (-beta).mul_add(xn, dx);
            let ey = mu_z * (-beta).mul_add(yn, dy);
            let ez = -mu_z * beta;
            let gia = gi * inv_a;
            let (gix, giy, giz) = (gi * ex, gi * ey, gi * ez);
            let (gxn, gyn) = (gia * xn, gia * yn);
            acc[0][l] += gu;
            acc[1][l] += gix;
            acc[2][l] += giy;
            acc[3][l] += giz;
            acc[4][l] += gxn.mul_add(xn, gix * ex);
            acc[5][l] += gxn.mul_add(yn, gix * ey);
            acc[6][l] += gix.mul_add(ez, gxn);
            acc[7][l] += gyn.mul_add(yn, giy * ey);
            acc[8][l] += giy.mul_add(ez, gyn);
            acc[9][l] += giz.mul_add(ez, gia);
        }
        j += LANES;
    }
}

/// Walks the footprint of one projected Gaussian over the upstream gradient `grad` (`H × W`).
#[inline(always)]
fn footprint_sums(p: &Projected, vp: &ViewParams, grad: &[f32]) -> Sums {
    let w = vp.width as usize;
    let mut acc = [[0.0f32; LANES]; 10];
    for row in p.row_min..=p.row_max {
        let grad_row = &grad[row as usize * w..(row as usize + 1) * w];
        row_sums(p, vp, row, p.col_min, p.col_max, grad_row, &mut acc);
    }
    let s: [f32; 10] = acc.map(|a| a.iter().sum());
    Sums { unit: s[0], e: [s[1], s[2], s[3]], m: [s[4], s[5], s[6], s[7], s[8], s[9]] }
}

/// World-frame gradient sums of one Gaussian over all views.
#[derive(Debug, Clone, Copy, Default)]
pub struct WorldSums {
    /// `∂L/∂ρ`.
    pub density: f32,
    /// `∂L/∂μ` (world).
    pub mean: [f32; 3],
    /// `∂L/∂Q` (world), symmetric.
    pub precision: Sym3,
    /// Sum over views of the NDC-scaled projected-centre gradient norm, and the visible-view count.
    pub stat: f32,
    pub visible: f32,
}

/// Adds the view's camera-frame sums to the world-frame sums.
#[inline(always)]
pub fn accumulate_view(
    ws: &mut WorldSums,
    unit: f32,
    e: [f32; 3],
    m: Sym3,
    frame: &Frame,
    p: &Projected,
    vp: &ViewParams,
) {
    let q = &frame.q;
    // ∂L/∂μ_c = Q E.
    let d_mu = [
        q[0] * e[0] + q[1] * e[1] + q[2] * e[2],
        q[1] * e[0] + q[3] * e[1] + q[4] * e[2],
        q[2] * e[0] + q[4] * e[1] + q[5] * e[2],
    ];
    let r = &vp.rotation;
    for (i, dm) in ws.mean.iter_mut().enumerate() {
        *dm += r[i] * d_mu[0] + r[3 + i] * d_mu[1] + r[6 + i] * d_mu[2];
    }
    // ∂L/∂Q_c = −½ M;  ∂L/∂Q_w = Rᵀ (∂L/∂Q_c) R, as T = M R then Rᵀ T.
    let mf = [m[0], m[1], m[2], m[1], m[3], m[4], m[2], m[4], m[5]];
    let mut t = [0.0f32; 9];
    for a in 0..3 {
        for j in 0..3 {
            t[3 * a + j] = mf[3 * a] * r[j] + mf[3 * a + 1] * r[3 + j] + mf[3 * a + 2] * r[6 + j];
        }
    }
    const PAIRS: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    for (slot, &(i, j)) in ws.precision.iter_mut().zip(PAIRS.iter()) {
        let v = r[i] * t[j] + r[3 + i] * t[3 + j] + r[6 + i] * t[6 + j];
        *slot += -0.5 * v;
    }
    ws.density += unit;
    let du = d_mu[0] * p.mu_z * vp.inv_fx * (vp.width as f32 * 0.5);
    let dv = d_mu[1] * p.mu_z * vp.inv_fy * (vp.height as f32 * 0.5);
    ws.stat += (du * du + dv * dv).sqrt();
    ws.visible += 1.0;
}

/// Chains world-frame `∂L/∂Q` to the (clamped) scales and the (unnormalised) quaternion:
/// `∂L/∂s_k = −2 s_k⁻³ r_kᵀ G r_k`, `∂L/∂R = 2 G R S⁻²`, then through `R(q̂)` and `q̂ = q/|q|`.
#[inline(always)]
pub fn chain_precision(scale: [f32; 3], quat: [f32; 4], g: &Sym3) -> ([f32; 3], [f32; 4]) {
    let (Some((s, inside)), Some((r, qn, norm))) = (clamp_scales(scale), quat_to_mat(quat)) else {
        return ([0.0; 3], [0.0; 4]);
    };
    let gm = [g[0], g[1], g[2], g[1], g[3], g[4], g[2], g[4], g[5]];
    // G R (row-major), column k of R is r[k], r[3+k], r[6+k].
    let mut gr = [0.0f32; 9];
    for i in 0..3 {
        for k in 0..3 {
            gr[3 * i + k] = gm[3 * i] * r[k] + gm[3 * i + 1] * r[3 + k] + gm[3 * i + 2] * r[6 + k];
        }
    }
    let mut d_scale = [0.0f32; 3];
    for k in 0..3 {
        let rgr = r[k] * gr[k] + r[3 + k] * gr[3 + k] + r[6 + k] * gr[6 + k];
        d_scale[k] = if inside[k] { -2.0 * rgr / (s[k] * s[k] * s[k]) } else { 0.0 };
    }
    let inv_s2 = s.map(|v| 1.0 / (v * v));
    let d = |i: usize, j: usize| 2.0 * gr[3 * i + j] * inv_s2[j];
    let [w, x, y, z] = qn;
    let gw = 2.0 * (-z * d(0, 1) + y * d(0, 2) + z * d(1, 0) - x * d(1, 2) - y * d(2, 0) + x * d(2, 1));
    let gx = 2.0
        * (y * d(0, 1) + z * d(0, 2) + y * d(1, 0) - 2.0 * x * d(1, 1) - w * d(1, 2) + z * d(2, 0) + w * d(2, 1)
            - 2.0 * x * d(2, 2));
    let gy = 2.0
        * (-2.0 * y * d(0, 0) + x * d(0, 1) + w * d(0, 2) + x * d(1, 0) + z * d(1, 2) - w * d(2, 0) + z * d(2, 1)
            - 2.0 * y * d(2, 2));
    let gz = 2.0
        * (-2.0 * z * d(0, 0) - w * d(0, 1) + x * d(0, 2) + w * d(1, 0) - 2.0 * z * d(1, 1)
            + y * d(1, 2)
            + x * d(2, 0)
            + y * d(2, 1));
    let gq = [gw, gx, gy, gz];
    let dot = gq[0] * w + gq[1] * x + gq[2] * y + gq[3] * z;
    let d_quat = [0, 1, 2, 3].map(|c| (gq[c] - qn[c] * dot) / norm);
    (d_scale, d_quat)
}

/// One Gaussian's gradients: `(mean, scale, quaternion, density, [statistic, visible views])`.
type GaussianGrad = ([f32; 3], [f32; 3], [f32; 4], f32, [f32; 2]);

/// Gradients of Gaussians `first..first + out.len()` over all views.
#[multiversion::multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn gradients_chunk(
    g: &HostGaussians,
    first: usize,
    views: &[ViewParams],
    k_sigma: f32,
    grad: &[f32],
    out: &mut [GaussianGrad],
) {
    let n = out.len();
    let mut sums = vec![WorldSums::default(); n];
    let mut projected = vec![None; n];
    let mut frames = vec![Frame::default(); n];
    let mut offset = 0;
    for vp in views {
        let size = (vp.width * vp.height) as usize;
        let view_grad = &grad[offset..offset + size];
        offset += size;
        project_range(g, first, vp, k_sigma, &mut projected, Some(&mut frames));
        for ((ws, p), frame) in sums.iter_mut().zip(&projected).zip(&frames) {
            let Some(p) = p else { continue };
            let s = footprint_sums(p, vp, view_grad);
            accumulate_view(ws, s.unit, s.e, s.m, frame, p, vp);
        }
    }
    for (j, (o, ws)) in out.iter_mut().zip(&sums).enumerate() {
        let (_, scale, quat, _) = g.get(first + j);
        let (d_scale, d_quat) = chain_precision(scale, quat, &ws.precision);
        *o = (ws.mean, d_scale, d_quat, ws.density, [ws.stat, ws.visible]);
    }
}

/// Backward pass over all views: `grad` is `∂L/∂image`, `[V, H, W]`.
pub fn render_backward(g: &HostGaussians, views: &[ViewParams], k_sigma: f32, grad: &[f32]) -> HostGrads {
    let n = g.len();
    const CHUNK: usize = 256;
    let mut out = HostGrads {
        means: vec![0.0; 3 * n],
        scales: vec![0.0; 3 * n],
        rotations: vec![0.0; 4 * n],
        densities: vec![0.0; n],
        screen_stats: vec![0.0; 2 * n],
    };
    out.means
        .par_chunks_mut(3 * CHUNK)
        .zip(out.scales.par_chunks_mut(3 * CHUNK))
        .zip(out.rotations.par_chunks_mut(4 * CHUNK))
        .zip(out.densities.par_chunks_mut(CHUNK))
        .zip(out.screen_stats.par_chunks_mut(2 * CHUNK))
        .enumerate()
        .with_max_len(4)
        .for_each(|(c, ((((means, scales), rotations), densities), stats))| {
            let mut per = [GaussianGrad::default(); CHUNK];
            let per = &mut per[..densities.len()];
            gradients_chunk(g, c * CHUNK, views, k_sigma, grad, per);
            for (j, (m, s, q, d, st)) in per.iter().enumerate() {
                means[3 * j..3 * j + 3].copy_from_slice(m);
                scales[3 * j..3 * j + 3].copy_from_slice(s);
                rotations[4 * j..4 * j + 4].copy_from_slice(q);
                densities[j] = *d;
                stats[2 * j..2 * j + 2].copy_from_slice(st);
            }
        });
    out
}

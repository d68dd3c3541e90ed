//! CubeCL backward kernel: `split` units per Gaussian walk its footprint in every view (each
//! every `split`-th row, over the row's exact column span), the first of them sums their
//! camera-frame gradient terms, moves them to the world frame and chains them to the scales and
//! the quaternion (`cpu::backward`, line by line). No atomics: each Gaussian's first unit writes
//! its outputs.
// CubeCL kernels: `x * -1.0` keeps the expression in the kernel IR's binary-op form.
#![allow(clippy::neg_multiply)]

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::math::{Params, Sym3, load_params, load_view, project, quat_to_mat, row_columns, row_eval, unit_value};

/// `∂L/∂s` and `∂L/∂q` (unnormalised) from the world-frame `∂L/∂Q` (`cpu::backward::chain_precision`).
#[derive(CubeType, Clone, Copy)]
pub struct Chain {
    pub ds0: f32,
    pub ds1: f32,
    pub ds2: f32,
    pub dw: f32,
    pub dx: f32,
    pub dy: f32,
    pub dz: f32,
}

#[cube]
pub fn chain_precision(p: &Params, g: &Sym3) -> Chain {
    let r = quat_to_mat(p.qw, p.qx, p.qy, p.qz);
    // G R
    let gr00 = g.xx * r.m00 + g.xy * r.m10 + g.xz * r.m20;
    let gr01 = g.xx * r.m01 + g.xy * r.m11 + g.xz * r.m21;
    let gr02 = g.xx * r.m02 + g.xy * r.m12 + g.xz * r.m22;
    let gr10 = g.xy * r.m00 + g.yy * r.m10 + g.yz * r.m20;
    let gr11 = g.xy * r.m01 + g.yy * r.m11 + g.yz * r.m21;
    let gr12 = g.xy * r.m02 + g.yy * r.m12 + g.yz * r.m22;
    let gr20 = g.xz * r.m00 + g.yz * r.m10 + g.zz * r.m20;
    let gr21 = g.xz * r.m01 + g.yz * r.m11 + g.zz * r.m21;
    let gr22 = g.xz * r.m02 + g.yz * r.m12 + g.zz * r.m22;
    let rgr0 = r.m00 * gr00 + r.m10 * gr10 + r.m20 * gr20;
    let rgr1 = r.m01 * gr01 + r.m11 * gr11 + r.m21 * gr21;
    let rgr2 = r.m02 * gr02 + r.m12 * gr12 + r.m22 * gr22;
    let ds0 = p.in0 * (rgr0 * -2.0f32 / (p.s0 * p.s0 * p.s0));
    let ds1 = p.in1 * (rgr1 * -2.0f32 / (p.s1 * p.s1 * p.s1));
    let ds2 = p.in2 * (rgr2 * -2.0f32 / (p.s2 * p.s2 * p.s2));
    let i0 = 1.0 / (p.s0 * p.s0);
    let i1 = 1.0 / (p.s1 * p.s1);
    let i2 = 1.0 / (p.s2 * p.s2);
    // ∂L/∂R = 2 G R S⁻²
    let d00 = 2.0 * gr00 * i0;
    let d01 = 2.0 * gr01 * i1;
    let d02 = 2.0 * gr02 * i2;
    let d10 = 2.0 * gr10 * i0;
    let d11 = 2.0 * gr11 * i1;
    let d12 = 2.0 * gr12 * i2;
    let d20 = 2.0 * gr20 * i0;
    let d21 = 2.0 * gr21 * i1;
    let d22 = 2.0 * gr22 * i2;
    let w = p.qw;
    let x = p.qx;
    let y = p.qy;
    let z = p.qz;
    let gw = 2.0 * (y * d02 - z * d01 + z * d10 - x * d12 - y * d20 + x * d21);
    let gx = 2.0 * (y * d01 + z * d02 + y * d10 - 2.0 * x * d11 - w * d12 + z * d20 + w * d21 - 2.0 * x * d22);
    let gy = 2.0 * (x * d01 - 2.0 * y * d00 + w * d02 + x * d10 + z * d12 - w * d20 + z * d21 - 2.0 * y * d22);
    let gz = 2.0 * (x * d02 - 2.0 * z * d00 - w * d01 + w * d10 - 2.0 * z * d11 + y * d12 + x * d20 + y * d21);
    let dot = gw * w + gx * x + gy * y + gz * z;
    Chain {
        ds0,
        ds1,
        ds2,
        dw: (gw - w * dot) / p.qnorm,
        dx: (gx - x * dot) / p.qnorm,
        dy: (gy - y * dot) / p.qnorm,
        dz: (gz - z * dot) / p.qnorm,
    }
}

/// Sums each view's pixel terms are gathered into, per unit of a workgroup.
const TERMS: usize = 10;

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn render_backward_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    views: &Tensor<f32>,
    grad: &Tensor<f32>,
    g_means: &mut Tensor<f32>,
    g_scales: &mut Tensor<f32>,
    g_rotations: &mut Tensor<f32>,
    g_densities: &mut Tensor<f32>,
    g_stats: &mut Tensor<f32>,
    n: u32,
    n_views: u32,
    split: u32,
    k_sigma: f32,
    #[comptime] units: usize,
) {
    // `split` consecutive units (of one workgroup: `split` divides `units`) share a Gaussian,
    // each walking every `split`-th footprint row; the first of them sums their terms per view.
    // Every unit reaches every barrier, those past the last Gaussian too.
    let u = UNIT_POS as usize;
    let lane = (ABSOLUTE_POS % (split as usize)) as u32;
    let i = ABSOLUTE_POS / (split as usize);
    let inside = i < n as usize;
    let mut terms = Shared::<[f32]>::new_slice(units * TERMS);
    let p = load_params(means, scales, rotations, densities, select(inside, i, 0));
    let live = inside && p.valid == 1u32;
    let mut d_rho = 0.0f32;
    let mut dm_x = 0.0f32;
    let mut dm_y = 0.0f32;
    let mut dm_z = 0.0f32;
    let mut dq_xx = 0.0f32;
    let mut dq_xy = 0.0f32;
    let mut dq_xz = 0.0f32;
    let mut dq_yy = 0.0f32;
    let mut dq_yz = 0.0f32;
    let mut dq_zz = 0.0f32;
    let mut stat = 0.0f32;
    let mut visible = 0.0f32;
    for v in 0..n_views {
        let vw = load_view(views, v as usize);
        let pr = project(&p, &vw, k_sigma);
        let seen = live && pr.valid == 1u32;
        let mut s_unit = 0.0f32;
        let mut e_x = 0.0f32;
        let mut e_y = 0.0f32;
        let mut e_z = 0.0f32;
        let mut m_xx = 0.0f32;
        let mut m_xy = 0.0f32;
        let mut m_xz = 0.0f32;
        let mut m_yy = 0.0f32;
        let mut m_yz = 0.0f32;
        let mut m_zz = 0.0f32;
        if seen {
            let plane = (v as usize) * (vw.width as usize) * (vw.height as usize);
            let rows = pr.row_max + 1 - pr.row_min;
            let mine = (rows + split - 1 - lane) / split;
            for k in 0..mine {
                let row = pr.row_min + lane + k * split;
                let re = row_eval(&pr, &vw, row);
                let dy = re.dy;
                let yn = re.yn;
                let base = plane + (row as usize) * (vw.width as usize);
                let (first, last) = row_columns(&pr, &re, &vw);
                for col in first..last + 1 {
                    let g = grad[base + col as usize];
                    let dx = (f32::cast_from(col) - pr.u0) * vw.inv_fx;
                    let (unit, inv_a) = unit_value(&pr, &re, dx);
                    let gu = g * unit;
                    let gi = gu * p.density;
                    let xn = pr.x0 + dx;
                    let qu_x = pr.g_x + pr.q.xx * dx + pr.q.xy * dy;
                    let qu_y = pr.g_y + pr.q.xy * dx + pr.q.yy * dy;
                    let beta = (qu_x * dx + qu_y * dy) * inv_a;
                    let ex = pr.mu_z * (dx - beta * xn);
                    let ey = pr.mu_z * (dy - beta * yn);
                    let ez = pr.mu_z * beta * -1.0f32;
                    let gia = gi * inv_a;
                    s_unit += gu;
                    e_x += gi * ex;
                    e_y += gi * ey;
                    e_z += gi * ez;
                    m_xx += gia * xn * xn + gi * ex * ex;
                    m_xy += gia * xn * yn + gi * ex * ey;
                    m_xz += gia * xn + gi * ex * ez;
                    m_yy += gia * yn * yn + gi * ey * ey;
                    m_yz += gia * yn + gi * ey * ez;
                    m_zz += gia + gi * ez * ez;
                }
            }
        }
        let t = u * TERMS;
        terms[t] = s_unit;
        terms[t + 1] = e_x;
        terms[t + 2] = e_y;
        terms[t + 3] = e_z;
        terms[t + 4] = m_xx;
        terms[t + 5] = m_xy;
        terms[t + 6] = m_xz;
        terms[t + 7] = m_yy;
        terms[t + 8] = m_yz;
        terms[t + 9] = m_zz;
        sync_cube();
        if seen && lane == 0u32 {
            for other in 1..split {
                let o = (u + other as usize) * TERMS;
                s_unit += terms[o];
                e_x += terms[o + 1];
                e_y += terms[o + 2];
                e_z += terms[o + 3];
                m_xx += terms[o + 4];
                m_xy += terms[o + 5];
                m_xz += terms[o + 6];
                m_yy += terms[o + 7];
                m_yz += terms[o + 8];
                m_zz += terms[o + 9];
            }
            // ∂L/∂μ_c = Q E, to world with Rᵀ.
            let q = pr.q;
            let dc_x = q.xx * e_x + q.xy * e_y + q.xz * e_z;
            let dc_y = q.xy * e_x + q.yy * e_y + q.yz * e_z;
            let dc_z = q.xz * e_x + q.yz * e_y + q.zz * e_z;
            let r = vw.r;
            dm_x += r.m00 * dc_x + r.m10 * dc_y + r.m20 * dc_z;
            dm_y += r.m01 * dc_x + r.m11 * dc_y + r.m21 * dc_z;
            dm_z += r.m02 * dc_x + r.m12 * dc_y + r.m22 * dc_z;
            // ∂L/∂Q_w = Rᵀ (−½ M) R: first T = M R, then Rᵀ T.
            let t00 = m_xx * r.m00 + m_xy * r.m10 + m_xz * r.m20;
            let t01 = m_xx * r.m01 + m_xy * r.m11 + m_xz * r.m21;
            let t02 = m_xx * r.m02 + m_xy * r.m12 + m_xz * r.m22;
            let t10 = m_xy * r.m00 + m_yy * r.m10 + m_yz * r.m20;
            let t11 = m_xy * r.m01 + m_yy * r.m11 + m_yz * r.m21;
            let t12 = m_xy * r.m02 + m_yy * r.m12 + m_yz * r.m22;
            let t20 = m_xz * r.m00 + m_yz * r.m10 + m_zz * r.m20;
            let t21 = m_xz * r.m01 + m_yz * r.m11 + m_zz * r.m21;
            let t22 = m_xz * r.m02 + m_yz * r.m12 + m_zz * r.m22;
            dq_xx += -0.5f32 * (r.m00 * t00 + r.m10 * t10 + r.m20 * t20);
            dq_xy += -0.5f32 * (r.m00 * t01 + r.m10 * t11 + r.m20 * t21);
            dq_xz += -0.5f32 * (r.m00 * t02 + r.m10 * t12 + r.m20 * t22);
            dq_yy += -0.5f32 * (r.m01 * t01 + r.m11 * t11 + r.m21 * t21);
            dq_yz += -0.5f32 * (r.m01 * t02 + r.m11 * t12 + r.m21 * t22);
            dq_zz += -0.5f32 * (r.m02 * t02 + r.m12 * t12 + r.m22 * t22);
            d_rho += s_unit;
            let du = dc_x * pr.mu_z * vw.inv_fx * (f32::cast_from(vw.width) * 0.5);
            let dv = dc_y * pr.mu_z * vw.inv_fy * (f32::cast_from(vw.height) * 0.5);
            stat += f32::sqrt(du * du + dv * dv);
            visible += 1.0;
        }
        sync_cube();
    }
    if inside && lane == 0u32 {
        let dq = Sym3 { xx: dq_xx, xy: dq_xy, xz: dq_xz, yy: dq_yy, yz: dq_yz, zz: dq_zz };
        let c = chain_precision(&p, &dq);
        // Invalid Gaussians get zero gradients (their chain values may be NaN).
        let valid = p.valid == 1u32;
        g_means[3 * i] = dm_x;
        g_means[3 * i + 1] = dm_y;
        g_means[3 * i + 2] = dm_z;
        g_scales[3 * i] = select(valid, c.ds0, 0.0f32);
        g_scales[3 * i + 1] = select(valid, c.ds1, 0.0f32);
        g_scales[3 * i + 2] = select(valid, c.ds2, 0.0f32);
        g_rotations[4 * i] = select(valid, c.dw, 0.0f32);
        g_rotations[4 * i + 1] = select(valid, c.dx, 0.0f32);
        g_rotations[4 * i + 2] = select(valid, c.dy, 0.0f32);
        g_rotations[4 * i + 3] = select(valid, c.dz, 0.0f32);
        g_densities[i] = d_rho;
        g_stats[2 * i] = stat;
        g_stats[2 * i + 1] = visible;
    }
}

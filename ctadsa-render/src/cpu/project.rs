//! Projection of Gaussians into one view, eight at a time: the per-Gaussian set-up of the exact
//! line integral (formulas in [`super::math`]) for the pixel loops, and the camera frame the
//! backward pass needs. Written branch-free over [`F8`] lanes so that it vectorises; a lane whose
//! Gaussian is invalid, behind the source or off the image comes out as `None`. The forward
//! pass's records are written from the same batches by [`super::splat::project_splats`].

use super::host::HostGaussians;
use super::lanes::{F8, LANES, M8};
use super::math::{Frame, Projected, SCALE_MAX_MM, SCALE_MIN_MM, SQRT_2PI};
use crate::view_params::ViewParams;

/// One batch of inputs: means (mm, world), scales (mm), quaternions (`w, x, y, z`) and densities.
pub(super) struct Inputs {
    pub(super) mean: [F8; 3],
    pub(super) scale: [F8; 3],
    pub(super) quat: [F8; 4],
    pub(super) density: F8,
}

/// One batch of outputs, lane-wise.
pub(super) struct Outputs {
    pub(super) u0: F8,
    pub(super) v0: F8,
    pub(super) x0: F8,
    pub(super) y0: F8,
    pub(super) mu: [F8; 3],
    pub(super) q: [F8; 6],
    pub(super) m: [F8; 9],
    pub(super) g_x: F8,
    pub(super) g_y: F8,
    pub(super) alpha_w: F8,
    pub(super) c_xx: F8,
    pub(super) c_xy: F8,
    pub(super) c_yy: F8,
    pub(super) amp: F8,
    pub(super) cut: F8,
    /// Clipped inclusive pixel box (whole numbers).
    pub(super) col_min: F8,
    pub(super) col_max: F8,
    pub(super) row_min: F8,
    pub(super) row_max: F8,
    pub(super) valid: M8,
}

/// Loads Gaussians `first..first + count` (`count ≤ LANES`); missing lanes get a zero
/// quaternion, which makes them invalid.
#[inline(always)]
pub(super) fn load(g: &HostGaussians, first: usize, count: usize) -> Inputs {
    let mut x = Inputs {
        mean: [F8::splat(0.0); 3],
        scale: [F8::splat(1.0); 3],
        quat: [F8::splat(0.0); 4],
        density: F8::splat(0.0),
    };
    for l in 0..count {
        let (m, s, q, d) = g.get(first + l);
        for k in 0..3 {
            x.mean[k].0[l] = m[k];
            x.scale[k].0[l] = s[k];
        }
        for (lane, v) in x.quat.iter_mut().zip(q) {
            lane.0[l] = v;
        }
        x.density.0[l] = d;
    }
    x
}

/// Entry `(i, j)` of `M diag(d) Mᵀ`.
#[inline(always)]
fn sandwich_entry(m: &[F8; 9], d: &[F8; 3], i: usize, j: usize) -> F8 {
    m[3 * i] * d[0] * m[3 * j] + m[3 * i + 1] * d[1] * m[3 * j + 1] + m[3 * i + 2] * d[2] * m[3 * j + 2]
}

/// `M diag(d) Mᵀ` as `[xx, xy, xz, yy, yz, zz]`.
#[inline(always)]
fn sandwich_diag(m: &[F8; 9], d: [F8; 3]) -> [F8; 6] {
    [
        sandwich_entry(m, &d, 0, 0),
        sandwich_entry(m, &d, 0, 1),
        sandwich_entry(m, &d, 0, 2),
        sandwich_entry(m, &d, 1, 1),
        sandwich_entry(m, &d, 1, 2),
        sandwich_entry(m, &d, 2, 2),
    ]
}

/// The projection of one batch (see [`super::math`] for the formulas).
#[inline(always)]
pub(super) fn project8(x: &Inputs, vp: &ViewParams, k_sigma: f32) -> Outputs {
    let finite = x.density.is_finite() & x.mean[0].is_finite() & x.mean[1].is_finite() & x.mean[2].is_finite();
    let mut scale_ok = M8::ALL;
    let mut s = x.scale;
    for v in &mut s {
        scale_ok = scale_ok & v.is_finite() & v.gt(0.0);
        *v = v.max(SCALE_MIN_MM).min(SCALE_MAX_MM);
    }
    // Unit quaternion and its rotation matrix.
    let [qw, qx, qy, qz] = x.quat;
    let n2 = qw * qw + qx * qx + qy * qy + qz * qz;
    let quat_ok = n2.is_finite() & n2.gt(1e-24);
    let n = n2.sqrt();
    let (w, qx, qy, qz) = (qw / n, qx / n, qy / n, qz / n);
    let rot = [
        1.0 - 2.0 * (qy * qy + qz * qz),
        2.0 * (qx * qy - w * qz),
        2.0 * (qx * qz + w * qy),
        2.0 * (qx * qy + w * qz),
        1.0 - 2.0 * (qx * qx + qz * qz),
        2.0 * (qy * qz - w * qx),
        2.0 * (qx * qz - w * qy),
        2.0 * (qy * qz + w * qx),
        1.0 - 2.0 * (qx * qx + qy * qy),
    ];
    // Camera frame: centre, Gaussian axes M = R_view · R, precision and covariance.
    let r = &vp.rotation;
    let mean = &x.mean;
    let mut mu = [F8::splat(0.0); 3];
    for (i, mu) in mu.iter_mut().enumerate() {
        *mu = r[3 * i] * mean[0] + r[3 * i + 1] * mean[1] + r[3 * i + 2] * mean[2] + vp.translation[i];
    }
    let mut m = [F8::splat(0.0); 9];
    for (k, m) in m.iter_mut().enumerate() {
        let (i, j) = (k / 3, k % 3);
        *m = r[3 * i] * rot[j] + r[3 * i + 1] * rot[3 + j] + r[3 * i + 2] * rot[6 + j];
    }
    let s2 = [s[0] * s[0], s[1] * s[1], s[2] * s[2]];
    let q = sandwich_diag(&m, [1.0 / s2[0], 1.0 / s2[1], 1.0 / s2[2]]);
    let [sxx, sxy, sxz, syy, syz, szz] = sandwich_diag(&m, s2);
    let [qxx, qxy, qxz, qyy, qyz, qzz] = q;
    let in_front = mu[2].gt(0.0);
    let x0 = mu[0] / mu[2];
    let y0 = mu[1] / mu[2];
    let g_x = qxx * x0 + qxy * y0 + qxz;
    let g_y = qxy * x0 + qyy * y0 + qyz;
    let g_z = qxz * x0 + qyz * y0 + qzz;
    let alpha_w = x0 * g_x + y0 * g_y + g_z;
    // Σ₂ = P Σ Pᵀ, P = [[1, 0, −x0], [0, 1, −y0]], and the conic C = μ_z² α_w Σ₂⁻¹.
    let s00 = sxx - 2.0 * x0 * sxz + x0 * x0 * szz;
    let s01 = sxy - x0 * syz - y0 * sxz + x0 * y0 * szz;
    let s11 = syy - 2.0 * y0 * syz + y0 * y0 * szz;
    let det = s00 * s11 - s01 * s01;
    let conic_ok = det.gt(0.0) & det.is_finite() & alpha_w.gt(0.0);
    let scale = mu[2] * mu[2] * alpha_w / det;
    let (c_xx, c_xy, c_yy) = (scale * s11, -(scale * s01), scale * s00);
    let k2 = k_sigma * k_sigma;
    let u0 = vp.fx * x0 + vp.cx;
    let v0 = vp.fy * y0 + vp.cy;
    // Footprint conic F = Δᵀ A Δ + 2 bᵀΔ + c with A = C − k² Q₂, b = −k² g, c = −k² α_w. Where A
    // is not positive definite the k-σ ellipsoid reaches the source plane: every pixel, no cut.
    let (a_xx, a_xy, a_yy) = (c_xx - k2 * qxx, c_xy - k2 * qxy, c_yy - k2 * qyy);
    let det_a = a_xx * a_yy - a_xy * a_xy;
    let bounded = a_xx.gt(0.0) & det_a.gt(0.0);
    let (b_x, b_y) = (-k2 * g_x, -k2 * g_y);
    let (i_xx, i_xy, i_yy) = (a_yy / det_a, -a_xy / det_a, a_xx / det_a);
    let (pc_x, pc_y) = (-(i_xx * b_x + i_xy * b_y), -(i_xy * b_x + i_yy * b_y));
    let f_min = -k2 * alpha_w + (b_x * pc_x + b_y * pc_y);
    let (hx, hy) = ((-f_min * i_xx).sqrt(), (-f_min * i_yy).sqrt());
    let col_lo = (u0 + (pc_x - hx) * vp.fx).ceil();
    let col_hi = (u0 + (pc_x + hx) * vp.fx).floor();
    let row_lo = (v0 + (pc_y - hy) * vp.fy).ceil();
    let row_hi = (v0 + (pc_y + hy) * vp.fy).floor();
    let box_ok = f_min.lt(0.0) & col_lo.is_finite() & col_hi.is_finite() & row_lo.is_finite() & row_hi.is_finite();
    let (last_col, last_row) = (vp.width as f32 - 1.0, vp.height as f32 - 1.0);
    let col_min = bounded.select(col_lo.max(0.0), 0.0);
    let col_max = bounded.select(col_hi.min(last_col), last_col);
    let row_min = bounded.select(row_lo.max(0.0), 0.0);
    let row_max = bounded.select(row_hi.min(last_row), last_row);
    let on_image = !bounded | (box_ok & col_min.le(col_max) & row_min.le(row_max));
    Outputs {
        u0,
        v0,
        x0,
        y0,
        mu,
        q,
        m,
        g_x,
        g_y,
        alpha_w,
        c_xx,
        c_xy,
        c_yy,
        amp: x.density * SQRT_2PI,
        cut: bounded.select(k2, f32::INFINITY),
        col_min,
        col_max,
        row_min,
        row_max,
        valid: finite & scale_ok & quat_ok & in_front & conic_ok & on_image,
    }
}

/// Projects Gaussians `first..first + out.len()` of `g` into view `vp` with a k-σ footprint:
/// `out[j]` is `None` for a Gaussian that is invalid (non-finite, non-positive scale, zero
/// quaternion), behind the source, or off the image. With `frames`, `frames[j]` receives the
/// camera frame of every Gaussian that is `Some` (same length as `out`).
#[inline(always)]
pub fn project_range(
    g: &HostGaussians,
    first: usize,
    vp: &ViewParams,
    k_sigma: f32,
    out: &mut [Option<Projected>],
    mut frames: Option<&mut [Frame]>,
) {
    for (b, out) in out.chunks_mut(LANES).enumerate() {
        let start = b * LANES;
        let o = project8(&load(g, first + start, out.len()), vp, k_sigma);
        for (l, slot) in out.iter_mut().enumerate() {
            if !o.valid.lane(l) {
                *slot = None;
                continue;
            }
            *slot = Some(Projected {
                u0: o.u0.0[l],
                v0: o.v0.0[l],
                x0: o.x0.0[l],
                y0: o.y0.0[l],
                mu_z: o.mu[2].0[l],
                q_xx: o.q[0].0[l],
                q_xy: o.q[1].0[l],
                q_yy: o.q[3].0[l],
                g_x: o.g_x.0[l],
                g_y: o.g_y.0[l],
                alpha_w: o.alpha_w.0[l],
                c_xx: o.c_xx.0[l],
                c_xy: o.c_xy.0[l],
                c_yy: o.c_yy.0[l],
                amp: o.amp.0[l],
                cut: o.cut.0[l],
                col_min: o.col_min.0[l] as i32,
                col_max: o.col_max.0[l] as i32,
                row_min: o.row_min.0[l] as i32,
                row_max: o.row_max.0[l] as i32,
            });
            if let Some(f) = frames.as_deref_mut() {
                let f = &mut f[start + l];
                for k in 0..9 {
                    f.m[k] = o.m[k].0[l];
                }
                for k in 0..6 {
                    f.q[k] = o.q[k].0[l];
                }
                for k in 0..3 {
                    f.mu[k] = o.mu[k].0[l];
                }
            }
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::geometry::{ConeBeamView, TigreGeometry};

    /// 21 Gaussians (not a multiple of the lane count), every fourth one invalid in a different
    /// way (3: non-finite mean, 7: zero scale, 11: zero quaternion, 15: behind the source), as
    /// `[means, scales, rotations, densities]`, and a view of 64 × 64 px.
    pub(in crate::cpu) fn scene() -> ([Vec<f32>; 4], ViewParams) {
        let view = ConeBeamView::from_tigre(&TigreGeometry {
            detector_px: [64, 64],
            pixel_mm: [4.0, 4.0],
            ..TigreGeometry::reference(30.0)
        })
        .unwrap();
        let n = 21;
        let mut means = Vec::new();
        let mut scales = Vec::new();
        let mut rotations = Vec::new();
        let mut densities = Vec::new();
        for i in 0..n {
            let t = i as f32;
            means.extend([10.0 * (t * 0.7).sin(), 8.0 * (t * 1.3).cos(), 5.0 - t]);
            scales.extend([0.5 + 0.1 * t, 1.0, 2.0 + 0.05 * t]);
            rotations.extend([1.0, 0.1 * t, -0.2, 0.05 * t]);
            densities.push(1.0 + t);
        }
        means[3 * 3] = f32::NAN; // non-finite mean
        scales[3 * 7 + 1] = 0.0; // zero scale
        rotations[4 * 11..4 * 11 + 4].fill(0.0); // zero quaternion
        means[3 * 15 + 2] = -2000.0; // behind the source (the source is 1000 mm away)
        ([means, scales, rotations, densities], ViewParams::new(&view))
    }

    /// The culled Gaussians of [`scene`].
    pub(in crate::cpu) const INVALID: [usize; 4] = [3, 7, 11, 15];

    /// Projected as one range and one at a time: the same results, lane by lane.
    #[test]
    fn batches_equal_single_gaussians() {
        let ([means, scales, rotations, densities], vp) = scene();
        let n = densities.len();
        let g = HostGaussians { means: &means, scales: &scales, rotations: &rotations, densities: &densities };
        let mut batch = vec![None; n];
        let mut frames = vec![Frame::default(); n];
        project_range(&g, 0, &vp, 3.0, &mut batch, Some(&mut frames));
        for i in 0..n {
            let mut one = [None];
            let mut frame = [Frame::default()];
            project_range(&g, i, &vp, 3.0, &mut one, Some(&mut frame));
            let invalid = INVALID.contains(&i);
            assert_eq!(batch[i].is_none(), invalid, "Gaussian {i}");
            if let (Some(a), Some(b)) = (batch[i], one[0]) {
                assert_eq!(format!("{a:?}"), format!("{b:?}"), "Gaussian {i}");
                assert_eq!(format!("{:?}", frames[i]), format!("{:?}", frame[0]), "Gaussian {i}");
            }
        }
    }
}

//! CPU kernels of the SSIM op: the prediction's window statistics, the mean of the SSIM map,
//! and the gradient of that mean with respect to the prediction. Pixel loops run in fixed
//! blocks and the mean sums the blocks in order, so results do not depend on the thread count.

use rayon::prelude::*;

use crate::blur_op::{cpu::blur, taps};

/// SSIM's stabilising constants for images in `[0, 1]`: `(0.01)²` and `(0.03)²`.
pub const C1: f32 = 0.01 * 0.01;
pub const C2: f32 = 0.03 * 0.03;

/// Pixels per parallel block.
const BLOCK: usize = 4096;

/// The prediction's window statistics, `[3 · V·H·W]`: `blur(x)`, `blur(x²)`, `blur(x·y)`.
pub fn stats(x: &[f32], y: &[f32], v: usize, h: usize, w: usize) -> Vec<f32> {
    let t = taps();
    let xx: Vec<f32> = x.par_iter().map(|a| a * a).collect();
    let xy: Vec<f32> = x.par_iter().zip(y).map(|(a, b)| a * b).collect();
    let mut out = blur(x, v, h, w, &t);
    out.extend(blur(&xx, v, h, w, &t));
    out.extend(blur(&xy, v, h, w, &t));
    out
}

/// One pixel's SSIM terms from the statistics: `(a1, a2, b1, b2)` with SSIM = `a1·a2 / (b1·b2)`.
#[inline(always)]
fn terms(mu_x: f32, exx: f32, exy: f32, mu_y: f32, syy: f32) -> (f32, f32, f32, f32) {
    let sxx = exx - mu_x * mu_x;
    let sxy = exy - mu_x * mu_y;
    let a1 = 2.0 * (mu_x * mu_y) + C1;
    let a2 = 2.0 * sxy + C2;
    let b1 = mu_x * mu_x + mu_y * mu_y + C1;
    let b2 = sxx + syy + C2;
    (a1, a2, b1, b2)
}

/// Mean of the SSIM map over all pixels, from [`stats`] and the target's windowed mean `mu_y`
/// and variance `syy` (summed in f64).
pub fn mean(stats: &[f32], mu_y: &[f32], syy: &[f32]) -> f64 {
    let p = mu_y.len();
    if p == 0 {
        return 0.0;
    }
    let (mu_x, rest) = stats.split_at(p);
    let (exx, exy) = rest.split_at(p);
    let block_sums: Vec<f64> = (0..p.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            (b * BLOCK..((b + 1) * BLOCK).min(p))
                .map(|i| {
                    let (a1, a2, b1, b2) = terms(mu_x[i], exx[i], exy[i], mu_y[i], syy[i]);
                    ((a1 * a2) / (b1 * b2)) as f64
                })
                .sum::<f64>()
        })
        .collect();
    block_sums.iter().sum::<f64>() / p as f64
}

/// `grad · ∂mean/∂x` for the prediction `x`, the target `y`, its `mu_y` and `syy`, and the
/// prediction's [`stats`]. With `S = a1·a2/(b1·b2)` a function of the statistics, the gradient
/// is `blur(∂S/∂μx) + 2x · blur(∂S/∂E[x²]) + y · blur(∂S/∂E[xy])` (the blur is its own adjoint),
/// each partial scaled by `grad / pixels`.
#[allow(clippy::too_many_arguments)]
pub fn backward(
    x: &[f32],
    y: &[f32],
    mu_y: &[f32],
    syy: &[f32],
    stats: &[f32],
    grad: f32,
    v: usize,
    h: usize,
    w: usize,
) -> Vec<f32> {
    let p = x.len();
    if p == 0 {
        return Vec::new();
    }
    let c = grad / p as f32;
    let (mu_x, rest) = stats.split_at(p);
    let (exx, exy) = rest.split_at(p);
    // ∂S/∂μx, ∂S/∂E[x²], ∂S/∂E[xy] per pixel, in three planes.
    let mut partials = vec![0.0f32; 3 * p];
    let (d_mu, rest) = partials.split_at_mut(p);
    let (d_exx, d_exy) = rest.split_at_mut(p);
    d_mu.par_chunks_mut(BLOCK).zip(d_exx.par_chunks_mut(BLOCK)).zip(d_exy.par_chunks_mut(BLOCK)).enumerate().for_each(
        |(b, ((dm, dxx), dxy))| {
            for k in 0..dm.len() {
                let i = b * BLOCK + k;
                let (mx, my) = (mu_x[i], mu_y[i]);
                let (a1, a2, b1, b2) = terms(mx, exx[i], exy[i], my, syy[i]);
                let inv = 1.0 / (b1 * b2);
                let s = a1 * a2 * inv;
                dm[k] = c * (2.0 * my * (a2 - a1) * inv - 2.0 * mx * s / b1 + 2.0 * mx * s / b2);
                dxx[k] = c * (-s / b2);
                dxy[k] = c * (2.0 * a1 * inv);
            }
        },
    );
    let t = taps();
    let g_mu = blur(d_mu, v, h, w, &t);
    let g_xx = blur(d_exx, v, h, w, &t);
    let g_xy = blur(d_exy, v, h, w, &t);
    let mut out = vec![0.0f32; p];
    out.par_chunks_mut(BLOCK).enumerate().for_each(|(b, o)| {
        for (k, ok) in o.iter_mut().enumerate() {
            let i = b * BLOCK + k;
            *ok = g_mu[i] + 2.0 * x[i] * g_xx[i] + y[i] * g_xy[i];
        }
    });
    out
}

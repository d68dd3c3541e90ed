//! The SSIM op on CubeCL in four launches forward and two backward (composed of tensor ops and
//! blurs it took about twenty each way). The separable 11-tap window runs as a pass along W and
//! a pass along H, zero-padded at each view's borders, as `blur_op`:
//!
//! - forward: (1) along W, the window sums of `x`, `x²` and `x·y`; (2) along H, the statistics
//!   `μx`, `E[x²]`, `E[xy]` (kept for the backward) and each pixel's SSIM; (3, 4) their mean, as a
//!   sum per workgroup and the sum of those;
//! - backward: (1) along W, the window sums of the three partial derivatives of SSIM with respect
//!   to the statistics (each computed where it is read); (2) along H, and
//!   `∂/∂x = blur(∂S/∂μx) + 2x · blur(∂S/∂E[x²]) + y · blur(∂S/∂E[xy])`, all scaled by
//!   `grad / pixels`.

use burn::backend::ops::FloatTensorOps;
use burn::backend::{FloatDType, TensorMetadata};
use burn::tensor::Shape;
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use super::cpu::{C1, C2};
use crate::blur_op::gpu::tap;
use crate::cube::{empty, launch_1d, mean, prepare};

/// `(a1, a2, b1, b2)` with SSIM = `a1·a2 / (b1·b2)`, as `cpu::terms`.
#[cube]
fn terms(mu_x: f32, exx: f32, exy: f32, mu_y: f32, syy: f32) -> (f32, f32, f32, f32) {
    let sxx = exx - mu_x * mu_x;
    let sxy = exy - mu_x * mu_y;
    let a1 = 2.0f32 * (mu_x * mu_y) + C1;
    let a2 = 2.0f32 * sxy + C2;
    let b1 = mu_x * mu_x + mu_y * mu_y + C1;
    let b2 = sxx + syy + C2;
    (a1, a2, b1, b2)
}

/// Forward (1): `rows[0..3][p]` = window sums along W of `x`, `x²`, `x·y` at pixel `p`.
#[cube(launch)]
fn ssim_rows_kernel(x: &Tensor<f32>, y: &Tensor<f32>, rows: &mut Tensor<f32>, pixels: u32, w: u32) {
    let id = ABSOLUTE_POS;
    if id >= pixels as usize {
        terminate!();
    }
    let col = id % (w as usize);
    let mut sx = 0.0f32;
    let mut sxx = 0.0f32;
    let mut sxy = 0.0f32;
    for k in 0..11u32 {
        let kk = k as usize;
        if col + kk >= 5usize && col + kk < (w as usize) + 5usize {
            let src = id + kk - 5usize;
            let t = tap(k);
            let xv = x[src];
            sx += t * xv;
            sxx += t * (xv * xv);
            sxy += t * (xv * y[src]);
        }
    }
    rows[id] = sx;
    rows[id + pixels as usize] = sxx;
    rows[id + 2 * pixels as usize] = sxy;
}

/// The window sums along H at pixel `id` of the three planes of `rows` (`p` pixels each).
#[cube]
fn window_along_h(rows: &Tensor<f32>, id: usize, p: usize, h: u32, w: u32) -> (f32, f32, f32) {
    let row = (id / (w as usize)) % (h as usize);
    let step = w as usize;
    let mut a = 0.0f32;
    let mut b = 0.0f32;
    let mut c = 0.0f32;
    for k in 0..11u32 {
        let kk = k as usize;
        if row + kk >= 5usize && row + kk < (h as usize) + 5usize {
            let src = id + kk * step - 5usize * step;
            let t = tap(k);
            a += t * rows[src];
            b += t * rows[src + p];
            c += t * rows[src + 2 * p];
        }
    }
    (a, b, c)
}

/// Forward (2): along H, the statistics `stats[0..3][p]` and the SSIM map.
#[cube(launch)]
fn ssim_cols_kernel(
    rows: &Tensor<f32>,
    mu_y: &Tensor<f32>,
    syy: &Tensor<f32>,
    stats: &mut Tensor<f32>,
    map: &mut Tensor<f32>,
    pixels: u32,
    h: u32,
    w: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= pixels as usize {
        terminate!();
    }
    let p = pixels as usize;
    let (mu, exx, exy) = window_along_h(rows, id, p, h, w);
    stats[id] = mu;
    stats[id + p] = exx;
    stats[id + 2 * p] = exy;
    let (a1, a2, b1, b2) = terms(mu, exx, exy, mu_y[id], syy[id]);
    map[id] = (a1 * a2) / (b1 * b2);
}

/// `(∂S/∂μx, ∂S/∂E[x²], ∂S/∂E[xy])` at pixel `q`.
#[cube]
fn partials(stats: &Tensor<f32>, mu_y: &Tensor<f32>, syy: &Tensor<f32>, q: usize, p: usize) -> (f32, f32, f32) {
    let mu_x = stats[q];
    let my = mu_y[q];
    let (a1, a2, b1, b2) = terms(mu_x, stats[q + p], stats[q + 2 * p], my, syy[q]);
    let inv = 1.0f32 / (b1 * b2);
    let s = a1 * a2 * inv;
    let d_mu = 2.0f32 * (my * (a2 - a1)) * inv + 2.0f32 * (mu_x * s) * (1.0f32 / b2 - 1.0f32 / b1);
    let d_exx = -(s / b2);
    let d_exy = 2.0f32 * (a1 * inv);
    (d_mu, d_exx, d_exy)
}

/// Backward (1): along W, window sums of the three partials.
#[cube(launch)]
fn ssim_grad_rows_kernel(
    stats: &Tensor<f32>,
    mu_y: &Tensor<f32>,
    syy: &Tensor<f32>,
    rows: &mut Tensor<f32>,
    pixels: u32,
    w: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= pixels as usize {
        terminate!();
    }
    let col = id % (w as usize);
    let p = pixels as usize;
    let mut g_mu = 0.0f32;
    let mut g_xx = 0.0f32;
    let mut g_xy = 0.0f32;
    for k in 0..11u32 {
        let kk = k as usize;
        if col + kk >= 5usize && col + kk < (w as usize) + 5usize {
            let src = id + kk - 5usize;
            let t = tap(k);
            let (d_mu, d_exx, d_exy) = partials(stats, mu_y, syy, src, p);
            g_mu += t * d_mu;
            g_xx += t * d_exx;
            g_xy += t * d_exy;
        }
    }
    rows[id] = g_mu;
    rows[id + p] = g_xx;
    rows[id + 2 * p] = g_xy;
}

/// Backward (2): along H, and the gradient with respect to `x`.
#[cube(launch)]
fn ssim_grad_cols_kernel(
    rows: &Tensor<f32>,
    x: &Tensor<f32>,
    y: &Tensor<f32>,
    grad: &Tensor<f32>,
    out: &mut Tensor<f32>,
    pixels: u32,
    h: u32,
    w: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= pixels as usize {
        terminate!();
    }
    let (g_mu, g_xx, g_xy) = window_along_h(rows, id, pixels as usize, h, w);
    let c = grad[0] / f32::cast_from(pixels);
    out[id] = c * (g_mu + 2.0f32 * x[id] * g_xx + y[id] * g_xy);
}

fn dims3(t: &CubeTensor) -> (usize, usize, usize) {
    let s = t.shape();
    (s[0], s[1], s[2])
}

/// `(mean SSIM [1], statistics [3V, H, W])`.
pub fn forward(x: CubeTensor, y: CubeTensor, mu_y: CubeTensor, syy: CubeTensor) -> (CubeTensor, CubeTensor) {
    let (x, y, mu_y, syy) = (prepare(x), prepare(y), prepare(mu_y), prepare(syy));
    let (v, h, w) = dims3(&x);
    let pixels = v * h * w;
    let rows = empty(vec![3 * v, h, w], &x);
    let stats = empty(vec![3 * v, h, w], &x);
    let map = empty(vec![v, h, w], &x);
    if pixels == 0 {
        let zero = CubeBackend::float_zeros(Shape::from(vec![1]), &x.device, FloatDType::F32);
        return (zero, stats);
    }
    let (count, dim) = launch_1d(&x, pixels, 256);
    ssim_rows_kernel::launch(
        &x.client,
        count.clone(),
        dim,
        x.clone().into_tensor_arg(),
        y.into_tensor_arg(),
        rows.clone().into_tensor_arg(),
        pixels as u32,
        w as u32,
    );
    ssim_cols_kernel::launch(
        &x.client,
        count,
        dim,
        rows.into_tensor_arg(),
        mu_y.into_tensor_arg(),
        syy.into_tensor_arg(),
        stats.clone().into_tensor_arg(),
        map.clone().into_tensor_arg(),
        pixels as u32,
        h as u32,
        w as u32,
    );
    (mean(&map, None), stats)
}

/// `∂(grad · mean SSIM)/∂x` `[V, H, W]` from the forward's statistics.
pub fn backward(
    x: CubeTensor,
    y: CubeTensor,
    mu_y: CubeTensor,
    syy: CubeTensor,
    stats: CubeTensor,
    grad: CubeTensor,
) -> CubeTensor {
    let (x, y, mu_y, syy, stats, grad) =
        (prepare(x), prepare(y), prepare(mu_y), prepare(syy), prepare(stats), prepare(grad));
    let (v, h, w) = dims3(&x);
    let pixels = v * h * w;
    let out = empty(vec![v, h, w], &x);
    if pixels == 0 {
        return out;
    }
    let rows = empty(vec![3 * v, h, w], &x);
    let (count, dim) = launch_1d(&x, pixels, 256);
    ssim_grad_rows_kernel::launch(
        &x.client,
        count.clone(),
        dim,
        stats.into_tensor_arg(),
        mu_y.into_tensor_arg(),
        syy.into_tensor_arg(),
        rows.clone().into_tensor_arg(),
        pixels as u32,
        w as u32,
    );
    ssim_grad_cols_kernel::launch(
        &x.client,
        count,
        dim,
        rows.into_tensor_arg(),
        x.clone().into_tensor_arg(),
        y.into_tensor_arg(),
        grad.into_tensor_arg(),
        out.clone().into_tensor_arg(),
        pixels as u32,
        h as u32,
        w as u32,
    );
    out
}

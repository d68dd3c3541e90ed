//! The SSIM op composed of a backend's own primitive ops (its elementwise ops, sums and the
//! window blur op): the path GPU backends take.

use burn::backend::{Backend, Scalar, TensorMetadata, tensor::FloatTensor};
use burn::tensor::{Shape, Slice};

use super::cpu::{C1, C2};
use crate::method::blur_op::BlurBackend;

fn s(v: f32) -> Scalar {
    Scalar::Float(v as f64)
}

/// `(mean, stats)` of [`super::SsimBackend::ssim_mean`].
pub fn forward<B: Backend + BlurBackend>(
    x: FloatTensor<B>,
    y: FloatTensor<B>,
    mu_y: FloatTensor<B>,
    syy: FloatTensor<B>,
) -> (FloatTensor<B>, FloatTensor<B>) {
    let mu_x = B::window_blur(x.clone());
    let exx = B::window_blur(B::float_mul(x.clone(), x.clone()));
    let exy = B::window_blur(B::float_mul(x, y));
    let map = ssim_map::<B>(mu_x.clone(), exx.clone(), exy.clone(), mu_y, syy);
    let mean = B::float_reshape(B::float_mean(map), Shape::new([1]));
    (mean, B::float_cat(vec![mu_x, exx, exy], 0))
}

fn ssim_map<B: Backend>(
    mu_x: FloatTensor<B>,
    exx: FloatTensor<B>,
    exy: FloatTensor<B>,
    mu_y: FloatTensor<B>,
    syy: FloatTensor<B>,
) -> FloatTensor<B> {
    let [a1, a2, b1, b2] = terms::<B>(mu_x, exx, exy, mu_y, syy);
    B::float_div(B::float_mul(a1, a2), B::float_mul(b1, b2))
}

/// `[a1, a2, b1, b2]` with SSIM = `a1·a2 / (b1·b2)`.
fn terms<B: Backend>(
    mu_x: FloatTensor<B>,
    exx: FloatTensor<B>,
    exy: FloatTensor<B>,
    mu_y: FloatTensor<B>,
    syy: FloatTensor<B>,
) -> [FloatTensor<B>; 4] {
    let mxx = B::float_mul(mu_x.clone(), mu_x.clone());
    let mxy = B::float_mul(mu_x, mu_y.clone());
    let sxx = B::float_sub(exx, mxx.clone());
    let sxy = B::float_sub(exy, mxy.clone());
    let a1 = B::float_add_scalar(B::float_mul_scalar(mxy, s(2.0)), s(C1));
    let a2 = B::float_add_scalar(B::float_mul_scalar(sxy, s(2.0)), s(C2));
    let b1 = B::float_add_scalar(B::float_add(mxx, B::float_mul(mu_y.clone(), mu_y)), s(C1));
    let b2 = B::float_add_scalar(B::float_add(sxx, syy), s(C2));
    [a1, a2, b1, b2]
}

/// [`super::SsimBackend::ssim_mean_backward`].
pub fn backward<B: Backend + BlurBackend>(
    x: FloatTensor<B>,
    y: FloatTensor<B>,
    mu_y: FloatTensor<B>,
    syy: FloatTensor<B>,
    stats: FloatTensor<B>,
    grad: FloatTensor<B>,
) -> FloatTensor<B> {
    let shape = x.shape();
    let (v, h, w) = (shape[0], shape[1], shape[2]);
    let plane = |k: usize| {
        B::float_slice(stats.clone(), &[Slice::from(k * v..(k + 1) * v), Slice::from(0..h), Slice::from(0..w)])
    };
    let (mu_x, exx, exy) = (plane(0), plane(1), plane(2));
    let [a1, a2, b1, b2] = terms::<B>(mu_x.clone(), exx, exy, mu_y.clone(), syy);
    // c = grad / pixels, broadcast from [1] to [1, 1, 1].
    let c = B::float_reshape(B::float_mul_scalar(grad, s(1.0 / (v * h * w) as f32)), Shape::new([1, 1, 1]));
    let inv = B::float_recip(B::float_mul(b1.clone(), b2.clone()));
    let ssim = B::float_mul(B::float_mul(a1.clone(), a2.clone()), inv.clone());
    // ∂S/∂μx = 2μy(a2 − a1)/(b1 b2) − 2μx S/b1 + 2μx S/b2
    let d_mu = B::float_add(
        B::float_mul(B::float_mul_scalar(B::float_mul(mu_y, B::float_sub(a2, a1.clone())), s(2.0)), inv.clone()),
        B::float_mul(
            B::float_mul_scalar(B::float_mul(mu_x, ssim.clone()), s(2.0)),
            B::float_sub(B::float_recip(b2.clone()), B::float_recip(b1)),
        ),
    );
    let d_exx = B::float_neg(B::float_div(ssim, b2));
    let d_exy = B::float_mul_scalar(B::float_mul(a1, inv), s(2.0));
    let g_mu = B::window_blur(B::float_mul(d_mu, c.clone()));
    let g_xx = B::window_blur(B::float_mul(d_exx, c.clone()));
    let g_xy = B::window_blur(B::float_mul(d_exy, c));
    B::float_add(g_mu, B::float_add(B::float_mul_scalar(B::float_mul(x, g_xx), s(2.0)), B::float_mul(y, g_xy)))
}

//! The image loss's small terms: the mean absolute difference of two `[V, H, W]` images and the
//! mix `(1 − λ)·L1 + λ·(1 − SSIM)` of two `[1]` terms. On a CubeCL device each is one op of
//! one launch forward and one backward (composed of burn's ops the two took about twenty);
//! elsewhere (NdArray) they are composed of tensor ops, unchanged, which is also the ops' oracle
//! (`tests/ops_wgpu.rs`).

#[cfg(feature = "wgpu")]
mod gpu;

use burn::tensor::Tensor;

/// `mean |x − y|` (`[1]`), differentiable in `x` (`y` is a constant target).
pub fn l1_mean(x: Tensor<3>, y: Tensor<3>) -> Tensor<1> {
    #[cfg(feature = "wgpu")]
    if crate::cube::runs_on_cube(&x.device()) {
        return gpu::l1_mean(x, y);
    }
    l1_mean_composed(x, y)
}

/// [`l1_mean`] composed of burn's tensor ops.
pub fn l1_mean_composed(x: Tensor<3>, y: Tensor<3>) -> Tensor<1> {
    (x - y).abs().mean()
}

/// `(1 − λ)·l1 + λ·(1 − ssim)` (`[1]` each), differentiable in both terms.
pub fn mix_l1_dssim(l1: Tensor<1>, ssim: Tensor<1>, lambda: f64) -> Tensor<1> {
    #[cfg(feature = "wgpu")]
    if crate::cube::runs_on_cube(&l1.device()) {
        return gpu::mix_l1_dssim(l1, ssim, lambda as f32);
    }
    mix_l1_dssim_composed(l1, ssim, lambda)
}

/// [`mix_l1_dssim`] composed of burn's tensor ops.
pub fn mix_l1_dssim_composed(l1: Tensor<1>, ssim: Tensor<1>, lambda: f64) -> Tensor<1> {
    l1.mul_scalar(1.0 - lambda) + ssim.neg().add_scalar(1.0).mul_scalar(lambda)
}

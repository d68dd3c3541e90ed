//! The loss's small pieces: the mean absolute difference of two `[V, H, W]` images and the
//! total `(1 − λ)·L1 + λ·(1 − SSIM) + Σ wₖ·termₖ` of `[1]` terms. On a CubeCL device each is one op of
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

/// The total loss `(1 − λ)·l1 + λ·(1 − ssim) + Σ wₖ·termₖ` (`[1]` each), differentiable in every
/// term; `terms` are `(termₖ, wₖ)`, added in their order.
pub fn total_loss(l1: Tensor<1>, ssim: Tensor<1>, lambda: f64, terms: Vec<(Tensor<1>, f64)>) -> Tensor<1> {
    #[cfg(feature = "wgpu")]
    if crate::cube::runs_on_cube(&l1.device()) {
        let mut terms = terms;
        // One launch each way for the mix and the last term (a constant 0 when there is none);
        // any other term composed.
        let (term, weight) = terms.pop().unwrap_or_else(|| (Tensor::zeros([1], &l1.device()), 0.0));
        let mut total = gpu::mix_l1_dssim_plus(l1, ssim, term, lambda as f32, weight as f32);
        for (term, weight) in terms {
            total = total + term.mul_scalar(weight);
        }
        return total;
    }
    total_loss_composed(l1, ssim, lambda, terms)
}

/// [`total_loss`] composed of burn's tensor ops.
pub fn total_loss_composed(l1: Tensor<1>, ssim: Tensor<1>, lambda: f64, terms: Vec<(Tensor<1>, f64)>) -> Tensor<1> {
    let mut total = l1.mul_scalar(1.0 - lambda) + ssim.neg().add_scalar(1.0).mul_scalar(lambda);
    for (term, weight) in terms {
        total = total + term.mul_scalar(weight);
    }
    total
}

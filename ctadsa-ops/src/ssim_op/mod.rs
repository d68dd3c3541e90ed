//! Mean SSIM of a prediction against a fixed target, `[V, H, W]` images, as one burn backend op
//! with a hand-written backward: three window blurs forward, three backward, and per-pixel
//! loops between them. Written with tensor operations (`ssim::ssim_against_composed`, kept as
//! the test oracle) it made about 25 autodiff nodes per call, each a pass over the image and a
//! fresh buffer. On CubeCL (wgpu) the op runs as the kernels of `gpu.rs` (checked against the
//! CPU kernels by the wgpu parity tests).

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

pub mod cpu;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, NdArray, TensorMetadata, backend_extension, tensor::FloatTensor,
};
use burn::tensor::{Tensor, TensorData};

use crate::ndarray_host::with_host;

/// Backend operations of the SSIM mean.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait SsimBackend: Backend {
    /// Mean SSIM (`[1]`) of `x` against `y`, given the target's windowed mean `mu_y` and
    /// variance `syy` (all `[V, H, W]`), and what the backward needs: the prediction's window
    /// statistics (`[3·V, H, W]`: `blur(x)`, `blur(x²)`, `blur(x·y)`).
    fn ssim_mean(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
    /// `∂(mean SSIM)/∂x` (`[V, H, W]`) times the upstream gradient `grad` (`[1]`).
    fn ssim_mean_backward(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
        stats: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;
}

fn dims<B: Backend>(x: &FloatTensor<B>) -> [usize; 3] {
    let s = x.shape();
    [s[0], s[1], s[2]]
}

impl SsimBackend for NdArray {
    fn ssim_mean(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let device = x.device();
        let [v, h, w] = dims::<Self>(&x);
        let stats = with_host(&x, |x| with_host(&y, |y| cpu::stats(x, y, v, h, w)));
        let mean = with_host(&mu_y, |my| with_host(&syy, |s| cpu::mean(&stats, my, s)));
        (
            Self::float_from_data(TensorData::new(vec![mean as f32], [1]), &device),
            Self::float_from_data(TensorData::new(stats, [3 * v, h, w]), &device),
        )
    }

    fn ssim_mean_backward(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
        stats: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        let device = x.device();
        let [v, h, w] = dims::<Self>(&x);
        let g = with_host(&grad, |g| g[0]);
        let out = with_host(&x, |x| {
            with_host(&y, |y| {
                with_host(&mu_y, |my| {
                    with_host(&syy, |s| with_host(&stats, |st| cpu::backward(x, y, my, s, st, g, v, h, w)))
                })
            })
        });
        Self::float_from_data(TensorData::new(out, [v, h, w]), &device)
    }
}

#[cfg(feature = "wgpu")]
mod gpu;

#[cfg(feature = "wgpu")]
impl SsimBackend for burn_cubecl::CubeBackend {
    fn ssim_mean(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        gpu::forward(x, y, mu_y, syy)
    }

    fn ssim_mean_backward(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
        stats: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        gpu::backward(x, y, mu_y, syy, stats, grad)
    }
}

#[derive(Debug)]
struct SsimBackward;

impl<B: Backend + SsimBackend> Backward<B, 1> for SsimBackward {
    type State = [FloatTensor<B>; 5];

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_x] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let [x, y, mu_y, syy, stats] = ops.state;
        if let Some(n) = node_x {
            grads.register::<B>(n.id, B::ssim_mean_backward(x, y, mu_y, syy, stats, grad));
        }
    }
}

impl<B: Backend + SsimBackend, C: CheckpointStrategy> SsimBackend for Autodiff<B, C> {
    fn ssim_mean(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        // The target and its statistics are constants: only the prediction is tracked.
        let (y, mu_y, syy) = (y.into_primitive(), mu_y.into_primitive(), syy.into_primitive());
        match SsimBackward.prepare::<C>([x.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let x = x.into_primitive();
                let (mean, stats) = B::ssim_mean(x.clone(), y.clone(), mu_y.clone(), syy.clone());
                (prep.finish([x, y, mu_y, syy, stats.clone()], mean), Self::from_inner(stats))
            }
            OpsKind::UnTracked(prep) => {
                let (mean, stats) = B::ssim_mean(x.into_primitive(), y, mu_y, syy);
                (prep.finish(mean), Self::from_inner(stats))
            }
        }
    }

    fn ssim_mean_backward(
        x: FloatTensor<Self>,
        y: FloatTensor<Self>,
        mu_y: FloatTensor<Self>,
        syy: FloatTensor<Self>,
        stats: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::ssim_mean_backward(
            x.into_primitive(),
            y.into_primitive(),
            mu_y.into_primitive(),
            syy.into_primitive(),
            stats.into_primitive(),
            grad.into_primitive(),
        ))
    }
}

/// Mean SSIM (`[1]`) of `x` against the target `y` with windowed mean `mu_y` and variance `syy`
/// (all `[V, H, W]`; Wang et al.'s 11 × 11 Gaussian window σ 1.5 px, zero padding, C1 = 0.01²,
/// C2 = 0.03²), differentiable in `x`.
pub fn ssim_mean(x: Tensor<3>, y: Tensor<3>, mu_y: Tensor<3>, syy: Tensor<3>) -> Tensor<1> {
    let (mean, _) = <Dispatch as SsimBackend>::ssim_mean(
        x.into_dispatch(),
        y.into_dispatch(),
        mu_y.into_dispatch(),
        syy.into_dispatch(),
    );
    Tensor::from_dispatch(mean)
}

#[cfg(test)]
mod tests {
    use burn::tensor::{Device, Distribution};

    use super::*;
    use crate::readback::host_vec;
    use crate::ssim::{SsimTarget, ssim_against_composed};

    fn worst(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max)
    }

    /// The op against SSIM written with tensor operations, value and gradient, on images smaller
    /// and larger than the window, similar and unrelated to the target.
    #[test]
    fn ssim_op_matches_the_composed_ssim_value_and_gradient() {
        let device = Device::ndarray().autodiff();
        for [v, h, w] in [[1, 4, 6], [2, 23, 31], [3, 40, 17]] {
            let y = Tensor::<3>::random([v, h, w], Distribution::Uniform(0.0, 1.0), &device);
            let noise = Tensor::<3>::random([v, h, w], Distribution::Uniform(-0.2, 0.2), &device);
            let unrelated = Tensor::<3>::random([v, h, w], Distribution::Uniform(0.0, 1.0), &device);
            let target = SsimTarget::new(y.clone());
            for x in [(y.clone() + noise).clamp(0.0, 1.0), unrelated] {
                let x = x.detach().require_grad();
                let (ours, composed) = (
                    ssim_mean(x.clone(), target.y.clone(), target.mu_y.clone(), target.syy.clone()),
                    ssim_against_composed(x.clone(), &target),
                );
                let (a, b) = (host_vec(ours.clone())[0], host_vec(composed.clone())[0]);
                assert!((a - b).abs() <= 1e-5, "[{v}, {h}, {w}] SSIM {a} vs {b}");
                let ga = host_vec(x.grad(&ours.mul_scalar(3.0).backward()).unwrap());
                let gb = host_vec(x.grad(&composed.mul_scalar(3.0).backward()).unwrap());
                let scale = gb.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                assert!(scale > 0.0);
                let d = worst(&ga, &gb);
                assert!(d <= 1e-4 * scale, "[{v}, {h}, {w}] gradient differs by {d} (scale {scale})");
            }
        }
    }
}

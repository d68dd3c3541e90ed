//! The CubeCL ops of [`super::l1_mean`] and [`super::total_loss`], with their autodiff.

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, TensorMetadata, backend_extension, tensor::FloatTensor,
};
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::{CubeBackend, cubecl};

use crate::cube::{empty, launch_1d, mean, prepare};

/// The loss terms as backend ops (CubeCL only: other backends compose them).
#[backend_extension(Autodiff, Cube)]
pub trait LossTermsBackend: Backend {
    /// `mean |x − y|` (`[1]`) of two tensors of one shape.
    fn l1_mean(x: FloatTensor<Self>, y: FloatTensor<Self>) -> FloatTensor<Self>;
    /// `∂ mean |x − y| / ∂x` times the upstream `grad` (`[1]`).
    fn l1_mean_backward(x: FloatTensor<Self>, y: FloatTensor<Self>, grad: FloatTensor<Self>) -> FloatTensor<Self>;
    /// The mix plus `weight·term` (`[1]` each).
    fn mix_l1_dssim_plus(
        l1: FloatTensor<Self>,
        ssim: FloatTensor<Self>,
        term: FloatTensor<Self>,
        lambda: f32,
        weight: f32,
    ) -> FloatTensor<Self>;
    /// Its gradients for `l1`, `ssim` and `term`.
    fn mix_l1_dssim_plus_backward(
        grad: FloatTensor<Self>,
        lambda: f32,
        weight: f32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// `gx[i] = sign(x − y)·grad / len` (0 where they are equal, as burn's `abs` backward).
#[cube(launch)]
fn l1_grad_kernel(x: &Tensor<f32>, y: &Tensor<f32>, grad: &Tensor<f32>, gx: &mut Tensor<f32>, len: u32) {
    let i = ABSOLUTE_POS;
    if i >= len as usize {
        terminate!();
    }
    let d = x[i] - y[i];
    let g = grad[0] / f32::cast_from(len);
    gx[i] = select(d > 0.0f32, g, select(d < 0.0f32, -g, 0.0f32));
}

#[cube(launch)]
fn mix_plus_kernel(
    l1: &Tensor<f32>,
    ssim: &Tensor<f32>,
    term: &Tensor<f32>,
    out: &mut Tensor<f32>,
    lambda: f32,
    weight: f32,
) {
    if ABSOLUTE_POS == 0 {
        out[0] = (1.0f32 - lambda) * l1[0] + lambda * (1.0f32 - ssim[0]) + weight * term[0];
    }
}

#[cube(launch)]
fn mix_plus_grad_kernel(
    grad: &Tensor<f32>,
    g_l1: &mut Tensor<f32>,
    g_ssim: &mut Tensor<f32>,
    g_term: &mut Tensor<f32>,
    lambda: f32,
    weight: f32,
) {
    if ABSOLUTE_POS == 0 {
        g_l1[0] = (1.0f32 - lambda) * grad[0];
        g_ssim[0] = -lambda * grad[0];
        g_term[0] = weight * grad[0];
    }
}

impl LossTermsBackend for CubeBackend {
    fn l1_mean(x: FloatTensor<Self>, y: FloatTensor<Self>) -> FloatTensor<Self> {
        let (x, y) = (prepare(x), prepare(y));
        mean(&x, Some(&y))
    }

    fn l1_mean_backward(x: FloatTensor<Self>, y: FloatTensor<Self>, grad: FloatTensor<Self>) -> FloatTensor<Self> {
        let (x, y, grad) = (prepare(x), prepare(y), prepare(grad));
        let shape: Vec<usize> = x.shape().iter().copied().collect();
        let len = x.shape().num_elements();
        let gx = empty(shape, &x);
        if len > 0 {
            let (count, dim) = launch_1d(&x, len, 256);
            l1_grad_kernel::launch(
                &x.client,
                count,
                dim,
                x.clone().into_tensor_arg(),
                y.into_tensor_arg(),
                grad.into_tensor_arg(),
                gx.clone().into_tensor_arg(),
                len as u32,
            );
        }
        gx
    }

    fn mix_l1_dssim_plus(
        l1: FloatTensor<Self>,
        ssim: FloatTensor<Self>,
        term: FloatTensor<Self>,
        lambda: f32,
        weight: f32,
    ) -> FloatTensor<Self> {
        let (l1, ssim, term) = (prepare(l1), prepare(ssim), prepare(term));
        let out = empty(vec![1], &l1);
        mix_plus_kernel::launch(
            &l1.client,
            CubeCount::Static(1, 1, 1),
            CubeDim::new_1d(1),
            l1.clone().into_tensor_arg(),
            ssim.into_tensor_arg(),
            term.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            lambda,
            weight,
        );
        out
    }

    fn mix_l1_dssim_plus_backward(
        grad: FloatTensor<Self>,
        lambda: f32,
        weight: f32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let grad = prepare(grad);
        let (g_l1, g_ssim, g_term) = (empty(vec![1], &grad), empty(vec![1], &grad), empty(vec![1], &grad));
        mix_plus_grad_kernel::launch(
            &grad.client,
            CubeCount::Static(1, 1, 1),
            CubeDim::new_1d(1),
            grad.clone().into_tensor_arg(),
            g_l1.clone().into_tensor_arg(),
            g_ssim.clone().into_tensor_arg(),
            g_term.clone().into_tensor_arg(),
            lambda,
            weight,
        );
        (g_l1, g_ssim, g_term)
    }
}

#[derive(Debug)]
struct L1Backward;

impl<B: Backend + LossTermsBackend> Backward<B, 1> for L1Backward {
    type State = (FloatTensor<B>, FloatTensor<B>);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_x] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (x, y) = ops.state;
        if let Some(node) = node_x {
            grads.register::<B>(node.id, B::l1_mean_backward(x, y, grad));
        }
    }
}

#[derive(Debug)]
struct MixPlusBackward;

impl<B: Backend + LossTermsBackend> Backward<B, 3> for MixPlusBackward {
    /// `(λ, weight)`.
    type State = (f32, f32);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_l1, node_ssim, node_term] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (lambda, weight) = ops.state;
        let (g_l1, g_ssim, g_term) = B::mix_l1_dssim_plus_backward(grad, lambda, weight);
        for (node, g) in [(node_l1, g_l1), (node_ssim, g_ssim), (node_term, g_term)] {
            if let Some(node) = node {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: Backend + LossTermsBackend, C: CheckpointStrategy> LossTermsBackend for Autodiff<B, C> {
    fn l1_mean(x: FloatTensor<Self>, y: FloatTensor<Self>) -> FloatTensor<Self> {
        let y = y.into_primitive();
        match L1Backward.prepare::<C>([x.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let x = x.into_primitive();
                let out = B::l1_mean(x.clone(), y.clone());
                prep.finish((x, y), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::l1_mean(x.into_primitive(), y)),
        }
    }

    fn l1_mean_backward(x: FloatTensor<Self>, y: FloatTensor<Self>, grad: FloatTensor<Self>) -> FloatTensor<Self> {
        Self::from_inner(B::l1_mean_backward(x.into_primitive(), y.into_primitive(), grad.into_primitive()))
    }

    fn mix_l1_dssim_plus(
        l1: FloatTensor<Self>,
        ssim: FloatTensor<Self>,
        term: FloatTensor<Self>,
        lambda: f32,
        weight: f32,
    ) -> FloatTensor<Self> {
        let prep = MixPlusBackward.prepare::<C>([l1.node(), ssim.node(), term.node()]).compute_bound().stateful();
        let out =
            B::mix_l1_dssim_plus(l1.into_primitive(), ssim.into_primitive(), term.into_primitive(), lambda, weight);
        match prep {
            OpsKind::Tracked(prep) => prep.finish((lambda, weight), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }

    fn mix_l1_dssim_plus_backward(
        grad: FloatTensor<Self>,
        lambda: f32,
        weight: f32,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let (a, b, c) = B::mix_l1_dssim_plus_backward(grad.into_primitive(), lambda, weight);
        (Self::from_inner(a), Self::from_inner(b), Self::from_inner(c))
    }
}

pub(super) fn l1_mean(x: burn::tensor::Tensor<3>, y: burn::tensor::Tensor<3>) -> burn::tensor::Tensor<1> {
    let y = y.detach();
    burn::tensor::Tensor::from_dispatch(<Dispatch as LossTermsBackend>::l1_mean(x.into_dispatch(), y.into_dispatch()))
}

pub(super) fn mix_l1_dssim_plus(
    l1: burn::tensor::Tensor<1>,
    ssim: burn::tensor::Tensor<1>,
    term: burn::tensor::Tensor<1>,
    lambda: f32,
    weight: f32,
) -> burn::tensor::Tensor<1> {
    burn::tensor::Tensor::from_dispatch(<Dispatch as LossTermsBackend>::mix_l1_dssim_plus(
        l1.into_dispatch(),
        ssim.into_dispatch(),
        term.into_dispatch(),
        lambda,
        weight,
    ))
}

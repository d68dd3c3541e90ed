//! A linear layer with its activation, `act(x w + b)`, as one burn backend op with a
//! hand-written backward. On NdArray the matrix products run on strided views (burn-ndarray's
//! autodiff matmul copies every transposed operand element by element, and its ReLU copies the
//! tensor autodiff keeps): the opacity field's MLP costs a fraction of the composed ops at
//! paper scale. On CubeCL (wgpu) the backend's matmul runs with the bias, activation and
//! gradient sums in kernels of their own (`gpu.rs`). `cpu::reference` (f64 loops) is the CPU
//! kernels' oracle; a test compares the op with burn's `Linear` + `relu` / `softplus`, and the
//! wgpu parity test the GPU path with the CPU kernels.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

pub mod cpu;
#[cfg(feature = "wgpu")]
mod gpu;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, NdArray, TensorMetadata, backend_extension,
    tensor::FloatTensor,
};
use burn::tensor::{Tensor, TensorData};

use crate::ndarray_host::with_host;

/// Gradients of the layer's inputs.
#[derive(ExtensionType)]
pub struct LinearGrads<B: Backend> {
    /// `∂L/∂x` `[N, I]`.
    pub x: FloatTensor<B>,
    /// `∂L/∂w` `[I, O]`.
    pub weight: FloatTensor<B>,
    /// `∂L/∂b` `[O]`.
    pub bias: FloatTensor<B>,
}

/// The activation a fused linear layer applies to `z = x·w + b`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// `z` itself.
    Identity,
    /// `max(0, z)`.
    Relu,
    /// `ln(1 + eᶻ)`, evaluated as `max(0, z) + ln(1 + e^(−|z|))` (no overflow for large `z`).
    Softplus,
}

impl Activation {
    /// The activation of `z` (the CPU kernels').
    #[inline(always)]
    pub fn apply(self, z: f32) -> f32 {
        match self {
            Self::Identity => z,
            Self::Relu => z.max(0.0),
            Self::Softplus => z.max(0.0) + (-z.abs()).exp().ln_1p(),
        }
    }

    /// `∂L/∂z` from the upstream gradient `g` and the output `y`: `g`; `g` where `y > 0`, else
    /// 0; and `g · (1 − e^(−y))` (the logistic of `z`, from the output: `e^(−y) = 1 / (1 + eᶻ)`),
    /// with `1 − e^(−y)` as `−expm1(−y)`, exact also for small `y`.
    #[inline(always)]
    pub fn gradient(self, g: f32, y: f32) -> f32 {
        match self {
            Self::Identity => g,
            Self::Relu => {
                if y > 0.0 {
                    g
                } else {
                    0.0
                }
            }
            Self::Softplus => g * -(-y).exp_m1(),
        }
    }
}

/// Backend operations of the fused linear layer.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait LinearBackend: Backend {
    /// `x` `[N, I]`, `weight` `[I, O]`, `bias` `[O]` → `act(x·weight + bias)` `[N, O]`.
    fn fused_linear(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        act: Activation,
    ) -> FloatTensor<Self>;
    /// Gradients for the upstream gradient `grad` `[N, O]`; `output` is the forward result.
    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        act: Activation,
    ) -> LinearGrads<Self>;
}

impl LinearBackend for NdArray {
    fn fused_linear(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        act: Activation,
    ) -> FloatTensor<Self> {
        let device = x.device();
        let n = x.shape()[0];
        let o = weight.shape()[1];
        let y = with_host(&x, |x| with_host(&weight, |w| with_host(&bias, |b| cpu::forward(x, w, b, n, act))));
        Self::float_from_data(TensorData::new(y, [n, o]), &device)
    }

    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        act: Activation,
    ) -> LinearGrads<Self> {
        let device = x.device();
        let (n, i, o) = (x.shape()[0], weight.shape()[0], weight.shape()[1]);
        let (gx, gw, gb) = with_host(&x, |x| {
            with_host(&weight, |w| with_host(&output, |y| with_host(&grad, |g| cpu::backward(x, w, y, g, n, o, act))))
        });
        LinearGrads {
            x: Self::float_from_data(TensorData::new(gx, [n, i]), &device),
            weight: Self::float_from_data(TensorData::new(gw, [i, o]), &device),
            bias: Self::float_from_data(TensorData::new(gb, [o]), &device),
        }
    }
}

#[cfg(feature = "wgpu")]
impl LinearBackend for burn_cubecl::CubeBackend {
    fn fused_linear(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        act: Activation,
    ) -> FloatTensor<Self> {
        gpu::forward(x, weight, bias, act)
    }

    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        act: Activation,
    ) -> LinearGrads<Self> {
        gpu::backward(x, weight, output, grad, act)
    }
}

#[derive(Debug)]
struct LinearBackward;

impl<B: Backend + LinearBackend> Backward<B, 3> for LinearBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, Activation);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_x, node_w, node_b] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (x, w, y, act) = ops.state;
        let g = B::fused_linear_backward(x, w, y, grad, act);
        if let Some(n) = node_x {
            grads.register::<B>(n.id, g.x);
        }
        if let Some(n) = node_w {
            grads.register::<B>(n.id, g.weight);
        }
        if let Some(n) = node_b {
            grads.register::<B>(n.id, g.bias);
        }
    }
}

impl<B: Backend + LinearBackend, C: CheckpointStrategy> LinearBackend for Autodiff<B, C> {
    fn fused_linear(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        act: Activation,
    ) -> FloatTensor<Self> {
        match LinearBackward.prepare::<C>([x.node(), weight.node(), bias.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (x, w) = (x.into_primitive(), weight.into_primitive());
                let y = B::fused_linear(x.clone(), w.clone(), bias.into_primitive(), act);
                prep.finish((x, w, y.clone(), act), y)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::fused_linear(x.into_primitive(), weight.into_primitive(), bias.into_primitive(), act))
            }
        }
    }

    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        act: Activation,
    ) -> LinearGrads<Self> {
        let g = B::fused_linear_backward(
            x.into_primitive(),
            weight.into_primitive(),
            output.into_primitive(),
            grad.into_primitive(),
            act,
        );
        LinearGrads { x: Self::from_inner(g.x), weight: Self::from_inner(g.weight), bias: Self::from_inner(g.bias) }
    }
}

/// `act(x·weight + bias)` for `x` `[N, I]`, `weight` `[I, O]`, `bias` `[O]`: `[N, O]`,
/// differentiable in all three.
pub fn fused_linear(x: Tensor<2>, weight: Tensor<2>, bias: Tensor<1>, act: Activation) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as LinearBackend>::fused_linear(
        x.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
        act,
    ))
}

#[cfg(test)]
mod tests {
    use burn::module::Param;
    use burn::nn::LinearConfig;
    use burn::tensor::activation::{relu, softplus};
    use burn::tensor::{Device, Distribution};

    use super::*;
    use crate::readback::host_vec;

    fn assert_close(name: &str, a: Tensor<2>, b: Tensor<2>) {
        let (a, b) = (host_vec(a), host_vec(b));
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1.0);
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(worst <= 1e-5 * scale, "{name}: worst difference {worst} (scale {scale})");
    }

    /// The op, forward and backward, against burn's own `Linear`, `relu` and `softplus` under
    /// autodiff (pre-activations over ±4, and some beyond burn's softplus threshold of 20).
    #[test]
    fn fused_op_matches_burns_linear_and_activations() {
        let device = Device::ndarray().autodiff();
        let (n, i, o) = (300, 24, 16);
        let mut layer = LinearConfig::new(i, o).init(&device);
        layer.weight = Param::from_tensor(Tensor::random([i, o], Distribution::Uniform(-1.0, 1.0), &device));
        let x = Tensor::<2>::random([n, i], Distribution::Uniform(-1.0, 1.0), &device).require_grad();
        let up = Tensor::<2>::random([n, o], Distribution::Uniform(-1.0, 1.0), &device);
        for act in [Activation::Relu, Activation::Identity, Activation::Softplus] {
            let bias = layer.bias.as_ref().expect("burn's Linear has a bias").val();
            let ours = fused_linear(x.clone(), layer.weight.val(), bias.clone(), act);
            let burns = match act {
                Activation::Identity => layer.forward(x.clone()),
                Activation::Relu => relu(layer.forward(x.clone())),
                Activation::Softplus => softplus(layer.forward(x.clone()), 1.0),
            };
            assert_close("output", ours.clone(), burns.clone());
            let (ga, gb) = ((ours * up.clone()).sum().backward(), (burns * up.clone()).sum().backward());
            assert_close("x", x.grad(&ga).unwrap(), x.grad(&gb).unwrap());
            assert_close("weight", layer.weight.val().grad(&ga).unwrap(), layer.weight.val().grad(&gb).unwrap());
            let (ba, bb) = (bias.grad(&ga).unwrap(), bias.grad(&gb).unwrap());
            assert_close("bias", ba.reshape([1, o]), bb.reshape([1, o]));
        }
    }

    /// The CPU activation and its slope from the output against f64 over ±40 (the softplus's
    /// output and slope both reach ≈ 4e-18 at −40): relative error ≤ 1e-5 of the value itself.
    #[test]
    fn softplus_and_its_slope_are_accurate_in_both_tails() {
        for k in -400..=400 {
            let z = k as f32 * 0.1;
            let zd = z as f64;
            let (y_exact, slope_exact) = (zd.exp().ln_1p(), 1.0 / (1.0 + (-zd).exp()));
            let y = Activation::Softplus.apply(z);
            let slope = Activation::Softplus.gradient(1.0, y);
            assert!((y as f64 - y_exact).abs() <= 1e-5 * y_exact, "softplus({z}) = {y}, not {y_exact}");
            assert!(
                (slope as f64 - slope_exact).abs() <= 1e-5 * slope_exact,
                "slope at {z}: {slope}, not {slope_exact}"
            );
        }
    }
}

//! A linear layer with its activation, `act(x w + b)`, as one burn backend op with a
//! hand-written backward. On NdArray the matrix products run on strided views (burn-ndarray's
//! autodiff matmul copies every transposed operand element by element, and its ReLU copies the
//! tensor autodiff keeps): the opacity field's MLP costs a fraction of the composed ops at
//! paper scale. Other backends compose their own primitive ops; `cpu::reference` (f64 loops)
//! is the kernels' oracle and a test compares the op with burn's `Linear` + `relu`.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

pub mod cpu;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, FloatDType, NdArray, TensorMetadata,
    backend_extension, tensor::FloatTensor,
};
use burn::tensor::{Shape, Tensor, TensorData};

use crate::method::ndarray_host::with_host;

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

/// Backend operations of the fused linear layer.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait LinearBackend: Backend {
    /// `x` `[N, I]`, `weight` `[I, O]`, `bias` `[O]` → `act(x·weight + bias)` `[N, O]`, with
    /// `act` = ReLU when `relu`, else the identity.
    fn fused_linear(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self>;
    /// Gradients for the upstream gradient `grad` `[N, O]`; `output` is the forward result.
    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        relu: bool,
    ) -> LinearGrads<Self>;
}

impl LinearBackend for NdArray {
    fn fused_linear(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self> {
        let device = x.device();
        let n = x.shape()[0];
        let o = weight.shape()[1];
        let y = with_host(&x, |x| with_host(&weight, |w| with_host(&bias, |b| cpu::forward(x, w, b, n, relu))));
        Self::float_from_data(TensorData::new(y, [n, o]), &device)
    }

    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        relu: bool,
    ) -> LinearGrads<Self> {
        let device = x.device();
        let (n, i, o) = (x.shape()[0], weight.shape()[0], weight.shape()[1]);
        let (gx, gw, gb) = with_host(&x, |x| {
            with_host(&weight, |w| with_host(&output, |y| with_host(&grad, |g| cpu::backward(x, w, y, g, n, o, relu))))
        });
        LinearGrads {
            x: Self::float_from_data(TensorData::new(gx, [n, i]), &device),
            weight: Self::float_from_data(TensorData::new(gw, [i, o]), &device),
            bias: Self::float_from_data(TensorData::new(gb, [o]), &device),
        }
    }
}

/// The layer composed of a backend's own primitive ops (its matmul, broadcasting add, ReLU).
#[cfg(any(feature = "wgpu", test))]
fn composed_forward<B: Backend>(x: FloatTensor<B>, w: FloatTensor<B>, b: FloatTensor<B>, relu: bool) -> FloatTensor<B> {
    let o = w.shape()[1];
    let z = B::float_add(B::float_matmul(x, w), B::float_reshape(b, Shape::new([1, o])));
    if relu { B::relu(z) } else { z }
}

#[cfg(any(feature = "wgpu", test))]
fn composed_backward<B: Backend>(
    x: FloatTensor<B>,
    w: FloatTensor<B>,
    y: FloatTensor<B>,
    grad: FloatTensor<B>,
    relu: bool,
) -> LinearGrads<B> {
    let (n, i, o) = (x.shape()[0], w.shape()[0], w.shape()[1]);
    let gz = if relu { B::relu_backward(y, grad) } else { grad };
    let grad_x = B::float_matmul(gz.clone(), B::float_transpose(w));
    // The sums over the N rows go in two passes: partial sums over chunks of rows, then over
    // the chunks. A backend without autotuning (CubeCL as built here) reduces an axis with one
    // unit per output walking it serially, and multiplies with one cube per output tile: one
    // pass over 100k rows would run on a handful of units.
    let chunk = row_chunk(n);
    let (x3, gz3) = (chunked::<B>(x, chunk), chunked::<B>(gz, chunk));
    let partial_weight = B::float_matmul(B::float_swap_dims(x3, 1, 2), gz3.clone());
    let partial_bias = B::float_sum_dim(gz3, 1);
    LinearGrads {
        weight: B::float_reshape(B::float_sum_dim(partial_weight, 0), Shape::new([i, o])),
        x: grad_x,
        bias: B::float_reshape(B::float_sum_dim(partial_bias, 0), Shape::new([o])),
    }
}

/// Rows per partial sum of the composed backward: ⌊√N⌋, at least 64 (both passes then walk
/// about √N elements per output).
#[cfg(any(feature = "wgpu", test))]
fn row_chunk(n: usize) -> usize {
    n.isqrt().max(64)
}

/// `t` `[N, C]` as `[⌈N / chunk⌉, chunk, C]`, the last chunk padded with zero rows.
#[cfg(any(feature = "wgpu", test))]
fn chunked<B: Backend>(t: FloatTensor<B>, chunk: usize) -> FloatTensor<B> {
    let (n, c) = (t.shape()[0], t.shape()[1]);
    let chunks = n.div_ceil(chunk);
    let pad = chunks * chunk - n;
    let t = if pad > 0 {
        let zeros = B::float_zeros(Shape::new([pad, c]), &t.device(), FloatDType::F32);
        B::float_cat(vec![t, zeros], 0)
    } else {
        t
    };
    B::float_reshape(t, Shape::new([chunks, chunk, c]))
}

#[cfg(feature = "wgpu")]
impl LinearBackend for burn_cubecl::CubeBackend {
    fn fused_linear(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self> {
        composed_forward::<Self>(x, weight, bias, relu)
    }

    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        relu: bool,
    ) -> LinearGrads<Self> {
        composed_backward::<Self>(x, weight, output, grad, relu)
    }
}

#[derive(Debug)]
struct LinearBackward;

impl<B: Backend + LinearBackend> Backward<B, 3> for LinearBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, bool);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_x, node_w, node_b] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (x, w, y, relu) = ops.state;
        let g = B::fused_linear_backward(x, w, y, grad, relu);
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
        relu: bool,
    ) -> FloatTensor<Self> {
        match LinearBackward.prepare::<C>([x.node(), weight.node(), bias.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (x, w) = (x.into_primitive(), weight.into_primitive());
                let y = B::fused_linear(x.clone(), w.clone(), bias.into_primitive(), relu);
                prep.finish((x, w, y.clone(), relu), y)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::fused_linear(x.into_primitive(), weight.into_primitive(), bias.into_primitive(), relu))
            }
        }
    }

    fn fused_linear_backward(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        output: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        relu: bool,
    ) -> LinearGrads<Self> {
        let g = B::fused_linear_backward(
            x.into_primitive(),
            weight.into_primitive(),
            output.into_primitive(),
            grad.into_primitive(),
            relu,
        );
        LinearGrads { x: Self::from_inner(g.x), weight: Self::from_inner(g.weight), bias: Self::from_inner(g.bias) }
    }
}

/// `act(x·weight + bias)` for `x` `[N, I]`, `weight` `[I, O]`, `bias` `[O]`: `[N, O]`,
/// differentiable in all three; `act` is ReLU when `relu`, else the identity.
pub fn fused_linear(x: Tensor<2>, weight: Tensor<2>, bias: Tensor<1>, relu: bool) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as LinearBackend>::fused_linear(
        x.into_dispatch(),
        weight.into_dispatch(),
        bias.into_dispatch(),
        relu,
    ))
}

#[cfg(test)]
mod tests {
    use burn::module::Param;
    use burn::nn::LinearConfig;
    use burn::tensor::activation::relu;
    use burn::tensor::{Device, Distribution};

    use super::*;
    use crate::method::model::host_vec;

    fn assert_close(name: &str, a: Tensor<2>, b: Tensor<2>) {
        let (a, b) = (host_vec(a), host_vec(b));
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1.0);
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(worst <= 1e-5 * scale, "{name}: worst difference {worst} (scale {scale})");
    }

    /// The op, forward and backward, against burn's own `Linear` and `relu` under autodiff.
    #[test]
    fn fused_op_matches_burns_linear_and_relu() {
        let device = Device::ndarray().autodiff();
        let (n, i, o) = (300, 24, 16);
        let mut layer = LinearConfig::new(i, o).init(&device);
        layer.weight = Param::from_tensor(Tensor::random([i, o], Distribution::Uniform(-1.0, 1.0), &device));
        let x = Tensor::<2>::random([n, i], Distribution::Uniform(-1.0, 1.0), &device).require_grad();
        let up = Tensor::<2>::random([n, o], Distribution::Uniform(-1.0, 1.0), &device);
        for act in [true, false] {
            let bias = layer.bias.as_ref().expect("burn's Linear has a bias").val();
            let ours = fused_linear(x.clone(), layer.weight.val(), bias.clone(), act);
            let burns = if act { relu(layer.forward(x.clone())) } else { layer.forward(x.clone()) };
            assert_close("output", ours.clone(), burns.clone());
            let (ga, gb) = ((ours * up.clone()).sum().backward(), (burns * up.clone()).sum().backward());
            assert_close("x", x.grad(&ga).unwrap(), x.grad(&gb).unwrap());
            assert_close("weight", layer.weight.val().grad(&ga).unwrap(), layer.weight.val().grad(&gb).unwrap());
            let (ba, bb) = (bias.grad(&ga).unwrap(), bias.grad(&gb).unwrap());
            assert_close("bias", ba.reshape([1, o]), bb.reshape([1, o]));
        }
    }

    /// The composed path other backends take, run on NdArray's primitives, against the kernels:
    /// row counts that fill whole chunks and that pad the last one.
    #[test]
    fn composed_path_matches_the_cpu_kernels() {
        for n in [257, 4096, 5000] {
            composed_path_matches_with(n);
        }
    }

    fn composed_path_matches_with(n: usize) {
        use crate::method::ndarray_host::host;
        let (i, o) = (9, 5);
        let mut s = 7u64;
        let mut values = |len: usize| -> Vec<f32> {
            (0..len)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
                })
                .collect()
        };
        let (x, w, b, g) = (values(n * i), values(i * o), values(o), values(n * o));
        let device = burn::backend::ndarray::NdArrayDevice::Cpu;
        let t = |v: &[f32], shape: Vec<usize>| NdArray::float_from_data(TensorData::new(v.to_vec(), shape), &device);
        for act in [true, false] {
            let y = composed_forward::<NdArray>(t(&x, vec![n, i]), t(&w, vec![i, o]), t(&b, vec![o]), act);
            let y_cpu = cpu::forward(&x, &w, &b, n, act);
            let y_host = host::<NdArray>(y.clone());
            let grads = composed_backward::<NdArray>(t(&x, vec![n, i]), t(&w, vec![i, o]), y, t(&g, vec![n, o]), act);
            let (gx, gw, gb) = cpu::backward(&x, &w, &y_cpu, &g, n, o, act);
            for (name, composed, kernel) in [
                ("output", y_host, y_cpu.clone()),
                ("x", host::<NdArray>(grads.x), gx),
                ("weight", host::<NdArray>(grads.weight), gw),
                ("bias", host::<NdArray>(grads.bias), gb),
            ] {
                assert_eq!(composed.len(), kernel.len(), "{name} (n = {n})");
                let worst = composed.iter().zip(&kernel).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
                let scale = kernel.iter().fold(1.0f32, |m, v| m.max(v.abs()));
                assert!(worst <= 1e-5 * scale, "{name} (n = {n}): worst difference {worst} (scale {scale})");
            }
        }
    }
}

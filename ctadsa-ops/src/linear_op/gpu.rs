//! The linear layer on CubeCL: the backend's matrix product, with the bias, activation and
//! weight-gradient sums in kernels of their own, so that a layer takes two launches forward and
//! four backward (composed of tensor ops it took eight to sixteen).
//!
//! - forward: `z = x·w` (matmul), then one unit per output element adds the bias and applies
//!   the activation;
//! - backward: one unit per element turns the upstream gradient into `∂L/∂z` (from the output,
//!   as the CPU kernels), `∂L/∂x = ∂L/∂z · wᵀ` (matmul), and the weight and bias gradients as
//!   partial sums over chunks of [`ROWS_PER_CHUNK`] rows (one unit per chunk and entry of the
//!   `[I + 1, O]` block, the last row being the bias's) summed over the chunks by one reduction.

use burn::backend::TensorMetadata;
use burn::backend::ops::FloatTensorOps;
use burn::tensor::Shape;
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use super::{Activation, LinearGrads};
use crate::cube::{empty, launch_1d, prepare};

/// Rows per partial sum of the weight and bias gradients.
pub const ROWS_PER_CHUNK: usize = 256;

/// Comptime code of an activation in the kernels.
fn code(act: Activation) -> u32 {
    match act {
        Activation::Identity => 0,
        Activation::Relu => 1,
        Activation::Softplus => 2,
    }
}

/// `out[r, o] = act(z[r, o] + bias[o])`.
#[cube(launch)]
fn bias_activation_kernel(
    z: &Tensor<f32>,
    bias: &Tensor<f32>,
    out: &mut Tensor<f32>,
    len: u32,
    outputs: u32,
    #[comptime] act: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= len as usize {
        terminate!();
    }
    let v = z[id] + bias[id % (outputs as usize)];
    let mut y = v;
    if act == 1u32 {
        y = f32::max(v, 0.0f32);
    }
    if act == 2u32 {
        y = f32::max(v, 0.0f32) + f32::log1p(f32::exp(-f32::abs(v)));
    }
    out[id] = y;
}

/// `∂L/∂z` from the upstream gradient and the layer's output (`Activation::gradient`).
#[cube(launch)]
fn activation_gradient_kernel(
    grad: &Tensor<f32>,
    y: &Tensor<f32>,
    out: &mut Tensor<f32>,
    len: u32,
    #[comptime] act: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= len as usize {
        terminate!();
    }
    let g = grad[id];
    let mut d = g;
    if act == 1u32 {
        d = select(y[id] > 0.0f32, g, 0.0f32);
    }
    if act == 2u32 {
        // 1 − e^(−y), the logistic of the pre-activation.
        d = g * (1.0f32 - f32::exp(-y[id]));
    }
    out[id] = d;
}

/// `partial[c, i, o] = Σ_{r in chunk c} x[r, i] · gz[r, o]` for `i < I`, and `Σ gz[r, o]` for
/// `i = I` (the bias row). One unit per `(c, i, o)`.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn weight_gradient_kernel(
    x: &Tensor<f32>,
    gz: &Tensor<f32>,
    partial: &mut Tensor<f32>,
    rows: u32,
    inputs: u32,
    outputs: u32,
    chunk: u32,
    len: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= len as usize {
        terminate!();
    }
    let o = id % (outputs as usize);
    let i = (id / (outputs as usize)) % (inputs as usize + 1);
    let c = id / ((outputs as usize) * (inputs as usize + 1));
    let start = c * (chunk as usize);
    let mut end = start + chunk as usize;
    if end > rows as usize {
        end = rows as usize;
    }
    let mut acc = 0.0f32;
    if i == inputs as usize {
        for r in start..end {
            acc += gz[r * (outputs as usize) + o];
        }
    } else {
        for r in start..end {
            acc += x[r * (inputs as usize) + i] * gz[r * (outputs as usize) + o];
        }
    }
    partial[id] = acc;
}

/// `act(x·w + b)`: `x` `[N, I]`, `w` `[I, O]`, `b` `[O]` → `[N, O]`.
pub fn forward(x: CubeTensor, w: CubeTensor, b: CubeTensor, act: Activation) -> CubeTensor {
    let (n, o) = (x.shape()[0], w.shape()[1]);
    let z = prepare(CubeBackend::float_matmul(x, w));
    let b = prepare(b);
    let out = empty(vec![n, o], &z);
    let len = n * o;
    if len > 0 {
        let (count, dim) = launch_1d(&z, len, 256);
        bias_activation_kernel::launch(
            &z.client,
            count,
            dim,
            z.clone().into_tensor_arg(),
            b.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            len as u32,
            o as u32,
            code(act),
        );
    }
    out
}

/// Gradients of [`forward`] for the upstream gradient `grad` `[N, O]` and its output `y`.
pub fn backward(
    x: CubeTensor,
    w: CubeTensor,
    y: CubeTensor,
    grad: CubeTensor,
    act: Activation,
) -> LinearGrads<CubeBackend> {
    let (x, w, grad) = (prepare(x), prepare(w), prepare(grad));
    let (n, i, o) = (x.shape()[0], w.shape()[0], w.shape()[1]);
    let gz = match act {
        Activation::Identity => grad,
        _ => {
            let y = prepare(y);
            let gz = empty(vec![n, o], &grad);
            let len = n * o;
            if len > 0 {
                let (count, dim) = launch_1d(&grad, len, 256);
                activation_gradient_kernel::launch(
                    &grad.client,
                    count,
                    dim,
                    grad.clone().into_tensor_arg(),
                    y.into_tensor_arg(),
                    gz.clone().into_tensor_arg(),
                    len as u32,
                    code(act),
                );
            }
            gz
        }
    };
    let grad_x = CubeBackend::float_matmul(gz.clone(), CubeBackend::float_transpose(w));
    let chunks = n.div_ceil(ROWS_PER_CHUNK).max(1);
    let partial = empty(vec![chunks, i + 1, o], &gz);
    let len = chunks * (i + 1) * o;
    let (count, dim) = launch_1d(&gz, len, 256);
    weight_gradient_kernel::launch(
        &gz.client,
        count,
        dim,
        x.into_tensor_arg(),
        gz.clone().into_tensor_arg(),
        partial.clone().into_tensor_arg(),
        n as u32,
        i as u32,
        o as u32,
        ROWS_PER_CHUNK as u32,
        len as u32,
    );
    let sums = CubeBackend::float_reshape(CubeBackend::float_sum_dim(partial, 0), Shape::new([i + 1, o]));
    let weight =
        CubeBackend::float_slice(sums.clone(), &[burn::tensor::Slice::from(0..i), burn::tensor::Slice::from(0..o)]);
    let bias = CubeBackend::float_slice(sums, &[burn::tensor::Slice::from(i..i + 1), burn::tensor::Slice::from(0..o)]);
    LinearGrads { x: grad_x, weight, bias: CubeBackend::float_reshape(bias, Shape::new([o])) }
}

//! The fused Adam step as one CubeCL kernel per parameter tensor: each unit reads its parameter,
//! gradient and two moments once and writes the three results once (burn's Adam expressions,
//! in burn's order: about fifteen tensor passes and launches each when composed of tensor ops).

use burn::backend::TensorMetadata;
use burn::backend::tensor::FloatTensor;
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use super::kernel::{AdamCoefficients, AdamUpdate, FusedAdamBackend};
use crate::cube::{empty, launch_1d, prepare};

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn adam_kernel(
    param: &Tensor<f32>,
    grad: &Tensor<f32>,
    moment_1: &Tensor<f32>,
    moment_2: &Tensor<f32>,
    param_out: &mut Tensor<f32>,
    moment_1_out: &mut Tensor<f32>,
    moment_2_out: &mut Tensor<f32>,
    beta_1: f32,
    beta_2: f32,
    combined: f32,
    eps: f32,
    lr: f32,
    penalty: f32,
    len: u32,
    #[comptime] decay: bool,
) {
    let i = ABSOLUTE_POS;
    if i >= len as usize {
        terminate!();
    }
    let f1 = 1.0f32 - beta_1;
    let f2 = 1.0f32 - beta_2;
    let p = param[i];
    let mut g = grad[i];
    if decay {
        // p·l + g (burn's order; f32 addition commutes exactly).
        g += p * penalty;
    }
    let m = moment_1[i] * beta_1 + g * f1;
    let v = moment_2[i] * beta_2 + (g * g) * f2;
    let step = m * combined / (f32::sqrt(v) + eps);
    param_out[i] = p - step * lr;
    moment_1_out[i] = m;
    moment_2_out[i] = v;
}

/// One Adam step on the GPU (all four tensors of one shape).
pub fn adam_update(
    param: CubeTensor,
    grad: CubeTensor,
    moment_1: CubeTensor,
    moment_2: CubeTensor,
    c: AdamCoefficients,
) -> AdamUpdate<CubeBackend> {
    let (param, grad, moment_1, moment_2) = (prepare(param), prepare(grad), prepare(moment_1), prepare(moment_2));
    let shape = param.shape();
    let len = shape.num_elements();
    let output = || empty(shape.to_vec(), &param);
    let (param_out, moment_1_out, moment_2_out) = (output(), output(), output());
    if len > 0 {
        let (bc2_sqrt, combined) = c.bias_corrections();
        let (count, dim) = launch_1d(&param, len, 256);
        adam_kernel::launch(
            &param.client,
            count,
            dim,
            param.clone().into_tensor_arg(),
            grad.into_tensor_arg(),
            moment_1.into_tensor_arg(),
            moment_2.into_tensor_arg(),
            param_out.clone().into_tensor_arg(),
            moment_1_out.clone().into_tensor_arg(),
            moment_2_out.clone().into_tensor_arg(),
            c.beta_1,
            c.beta_2,
            combined,
            c.epsilon * bc2_sqrt,
            c.lr,
            c.weight_decay.unwrap_or(0.0),
            len as u32,
            c.weight_decay.is_some(),
        );
    }
    AdamUpdate { param: param_out, moment_1: moment_1_out, moment_2: moment_2_out }
}

/// The op on CubeCL: `adam_update`.
impl FusedAdamBackend for burn_cubecl::CubeBackend {
    fn adam_update(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        c: AdamCoefficients,
    ) -> AdamUpdate<Self> {
        adam_update(param, grad, moment_1, moment_2, c)
    }
}

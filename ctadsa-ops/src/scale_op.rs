//! The bounded scale activation `s = (max − min)·σ(raw) + min` (mm) as one backend op with a
//! hand-written backward. Composed of burn's ops on NdArray it made nine single-threaded passes
//! over the `[N, 3]` raw scales per training step (the sigmoid's exp, log and exp, the scaling,
//! and their backward) while the other cores waited. The CPU kernels make one parallel pass each
//! way with the same operations in the same order as burn's `sigmoid` (`exp(−ln(exp(−x) + 1))`),
//! its backward (`σ·(1 − σ)·grad`) and the scaling, so the results are the same bit for bit
//! (test); the CubeCL kernels do the same in one launch each way.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

#[cfg(test)]
use burn::backend::Scalar;
use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, NdArray, TensorMetadata, backend_extension, tensor::FloatTensor,
};
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;

use crate::ndarray_host::with_host;

/// Backend operations of the bounded scale activation.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait BoundedScaleBackend: Backend {
    /// `raw` (any shape) → `(scales, sigmoid)`: `σ(raw)·(max_mm − min_mm) + min_mm` and `σ(raw)`,
    /// the latter for the backward.
    fn bounded_scale(raw: FloatTensor<Self>, min_mm: f32, max_mm: f32) -> (FloatTensor<Self>, FloatTensor<Self>);
    /// `∂L/∂raw = σ·(1 − σ)·(grad·(max_mm − min_mm))` from the forward's `sigmoid`.
    fn bounded_scale_backward(
        sigmoid: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        min_mm: f32,
        max_mm: f32,
    ) -> FloatTensor<Self>;
}

/// burn's `sigmoid` of one value, operation for operation.
#[inline(always)]
fn sigmoid(x: f32) -> f32 {
    (-((-x).exp() + 1.0).ln()).exp()
}

impl BoundedScaleBackend for NdArray {
    fn bounded_scale(raw: FloatTensor<Self>, min_mm: f32, max_mm: f32) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let device = raw.device();
        let dims: Vec<usize> = raw.shape().iter().copied().collect();
        let range = max_mm - min_mm;
        let (scales, sig): (Vec<f32>, Vec<f32>) = with_host(&raw, |r| {
            r.par_iter()
                .map(|&x| {
                    let s = sigmoid(x);
                    (s * range + min_mm, s)
                })
                .unzip()
        });
        (
            Self::float_from_data(TensorData::new(scales, dims.clone()), &device),
            Self::float_from_data(TensorData::new(sig, dims), &device),
        )
    }

    fn bounded_scale_backward(
        sigmoid: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        min_mm: f32,
        max_mm: f32,
    ) -> FloatTensor<Self> {
        let device = sigmoid.device();
        let dims: Vec<usize> = sigmoid.shape().iter().copied().collect();
        let range = max_mm - min_mm;
        let g: Vec<f32> = with_host(&sigmoid, |s| {
            with_host(&grad, |g| s.par_iter().zip(g).map(|(&s, &g)| (s * (-s + 1.0)) * (g * range)).collect())
        });
        Self::float_from_data(TensorData::new(g, dims), &device)
    }
}

/// The forward composed of a backend's own primitive ops (the kernels' second oracle).
#[cfg(test)]
fn composed_forward<B: Backend>(raw: FloatTensor<B>, min_mm: f32, max_mm: f32) -> (FloatTensor<B>, FloatTensor<B>) {
    let sig = B::sigmoid(raw);
    let scales = B::float_add_scalar(
        B::float_mul_scalar(sig.clone(), Scalar::Float((max_mm - min_mm) as f64)),
        Scalar::Float(min_mm as f64),
    );
    (scales, sig)
}

/// The backward composed of a backend's own primitive ops.
#[cfg(test)]
fn composed_backward<B: Backend>(
    sig: FloatTensor<B>,
    grad: FloatTensor<B>,
    min_mm: f32,
    max_mm: f32,
) -> FloatTensor<B> {
    B::sigmoid_backward(sig, B::float_mul_scalar(grad, Scalar::Float((max_mm - min_mm) as f64)))
}

#[cfg(feature = "wgpu")]
impl BoundedScaleBackend for burn_cubecl::CubeBackend {
    fn bounded_scale(raw: FloatTensor<Self>, min_mm: f32, max_mm: f32) -> (FloatTensor<Self>, FloatTensor<Self>) {
        gpu::forward(raw, min_mm, max_mm)
    }

    fn bounded_scale_backward(
        sigmoid: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        min_mm: f32,
        max_mm: f32,
    ) -> FloatTensor<Self> {
        gpu::backward(sigmoid, grad, min_mm, max_mm)
    }
}

/// The CubeCL kernels: one launch each way (burn's composed sigmoid and scaling took six
/// forward and four backward). Their oracle is the CPU kernels (`tests/ops_wgpu.rs`).
#[cfg(feature = "wgpu")]
mod gpu {
    use burn::backend::TensorMetadata;
    use burn_cubecl::cubecl;
    use burn_cubecl::cubecl::prelude::*;
    use burn_cubecl::tensor::CubeTensor;

    use crate::cube::{empty, launch_1d, prepare};

    /// `sig = σ(raw)`, `scales = sig·range + min`.
    #[cube(launch)]
    fn scale_forward_kernel(
        raw: &Tensor<f32>,
        scales: &mut Tensor<f32>,
        sig: &mut Tensor<f32>,
        min_mm: f32,
        range: f32,
        len: u32,
    ) {
        let id = ABSOLUTE_POS;
        if id >= len as usize {
            terminate!();
        }
        let s = f32::exp(-f32::ln(f32::exp(-raw[id]) + 1.0f32));
        sig[id] = s;
        scales[id] = s * range + min_mm;
    }

    /// `∂L/∂raw = σ·(1 − σ)·(grad·range)`.
    #[cube(launch)]
    fn scale_backward_kernel(sig: &Tensor<f32>, grad: &Tensor<f32>, out: &mut Tensor<f32>, range: f32, len: u32) {
        let id = ABSOLUTE_POS;
        if id >= len as usize {
            terminate!();
        }
        let s = sig[id];
        out[id] = (s * (1.0f32 - s)) * (grad[id] * range);
    }

    pub(super) fn forward(raw: CubeTensor, min_mm: f32, max_mm: f32) -> (CubeTensor, CubeTensor) {
        let raw = prepare(raw);
        let shape: Vec<usize> = raw.shape().iter().copied().collect();
        let len: usize = shape.iter().product();
        let (scales, sig) = (empty(shape.clone(), &raw), empty(shape, &raw));
        if len > 0 {
            let (count, dim) = launch_1d(&raw, len, 256);
            scale_forward_kernel::launch(
                &raw.client,
                count,
                dim,
                raw.clone().into_tensor_arg(),
                scales.clone().into_tensor_arg(),
                sig.clone().into_tensor_arg(),
                min_mm,
                max_mm - min_mm,
                len as u32,
            );
        }
        (scales, sig)
    }

    pub(super) fn backward(sig: CubeTensor, grad: CubeTensor, min_mm: f32, max_mm: f32) -> CubeTensor {
        let (sig, grad) = (prepare(sig), prepare(grad));
        let shape: Vec<usize> = sig.shape().iter().copied().collect();
        let len: usize = shape.iter().product();
        let out = empty(shape, &sig);
        if len > 0 {
            let (count, dim) = launch_1d(&sig, len, 256);
            scale_backward_kernel::launch(
                &sig.client,
                count,
                dim,
                sig.clone().into_tensor_arg(),
                grad.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                max_mm - min_mm,
                len as u32,
            );
        }
        out
    }
}

#[derive(Debug)]
struct ScaleBackward;

impl<B: Backend + BoundedScaleBackend> Backward<B, 1> for ScaleBackward {
    type State = (FloatTensor<B>, f32, f32);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_raw] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (sig, min_mm, max_mm) = ops.state;
        if let Some(n) = node_raw {
            grads.register::<B>(n.id, B::bounded_scale_backward(sig, grad, min_mm, max_mm));
        }
    }
}

impl<B: Backend + BoundedScaleBackend, C: CheckpointStrategy> BoundedScaleBackend for Autodiff<B, C> {
    fn bounded_scale(raw: FloatTensor<Self>, min_mm: f32, max_mm: f32) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (scales, sig) = match ScaleBackward.prepare::<C>([raw.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (scales, sig) = B::bounded_scale(raw.into_primitive(), min_mm, max_mm);
                (prep.finish((sig.clone(), min_mm, max_mm), scales), sig)
            }
            OpsKind::UnTracked(prep) => {
                let (scales, sig) = B::bounded_scale(raw.into_primitive(), min_mm, max_mm);
                (prep.finish(scales), sig)
            }
        };
        (scales, Self::from_inner(sig))
    }

    fn bounded_scale_backward(
        sigmoid: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        min_mm: f32,
        max_mm: f32,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::bounded_scale_backward(sigmoid.into_primitive(), grad.into_primitive(), min_mm, max_mm))
    }
}

/// `σ(raw)·(max_mm − min_mm) + min_mm`, element-wise and differentiable in `raw` (mm when the
/// bounds are).
pub fn bounded_scale<const D: usize>(raw: Tensor<D>, min_mm: f32, max_mm: f32) -> Tensor<D> {
    let (scales, _) = <Dispatch as BoundedScaleBackend>::bounded_scale(raw.into_dispatch(), min_mm, max_mm);
    Tensor::from_dispatch(scales)
}

#[cfg(test)]
mod tests {
    use burn::tensor::activation::sigmoid as burn_sigmoid;
    use burn::tensor::{Device, Distribution};

    use super::*;
    use crate::readback::host_vec;

    /// The op, forward and backward, equals burn's `sigmoid` scaled, bit for bit.
    #[test]
    fn op_equals_burns_sigmoid_composition_bit_for_bit() {
        let device = Device::ndarray().autodiff();
        let (min_mm, max_mm) = (0.035f32, 3.5f32);
        let raw = Tensor::<2>::random([5000, 3], Distribution::Uniform(-30.0, 30.0), &device).require_grad();
        let up = Tensor::<2>::random([5000, 3], Distribution::Uniform(-1.0, 1.0), &device);
        let ours = bounded_scale(raw.clone(), min_mm, max_mm);
        let burns = burn_sigmoid(raw.clone()).mul_scalar(max_mm - min_mm).add_scalar(min_mm);
        let (ga, gb) = ((ours.clone() * up.clone()).sum().backward(), (burns.clone() * up).sum().backward());
        assert_eq!(host_vec(ours), host_vec(burns));
        assert_eq!(host_vec(raw.grad(&ga).unwrap()), host_vec(raw.grad(&gb).unwrap()));
    }

    /// The composed path other backends take, run on NdArray's primitives, against the kernels.
    #[test]
    fn composed_path_matches_the_cpu_kernels() {
        use crate::ndarray_host::host;
        let device = burn::backend::ndarray::NdArrayDevice::Cpu;
        let values: Vec<f32> = (0..997).map(|i| (i as f32 - 498.0) * 0.05).collect();
        let grad: Vec<f32> = (0..997).map(|i| ((i * 37) % 101) as f32 / 50.0 - 1.0).collect();
        let t = |v: &[f32]| NdArray::float_from_data(TensorData::new(v.to_vec(), [v.len()]), &device);
        let (s_kernel, sig_kernel) = NdArray::bounded_scale(t(&values), 0.1, 4.0);
        let (s_composed, sig_composed) = composed_forward::<NdArray>(t(&values), 0.1, 4.0);
        let g_kernel = NdArray::bounded_scale_backward(sig_kernel.clone(), t(&grad), 0.1, 4.0);
        let g_composed = composed_backward::<NdArray>(sig_composed.clone(), t(&grad), 0.1, 4.0);
        for (name, a, b) in [
            ("scales", s_kernel, s_composed),
            ("sigmoid", sig_kernel, sig_composed),
            ("gradient", g_kernel, g_composed),
        ] {
            assert_eq!(host::<NdArray>(a), host::<NdArray>(b), "{name}");
        }
    }
}

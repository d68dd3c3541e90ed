//! The hash encoding as a burn backend op with a hand-written backward: CPU kernels for
//! NdArray (burn-ndarray's gather and broadcasting are too slow for millions of corner lookups
//! per step) and CubeCL kernels for wgpu. `HashGrid::forward_tensor_ops` is the same encoding
//! composed of plain tensor operations; tests check that both agree.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

pub mod cpu;
#[cfg(feature = "wgpu")]
pub mod gpu;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, NdArray, TensorMetadata, backend_extension,
    tensor::FloatTensor,
};
use burn::tensor::{Tensor, TensorData};

use super::hash_grid::HashGridConfig;
use crate::method::ndarray_host::with_host;

/// Gradients of the encoding's inputs.
#[derive(ExtensionType)]
pub struct HashGrads<B: Backend> {
    /// `∂L/∂u` `[N, 3]`.
    pub u: FloatTensor<B>,
    /// `∂L/∂tables` `[F, L·T]`.
    pub tables: FloatTensor<B>,
}

/// Backend operations of the hash encoding.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait HashEncodeBackend: Backend {
    /// `u` `[N, 3]` (in `[0, 1]³`, clamped), `tables` `[F, L·T]` → `[N, L·F]`.
    fn hash_encode(u: FloatTensor<Self>, tables: FloatTensor<Self>, config: HashGridConfig) -> FloatTensor<Self>;
    /// Gradients for the upstream gradient `grad` `[N, L·F]`.
    fn hash_encode_backward(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self>;
}

impl HashEncodeBackend for NdArray {
    fn hash_encode(u: FloatTensor<Self>, tables: FloatTensor<Self>, config: HashGridConfig) -> FloatTensor<Self> {
        let device = u.device();
        let n = u.shape()[0];
        let out = with_host(&u, |u| with_host(&tables, |t| cpu::encode(&config, u, t)));
        Self::float_from_data(TensorData::new(out, [n, config.output_dim()]), &device)
    }

    fn hash_encode_backward(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self> {
        let device = u.device();
        let n = u.shape()[0];
        let tshape = tables.shape();
        let (gu, gt) =
            with_host(&u, |u| with_host(&tables, |t| with_host(&grad, |g| cpu::encode_backward(&config, u, t, g))));
        HashGrads {
            u: Self::float_from_data(TensorData::new(gu, [n, 3]), &device),
            tables: Self::float_from_data(TensorData::new(gt, tshape), &device),
        }
    }
}

#[cfg(feature = "wgpu")]
impl HashEncodeBackend for burn_cubecl::CubeBackend {
    fn hash_encode(u: FloatTensor<Self>, tables: FloatTensor<Self>, config: HashGridConfig) -> FloatTensor<Self> {
        gpu::encode(u, tables, &config)
    }

    fn hash_encode_backward(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self> {
        let (u, tables) = gpu::encode_backward(u, tables, grad, &config);
        HashGrads { u, tables }
    }
}

#[derive(Debug)]
struct EncodeBackward;

impl<B: Backend + HashEncodeBackend> Backward<B, 2> for EncodeBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, HashGridConfig);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_u, node_t] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (u, tables, config) = ops.state;
        let g = B::hash_encode_backward(u, tables, grad, config);
        if let Some(n) = node_u {
            grads.register::<B>(n.id, g.u);
        }
        if let Some(n) = node_t {
            grads.register::<B>(n.id, g.tables);
        }
    }
}

impl<B: Backend + HashEncodeBackend, C: CheckpointStrategy> HashEncodeBackend for Autodiff<B, C> {
    fn hash_encode(u: FloatTensor<Self>, tables: FloatTensor<Self>, config: HashGridConfig) -> FloatTensor<Self> {
        match EncodeBackward.prepare::<C>([u.node(), tables.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (u, t) = (u.into_primitive(), tables.into_primitive());
                let out = B::hash_encode(u.clone(), t.clone(), config);
                prep.finish((u, t, config), out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::hash_encode(u.into_primitive(), tables.into_primitive(), config))
            }
        }
    }

    fn hash_encode_backward(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self> {
        let g = B::hash_encode_backward(u.into_primitive(), tables.into_primitive(), grad.into_primitive(), config);
        HashGrads { u: Self::from_inner(g.u), tables: Self::from_inner(g.tables) }
    }
}

/// The encoding of `u` `[N, 3]` with `tables` `[F, L·T]`: `[N, L·F]`, differentiable in both.
pub fn hash_encode(u: Tensor<2>, tables: Tensor<2>, config: HashGridConfig) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as HashEncodeBackend>::hash_encode(
        u.into_dispatch(),
        tables.into_dispatch(),
        config,
    ))
}

//! The hash encoding as a burn backend op with a hand-written backward: CPU kernels for
//! NdArray (burn-ndarray's gather and broadcasting are too slow for millions of corner lookups
//! per step) and CubeCL kernels for wgpu. `HashGrid::forward_tensor_ops` is the same encoding
//! composed of plain tensor operations; tests check that both agree.
//!
//! Under autodiff the forward saves what the backward needs (`hash_encode_saving`): on the CPU
//! the encoding's Jacobian with respect to the points, computed from the corner values the
//! forward reads anyway, so that the backward only scatters into the table gradient and reads
//! no table (the reads cost as much as the scatter); `hash_encode_backward`, which reads the
//! tables, stays as the reference the tests compare it with.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

mod avx2;
mod config;
pub mod cpu;
#[cfg(feature = "wgpu")]
pub mod gpu;
mod level;

use std::sync::Mutex;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ndarray::NdArrayTensor;
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, NdArray, TensorMetadata, backend_extension,
    tensor::FloatTensor,
};
use burn::tensor::{Tensor, TensorData};
use ndarray::{ArcArray, IxDyn};
use rayon::prelude::*;

use crate::ndarray_host::with_host;
pub use config::{HASH_P1, HASH_P2, HashGridConfig};

/// Gradients of the encoding's inputs.
#[derive(ExtensionType)]
pub struct HashGrads<B: Backend> {
    /// `∂L/∂u` `[N, 3]`.
    pub u: FloatTensor<B>,
    /// `∂L/∂tables` `[F, R]`.
    pub tables: FloatTensor<B>,
}

/// Backend operations of the hash encoding.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait HashEncodeBackend: Backend {
    /// `u` `[N, 3]` (in `[0, 1]³`, clamped), `tables` `[F, R]` → `[N, L·F]`.
    fn hash_encode(u: FloatTensor<Self>, tables: FloatTensor<Self>, config: HashGridConfig) -> FloatTensor<Self>;
    /// Gradients for the upstream gradient `grad` `[N, L·F]`.
    fn hash_encode_backward(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self>;
    /// The encoding for training: `[N, L·F]` and `saved`, what
    /// [`hash_encode_backward_saved`](HashEncodeBackend::hash_encode_backward_saved) needs
    /// besides `u` — on the CPU the encoding's Jacobian with respect to `u` (`[L, N·F·3]`, so that
    /// the backward reads no table), on the GPU the tables.
    fn hash_encode_saving(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);
    /// The gradients of [`hash_encode_backward`](HashEncodeBackend::hash_encode_backward) from
    /// what [`hash_encode_saving`](HashEncodeBackend::hash_encode_saving) saved.
    fn hash_encode_backward_saved(
        u: FloatTensor<Self>,
        saved: FloatTensor<Self>,
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
        let mut grad_t = table_grad_buffer(&tables.shape());
        let gu = {
            let slice = grad_t.as_slice_mut().expect("a fresh or pooled buffer is contiguous");
            with_host(&u, |u| {
                with_host(&tables, |t| with_host(&grad, |g| cpu::encode_backward_into(&config, u, t, g, slice)))
            })
        };
        pooled_grads(gu, grad_t, &device)
    }

    fn hash_encode_saving(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let device = u.device();
        let n = u.shape()[0];
        // Every element is overwritten, so a reused buffer is not cleared.
        let (mut jacobian, _) = JACOBIAN_POOL.take(&[config.levels, n * config.features * 3]);
        let out = {
            let slice = jacobian.as_slice_mut().expect("a fresh or pooled buffer is contiguous");
            with_host(&u, |u| with_host(&tables, |t| cpu::encode_with_jacobian_into(&config, u, t, slice)))
        };
        JACOBIAN_POOL.keep(&jacobian);
        (Self::float_from_data(TensorData::new(out, [n, config.output_dim()]), &device), NdArrayTensor::from(jacobian))
    }

    fn hash_encode_backward_saved(
        u: FloatTensor<Self>,
        saved: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self> {
        let device = u.device();
        let mut grad_t = table_grad_buffer(&burn::tensor::Shape::new([config.features, config.rows()]));
        let gu = {
            let slice = grad_t.as_slice_mut().expect("a fresh or pooled buffer is contiguous");
            with_host(&u, |u| {
                with_host(&saved, |j| {
                    with_host(&grad, |g| cpu::encode_backward_from_jacobian_into(&config, u, j, g, slice))
                })
            })
        };
        pooled_grads(gu, grad_t, &device)
    }
}

/// The gradients as tensors; the table gradient's buffer goes back to the pool.
fn pooled_grads(
    gu: Vec<f32>,
    grad_t: ArcArray<f32, IxDyn>,
    device: &burn::backend::ndarray::NdArrayDevice,
) -> HashGrads<NdArray> {
    let n = gu.len() / 3;
    TABLE_GRAD_POOL.keep(&grad_t);
    HashGrads { u: NdArray::float_from_data(TensorData::new(gu, [n, 3]), device), tables: NdArrayTensor::from(grad_t) }
}

/// One large buffer kept between steps: at paper scale the table gradient is 43 MB and the
/// Jacobian 35–48 MB, and a fresh allocation every step is unmapped on drop and faulted back in
/// page by page (and cleared) on the next (≈ 15 % of the step for the table gradient). A buffer
/// is reused only once burn has dropped its share (the optimizer consumed the gradient, the
/// backward the Jacobian), so no tensor burn still holds is overwritten.
struct BufferPool(Mutex<Option<ArcArray<f32, IxDyn>>>);

impl BufferPool {
    const fn new() -> Self {
        Self(Mutex::new(None))
    }

    /// A buffer of `dims` and whether it holds old values: the pooled one when it has that
    /// shape and nobody else holds it, else a new zeroed one.
    fn take(&self, dims: &[usize]) -> (ArcArray<f32, IxDyn>, bool) {
        let pooled = self.0.lock().ok().and_then(|mut pool| pool.take());
        if let Some(mut buffer) = pooled
            && buffer.shape() == dims
            && buffer.is_unique()
            && buffer.as_slice_mut().is_some()
        {
            return (buffer, true);
        }
        (ArcArray::zeros(IxDyn(dims)), false)
    }

    /// Keeps a share of `buffer` for a later [`take`](Self::take).
    fn keep(&self, buffer: &ArcArray<f32, IxDyn>) {
        if let Ok(mut pool) = self.0.lock() {
            *pool = Some(buffer.clone());
        }
    }
}

static TABLE_GRAD_POOL: BufferPool = BufferPool::new();
static JACOBIAN_POOL: BufferPool = BufferPool::new();

/// A zeroed buffer of `shape` for the table gradient (the pooled one, cleared, when free).
fn table_grad_buffer(shape: &burn::tensor::Shape) -> ArcArray<f32, IxDyn> {
    let dims: Vec<usize> = shape.iter().copied().collect();
    let (mut buffer, used) = TABLE_GRAD_POOL.take(&dims);
    if used && let Some(values) = buffer.as_slice_mut() {
        values.par_chunks_mut(1 << 16).for_each(|c| c.fill(0.0));
    }
    buffer
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

    fn hash_encode_saving(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        (gpu::encode(u, tables.clone(), &config), tables)
    }

    fn hash_encode_backward_saved(
        u: FloatTensor<Self>,
        saved: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self> {
        Self::hash_encode_backward(u, saved, grad, config)
    }
}

#[derive(Debug)]
struct EncodeBackward;

impl<B: Backend + HashEncodeBackend> Backward<B, 2> for EncodeBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, HashGridConfig);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_u, node_t] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (u, saved, config) = ops.state;
        let g = B::hash_encode_backward_saved(u, saved, grad, config);
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
                let u = u.into_primitive();
                let (out, saved) = B::hash_encode_saving(u.clone(), tables.into_primitive(), config);
                prep.finish((u, saved, config), out)
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

    fn hash_encode_saving(
        u: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (out, saved) = B::hash_encode_saving(u.into_primitive(), tables.into_primitive(), config);
        (Self::from_inner(out), Self::from_inner(saved))
    }

    fn hash_encode_backward_saved(
        u: FloatTensor<Self>,
        saved: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        config: HashGridConfig,
    ) -> HashGrads<Self> {
        let g =
            B::hash_encode_backward_saved(u.into_primitive(), saved.into_primitive(), grad.into_primitive(), config);
        HashGrads { u: Self::from_inner(g.u), tables: Self::from_inner(g.tables) }
    }
}

/// The encoding of `u` `[N, 3]` with `tables` `[F, R]`: `[N, L·F]`, differentiable in both.
pub fn hash_encode(u: Tensor<2>, tables: Tensor<2>, config: HashGridConfig) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as HashEncodeBackend>::hash_encode(
        u.into_dispatch(),
        tables.into_dispatch(),
        config,
    ))
}

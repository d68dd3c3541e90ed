//! The prior-anchoring term: the mean, over the sampled centres whose nearest prior point lies
//! within the anchoring radius, of the squared distance (mm²) from the centre to the mean of its
//! `k` nearest prior points (the targets are not differentiated).
//!
//! On a CubeCL device it is one op of two launches forward (the search, which gathers the
//! sampled centres, and a one-workgroup reduction) and two backward (zeros, an atomic scatter-add of the scaled factors), where burn's tensor ops took about
//! twenty; elsewhere (NdArray) it is composed of tensor ops, unchanged, which is also the op's
//! oracle (`tests/ops_wgpu.rs`).

use burn::tensor::{Int, Tensor};

use super::{DeviceGrid, anchor_targets};

/// The anchoring term of the centres `means[sample]` (`means` `[N, 3]` mm, `sample` `[m]` row
/// indices, repeats allowed): `Σ keep·|c − target|² / max(Σ keep, 1)`, shape `[1]` (mm²).
/// Differentiable in `means`.
pub fn anchor_loss(means: Tensor<2>, sample: Tensor<1, Int>, grid: &DeviceGrid) -> Tensor<1> {
    #[cfg(feature = "wgpu")]
    if cube::runs_on_cube(&means) {
        return cube::anchor_loss(means, sample, grid);
    }
    composed(means, sample, grid)
}

/// The term composed of burn's tensor ops.
pub fn composed(means: Tensor<2>, sample: Tensor<1, Int>, grid: &DeviceGrid) -> Tensor<1> {
    let m = sample.dims()[0];
    let chosen = means.select(0, sample);
    let (target, keep) = anchor_targets(chosen.clone(), grid);
    let squared = (chosen - target).powi_scalar(2).sum_dim(1).reshape([m]);
    let anchored = keep.clone().sum().clamp_min(1.0);
    (squared * keep).sum() / anchored
}

#[cfg(feature = "wgpu")]
mod cube {
    use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::{
        Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, TensorMetadata, backend_extension,
        tensor::{FloatTensor, IntTensor},
    };
    use burn::tensor::{Int, Shape};
    use burn_cubecl::cubecl::prelude::*;
    use burn_cubecl::{CubeBackend, cubecl};

    use super::super::{AnchorSearch, DeviceGrid};
    use crate::cube::{REDUCE_LEVELS, REDUCE_UNITS, empty, launch_1d, prepare, runs_on_cube as on_cube, tree_sum};
    use burn::backend::ops::{FloatTensorOps, IntTensorOps};
    use burn::backend::{FloatDType, IntDType};
    use burn_cubecl::kernel::into_contiguous;
    use ctadsa_render::F32Add;
    use ctadsa_render::kernels::{Accumulator, add_f32};

    /// Whether `t` lives on a CubeCL device (with or without autodiff).
    pub(super) fn runs_on_cube(t: &burn::tensor::Tensor<2>) -> bool {
        on_cube(&t.device())
    }

    /// The term `[1]` and each sample's gradient factor `2·keep·(c − target) / max(Σ keep, 1)`
    /// `[m, 3]`.
    #[derive(ExtensionType)]
    pub struct AnchorLoss<B: Backend> {
        pub loss: FloatTensor<B>,
        pub factors: FloatTensor<B>,
    }

    /// The fused anchoring term (CubeCL only: other backends compose it, see [`super::composed`]).
    #[backend_extension(Autodiff, Cube)]
    pub trait AnchorLossBackend: Backend {
        /// The term of `means[sample]` against the grid's `points` and hash `table`.
        fn anchor_loss(
            means: FloatTensor<Self>,
            sample: IntTensor<Self>,
            points: FloatTensor<Self>,
            table: FloatTensor<Self>,
            search: AnchorSearch,
        ) -> AnchorLoss<Self>;

        /// The centres' gradient `[n, 3]`: `grad · factors[j]` added to row `sample[j]` for
        /// every sample (zero elsewhere).
        fn anchor_loss_backward(
            factors: FloatTensor<Self>,
            sample: IntTensor<Self>,
            grad: FloatTensor<Self>,
            n: usize,
        ) -> FloatTensor<Self>;
    }

    /// One unit per sample: `out[sample[j]] += grad · factors[j]` (atomically: samples repeat).
    #[cube(launch)]
    fn anchor_scatter_kernel(
        factors: &Tensor<f32>,
        sample: &Tensor<i32>,
        grad: &Tensor<f32>,
        out_f32: &mut Tensor<Atomic<f32>>,
        out_u32: &mut Tensor<Atomic<u32>>,
        m: u32,
        #[comptime] native: bool,
    ) {
        let j = ABSOLUTE_POS;
        if j >= m as usize {
            terminate!();
        }
        let row = sample[j] as usize;
        let g = grad[0];
        for c in 0..3usize {
            add_f32(out_f32, out_u32, 3 * row + c, g * factors[3 * j + c], native);
        }
    }

    /// One workgroup of `units` units: the sums of `keep·|c − target|²` and of `keep` over the
    /// samples, the term, then every sample's gradient factor.
    #[cube(launch)]
    fn anchor_sums_kernel(
        chosen: &Tensor<f32>,
        targets: &Tensor<f32>,
        keep: &Tensor<f32>,
        loss: &mut Tensor<f32>,
        factors: &mut Tensor<f32>,
        m: u32,
        #[comptime] units: usize,
        #[comptime] levels: u32,
    ) {
        let u = UNIT_POS as usize;
        let rounds = (m as usize).div_ceil(units);
        let mut squared = Shared::<[f32]>::new_slice(units);
        let mut kept = Shared::<[f32]>::new_slice(units);
        let mut a = 0.0f32;
        let mut b = 0.0f32;
        for r in 0..rounds {
            let j = r * units + u;
            if j < m as usize {
                let dx = chosen[3 * j] - targets[3 * j];
                let dy = chosen[3 * j + 1] - targets[3 * j + 1];
                let dz = chosen[3 * j + 2] - targets[3 * j + 2];
                a += keep[j] * (dx * dx + dy * dy + dz * dz);
                b += keep[j];
            }
        }
        squared[u] = a;
        kept[u] = b;
        tree_sum(&mut squared, units, levels);
        tree_sum(&mut kept, units, levels);
        let anchored = f32::max(kept[0], 1.0f32);
        if u == 0 {
            loss[0] = squared[0] / anchored;
        }
        let f = 2.0f32 / anchored;
        for r in 0..rounds {
            let j = r * units + u;
            if j < m as usize {
                let w = f * keep[j];
                factors[3 * j] = w * (chosen[3 * j] - targets[3 * j]);
                factors[3 * j + 1] = w * (chosen[3 * j + 1] - targets[3 * j + 1]);
                factors[3 * j + 2] = w * (chosen[3 * j + 2] - targets[3 * j + 2]);
            }
        }
    }

    impl AnchorLossBackend for CubeBackend {
        fn anchor_loss(
            means: FloatTensor<Self>,
            sample: IntTensor<Self>,
            points: FloatTensor<Self>,
            table: FloatTensor<Self>,
            search: AnchorSearch,
        ) -> AnchorLoss<Self> {
            let (chosen, found) = super::super::gpu::gathered_anchor_targets(means, sample, points, table, search);
            let m = chosen.shape()[0];
            let (targets, keep) = (found.targets, found.keep);
            let loss = empty(vec![1], &chosen);
            let factors = empty(vec![m, 3], &chosen);
            anchor_sums_kernel::launch(
                &chosen.client,
                CubeCount::Static(1, 1, 1),
                CubeDim::new_1d(REDUCE_UNITS as u32),
                chosen.clone().into_tensor_arg(),
                targets.into_tensor_arg(),
                keep.into_tensor_arg(),
                loss.clone().into_tensor_arg(),
                factors.clone().into_tensor_arg(),
                m as u32,
                REDUCE_UNITS,
                REDUCE_LEVELS,
            );
            AnchorLoss { loss, factors }
        }

        fn anchor_loss_backward(
            factors: FloatTensor<Self>,
            sample: IntTensor<Self>,
            grad: FloatTensor<Self>,
            n: usize,
        ) -> FloatTensor<Self> {
            let (factors, grad) = (prepare(factors), prepare(grad));
            let sample = into_contiguous(CubeBackend::int_cast(sample, IntDType::I32));
            let m = sample.shape()[0];
            let out = CubeBackend::float_zeros(Shape::new([n, 3]), &factors.device, FloatDType::F32);
            if m > 0 {
                let acc = Accumulator::new(&out, F32Add::Auto);
                let (count, dim) = launch_1d(&factors, m, 256);
                anchor_scatter_kernel::launch(
                    &factors.client,
                    count,
                    dim,
                    factors.clone().into_tensor_arg(),
                    sample.into_tensor_arg(),
                    grad.into_tensor_arg(),
                    acc.as_f32.into_tensor_arg(),
                    acc.as_u32.into_tensor_arg(),
                    m as u32,
                    acc.native,
                );
            }
            out
        }
    }

    #[derive(Debug)]
    struct AnchorLossBackward;

    impl<B: Backend + AnchorLossBackend> Backward<B, 1> for AnchorLossBackward {
        /// The factors `[m, 3]`, the sample, and the number of centres.
        type State = (FloatTensor<B>, IntTensor<B>, usize);

        fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
            let [node_means] = ops.parents;
            let grad = grads.consume::<B>(&ops.node);
            let (factors, sample, n) = ops.state;
            if let Some(node) = node_means {
                grads.register::<B>(node.id, B::anchor_loss_backward(factors, sample, grad, n));
            }
        }
    }

    impl<B: Backend + AnchorLossBackend, C: CheckpointStrategy> AnchorLossBackend for Autodiff<B, C> {
        fn anchor_loss(
            means: FloatTensor<Self>,
            sample: IntTensor<Self>,
            points: FloatTensor<Self>,
            table: FloatTensor<Self>,
            search: AnchorSearch,
        ) -> AnchorLoss<Self> {
            let n = means.shape()[0];
            let (points, table) = (points.into_primitive(), table.into_primitive());
            let prep = AnchorLossBackward.prepare::<C>([means.node()]).compute_bound().stateful();
            let out = B::anchor_loss(means.into_primitive(), sample.clone(), points, table, search);
            let factors = Self::from_inner(out.factors.clone());
            let loss = match prep {
                OpsKind::Tracked(prep) => prep.finish((out.factors, sample, n), out.loss),
                OpsKind::UnTracked(prep) => prep.finish(out.loss),
            };
            AnchorLoss { loss, factors }
        }

        fn anchor_loss_backward(
            factors: FloatTensor<Self>,
            sample: IntTensor<Self>,
            grad: FloatTensor<Self>,
            n: usize,
        ) -> FloatTensor<Self> {
            Self::from_inner(B::anchor_loss_backward(factors.into_primitive(), sample, grad.into_primitive(), n))
        }
    }

    pub(super) fn anchor_loss(
        means: burn::tensor::Tensor<2>,
        sample: burn::tensor::Tensor<1, Int>,
        grid: &DeviceGrid,
    ) -> burn::tensor::Tensor<1> {
        let out = <Dispatch as AnchorLossBackend>::anchor_loss(
            means.into_dispatch(),
            sample.into_dispatch(),
            grid.points.clone().into_dispatch(),
            grid.table.clone().into_dispatch(),
            grid.search,
        );
        burn::tensor::Tensor::from_dispatch(out.loss)
    }
}

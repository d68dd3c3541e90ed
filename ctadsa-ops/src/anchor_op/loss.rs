//! The prior-anchoring term: the mean, over the sampled centres whose nearest prior point lies
//! within the anchoring radius, of the squared distance (mm²) from the centre to the mean of its
//! `k` nearest prior points (the targets are not differentiated).
//!
//! On a CubeCL device it is one op of two launches forward (the search, which gathers the
//! sampled centres, and a one-workgroup reduction) and three backward (scale, zeros, scatter-add), where burn's tensor ops took about
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
    use burn::backend::tensor::IndexingUpdateOp;
    use burn::backend::{
        Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, TensorMetadata, backend_extension,
        tensor::{FloatTensor, IntTensor},
    };
    use burn::tensor::{Int, Shape};
    use burn_cubecl::cubecl::prelude::*;
    use burn_cubecl::{CubeBackend, cubecl};

    use super::super::{AnchorSearch, DeviceGrid};
    use crate::cube::{REDUCE_LEVELS, REDUCE_UNITS, empty, runs_on_cube as on_cube, tree_sum};

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
    }

    #[derive(Debug)]
    struct AnchorLossBackward;

    impl<B: Backend> Backward<B, 1> for AnchorLossBackward {
        /// The factors `[m, 3]`, the sample, and the number of centres.
        type State = (FloatTensor<B>, IntTensor<B>, usize);

        fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
            let [node_means] = ops.parents;
            let grad = grads.consume::<B>(&ops.node);
            let (factors, sample, n) = ops.state;
            if let Some(node) = node_means {
                let values = B::float_mul(factors, B::float_reshape(grad, Shape::new([1, 1])));
                let device = values.device();
                let zeros = B::float_zeros(Shape::new([n, 3]), &device, values.dtype().into());
                grads.register::<B>(node.id, B::float_select_assign(zeros, 0, sample, values, IndexingUpdateOp::Add));
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

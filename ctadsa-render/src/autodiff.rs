//! The render op under `Autodiff`: the forward runs the inner backend's kernel and keeps its
//! inputs; the backward calls the inner backend's backward kernel.

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::{Autodiff, AutodiffBackend, Backend, tensor::FloatTensor};

use crate::ops::{RenderGrads, RenderSetup, XrayBackend};
use crate::{RenderSettings, VoxelGrid};

#[derive(Debug)]
struct RenderBackward;

impl<B: Backend + XrayBackend> Backward<B, 5> for RenderBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, RenderSetup);

    fn backward(self, ops: Ops<Self::State, 5>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [n_means, n_scales, n_rotations, n_densities, n_probe] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (means, scales, rotations, densities, setup) = ops.state;
        let g = B::xray_render_backward(means, scales, rotations, densities, grad, setup);
        for (node, g) in [
            (n_means, g.means),
            (n_scales, g.scales),
            (n_rotations, g.rotations),
            (n_densities, g.densities),
            (n_probe, g.screen_stats),
        ] {
            if let Some(node) = node {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

impl<B: Backend + XrayBackend, C: CheckpointStrategy> XrayBackend for Autodiff<B, C> {
    fn xray_render(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen_probe: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> FloatTensor<Self> {
        let nodes = [means.node(), scales.node(), rotations.node(), densities.node(), screen_probe.node()];
        match RenderBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let m = means.into_primitive();
                let s = scales.into_primitive();
                let r = rotations.into_primitive();
                let d = densities.into_primitive();
                let p = screen_probe.into_primitive();
                let out = B::xray_render(m.clone(), s.clone(), r.clone(), d.clone(), p, setup.clone());
                prep.finish((m, s, r, d, setup), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::xray_render(
                means.into_primitive(),
                scales.into_primitive(),
                rotations.into_primitive(),
                densities.into_primitive(),
                screen_probe.into_primitive(),
                setup,
            )),
        }
    }

    fn xray_render_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grad_image: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> RenderGrads<Self> {
        let g = B::xray_render_backward(
            means.into_primitive(),
            scales.into_primitive(),
            rotations.into_primitive(),
            densities.into_primitive(),
            grad_image.into_primitive(),
            setup,
        );
        RenderGrads {
            means: Self::from_inner(g.means),
            scales: Self::from_inner(g.scales),
            rotations: Self::from_inner(g.rotations),
            densities: Self::from_inner(g.densities),
            screen_stats: Self::from_inner(g.screen_stats),
        }
    }

    fn xray_voxelize(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        settings: RenderSettings,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::xray_voxelize(
            means.into_primitive(),
            scales.into_primitive(),
            rotations.into_primitive(),
            densities.into_primitive(),
            grid,
            settings,
        ))
    }
}

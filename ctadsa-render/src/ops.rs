//! The burn backend extension: the X-ray render op, its backward, and voxelisation, with one
//! implementation per backend (CPU kernels for NdArray, CubeCL kernels for wgpu) and a
//! hand-written backward for `Autodiff`.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

use std::sync::Arc;

use burn::backend::{Backend, ExtensionType, backend_extension, tensor::FloatTensor};

use crate::view_params::ViewParams;
use crate::{F32Add, RenderSettings, VoxelGrid};

/// The non-tensor inputs of a render call: the packed views and the footprint cut-off.
#[derive(Debug, Clone)]
pub struct RenderSetup {
    /// Views, all of the same detector size.
    pub views: Arc<[ViewParams]>,
    /// Footprint cut-off in standard deviations (`k`): pixels whose ray passes farther than `k`
    /// Mahalanobis units from a Gaussian's centre do not see it.
    pub k_sigma: f32,
    /// How the GPU kernels add atomically.
    pub f32_add: F32Add,
    /// Units per Gaussian (and view) in the GPU render kernels ([`crate::RenderSettings::row_split_for`]).
    pub row_split: u32,
}

impl RenderSetup {
    /// `(width, height)` of every view.
    pub fn image_size(&self) -> (u32, u32) {
        self.views.first().map_or((0, 0), |v| (v.width, v.height))
    }
}

/// Gradients of the render op's inputs, and the densification statistic.
#[derive(ExtensionType)]
pub struct RenderGrads<B: Backend> {
    /// `∂L/∂means` `[N, 3]`.
    pub means: FloatTensor<B>,
    /// `∂L/∂scales` `[N, 3]`.
    pub scales: FloatTensor<B>,
    /// `∂L/∂rotations` `[N, 4]` (unnormalised quaternions).
    pub rotations: FloatTensor<B>,
    /// `∂L/∂densities` `[N]`.
    pub densities: FloatTensor<B>,
    /// `[N, 2]`: Σ over views of the NDC projected-centre gradient norm; visible-view count.
    pub screen_stats: FloatTensor<B>,
}

/// Backend operations of the renderer. Users call [`crate::render`] and [`crate::voxelize`];
/// implement this trait only to port the renderer to another backend.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait XrayBackend: Backend {
    /// Forward render: `[V, H, W]` line integrals. `screen_probe` (`[N, 2]`, any values) only
    /// exists so that the backward pass can hand out the densification statistic as its
    /// "gradient"; it does not change the output.
    fn xray_render(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        screen_probe: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> FloatTensor<Self>;

    /// Backward render: gradients of the inputs for the upstream gradient `grad_image` `[V, H, W]`.
    fn xray_render_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grad_image: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> RenderGrads<Self>;

    /// The density field at the centres of `grid`: `[X, Y, Z]` (not differentiable).
    fn xray_voxelize(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        settings: RenderSettings,
    ) -> FloatTensor<Self>;
}

//! Glue from NdArray tensors to the CPU kernels: borrow the inputs in place (copy only where a
//! tensor is not contiguous f32), run the kernel, and write the result back as a tensor.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

use burn::backend::ops::FloatTensorOps;
use burn::backend::{NdArray, TensorMetadata, tensor::FloatTensor};
use burn::tensor::TensorData;

use crate::RenderSettings;
use crate::VoxelGrid;
use crate::cpu::{self, HostGaussians};
use crate::ndarray_host::with_host;
use crate::ops::{RenderGrads, RenderSetup, XrayBackend};

fn from_vec(v: Vec<f32>, shape: Vec<usize>, like: &FloatTensor<NdArray>) -> FloatTensor<NdArray> {
    NdArray::float_from_data(TensorData::new(v, shape), &like.device())
}

/// The Gaussians' tensors, borrowed as host slices for the duration of `f`.
struct Inputs<'a> {
    means: &'a FloatTensor<NdArray>,
    scales: &'a FloatTensor<NdArray>,
    rotations: &'a FloatTensor<NdArray>,
    densities: &'a FloatTensor<NdArray>,
}

impl Inputs<'_> {
    fn with<R>(&self, f: impl FnOnce(&HostGaussians<'_>) -> R) -> R {
        with_host(self.means, |means| {
            with_host(self.scales, |scales| {
                with_host(self.rotations, |rotations| {
                    with_host(self.densities, |densities| f(&HostGaussians { means, scales, rotations, densities }))
                })
            })
        })
    }
}

/// Forward render through the CPU kernels.
pub fn render(
    means: FloatTensor<NdArray>,
    scales: FloatTensor<NdArray>,
    rotations: FloatTensor<NdArray>,
    densities: FloatTensor<NdArray>,
    setup: &RenderSetup,
) -> FloatTensor<NdArray> {
    let inputs = Inputs { means: &means, scales: &scales, rotations: &rotations, densities: &densities };
    let image = inputs.with(|g| cpu::render(g, &setup.views, setup.k_sigma));
    let (w, h) = setup.image_size();
    from_vec(image, vec![setup.views.len(), h as usize, w as usize], &means)
}

/// Backward render through the CPU kernels.
pub fn render_backward(
    means: FloatTensor<NdArray>,
    scales: FloatTensor<NdArray>,
    rotations: FloatTensor<NdArray>,
    densities: FloatTensor<NdArray>,
    grad_image: FloatTensor<NdArray>,
    setup: &RenderSetup,
) -> RenderGrads<NdArray> {
    let n = means.shape()[0];
    let inputs = Inputs { means: &means, scales: &scales, rotations: &rotations, densities: &densities };
    let out =
        inputs.with(|g| with_host(&grad_image, |grad| cpu::render_backward(g, &setup.views, setup.k_sigma, grad)));
    RenderGrads {
        means: from_vec(out.means, vec![n, 3], &means),
        scales: from_vec(out.scales, vec![n, 3], &means),
        rotations: from_vec(out.rotations, vec![n, 4], &means),
        densities: from_vec(out.densities, vec![n], &means),
        screen_stats: from_vec(out.screen_stats, vec![n, 2], &means),
    }
}

/// Voxelisation through the CPU kernel.
pub fn voxelize(
    means: FloatTensor<NdArray>,
    scales: FloatTensor<NdArray>,
    rotations: FloatTensor<NdArray>,
    densities: FloatTensor<NdArray>,
    grid: &VoxelGrid,
    k_sigma: f32,
) -> FloatTensor<NdArray> {
    let inputs = Inputs { means: &means, scales: &scales, rotations: &rotations, densities: &densities };
    let volume = inputs.with(|g| cpu::voxelize(g, grid, k_sigma));
    from_vec(volume, grid.dims.map(|d| d as usize).to_vec(), &means)
}

/// The op on the CPU backend: the kernels above.
impl XrayBackend for NdArray {
    fn xray_render(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        _screen_probe: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> FloatTensor<Self> {
        render(means, scales, rotations, densities, &setup)
    }

    fn xray_render_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grad_image: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> RenderGrads<Self> {
        render_backward(means, scales, rotations, densities, grad_image, &setup)
    }

    fn xray_voxelize(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grid: VoxelGrid,
        settings: RenderSettings,
    ) -> FloatTensor<Self> {
        voxelize(means, scales, rotations, densities, &grid, settings.k_sigma)
    }
}

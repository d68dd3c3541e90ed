//! Glue from backend tensors to the CPU kernels: read the inputs to host memory, run the kernel,
//! and write the result back as a tensor of the same backend. Used by the NdArray backend.

use burn::backend::{Backend, TensorMetadata, read_sync, tensor::FloatTensor};
use burn::tensor::TensorData;

use crate::VoxelGrid;
use crate::cpu::{self, HostGaussians};
use crate::ops::{RenderGrads, RenderSetup};

/// Reads a float tensor into a `Vec<f32>`. The tensors come from this crate's own checked
/// entry points, so a failure here is a backend fault, not bad user input.
fn to_vec<B: Backend>(t: FloatTensor<B>) -> Vec<f32> {
    read_sync(B::float_into_data(t))
        .expect("reading a CPU tensor cannot fail")
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("converted to f32")
}

fn from_vec<B: Backend>(v: Vec<f32>, shape: Vec<usize>, device: &B::Device) -> FloatTensor<B> {
    B::float_from_data(TensorData::new(v, shape), device)
}

struct Owned {
    means: Vec<f32>,
    scales: Vec<f32>,
    rotations: Vec<f32>,
    densities: Vec<f32>,
}

impl Owned {
    fn read<B: Backend>(
        means: FloatTensor<B>,
        scales: FloatTensor<B>,
        rotations: FloatTensor<B>,
        densities: FloatTensor<B>,
    ) -> Self {
        Self {
            means: to_vec::<B>(means),
            scales: to_vec::<B>(scales),
            rotations: to_vec::<B>(rotations),
            densities: to_vec::<B>(densities),
        }
    }

    fn host(&self) -> HostGaussians<'_> {
        HostGaussians {
            means: &self.means,
            scales: &self.scales,
            rotations: &self.rotations,
            densities: &self.densities,
        }
    }
}

/// Forward render through the CPU kernels.
pub fn render<B: Backend>(
    means: FloatTensor<B>,
    scales: FloatTensor<B>,
    rotations: FloatTensor<B>,
    densities: FloatTensor<B>,
    setup: &RenderSetup,
) -> FloatTensor<B> {
    let device = means.device();
    let g = Owned::read::<B>(means, scales, rotations, densities);
    let image = cpu::render(&g.host(), &setup.views, setup.k_sigma);
    let (w, h) = setup.image_size();
    from_vec::<B>(image, vec![setup.views.len(), h as usize, w as usize], &device)
}

/// Backward render through the CPU kernels.
pub fn render_backward<B: Backend>(
    means: FloatTensor<B>,
    scales: FloatTensor<B>,
    rotations: FloatTensor<B>,
    densities: FloatTensor<B>,
    grad_image: FloatTensor<B>,
    setup: &RenderSetup,
) -> RenderGrads<B> {
    let device = means.device();
    let n = means.shape()[0];
    let g = Owned::read::<B>(means, scales, rotations, densities);
    let grad = to_vec::<B>(grad_image);
    let out = cpu::render_backward(&g.host(), &setup.views, setup.k_sigma, &grad);
    RenderGrads {
        means: from_vec::<B>(out.means, vec![n, 3], &device),
        scales: from_vec::<B>(out.scales, vec![n, 3], &device),
        rotations: from_vec::<B>(out.rotations, vec![n, 4], &device),
        densities: from_vec::<B>(out.densities, vec![n], &device),
        screen_stats: from_vec::<B>(out.screen_stats, vec![n, 2], &device),
    }
}

/// Voxelisation through the CPU kernel.
pub fn voxelize<B: Backend>(
    means: FloatTensor<B>,
    scales: FloatTensor<B>,
    rotations: FloatTensor<B>,
    densities: FloatTensor<B>,
    grid: &VoxelGrid,
    k_sigma: f32,
) -> FloatTensor<B> {
    let device = means.device();
    let g = Owned::read::<B>(means, scales, rotations, densities);
    let volume = cpu::voxelize(&g.host(), grid, k_sigma);
    from_vec::<B>(volume, grid.dims.map(|d| d as usize).to_vec(), &device)
}

//! The renderer on CubeCL (`CubeBackend`, used by burn's wgpu device): kernel launches.
//! Kernels: [`forward`], [`backward`], [`voxelize`]; device functions in [`math`] and
//! [`atomics`].

pub mod atomics;
pub mod backward;
pub mod forward;
pub mod math;
pub mod probe;
pub mod voxelize;

use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{FloatDType, TensorMetadata};
use burn::tensor::{DType, Shape, TensorData};
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use crate::ops::{RenderGrads, RenderSetup, XrayBackend};
use crate::{RenderSettings, VoxelGrid};

/// Units per cube for all launches.
const CUBE_UNITS: u32 = 64;
const _: () = assert!(crate::settings::MAX_ROW_SPLIT == CUBE_UNITS, "a Gaussian's units share a workgroup");

fn prepare(t: CubeTensor) -> CubeTensor {
    let t = if t.dtype() == DType::F32 { t } else { CubeBackend::float_cast(t, FloatDType::F32) };
    into_contiguous(t)
}

fn upload(data: Vec<f32>, shape: Vec<usize>, like: &CubeTensor) -> CubeTensor {
    CubeBackend::float_from_data(TensorData::new(data, shape), &like.device)
}

fn zeros(shape: Vec<usize>, like: &CubeTensor) -> CubeTensor {
    CubeBackend::float_zeros(Shape::from(shape), &like.device, FloatDType::F32)
}

/// An uninitialised tensor, for outputs a kernel writes whole (no fill launch).
fn empty(shape: Vec<usize>, like: &CubeTensor) -> CubeTensor {
    CubeBackend::float_empty(Shape::from(shape), &like.device, FloatDType::F32)
}

fn launch_dims(like: &CubeTensor, units: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new_1d(CUBE_UNITS);
    (cubecl::calculate_cube_count_elemwise(&like.client, units, dim), dim)
}

fn packed_views(setup: &RenderSetup, like: &CubeTensor) -> CubeTensor {
    let flat: Vec<f32> = setup.views.iter().flat_map(|v| v.to_array()).collect();
    upload(flat, vec![setup.views.len(), crate::VIEW_PARAMS_LEN], like)
}

impl XrayBackend for CubeBackend {
    fn xray_render(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        _screen_probe: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> FloatTensor<Self> {
        let (means, scales, rotations, densities) =
            (prepare(means), prepare(scales), prepare(rotations), prepare(densities));
        let n = means.shape()[0];
        let (w, h) = setup.image_size();
        let v = setup.views.len();
        let image = zeros(vec![v, h as usize, w as usize], &means);
        let split = setup.row_split.max(1);
        let units = n * v * split as usize;
        if units == 0 {
            return image;
        }
        let views = packed_views(&setup, &means);
        let (count, dim) = launch_dims(&means, units);
        let acc = atomics::Accumulator::new(&image, setup.f32_add);
        forward::render_forward_kernel::launch(
            &means.client,
            count,
            dim,
            means.clone().into_tensor_arg(),
            scales.into_tensor_arg(),
            rotations.into_tensor_arg(),
            densities.into_tensor_arg(),
            views.into_tensor_arg(),
            acc.as_f32.into_tensor_arg(),
            acc.as_u32.into_tensor_arg(),
            n as u32,
            v as u32,
            split,
            setup.k_sigma,
            acc.native,
        );
        image
    }

    fn xray_render_backward(
        means: FloatTensor<Self>,
        scales: FloatTensor<Self>,
        rotations: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grad_image: FloatTensor<Self>,
        setup: RenderSetup,
    ) -> RenderGrads<Self> {
        let (means, scales, rotations, densities, grad) =
            (prepare(means), prepare(scales), prepare(rotations), prepare(densities), prepare(grad_image));
        let n = means.shape()[0];
        // Every unit writes all of its Gaussian's gradients (zero where it sees no pixel).
        let g_means = empty(vec![n, 3], &means);
        let g_scales = empty(vec![n, 3], &means);
        let g_rotations = empty(vec![n, 4], &means);
        let g_densities = empty(vec![n], &means);
        let g_stats = empty(vec![n, 2], &means);
        if n > 0 {
            let split = setup.row_split.max(1);
            let views = packed_views(&setup, &means);
            let (count, dim) = launch_dims(&means, n * split as usize);
            backward::render_backward_kernel::launch(
                &means.client,
                count,
                dim,
                means.clone().into_tensor_arg(),
                scales.into_tensor_arg(),
                rotations.into_tensor_arg(),
                densities.into_tensor_arg(),
                views.into_tensor_arg(),
                grad.into_tensor_arg(),
                g_means.clone().into_tensor_arg(),
                g_scales.clone().into_tensor_arg(),
                g_rotations.clone().into_tensor_arg(),
                g_densities.clone().into_tensor_arg(),
                g_stats.clone().into_tensor_arg(),
                n as u32,
                setup.views.len() as u32,
                split,
                setup.k_sigma,
                CUBE_UNITS as usize,
            );
        }
        RenderGrads {
            means: g_means,
            scales: g_scales,
            rotations: g_rotations,
            densities: g_densities,
            screen_stats: g_stats,
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
        let (means, scales, rotations, densities) =
            (prepare(means), prepare(scales), prepare(rotations), prepare(densities));
        let n = means.shape()[0];
        let volume = zeros(grid.dims.map(|d| d as usize).to_vec(), &means);
        if n == 0 {
            return volume;
        }
        let mut g = grid.origin_mm.to_vec();
        g.extend(grid.spacing_mm);
        g.extend(grid.dims.map(|d| d as f32));
        let grid_t = upload(g, vec![9], &means);
        let (count, dim) = launch_dims(&means, n);
        let acc = atomics::Accumulator::new(&volume, settings.f32_add);
        voxelize::voxelize_kernel::launch(
            &means.client,
            count,
            dim,
            means.clone().into_tensor_arg(),
            scales.into_tensor_arg(),
            rotations.into_tensor_arg(),
            densities.into_tensor_arg(),
            grid_t.into_tensor_arg(),
            acc.as_f32.into_tensor_arg(),
            acc.as_u32.into_tensor_arg(),
            n as u32,
            settings.k_sigma,
            acc.native,
        );
        volume
    }
}

//! CubeCL kernel of the window blur: one unit per output pixel and pass (along W, then H).

use burn::backend::ops::FloatTensorOps;
use burn::backend::{FloatDType, TensorMetadata};
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use super::cpu::RADIUS;
use crate::method::model::hash_op::gpu::prepare;

/// `step` = 1 blurs along W (neighbours in the same row), `w` along H; `extent` is the row
/// length or the image height, `coord` the pixel's column or row.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn blur_pass_kernel(
    input: &Tensor<f32>,
    output: &mut Tensor<f32>,
    t0: f32,
    t1: f32,
    t2: f32,
    t3: f32,
    t4: f32,
    t5: f32,
    len: u32,
    h: u32,
    w: u32,
    along_w: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= len as usize {
        terminate!();
    }
    let col = id % (w as usize);
    let row = (id / (w as usize)) % (h as usize);
    let mut coord = row;
    let mut extent = h as usize;
    let mut step = w as usize;
    if along_w == 1u32 {
        coord = col;
        extent = w as usize;
        step = 1usize;
    }
    let mut acc = 0.0f32;
    for k in 0..11u32 {
        let kk = k as usize;
        // The window is symmetric: tap k is t_|k − 5| (t0 the centre).
        let off = select(k >= 5u32, k - 5u32, 5u32 - k);
        let mut tap = t5;
        if off == 0u32 {
            tap = t0;
        } else if off == 1u32 {
            tap = t1;
        } else if off == 2u32 {
            tap = t2;
        } else if off == 3u32 {
            tap = t3;
        } else if off == 4u32 {
            tap = t4;
        }
        // source coordinate coord + k − RADIUS, inside [0, extent)
        if coord + kk >= 5usize && coord + kk < extent + 5usize {
            let src = id + (kk * step) - 5usize * step;
            acc += tap * input[src];
        }
    }
    output[id] = acc;
}

/// The blur on the GPU: `[V, H, W]`.
pub fn blur(images: CubeTensor, taps: &[f32; 2 * RADIUS + 1]) -> CubeTensor {
    let images = prepare(images);
    let shape = images.shape();
    let (h, w) = (shape[1], shape[2]);
    let len = shape.num_elements();
    // Both passes write every pixel.
    let mid = CubeBackend::float_empty(shape.clone(), &images.device, FloatDType::F32);
    let out = CubeBackend::float_empty(shape, &images.device, FloatDType::F32);
    if len == 0 {
        return out;
    }
    // The taps as launch arguments (no upload per call): the centre and one side.
    let [t0, t1, t2, t3, t4, t5] = [5, 6, 7, 8, 9, 10].map(|k| taps[k]);
    let dim = CubeDim::new_1d(64);
    let count = cubecl::calculate_cube_count_elemwise(&images.client, len, dim);
    for (src, dst, along_w) in [(&images, &mid, 1u32), (&mid, &out, 0u32)] {
        blur_pass_kernel::launch(
            &images.client,
            count.clone(),
            dim,
            src.clone().into_tensor_arg(),
            dst.clone().into_tensor_arg(),
            t0,
            t1,
            t2,
            t3,
            t4,
            t5,
            len as u32,
            h as u32,
            w as u32,
            along_w,
        );
    }
    out
}

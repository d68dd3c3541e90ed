//! CubeCL kernel of the window blur: one unit per output pixel and pass (along W, then H).

use burn::backend::TensorMetadata;
use burn_cubecl::cubecl;
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::tensor::CubeTensor;

use crate::cube::{empty, launch_1d, prepare};

/// The window's taps from the centre out (`taps()[5..]`, a Gaussian of σ = 1.5 px normalised
/// to sum 1), as the f32 values the CPU kernels use: a test checks them against `taps()`.
const TAP0: f32 = 0.266_011_71;
const TAP1: f32 = 0.213_005_54;
const TAP2: f32 = 0.109_360_69;
const TAP3: f32 = 0.036_000_773;
const TAP4: f32 = 0.007_598_758;
const TAP5: f32 = 0.001_028_380_1;

/// [`tap`]'s values, centre first.
#[cfg(test)]
pub(crate) const HALF_TAPS: [f32; 6] = [TAP0, TAP1, TAP2, TAP3, TAP4, TAP5];

/// Tap `k` (0..11) of the symmetric window.
#[cube]
pub(crate) fn tap(k: u32) -> f32 {
    let off = select(k >= 5u32, k - 5u32, 5u32 - k);
    let mut t = f32::new(TAP5);
    if off == 0u32 {
        t = f32::new(TAP0);
    } else if off == 1u32 {
        t = f32::new(TAP1);
    } else if off == 2u32 {
        t = f32::new(TAP2);
    } else if off == 3u32 {
        t = f32::new(TAP3);
    } else if off == 4u32 {
        t = f32::new(TAP4);
    }
    t
}

/// `step` = 1 blurs along W (neighbours in the same row), `w` along H; `extent` is the row
/// length or the image height, `coord` the pixel's column or row.
#[cube(launch)]
fn blur_pass_kernel(input: &Tensor<f32>, output: &mut Tensor<f32>, len: u32, h: u32, w: u32, along_w: u32) {
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
        // source coordinate coord + k − 5, inside [0, extent)
        if coord + kk >= 5usize && coord + kk < extent + 5usize {
            let src = id + (kk * step) - 5usize * step;
            acc += tap(k) * input[src];
        }
    }
    output[id] = acc;
}

/// The blur on the GPU: `[V, H, W]` (the window of [`HALF_TAPS`]).
pub fn blur(images: CubeTensor) -> CubeTensor {
    let images = prepare(images);
    let shape = images.shape();
    let (h, w) = (shape[1], shape[2]);
    let len = shape.num_elements();
    // Both passes write every pixel.
    let mid = empty(shape.to_vec(), &images);
    let out = empty(shape.to_vec(), &images);
    if len == 0 {
        return out;
    }
    let (count, dim) = launch_1d(&images, len, 64);
    for (src, dst, along_w) in [(&images, &mid, 1u32), (&mid, &out, 0u32)] {
        blur_pass_kernel::launch(
            &images.client,
            count.clone(),
            dim,
            src.clone().into_tensor_arg(),
            dst.clone().into_tensor_arg(),
            len as u32,
            h as u32,
            w as u32,
            along_w,
        );
    }
    out
}

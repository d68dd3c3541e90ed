//! CubeCL forward kernel: one unit per (Gaussian, view) walks the exact row spans of its k-σ
//! footprint and adds each pixel's line integral to the image with an atomic add (the image is
//! bound as both of its typed arguments; see [`super::atomics`]).

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::atomics::add_f32;
use super::math::{load_params, load_view, project, row_eval, unit_value};

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
pub fn render_forward_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    views: &Tensor<f32>,
    image_f32: &mut Tensor<Atomic<f32>>,
    image_u32: &mut Tensor<Atomic<u32>>,
    n: u32,
    n_views: u32,
    k_sigma: f32,
    #[comptime] native: bool,
) {
    let id = ABSOLUTE_POS;
    if id >= (n * n_views) as usize {
        terminate!();
    }
    let i = id % (n as usize);
    let v = id / (n as usize);
    let p = load_params(means, scales, rotations, densities, i);
    let vw = load_view(views, v);
    let pr = project(&p, &vw, k_sigma);
    if pr.valid == 1u32 {
        let plane = v * (vw.width as usize) * (vw.height as usize);
        for row in pr.row_min..pr.row_max + 1 {
            let re = row_eval(&pr, &vw, row);
            let base = plane + (row as usize) * (vw.width as usize);
            for col in pr.col_min..pr.col_max + 1 {
                let dx = (f32::cast_from(col) - pr.u0) * vw.inv_fx;
                let (unit, _inv_a) = unit_value(&pr, &re, dx);
                add_f32(image_f32, image_u32, base + col as usize, unit * p.density, native);
            }
        }
    }
}

//! CubeCL forward kernel: `split` units per (Gaussian, view), each walking every `split`-th row of
//! the Gaussian's k-σ footprint over the row's exact column span ([`row_columns`]), add each
//! pixel's line integral to the image with an atomic add (the image is bound as both of its
//! typed arguments; see [`super::atomics`]). Splitting the rows keeps a warp from waiting on
//! its largest footprint.

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::atomics::add_f32;
use super::math::{load_params, load_view, project, row_columns, row_eval, unit_value};

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
    split: u32,
    k_sigma: f32,
    #[comptime] native: bool,
) {
    let id = ABSOLUTE_POS;
    if id >= (n * n_views * split) as usize {
        terminate!();
    }
    let lane = (id % (split as usize)) as u32;
    let pair = id / (split as usize);
    let i = pair % (n as usize);
    let v = pair / (n as usize);
    let p = load_params(means, scales, rotations, densities, i);
    let vw = load_view(views, v);
    let pr = project(&p, &vw, k_sigma);
    if pr.valid == 1u32 {
        let plane = v * (vw.width as usize) * (vw.height as usize);
        let rows = pr.row_max + 1 - pr.row_min;
        let mine = (rows + split - 1 - lane) / split;
        for k in 0..mine {
            let row = pr.row_min + lane + k * split;
            let re = row_eval(&pr, &vw, row);
            let base = plane + (row as usize) * (vw.width as usize);
            let (first, last) = row_columns(&pr, &re, &vw);
            for col in first..last + 1 {
                let dx = (f32::cast_from(col) - pr.u0) * vw.inv_fx;
                let (unit, _inv_a) = unit_value(&pr, &re, dx);
                add_f32(image_f32, image_u32, base + col as usize, unit * p.density, native);
            }
        }
    }
}

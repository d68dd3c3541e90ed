//! Pair and lane counts of the forward kernel, for the benchmarks' throughput figures.

use rayon::prelude::*;

use super::host::HostGaussians;
use super::math::Projected;
use super::project::project_range;
use crate::view_params::ViewParams;

/// Gaussians per parallel task.
const CHUNK: usize = 2048;

/// Lanes of the forward's vectors.
const LANES: usize = super::forward::LANES;

/// Projects all Gaussians into one view (`None` = culled), for counting.
pub fn project_all(g: &HostGaussians, vp: &ViewParams, k_sigma: f32) -> Vec<Option<Projected>> {
    let mut out = vec![None; g.len()];
    out.par_chunks_mut(CHUNK).enumerate().for_each(|(c, chunk)| project_range(g, c * CHUNK, vp, k_sigma, chunk, None));
    out
}

/// Sums `per_footprint` over every visible Gaussian in every view (bench figures).
fn sum_over_footprints(
    g: &HostGaussians,
    views: &[ViewParams],
    k_sigma: f32,
    per_footprint: impl Fn(&Projected, &ViewParams) -> u64 + Sync,
) -> u64 {
    views
        .iter()
        .map(|vp| project_all(g, vp, k_sigma).par_iter().flatten().map(|p| per_footprint(p, vp)).sum::<u64>())
        .sum()
}

/// Number of (pixel, Gaussian) pairs that contribute (pixels whose ray meets the k-σ
/// ellipsoid), for throughput figures.
pub fn count_pairs(g: &HostGaussians, views: &[ViewParams], k_sigma: f32) -> u64 {
    sum_over_footprints(g, views, k_sigma, |p, vp| {
        let mut count = 0u64;
        for row in p.row_min..=p.row_max {
            let re = p.row_eval(row, vp);
            for col in p.col_min..=p.col_max {
                let dx = (col as f32 - p.u0) * vp.inv_fx;
                count += p.sees(re.quad(dx), re.alpha(dx)) as u64;
            }
        }
        count
    })
}

/// Number of pixel lanes the forward kernel evaluates (footprint boxes, rows rounded up to
/// whole `LANES`-pixel chunks, row pairs of narrow footprints sharing one), for throughput
/// figures: the ratio to [`count_pairs`] is the share of the vector work spent outside
/// footprints.
pub fn count_lanes(g: &HostGaussians, views: &[ViewParams], k_sigma: f32) -> u64 {
    sum_over_footprints(g, views, k_sigma, |p, _| {
        let rows = (p.row_max - p.row_min + 1) as u64;
        if p.col_max - p.col_min < LANES as i32 / 2 {
            // Row pairs share a vector (`splat_narrow_pair`); an odd last row gets its own.
            (rows / 2 + rows % 2) * LANES as u64
        } else {
            let width = (p.col_max - p.col_min + 1) as u64;
            width.div_ceil(LANES as u64) * LANES as u64 * rows
        }
    })
}

//! The back-projection of the views' residual: every voxel of a grid looked up in each view's
//! support mask, kept when the views support it (all of them, or any), scored by the images.

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rayon::prelude::*;

use crate::data::case::images::Image;
use crate::data::masks::{Mask, pixel_of};
use crate::data::volume::{Grid, Volume};

/// A supported voxel of the back-projection: its score, its centre (mm) and whether every view
/// that sees it shows residual there (no view passed it only because the prior hides it).
pub(crate) type Scored = (f64, DVec3, bool);

/// Seeds scored by the back-projection of per-view support masks and intensity images.
pub(crate) fn back_project(
    grid: &Grid,
    views: &[ConeBeamView],
    masks: &[Mask],
    occluded: Option<&[Mask]>,
    values: &[Image],
    prior: Option<&Volume<u8>>,
    intersect: bool,
) -> Vec<Scored> {
    // With occlusion masks, a view where the prior hides the pixel supports without residual,
    // but at least half of the views (rounded up) must see residual.
    let min_residual = if occluded.is_some() { views.len().div_ceil(2) } else { views.len() };
    let [nx, ny, nz] = grid.dims;
    (0..nx)
        .into_par_iter()
        .flat_map_iter(|i| {
            let mut out = Vec::new();
            for j in 0..ny {
                for k in 0..nz {
                    let idx = grid.index(i, j, k);
                    if prior.is_some_and(|p| p.data[idx] != 0) {
                        continue;
                    }
                    let c = grid.centre_mm(i, j, k);
                    let (mut supported, mut residual, mut seen) = (0usize, 0usize, 0usize);
                    let mut log_sum = 0.0;
                    let mut sum = 0.0;
                    for (vi, ((v, m), img)) in views.iter().zip(masks).zip(values).enumerate() {
                        let Some(px) = pixel_of(v, c) else { continue };
                        seen += 1;
                        let hidden = occluded.is_some_and(|o| o[vi].data[px]);
                        if m.data[px] || hidden {
                            supported += 1;
                        }
                        // Scored by the views that show residual (an occluded view's pixel is
                        // bright from the prior in front of or behind it).
                        if m.data[px] {
                            residual += 1;
                            let val = (img.data[px] as f64).max(1e-12);
                            log_sum += val.ln();
                            sum += val;
                        }
                    }
                    let keep =
                        if intersect { supported == views.len() && residual >= min_residual } else { supported > 0 };
                    if keep {
                        let score = if intersect { (log_sum / residual.max(1) as f64).exp() } else { sum };
                        out.push((score, c, residual == seen));
                    }
                }
            }
            out
        })
        .collect()
}

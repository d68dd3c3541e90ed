//! The box (mm) a completion works in, from the inputs alone: the bounding box of the vessels'
//! visual hull (points whose projection falls on a vessel pixel in every view) joined with the
//! prior's bounding box, plus a margin. Nothing of the case's ground truth — nor the box the
//! case file declares, which a synthetic case takes from its complete tree — enters it.

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rayon::prelude::*;

use crate::data::case::images::Image;
use crate::data::masks::{Mask, vessel_masks};
use crate::data::mesh::TriMesh;
use crate::data::volume::BoxMm;
use crate::error::{CoreError, Result};

/// Margin (mm) added around the hull and prior.
pub const MARGIN_MM: f64 = 2.0;
/// Vessel masks are dilated by this many pixels before the hull is carved (thin vessels that
/// are one pixel wide in one view and fall between pixel centres in another stay in).
const HULL_DILATION_PX: u32 = 1;
/// Scan points per axis at most.
const SCAN_POINTS: f64 = 192.0;

/// Half-width (mm) of the cube around the isocentre that every view can see a part of: the
/// largest field of view at the isocentre over the views.
fn scan_half_width(views: &[ConeBeamView]) -> f64 {
    views
        .iter()
        .map(|v| {
            let f = v.intrinsics().focal_px;
            let half = 0.5 * (v.width() as f64 / f[0]).max(v.height() as f64 / f[1]);
            v.source_mm().length() * half
        })
        .fold(0.0, f64::max)
}

/// Whether `p` falls on a set pixel of `mask` in `view`.
fn on_mask(view: &ConeBeamView, mask: &Mask, p: DVec3) -> bool {
    let Some(uv) = view.project(p) else { return false };
    let (c, r) = (uv.x.round(), uv.y.round());
    if !(c >= 0.0 && r >= 0.0 && c < view.width() as f64 && r < view.height() as f64) {
        return false;
    }
    mask.data[r as usize * view.width() as usize + c as usize]
}

/// The working box from the views, their images (vessel masks at `mask_threshold`, as the N2
/// seeds) and the prior mesh.
pub fn working_box_from_inputs(
    views: &[ConeBeamView],
    images: &[Image],
    prior: Option<&TriMesh>,
    mask_threshold: f64,
) -> Result<BoxMm> {
    let masks: Vec<Mask> = vessel_masks(images, mask_threshold).iter().map(|m| m.dilated(HULL_DILATION_PX)).collect();
    let r = scan_half_width(views);
    if !(r > 0.0 && r.is_finite()) {
        return Err(CoreError::invalid("the views see no region around the isocentre"));
    }
    let n = SCAN_POINTS as usize;
    let step = 2.0 * r / SCAN_POINTS;
    let at = |i: usize| -r + (i as f64 + 0.5) * step;
    let hull = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut b: Option<(DVec3, DVec3)> = None;
            for j in 0..n {
                for k in 0..n {
                    let p = DVec3::new(at(i), at(j), at(k));
                    if views.iter().zip(&masks).all(|(v, m)| on_mask(v, m, p)) {
                        b = Some(b.map_or((p, p), |(lo, hi)| (lo.min(p), hi.max(p))));
                    }
                }
            }
            b
        })
        .reduce(|| None, join);
    let hull = hull.map(|(lo, hi)| (lo - DVec3::splat(0.5 * step), hi + DVec3::splat(0.5 * step)));
    let joined = join(hull, prior.and_then(TriMesh::bounds_mm))
        .ok_or_else(|| CoreError::invalid("no vessel pixel is seen in every view and there is no prior"))?;
    Ok(BoxMm { min_mm: joined.0.to_array(), max_mm: joined.1.to_array() }.padded(MARGIN_MM))
}

fn join(a: Option<(DVec3, DVec3)>, b: Option<(DVec3, DVec3)>) -> Option<(DVec3, DVec3)> {
    match (a, b) {
        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
        (a, None) => a,
        (None, b) => b,
    }
}

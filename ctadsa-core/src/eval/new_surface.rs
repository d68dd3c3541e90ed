//! Where a completion's new surface lies (`ctadsa diagnose`): the faces of the completed mesh
//! that are not the prior's, in bands of distance to the prior, each band with its area and
//! its distance to the true surface — to tell a prior vessel drawn too wide (new surface right
//! beside the prior) from a vessel at the wrong depth (far from it and from the truth).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::data::mesh::TriMesh;
use crate::data::mesh::distance::SurfaceIndex;
use crate::eval::surface_metrics::FALSE_SURFACE_MM;

/// Band edges (mm of distance to the prior surface): [0, 1), [1, 3), [3, ∞).
pub const BAND_EDGES_MM: [f64; 2] = [1.0, 3.0];
/// A face whose centroid lies within this (mm) of the prior surface is the prior's own.
const ON_PRIOR_MM: f64 = 1e-6;

/// The new faces within one band of distance to the prior.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceBand {
    /// The band: from this distance to the prior (mm) …
    pub from_mm: f64,
    /// … up to this one (mm; `None`: no upper bound).
    pub to_mm: Option<f64>,
    /// Area (mm²) and share of the new surface's area.
    pub area_mm2: f64,
    pub share: f64,
    /// Area-weighted mean distance (mm) of the faces' centroids to the true surface.
    pub mean_truth_mm: f64,
    /// Share of the band's area farther than [`FALSE_SURFACE_MM`] from the true surface.
    pub false_share: f64,
}

/// The new surface of a completion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NewSurface {
    /// Area (mm²) of the completed surface's faces that are not on the prior.
    pub area_mm2: f64,
    /// Area (mm²) of the true missing vessels' surface, for scale.
    pub missing_area_mm2: Option<f64>,
    pub bands: Vec<SurfaceBand>,
}

/// [`NewSurface`] of `completed` (the prior joined with new vessels, or any surface) against
/// the prior and true surfaces. Distances are exact point-to-triangle distances of each face's
/// centroid, weighted by the face's area.
pub fn new_surface(
    completed: &TriMesh,
    prior: &SurfaceIndex,
    truth: &SurfaceIndex,
    missing_area_mm2: Option<f64>,
) -> NewSurface {
    // (area, distance to the prior, distance to the truth) of every face not on the prior.
    let faces: Vec<(f64, f64, f64)> = completed
        .faces
        .par_iter()
        .filter_map(|f| {
            let centroid = f.iter().map(|&i| completed.vertices[i as usize]).sum::<glam::DVec3>() / 3.0;
            let to_prior = prior.distance(centroid);
            (to_prior > ON_PRIOR_MM).then(|| (completed.face_area(f), to_prior, truth.distance(centroid)))
        })
        .collect();
    let area_mm2: f64 = faces.iter().map(|f| f.0).sum();
    let mut edges = vec![0.0];
    edges.extend(BAND_EDGES_MM);
    let bands = edges
        .iter()
        .enumerate()
        .map(|(k, &from_mm)| {
            let to_mm = edges.get(k + 1).copied();
            let inside: Vec<&(f64, f64, f64)> =
                faces.iter().filter(|f| f.1 >= from_mm && to_mm.is_none_or(|t| f.1 < t)).collect();
            let area: f64 = inside.iter().map(|f| f.0).sum();
            let weighted = |g: &dyn Fn(&(f64, f64, f64)) -> f64| {
                if area > 0.0 { inside.iter().map(|f| f.0 * g(f)).sum::<f64>() / area } else { 0.0 }
            };
            SurfaceBand {
                from_mm,
                to_mm,
                area_mm2: area,
                share: if area_mm2 > 0.0 { area / area_mm2 } else { 0.0 },
                mean_truth_mm: weighted(&|f| f.2),
                false_share: weighted(&|f| f64::from(u8::from(f.2 > FALSE_SURFACE_MM))),
            }
        })
        .collect();
    NewSurface { area_mm2, missing_area_mm2, bands }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;

    /// A square of side `s` (mm) in the plane z = `z`, corner at (`x`, 0).
    fn square(x: f64, z: f64, s: f64) -> TriMesh {
        let v = |a: f64, b: f64| DVec3::new(x + a, b, z);
        TriMesh { vertices: vec![v(0.0, 0.0), v(s, 0.0), v(s, s), v(0.0, s)], faces: vec![[0, 1, 2], [0, 2, 3]] }
    }

    #[test]
    fn a_shell_beside_the_prior_a_false_patch_and_a_true_far_patch_fall_in_their_bands() {
        let prior = square(0.0, 0.0, 10.0);
        // The truth: the prior and a patch 5 mm above it. The completion adds a shell 0.5 mm
        // above the prior (the prior too wide), the patch, and a false patch 2.5 mm above it.
        let patch = square(2.0, 5.0, 2.0);
        let mut truth = prior.clone();
        truth.append(&patch);
        let mut completed = prior.clone();
        completed.append(&square(0.0, 0.5, 10.0));
        completed.append(&patch);
        completed.append(&square(6.0, 2.5, 1.0));
        let ns = new_surface(&completed, &SurfaceIndex::new(&prior), &SurfaceIndex::new(&truth), Some(4.0));
        assert!((ns.area_mm2 - 105.0).abs() < 1e-9, "{ns:?}");
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        let [near, mid, far] = [ns.bands[0], ns.bands[1], ns.bands[2]];
        assert!(close(near.area_mm2, 100.0) && close(near.mean_truth_mm, 0.5) && near.false_share == 0.0, "{near:?}");
        assert!(close(mid.area_mm2, 1.0) && close(mid.mean_truth_mm, 2.5) && close(mid.false_share, 1.0), "{mid:?}");
        assert!(close(far.area_mm2, 4.0) && close(far.mean_truth_mm, 0.0) && far.to_mm.is_none(), "{far:?}");
        assert!(close(ns.bands.iter().map(|b| b.share).sum::<f64>(), 1.0));
    }
}

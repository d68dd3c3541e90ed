//! Isotropic Gaussians at the chosen centres, their scales from the nearest other centres.

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};

use crate::method::model::{GaussianInit, ScaleBounds};

/// Isotropic Gaussians with identity rotations at `centres` (mm), scales (mm) clamped to `bounds`.
pub(crate) fn isotropic_gaussians(centres: &[DVec3], scales: &[f64], bounds: ScaleBounds) -> GaussianInit {
    let mut g = GaussianInit::default();
    for (c, &s) in centres.iter().zip(scales) {
        g.means.extend([c.x as f32, c.y as f32, c.z as f32]);
        g.raw_scales.extend([bounds.inverse((s as f32).clamp(bounds.min_mm, bounds.max_mm)); 3]);
        g.rotations.extend([1.0, 0.0, 0.0, 0.0]);
    }
    g
}

/// Isotropic scale (mm) of each point: sqrt of the mean squared distance to its `k` nearest
/// other points (a point alone gets `fallback`).
pub fn knn_scales(points: &[DVec3], k: usize, fallback: f64) -> Vec<f64> {
    if points.len() < 2 {
        return vec![fallback; points.len()];
    }
    let pts: Vec<[f64; 3]> = points.iter().map(|p| p.to_array()).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&pts).expect("finite points");
    let kk = (k + 1).min(points.len());
    let n = std::num::NonZero::new(kk).expect("k + 1 ≥ 1");
    tree.query_batch(&pts)
        .nearest_n::<SquaredEuclidean<f64>>(n)
        .execute()
        .into_iter()
        .map(|res| {
            let d: Vec<f64> = res.iter().skip(1).map(|r| r.distance).collect();
            if d.is_empty() { fallback } else { (d.iter().sum::<f64>() / d.len() as f64).sqrt() }
        })
        .collect()
}

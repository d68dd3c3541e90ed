//! Gaussians laid along a tree's centrelines: a vessel-like scene for benchmarks and tests.

use glam::{DQuat, DVec3};

use super::VesselTree;

/// Gaussian parameters as flat arrays (row-major): means `[N·3]` mm, scales `[N·3]` mm,
/// quaternions `[N·4]` (w, x, y, z), densities `[N]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GaussianArrays {
    pub means: Vec<f32>,
    pub scales: Vec<f32>,
    pub rotations: Vec<f32>,
    pub densities: Vec<f32>,
}

impl GaussianArrays {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.densities.len()
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.densities.is_empty()
    }
}

/// About `count` Gaussians spaced evenly along the centrelines: each elongated along its
/// segment (standard deviation ≈ 0.6 × spacing) and `0.5 ×` the local radius across, with
/// `density` each.
pub fn tree_gaussians(tree: &VesselTree, count: usize, density: f32) -> GaussianArrays {
    let segments = tree.segments();
    let total: f64 = segments.iter().map(|s| s.length_mm()).sum();
    let mut out = GaussianArrays::default();
    if total <= 0.0 || count == 0 {
        return out;
    }
    let spacing = total / count as f64;
    for s in &segments {
        let len = s.length_mm();
        let n = ((len / spacing).round() as usize).max(1);
        let dir = (s.end_mm - s.start_mm).normalize_or(DVec3::X);
        let q = DQuat::from_rotation_arc(DVec3::X, dir);
        for k in 0..n {
            let t = (k as f64 + 0.5) / n as f64;
            let p = s.start_mm + t * (s.end_mm - s.start_mm);
            let r = s.start_radius_mm + t * (s.end_radius_mm - s.start_radius_mm);
            let along = (0.6 * len / n as f64).max(0.5 * r);
            out.means.extend([p.x as f32, p.y as f32, p.z as f32]);
            out.scales.extend([along as f32, (0.5 * r) as f32, (0.5 * r) as f32]);
            out.rotations.extend([q.w as f32, q.x as f32, q.y as f32, q.z as f32]);
            out.densities.push(density);
        }
    }
    out
}

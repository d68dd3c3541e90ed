//! Scoring a predicted vessel surface against a ground truth (`ctadsa eval`): surface samples,
//! optional ICP alignment, overall and per-region distances (see `docs/METRICS.md`).

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::icp::icp;
use crate::mesh::TriMesh;
use crate::mesh::io::read_mesh;
use crate::mesh::sample::sample_surface;
use crate::metrics::{RegionScores, region_scores};

/// How the surfaces are turned into point sets.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    /// Area-uniform samples per surface.
    pub samples: usize,
    /// Seed of the sampling (the same seed gives the same points).
    pub seed: u64,
    /// Use mesh vertices instead of area-uniform samples (parity with vertex-based evaluations).
    pub vertices: bool,
    /// Rigidly align the prediction to the ground truth first (trimmed ICP keeping the closest 80%
    /// of correspondences, at most 75 steps, as the reference evaluation).
    pub icp: bool,
    /// Drop connected components of the prediction smaller than this surface area (mm²) first;
    /// 0 keeps everything.
    pub min_island_mm2: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self { samples: 20_000, seed: 1234, vertices: false, icp: false, min_island_mm2: 0.0 }
    }
}

/// The result of an evaluation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    pub options: EvalOptions,
    pub scores: RegionScores,
    /// ICP: mean distance after alignment (mm), and the translation applied (mm).
    pub icp_mean_mm: Option<f64>,
    pub icp_translation_mm: Option<[f64; 3]>,
}

fn points(mesh: &TriMesh, o: &EvalOptions) -> Vec<DVec3> {
    if o.vertices { mesh.vertices.clone() } else { sample_surface(mesh, o.samples, o.seed) }
}

/// Scores `pred` against `gt`; with `split = (prior, missing)` also per region.
pub fn evaluate(pred: &TriMesh, gt: &TriMesh, split: Option<(&TriMesh, &TriMesh)>, o: &EvalOptions) -> EvalReport {
    let mut pred_pts = points(pred, o);
    let gt_pts = points(gt, o);
    let (mut icp_mean_mm, mut icp_translation_mm) = (None, None);
    if o.icp {
        let (motion, mean) = icp(&pred_pts, &gt_pts, 75, 0.8);
        pred_pts.iter_mut().for_each(|p| *p = motion.apply(*p));
        icp_mean_mm = Some(mean);
        icp_translation_mm = Some(motion.translation_mm.to_array());
    }
    let split_pts = split.map(|(p, m)| (points(p, o), points(m, o)));
    let scores = region_scores(&pred_pts, &gt_pts, split_pts.as_ref().map(|(p, m)| (p.as_slice(), m.as_slice())));
    EvalReport { options: *o, scores, icp_mean_mm, icp_translation_mm }
}

/// [`evaluate`] on mesh files (OBJ, PLY or STL).
pub fn evaluate_files(pred: &Path, gt: &Path, split: Option<(&Path, &Path)>, o: &EvalOptions) -> Result<EvalReport> {
    let mut pred = read_mesh(pred)?;
    if o.min_island_mm2 > 0.0 {
        pred = pred.without_islands_below(o.min_island_mm2).0;
    }
    let gt = read_mesh(gt)?;
    let split = match split {
        Some((p, m)) => Some((read_mesh(p)?, read_mesh(m)?)),
        None => None,
    };
    Ok(evaluate(&pred, &gt, split.as_ref().map(|(p, m)| (p, m)), o))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed UV sphere (mm) with `n` rings.
    fn sphere(centre: DVec3, radius: f64, n: u32) -> TriMesh {
        let mut m = TriMesh::default();
        m.vertices.push(centre + DVec3::Z * radius);
        for i in 1..n {
            let th = std::f64::consts::PI * i as f64 / n as f64;
            for j in 0..2 * n {
                let ph = std::f64::consts::PI * j as f64 / n as f64;
                m.vertices.push(centre + radius * DVec3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()));
            }
        }
        m.vertices.push(centre - DVec3::Z * radius);
        let ring = |i: u32, j: u32| 1 + (i - 1) * 2 * n + (j % (2 * n));
        let last = m.vertices.len() as u32 - 1;
        for j in 0..2 * n {
            m.faces.push([0, ring(1, j), ring(1, j + 1)]);
            m.faces.push([last, ring(n - 1, j + 1), ring(n - 1, j)]);
            for i in 1..n - 1 {
                m.faces.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
                m.faces.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
            }
        }
        m
    }

    fn opts() -> EvalOptions {
        EvalOptions { samples: 20_000, ..EvalOptions::default() }
    }

    #[test]
    fn a_mesh_against_itself_scores_zero() {
        let s = sphere(DVec3::ZERO, 10.0, 32);
        let r = evaluate(&s, &s, None, &opts());
        assert_eq!(r.scores.overall.cd_sum_mm, 0.0);
        assert_eq!(r.scores.overall.hd_mm, 0.0);
    }

    #[test]
    fn concentric_spheres_are_their_radius_difference_apart() {
        // Every point of one sphere is 2 mm from the other (up to the tessellation's sag,
        // 10·(1 − cos(π/128)) ≈ 0.003 mm, and the sampling density).
        let a = sphere(DVec3::ZERO, 10.0, 128);
        let b = sphere(DVec3::ZERO, 12.0, 128);
        let s = evaluate(&a, &b, None, &opts()).scores.overall;
        assert!((s.cd_mean_mm - 2.0).abs() < 0.02, "CD mean {}", s.cd_mean_mm);
        assert!((s.cd_sum_mm - 4.0).abs() < 0.04, "CD sum {}", s.cd_sum_mm);
        assert!((s.hd_mm - 2.0).abs() < 0.1, "HD {}", s.hd_mm);
        assert!(s.hd95_mm <= s.hd_mm && s.hd95_mm > 1.9, "HD95 {}", s.hd95_mm);
    }

    #[test]
    fn an_extra_blob_is_seen_from_the_prediction_side_only() {
        let gt = sphere(DVec3::ZERO, 10.0, 48);
        let mut pred = gt.clone();
        pred.append(&sphere(DVec3::new(40.0, 0.0, 0.0), 2.0, 24)); // false positive, 28 mm away
        let s = evaluate(&pred, &gt, None, &opts()).scores.overall;
        // Different samples of the same sphere: ~0.13 mm apart (20,000 points on 1,257 mm²).
        assert!(s.gt_to_pred_mm < 0.2, "truth→prediction {}", s.gt_to_pred_mm);
        assert!(s.pred_to_gt_mm > 0.5, "prediction→truth {}", s.pred_to_gt_mm);
        assert!((s.hd_mm - 32.0).abs() < 0.5, "the farthest false point is 32 mm away, got {}", s.hd_mm);
    }

    #[test]
    fn regions_split_by_the_nearer_reference() {
        // Prior: sphere at the origin; missing vessel: sphere at x = 30. The prediction has the
        // prior exactly and the missing part 1 mm too large.
        let prior = sphere(DVec3::ZERO, 5.0, 48);
        let missing = sphere(DVec3::new(30.0, 0.0, 0.0), 3.0, 48);
        let mut gt = prior.clone();
        gt.append(&missing);
        let mut pred = prior.clone();
        pred.append(&sphere(DVec3::new(30.0, 0.0, 0.0), 4.0, 48));
        let r = evaluate(&pred, &gt, Some((&prior, &missing)), &opts()).scores;
        let (roi, pri) = (r.roi.unwrap(), r.prior.unwrap());
        assert!((roi.cd_mean_mm - 1.0).abs() < 0.06, "ROI CD {}", roi.cd_mean_mm);
        assert!(pri.cd_mean_mm < 0.2, "prior-region CD {}", pri.cd_mean_mm);
    }

    #[test]
    fn seeded_sampling_is_deterministic_and_icp_removes_a_shift() {
        let gt = sphere(DVec3::ZERO, 10.0, 64);
        let pred = sphere(DVec3::new(0.8, -0.5, 0.3), 10.0, 64);
        let a = evaluate(&pred, &gt, None, &opts());
        let b = evaluate(&pred, &gt, None, &opts());
        assert_eq!(a.scores.overall, b.scores.overall);
        let aligned = evaluate(&pred, &gt, None, &EvalOptions { icp: true, ..opts() });
        assert!(aligned.scores.overall.cd_mean_mm < 0.2 * a.scores.overall.cd_mean_mm);
        let t = aligned.icp_translation_mm.unwrap();
        assert!((t[0] + 0.8).abs() < 0.05 && (t[1] - 0.5).abs() < 0.05, "ICP shift {t:?}");
    }
}

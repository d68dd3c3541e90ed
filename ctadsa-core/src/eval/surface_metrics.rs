//! The project's scores of a predicted vessel surface (see `docs/METRICS.md`): area-uniform
//! samples of each surface, each at its **exact** distance to the other surface's triangles
//! ([`SurfaceIndex`]), so that a surface against itself scores 0; the reference's ROI / prior
//! partition done per predicted face; and how much of the missing vessels was found
//! ([`Coverage`]).

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::data::mesh::TriMesh;
use crate::data::mesh::distance::SurfaceIndex;
use crate::data::mesh::sample::sample_surface;
use crate::data::tree::Segment;
use crate::eval::metrics::{RegionScores, SurfaceScores, scores_from_distances};

/// Distance (mm) beyond which a predicted surface point counts as false surface.
pub const FALSE_SURFACE_MM: f64 = 2.0;
/// Tolerance (mm) of the missing-surface coverage.
pub const SURFACE_COVERAGE_MM: f64 = 1.0;
/// Slack (mm) added to the vessel radius for centreline recall.
pub const RECALL_SLACK_MM: f64 = 0.5;

/// A surface, its samples and its distance index.
struct Sampled {
    points: Vec<DVec3>,
    index: SurfaceIndex,
}

impl Sampled {
    fn new(mesh: &TriMesh, samples: usize, seed: u64) -> Self {
        Self { points: sample_surface(mesh, samples, seed), index: SurfaceIndex::new(mesh) }
    }
}

/// Exact scores of two sampled surfaces.
fn compare_sampled(pred: &Sampled, gt: &Sampled) -> SurfaceScores {
    scores_from_distances(&gt.index.distances(&pred.points), &pred.index.distances(&gt.points))
}

/// Exact Chamfer/Hausdorff scores of surface `pred` against surface `gt` (`samples` area-uniform
/// points per surface, drawn from `seed`).
pub fn compare_surfaces(pred: &TriMesh, gt: &TriMesh, samples: usize, seed: u64) -> SurfaceScores {
    compare_sampled(&Sampled::new(pred, samples, seed), &Sampled::new(gt, samples, seed))
}

/// The faces of `mesh` whose centroid is nearer `missing` than `prior` (the ROI part), and the
/// others.
pub fn partition_faces(mesh: &TriMesh, prior: &SurfaceIndex, missing: &SurfaceIndex) -> (TriMesh, TriMesh) {
    let centroids: Vec<DVec3> =
        mesh.faces.iter().map(|f| f.iter().map(|&i| mesh.vertices[i as usize]).sum::<DVec3>() / 3.0).collect();
    let (dp, dm) = (prior.distances(&centroids), missing.distances(&centroids));
    let (mut roi, mut rest) = (mesh.clone(), mesh.clone());
    roi.faces.clear();
    rest.faces.clear();
    for (k, f) in mesh.faces.iter().enumerate() {
        if dm[k] < dp[k] { roi.faces.push(*f) } else { rest.faces.push(*f) }
    }
    (roi, rest)
}

/// How much of the truth the prediction found, and how much of it is made up.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Coverage {
    /// Area fraction of the predicted surface farther than [`FALSE_SURFACE_MM`] from every true
    /// vessel surface.
    pub false_surface: f64,
    /// Area fraction of the missing-vessel surface within [`SURFACE_COVERAGE_MM`] of the
    /// prediction (when the missing surface is known).
    pub missing_surface_within_1mm: Option<f64>,
    /// Fraction of the missing vessels' centreline length whose points lie within
    /// radius + [`RECALL_SLACK_MM`] of the predicted surface (when the case has a tree).
    pub missing_recall: Option<f64>,
}

/// Exact region scores and coverage of a prediction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceEvaluation {
    pub scores: RegionScores,
    pub coverage: Coverage,
}

/// What a prediction is scored against.
pub struct Truth<'a> {
    /// The complete vessel surface.
    pub complete: &'a TriMesh,
    /// `(prior, missing)` surfaces, for the ROI / prior-region split.
    pub split: Option<(&'a TriMesh, &'a TriMesh)>,
    /// Centreline segments of the missing vessels, for recall.
    pub missing_centreline: Option<&'a [Segment]>,
}

/// Scores `pred` against `truth` with exact distances (`samples` per surface, from `seed`).
pub fn evaluate_surface(pred: &TriMesh, truth: &Truth, samples: usize, seed: u64) -> SurfaceEvaluation {
    let p = Sampled::new(pred, samples, seed);
    let g = Sampled::new(truth.complete, samples, seed);
    let pred_to_gt = g.index.distances(&p.points);
    let overall = scores_from_distances(&pred_to_gt, &p.index.distances(&g.points));
    let false_surface = fraction(&pred_to_gt, |d| d > FALSE_SURFACE_MM);
    let (roi, prior, missing_surface_within_1mm) = match truth.split {
        Some((prior_mesh, missing_mesh)) => {
            let prior = Sampled::new(prior_mesh, samples, seed);
            let missing = Sampled::new(missing_mesh, samples, seed);
            let (roi_faces, prior_faces) = partition_faces(pred, &prior.index, &missing.index);
            let roi_part = Sampled::new(&roi_faces, samples, seed);
            let prior_part = Sampled::new(&prior_faces, samples, seed);
            let within = fraction(&p.index.distances(&missing.points), |d| d <= SURFACE_COVERAGE_MM);
            (Some(compare_sampled(&roi_part, &missing)), Some(compare_sampled(&prior_part, &prior)), Some(within))
        }
        None => (None, None, None),
    };
    let missing_recall = truth.missing_centreline.map(|segs| centreline_recall(&p.index, segs));
    SurfaceEvaluation {
        scores: RegionScores { overall, roi, prior },
        coverage: Coverage { false_surface, missing_surface_within_1mm, missing_recall },
    }
}

/// Fraction of `values` for which `keep` holds (NaN when empty).
fn fraction(values: &[f64], keep: impl Fn(f64) -> bool) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.iter().filter(|&&d| keep(d)).count() as f64 / values.len() as f64
}

/// A point of a centreline: position (mm), vessel radius there (mm), and the length (mm) it
/// stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CentrelinePoint {
    pub position_mm: DVec3,
    pub radius_mm: f64,
    pub length_mm: f64,
}

/// Points every ≤ 0.1 mm along `segments` (at the middle of equal pieces), radius interpolated
/// along each segment.
pub fn centreline_points(segments: &[Segment]) -> Vec<CentrelinePoint> {
    let mut points = Vec::new();
    for s in segments {
        let len = s.length_mm();
        if !(len > 0.0) {
            continue;
        }
        let steps = (len / 0.1).ceil().clamp(1.0, 1e6) as usize;
        for k in 0..steps {
            let t = (k as f64 + 0.5) / steps as f64;
            points.push(CentrelinePoint {
                position_mm: s.start_mm.lerp(s.end_mm, t),
                radius_mm: s.start_radius_mm + t * (s.end_radius_mm - s.start_radius_mm),
                length_mm: len / steps as f64,
            });
        }
    }
    points
}

/// Fraction of the centreline length of `segments` whose points lie within their radius +
/// [`RECALL_SLACK_MM`] of `surface` ([`centreline_points`]; NaN for no length).
pub fn centreline_recall(surface: &SurfaceIndex, segments: &[Segment]) -> f64 {
    let points = centreline_points(segments);
    let total: f64 = points.iter().map(|p| p.length_mm).sum();
    if !(total > 0.0) {
        return f64::NAN;
    }
    let d = surface.distances(&points.iter().map(|p| p.position_mm).collect::<Vec<_>>());
    let covered: f64 =
        points.iter().zip(&d).filter(|(p, d)| **d <= p.radius_mm + RECALL_SLACK_MM).map(|(p, _)| p.length_mm).sum();
    covered / total
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A closed UV sphere (mm) with `n` rings.
    pub fn sphere(centre: DVec3, radius: f64, n: u32) -> TriMesh {
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

    /// An open tube of radius `r` along x from `x0` to `x1` (`k` facets around).
    pub fn tube(x0: f64, x1: f64, r: f64, rings: u32, k: u32) -> TriMesh {
        let mut m = TriMesh::default();
        for i in 0..=rings {
            let x = x0 + (x1 - x0) * i as f64 / rings as f64;
            for j in 0..k {
                let a = std::f64::consts::TAU * j as f64 / k as f64;
                m.vertices.push(DVec3::new(x, r * a.cos(), r * a.sin()));
            }
        }
        for i in 0..rings {
            for j in 0..k {
                let (a, b) = (i * k + j, i * k + (j + 1) % k);
                let (c, d) = (a + k, b + k);
                m.faces.push([a, b, d]);
                m.faces.push([a, d, c]);
            }
        }
        m
    }

    fn segment(x0: f64, x1: f64, r: f64) -> Segment {
        Segment {
            child: 0,
            start_mm: DVec3::new(x0, 0.0, 0.0),
            end_mm: DVec3::new(x1, 0.0, 0.0),
            start_radius_mm: r,
            end_radius_mm: r,
        }
    }

    #[test]
    fn a_mesh_against_itself_scores_zero_whatever_the_samples() {
        let s = sphere(DVec3::ZERO, 10.0, 24);
        // Different seeds: different points on the same surface, still exactly 0 (≤ 1e-9 mm).
        let a = Sampled::new(&s, 20_000, 1);
        let b = Sampled::new(&s, 20_000, 2);
        let r = compare_sampled(&a, &b);
        assert!(r.cd_sum_mm < 1e-9 && r.hd_mm < 1e-9, "{r:?}");
        let mut reordered = s.clone();
        reordered.faces.reverse();
        let r = compare_surfaces(&s, &reordered, 5_000, 3);
        assert!(r.cd_sum_mm <= 0.01 && r.hd_mm <= 0.01, "{r:?}");
    }

    #[test]
    fn concentric_spheres_are_their_radius_difference_apart() {
        let a = sphere(DVec3::ZERO, 10.0, 96);
        let b = sphere(DVec3::ZERO, 12.0, 96);
        let s = compare_surfaces(&a, &b, 10_000, 5);
        // Up to the tessellation's sag, 12·(1 − cos(π/96)) ≈ 0.006 mm.
        assert!((s.cd_mean_mm - 2.0).abs() < 0.01, "CD mean {}", s.cd_mean_mm);
        assert!((s.cd_sum_mm - 4.0).abs() < 0.02, "CD sum {}", s.cd_sum_mm);
        assert!((s.hd_mm - 2.0).abs() < 0.01 && (s.hd95_mm - 2.0).abs() < 0.01, "HD {} / {}", s.hd_mm, s.hd95_mm);
    }

    #[test]
    fn a_vessel_half_missing_has_recall_one_half() {
        // True vessel: a 1 mm-radius tube from x = 0 to 20; the prediction has only x ∈ [0, 10].
        let truth = tube(0.0, 20.0, 1.0, 40, 24);
        let pred = tube(0.0, 10.0, 1.0, 20, 24);
        let e = evaluate_surface(
            &pred,
            &Truth {
                complete: &truth,
                split: Some((&TriMesh::default(), &truth)),
                missing_centreline: Some(&[segment(0.0, 20.0, 1.0)]),
            },
            20_000,
            9,
        );
        let recall = e.coverage.missing_recall.unwrap();
        // Points up to radius + 0.5 mm past the open end are still covered: (10 + √(1.5² − 1²)) / 20.
        let expected = (10.0 + (1.5f64 * 1.5 - 1.0).sqrt()) / 20.0;
        assert!((recall - expected).abs() < 0.01, "recall {recall}, expected {expected}");
        assert!((recall - 0.5).abs() < 0.06);
        let within = e.coverage.missing_surface_within_1mm.unwrap();
        assert!((within - 0.55).abs() < 0.02, "surface within 1 mm {within}");
        assert_eq!(e.coverage.false_surface, 0.0, "everything predicted is true");
        assert!(e.scores.overall.pred_to_gt_mm < 1e-9);
    }

    #[test]
    fn false_surface_and_regions() {
        // Prior: sphere at the origin; missing: sphere at x = 30. The prediction has the prior
        // exactly, the missing part 1 mm too large, and a false blob far from both.
        let prior = sphere(DVec3::ZERO, 5.0, 48);
        let missing = sphere(DVec3::new(30.0, 0.0, 0.0), 3.0, 48);
        let mut gt = prior.clone();
        gt.append(&missing);
        let mut pred = prior.clone();
        pred.append(&sphere(DVec3::new(30.0, 0.0, 0.0), 4.0, 48));
        let blob = sphere(DVec3::new(0.0, 40.0, 0.0), 2.0, 24);
        let truth = Truth { complete: &gt, split: Some((&prior, &missing)), missing_centreline: None };
        let e = evaluate_surface(&pred, &truth, 20_000, 4);
        let (roi, pri) = (e.scores.roi.unwrap(), e.scores.prior.unwrap());
        assert!((roi.cd_mean_mm - 1.0).abs() < 0.01, "ROI CD {}", roi.cd_mean_mm);
        assert!(pri.cd_mean_mm < 1e-9, "prior-region CD {}", pri.cd_mean_mm);
        assert_eq!(e.coverage.false_surface, 0.0);
        assert_eq!(e.coverage.missing_surface_within_1mm, Some(1.0));
        pred.append(&blob);
        let area = |m: &TriMesh| m.area_mm2();
        let expected = area(&blob) / area(&pred);
        let f = evaluate_surface(&pred, &truth, 20_000, 4).coverage.false_surface;
        assert!((f - expected).abs() < 0.01, "false surface {f}, blob's share of the area {expected}");
    }
}

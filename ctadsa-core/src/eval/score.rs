//! Scoring a predicted vessel surface against a ground truth (`ctadsa eval`, and every finished
//! run): exact point-to-surface distances overall and per region, missing-vessel coverage, and
//! beside them the paper's convention (point sets, optional ICP). See `docs/METRICS.md`.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::data::case::Case;
use crate::data::mesh::TriMesh;
use crate::data::mesh::io::read_mesh;
use crate::data::mesh::sample::sample_surface;
use crate::data::tree::Segment;
use crate::data::tree::prior::split_by_diameter;
use crate::data::tree::swc::read_swc;
use crate::error::{CoreError, Result};
use crate::eval::icp::icp;
use crate::eval::metrics::{RegionScores, region_scores};
use crate::eval::surface_metrics::{Coverage, Truth, evaluate_surface};

pub use crate::config::MAX_SAMPLES;

/// How the surfaces are scored.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalOptions {
    /// Area-uniform samples per surface.
    pub samples: usize,
    /// Seed of the sampling (the same seed gives the same points).
    pub seed: u64,
    /// Paper column: use area-uniform samples instead of mesh vertices.
    pub paper_samples: bool,
    /// Rigidly align the prediction to the ground truth first (trimmed ICP keeping the closest 80%
    /// of correspondences, at most 75 steps, as the reference evaluation).
    pub icp: bool,
    /// Drop connected components of the prediction smaller than this surface area (mm²) first;
    /// 0 keeps everything.
    pub min_island_mm2: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self { samples: 20_000, seed: 1234, paper_samples: false, icp: false, min_island_mm2: 0.0 }
    }
}

impl EvalOptions {
    /// Checks the sample count.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_SAMPLES).contains(&self.samples) {
            return Err(CoreError::invalid(format!(
                "samples per surface must be in 1..={MAX_SAMPLES}, got {}",
                self.samples
            )));
        }
        if !(self.min_island_mm2 >= 0.0 && self.min_island_mm2.is_finite()) {
            return Err(CoreError::invalid(format!("min_island_mm2 must be ≥ 0, got {}", self.min_island_mm2)));
        }
        Ok(())
    }
}

/// The result of an evaluation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvalReport {
    pub options: EvalOptions,
    /// The project's scores: exact point-to-surface distances.
    pub scores: RegionScores,
    /// Missing-vessel recall and false surface.
    pub coverage: Coverage,
    /// The paper's convention: nearest-point distances between point sets (mesh vertices unless
    /// `paper_samples`), after ICP when asked.
    pub paper: RegionScores,
    /// ICP: mean distance after alignment (mm), and the translation applied (mm).
    pub icp_mean_mm: Option<f64>,
    pub icp_translation_mm: Option<[f64; 3]>,
}

fn points(mesh: &TriMesh, o: &EvalOptions) -> Vec<DVec3> {
    if o.paper_samples { sample_surface(mesh, o.samples, o.seed) } else { mesh.vertices.clone() }
}

/// Scores `pred` against `gt`; with `split = (prior, missing)` also per region, and with the
/// missing vessels' centreline their recall.
pub fn evaluate(
    pred: &TriMesh,
    gt: &TriMesh,
    split: Option<(&TriMesh, &TriMesh)>,
    missing_centreline: Option<&[Segment]>,
    o: &EvalOptions,
) -> EvalReport {
    let mut pred = pred.clone();
    let (mut icp_mean_mm, mut icp_translation_mm) = (None, None);
    if o.icp {
        let (motion, mean) =
            icp(&sample_surface(&pred, o.samples, o.seed), &sample_surface(gt, o.samples, o.seed), 75, 0.8);
        pred.vertices.iter_mut().for_each(|p| *p = motion.apply(*p));
        icp_mean_mm = Some(mean);
        icp_translation_mm = Some(motion.translation_mm.to_array());
    }
    let exact = evaluate_surface(&pred, &Truth { complete: gt, split, missing_centreline }, o.samples, o.seed);
    let split_pts = split.map(|(p, m)| (points(p, o), points(m, o)));
    let paper =
        region_scores(&points(&pred, o), &points(gt, o), split_pts.as_ref().map(|(p, m)| (p.as_slice(), m.as_slice())));
    EvalReport { options: *o, scores: exact.scores, coverage: exact.coverage, paper, icp_mean_mm, icp_translation_mm }
}

/// [`evaluate`] on mesh files (OBJ, PLY or STL).
pub fn evaluate_files(
    pred_path: &Path,
    gt_path: &Path,
    split: Option<(&Path, &Path)>,
    missing_centreline: Option<&[Segment]>,
    o: &EvalOptions,
) -> Result<EvalReport> {
    o.validate()?;
    let mut pred = read_mesh(pred_path)?;
    if o.min_island_mm2 > 0.0 {
        pred = pred.without_islands_below(o.min_island_mm2).0;
        if pred.is_empty() {
            return Err(CoreError::format(
                pred_path,
                format!("every connected component has less surface than min_island_mm2 = {} mm²", o.min_island_mm2),
            ));
        }
    }
    let gt = read_mesh(gt_path)?;
    check_same_frame(pred_path, &pred, &gt, gt_path)?;
    let split = match split {
        Some((p, m)) => {
            let (prior, missing) = (read_mesh(p)?, read_mesh(m)?);
            check_same_frame(p, &prior, &gt, gt_path)?;
            check_same_frame(m, &missing, &gt, gt_path)?;
            Some((prior, missing))
        }
        None => None,
    };
    Ok(evaluate(&pred, &gt, split.as_ref().map(|(p, m)| (p, m)), missing_centreline, o))
}

/// Refuses a surface (read from `path`: the prediction, or the prior / missing split) that
/// cannot be in the frame and unit of the truth (read from `gt_path`): one whose extent (box
/// diagonal) is under 1/50 or over 50 times the truth's (metres or micrometres for mm), or whose
/// box lies farther from the truth's than the larger extent.
/// Scores of such a pair are numbers about the files, not the surface.
fn check_same_frame(path: &Path, mesh: &TriMesh, gt: &TriMesh, gt_path: &Path) -> Result<()> {
    let (Some((plo, phi)), Some((glo, ghi))) = (mesh.bounds_mm(), gt.bounds_mm()) else { return Ok(()) };
    let (pd, gd) = ((phi - plo).length(), (ghi - glo).length());
    let ratio = pd / gd.max(1e-9);
    if !(1.0 / 50.0..=50.0).contains(&ratio) {
        return Err(CoreError::format(
            path,
            format!(
                "the surface spans {pd:.3} mm (box diagonal) where the ground truth ({}) spans {gd:.3} mm: \
                 not in the truth's unit (both must be in mm)",
                gt_path.display()
            ),
        ));
    }
    let gap = (glo - phi).max(plo - ghi).max(DVec3::ZERO).length();
    if gap > pd.max(gd) {
        return Err(CoreError::format(
            path,
            format!(
                "the surface's box lies {gap:.1} mm from the ground truth's ({}; extents {pd:.1} and {gd:.1} mm): \
                 not in the truth's frame (world mm, docs/DATA.md)",
                gt_path.display()
            ),
        ));
    }
    Ok(())
}

/// A case's ground truth, loaded once for scoring any number of surfaces.
pub struct CaseTruth {
    pub complete: TriMesh,
    /// `(prior, missing)` surfaces.
    pub split: Option<(TriMesh, TriMesh)>,
    /// The missing vessels' centreline (cases made from a tree).
    pub missing_centreline: Option<Vec<Segment>>,
    /// The whole true centreline (cases made from a tree).
    pub centreline: Option<Vec<Segment>>,
}

impl CaseTruth {
    /// The ground truth of `case`, `None` when it has none — or when its complete surface is not
    /// there (e.g. a copy of a case without its `gt/` folder): scoring is then skipped.
    pub fn load(case: &Case) -> Result<Option<Self>> {
        let Some(gt) = &case.file.ground_truth else { return Ok(None) };
        let complete_path = case.path(&gt.complete_mesh);
        if !complete_path.exists() {
            return Ok(None);
        }
        let complete = read_mesh(&complete_path)?;
        let split = match (&gt.missing_mesh, &case.file.prior) {
            (Some(missing), Some(prior)) => {
                let (prior_path, missing_path) = (case.path(&prior.mesh), case.path(missing));
                let (prior, missing) = (read_mesh(&prior_path)?, read_mesh(&missing_path)?);
                check_same_frame(&prior_path, &prior, &complete, &complete_path)?;
                check_same_frame(&missing_path, &missing, &complete, &complete_path)?;
                Some((prior, missing))
            }
            _ => None,
        };
        let threshold = case.file.prior.as_ref().and_then(|p| p.threshold_mm);
        let tree = match &gt.tree {
            Some(path) => Some(read_swc(&case.path(path))?.tree),
            None => None,
        };
        let missing_centreline = match (&tree, threshold) {
            (Some(tree), Some(d)) => Some(split_by_diameter(tree, d).missing),
            _ => None,
        };
        let centreline = tree.map(|t| t.segments());
        Ok(Some(Self { complete, split, missing_centreline, centreline }))
    }

    /// Scores `pred` against this truth.
    pub fn evaluate(&self, pred: &TriMesh, o: &EvalOptions) -> EvalReport {
        let split = self.split.as_ref().map(|(p, m)| (p, m));
        evaluate(pred, &self.complete, split, self.missing_centreline.as_deref(), o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::eval::surface_metrics::tests::sphere;

    fn opts() -> EvalOptions {
        EvalOptions { samples: 20_000, ..EvalOptions::default() }
    }

    #[test]
    fn a_mesh_against_itself_scores_zero() {
        let s = sphere(DVec3::ZERO, 10.0, 32);
        let r = evaluate(&s, &s, None, None, &opts());
        assert!(r.scores.overall.cd_sum_mm < 1e-9 && r.scores.overall.hd_mm < 1e-9, "{:?}", r.scores.overall);
        assert_eq!(r.paper.overall.cd_sum_mm, 0.0, "vertex sets of the same mesh coincide");
    }

    #[test]
    fn concentric_spheres_are_their_radius_difference_apart() {
        // Every point of one sphere is 2 mm from the other (up to the tessellation's sag,
        // 10·(1 − cos(π/128)) ≈ 0.003 mm, and the sampling density).
        let a = sphere(DVec3::ZERO, 10.0, 128);
        let b = sphere(DVec3::ZERO, 12.0, 128);
        let s = evaluate(&a, &b, None, None, &opts()).scores.overall;
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
        let s = evaluate(&pred, &gt, None, None, &opts()).scores.overall;
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
        let r = evaluate(&pred, &gt, Some((&prior, &missing)), None, &opts()).scores;
        let (roi, pri) = (r.roi.unwrap(), r.prior.unwrap());
        assert!((roi.cd_mean_mm - 1.0).abs() < 0.06, "ROI CD {}", roi.cd_mean_mm);
        assert!(pri.cd_mean_mm < 0.2, "prior-region CD {}", pri.cd_mean_mm);
    }

    /// A surface in metres, or shifted into another frame, is refused naming its file; a
    /// prediction a little off (a vessel missing, 5 mm shifted) is scored.
    #[test]
    fn surfaces_in_another_unit_or_frame_are_refused() {
        let gt = sphere(DVec3::ZERO, 50.0, 32);
        let path = Path::new("pred.obj");
        let scaled =
            |f: f64| TriMesh { vertices: gt.vertices.iter().map(|v| *v * f).collect(), faces: gt.faces.clone() };
        let shifted = |d: f64| TriMesh {
            vertices: gt.vertices.iter().map(|v| *v + DVec3::new(d, 0.0, 0.0)).collect(),
            faces: gt.faces.clone(),
        };
        let truth = Path::new("truth.obj");
        let e = check_same_frame(path, &scaled(0.001), &gt, truth).unwrap_err().to_string();
        assert!(e.contains("pred.obj") && e.contains("unit"), "{e}");
        let e = check_same_frame(path, &shifted(500.0), &gt, truth).unwrap_err().to_string();
        assert!(e.contains("pred.obj") && e.contains("truth.obj") && e.contains("frame"), "{e}");
        check_same_frame(path, &shifted(5.0), &gt, truth).unwrap();
        check_same_frame(path, &sphere(DVec3::new(20.0, 0.0, 0.0), 10.0, 16), &gt, truth).unwrap();
    }

    #[test]
    fn seeded_sampling_is_deterministic_and_icp_removes_a_shift() {
        let gt = sphere(DVec3::ZERO, 10.0, 64);
        let pred = sphere(DVec3::new(0.8, -0.5, 0.3), 10.0, 64);
        let a = evaluate(&pred, &gt, None, None, &opts());
        let b = evaluate(&pred, &gt, None, None, &opts());
        assert_eq!(a.scores.overall, b.scores.overall);
        let aligned = evaluate(&pred, &gt, None, None, &EvalOptions { icp: true, ..opts() });
        assert!(aligned.scores.overall.cd_mean_mm < 0.2 * a.scores.overall.cd_mean_mm);
        let t = aligned.icp_translation_mm.unwrap();
        assert!((t[0] + 0.8).abs() < 0.05 && (t[1] - 0.5).abs() < 0.05, "ICP shift {t:?}");
    }
}

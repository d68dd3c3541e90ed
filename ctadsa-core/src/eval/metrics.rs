//! Surface distances between a predicted and a reference vessel surface (mm).
//!
//! Both surfaces are represented by point sets (area-uniform samples, or vertices). With
//! `d(a, B)` the distance from `a` to the nearest point of `B`:
//! - `cd_mean` = ½ (mean_a d(a, B) + mean_b d(b, A)) — the Chamfer distance as an average;
//! - `cd_sum` = mean_a d(a, B) + mean_b d(b, A) — the reference implementation's convention;
//! - `hd` = max(max_a d(a, B), max_b d(b, A)) — the Hausdorff distance;
//! - `hd95` = max(P95_a d(a, B), P95_b d(b, A)) — the reference's "HD" (linear-interpolated
//!   percentile, as numpy's default).
//!
//! The ROI / prior split follows the reference: a predicted point belongs to the missing region
//! when it is nearer the missing-vessel surface than the prior surface; the ROI score compares
//! those points with the missing-vessel surface, the prior score the others with the prior.

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

use crate::stats::percentile;

/// Distances from every point of `from` to the nearest point of `to` (mm). Empty `to` gives
/// infinite distances.
pub fn nearest_distances(from: &[DVec3], to: &[DVec3]) -> Vec<f64> {
    nearest_points(from, to).into_iter().map(|(d, _)| d).collect()
}

/// For every point of `from`: the distance to the nearest point of `to` (mm) and its index.
/// Empty `to` gives `(∞, usize::MAX)`.
pub fn nearest_points(from: &[DVec3], to: &[DVec3]) -> Vec<(f64, usize)> {
    if to.is_empty() {
        return vec![(f64::INFINITY, usize::MAX); from.len()];
    }
    let pts: Vec<[f64; 3]> = to.iter().map(|p| p.to_array()).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&pts).expect("non-empty, finite points");
    let queries: Vec<[f64; 3]> = from.iter().map(|p| p.to_array()).collect();
    tree.query_batch(&queries)
        .nearest_one::<SquaredEuclidean<f64>>()
        .execute()
        .into_iter()
        .map(|r| (r.distance.sqrt(), r.item as usize))
        .collect()
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 }
}

/// Distances between two point sets (mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceScores {
    /// ½ (mean pred→gt + mean gt→pred).
    pub cd_mean_mm: f64,
    /// mean pred→gt + mean gt→pred (reference convention).
    pub cd_sum_mm: f64,
    /// Symmetric maximum.
    pub hd_mm: f64,
    /// max of the two one-sided 95th percentiles (reference convention).
    pub hd95_mm: f64,
    /// One-sided means, for diagnosis.
    pub pred_to_gt_mm: f64,
    pub gt_to_pred_mm: f64,
    pub pred_points: usize,
    pub gt_points: usize,
}

/// Scores of `pred` against `gt`. With an empty side every distance is `NaN` (nothing to
/// compare), except that an empty prediction against a non-empty truth is reported as
/// infinitely far.
pub fn compare(pred: &[DVec3], gt: &[DVec3]) -> SurfaceScores {
    let a = nearest_distances(pred, gt);
    let b = nearest_distances(gt, pred);
    scores_from_distances(&a, &b)
}

/// Scores from the one-sided distances `pred_to_gt` (one per predicted point) and `gt_to_pred`
/// (one per true point). An empty prediction against a non-empty truth is infinitely far.
pub fn scores_from_distances(pred_to_gt: &[f64], gt_to_pred: &[f64]) -> SurfaceScores {
    let (a, b) = (pred_to_gt, gt_to_pred);
    let missed = a.is_empty() && !b.is_empty();
    let (ma, mb) = if missed { (f64::INFINITY, f64::INFINITY) } else { (mean(a), mean(b)) };
    let max = |v: &[f64]| v.iter().copied().fold(f64::NAN, f64::max);
    let (pa, pb) = if missed { (f64::INFINITY, f64::INFINITY) } else { (percentile(a, 95.0), percentile(b, 95.0)) };
    SurfaceScores {
        cd_mean_mm: 0.5 * (ma + mb),
        cd_sum_mm: ma + mb,
        hd_mm: if missed { f64::INFINITY } else { max(a).max(max(b)) },
        hd95_mm: pa.max(pb),
        pred_to_gt_mm: ma,
        gt_to_pred_mm: mb,
        pred_points: a.len(),
        gt_points: b.len(),
    }
}

/// Splits predicted points into (missing region, prior region) by which reference surface is
/// nearer.
pub fn partition(pred: &[DVec3], prior: &[DVec3], missing: &[DVec3]) -> (Vec<DVec3>, Vec<DVec3>) {
    let to_prior = nearest_distances(pred, prior);
    let to_missing = nearest_distances(pred, missing);
    let mut roi = Vec::new();
    let mut rest = Vec::new();
    for ((p, dp), dm) in pred.iter().zip(&to_prior).zip(&to_missing) {
        if dm < dp {
            roi.push(*p);
        } else {
            rest.push(*p);
        }
    }
    (roi, rest)
}

/// Overall, ROI (missing vessels) and prior-region scores.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RegionScores {
    pub overall: SurfaceScores,
    pub roi: Option<SurfaceScores>,
    pub prior: Option<SurfaceScores>,
}

/// Scores of a prediction against the complete truth and, when the prior and missing surfaces
/// are given, per region.
pub fn region_scores(pred: &[DVec3], gt: &[DVec3], split: Option<(&[DVec3], &[DVec3])>) -> RegionScores {
    let overall = compare(pred, gt);
    let (roi, prior) = match split {
        Some((prior_pts, missing_pts)) => {
            let (p_roi, p_prior) = partition(pred, prior_pts, missing_pts);
            (Some(compare(&p_roi, missing_pts)), Some(compare(&p_prior, prior_pts)))
        }
        None => (None, None),
    };
    RegionScores { overall, roi, prior }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_point_sets() {
        let a = [DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0)];
        let b = [DVec3::new(0.0, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0), DVec3::new(4.0, 0.0, 0.0)];
        let s = compare(&a, &b);
        // a→b: 0, 0. b→a: 0, 0, 3.  Means 0 and 1.
        assert_eq!(s.pred_to_gt_mm, 0.0);
        assert_eq!(s.gt_to_pred_mm, 1.0);
        assert_eq!(s.cd_sum_mm, 1.0);
        assert_eq!(s.cd_mean_mm, 0.5);
        assert_eq!(s.hd_mm, 3.0);
        // P95 of [0, 0, 3] with linear interpolation: position 1.9 → 0 + 0.9·3 = 2.7.
        assert!((s.hd95_mm - 2.7).abs() < 1e-12);
        let same = compare(&a, &a);
        assert_eq!((same.cd_sum_mm, same.hd_mm), (0.0, 0.0));
        assert!(compare(&[], &a).cd_mean_mm.is_infinite());
    }

    #[test]
    fn percentile_matches_numpy_linear() {
        assert_eq!(percentile(&[1.0, 2.0, 3.0, 4.0], 50.0), 2.5);
        assert_eq!(percentile(&[5.0], 95.0), 5.0);
        assert!((percentile(&[0.0, 10.0], 95.0) - 9.5).abs() < 1e-12);
    }

    #[test]
    fn partition_by_nearest_reference() {
        let prior = [DVec3::new(0.0, 0.0, 0.0)];
        let missing = [DVec3::new(10.0, 0.0, 0.0)];
        let pred = [DVec3::new(1.0, 0.0, 0.0), DVec3::new(9.0, 0.0, 0.0), DVec3::new(6.0, 0.0, 0.0)];
        let (roi, rest) = partition(&pred, &prior, &missing);
        assert_eq!(roi, vec![DVec3::new(9.0, 0.0, 0.0), DVec3::new(6.0, 0.0, 0.0)]);
        assert_eq!(rest, vec![DVec3::new(1.0, 0.0, 0.0)]);
        let r = region_scores(&pred, &[prior[0], missing[0]], Some((&prior, &missing)));
        let roi_scores = r.roi.unwrap();
        // pred ROI {9, 6} vs missing {10}: 1, 4 → mean 2.5; missing→pred: 1.
        assert!((roi_scores.cd_sum_mm - 3.5).abs() < 1e-12);
    }
}

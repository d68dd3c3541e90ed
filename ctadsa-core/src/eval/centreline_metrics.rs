//! A completed centreline against the case's true tree: how much of the missing vessels it
//! found, how much of what it added is real, and how wide it says the vessels are.
//!
//! Both centrelines are taken as points every ≤ 0.1 mm ([`centreline_points`]). A true point
//! of radius `r` is *found* when a predicted centreline point lies within `r` +
//! [`RECALL_SLACK_MM`] (inside the true vessel, up to the slack); a predicted new point is
//! *true* when it lies that close to the nearest true centreline point (any vessel of the tree),
//! and its radius error is then measured against that point's radius.

use serde::{Deserialize, Serialize};

use crate::data::tree::{KIND_NEW_VESSEL, Segment, VesselTree};
use crate::eval::metrics::nearest_points;
use crate::eval::surface_metrics::{CentrelinePoint, RECALL_SLACK_MM, centreline_points};

/// Scores of a predicted centreline (lengths and radii in mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CentrelineScores {
    /// Length of the true missing vessels' centreline.
    pub missing_length_mm: f64,
    /// Fraction of that length found by the predicted centreline (NaN without missing length).
    pub recall: f64,
    /// Length of the predicted centreline marked new.
    pub new_length_mm: f64,
    /// Fraction of the new length on a true vessel (NaN without new length).
    pub precision: f64,
    /// Mean |predicted − true radius| over the new length on a true vessel (length-weighted).
    pub radius_error_mm: f64,
    /// Mean (predicted − true radius) over the same points.
    pub radius_bias_mm: f64,
}

/// Per-segment verdicts, for pictures.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CentrelineMatch {
    /// For each true missing segment: whether most of its length was found.
    pub missing_found: Vec<bool>,
    /// The predicted new segments, and for each whether most of its length is on a true vessel.
    pub new_segments: Vec<Segment>,
    pub new_true: Vec<bool>,
    /// For each new segment: the part of its length on a true vessel (mm).
    pub new_true_length_mm: Vec<f64>,
}

/// Points of every segment, each tagged with its segment's index.
pub(crate) fn tagged_points(segments: &[Segment]) -> (Vec<CentrelinePoint>, Vec<usize>) {
    let mut points = Vec::new();
    let mut tags = Vec::new();
    for (k, s) in segments.iter().enumerate() {
        let p = centreline_points(std::slice::from_ref(s));
        tags.extend(std::iter::repeat_n(k, p.len()));
        points.extend(p);
    }
    (points, tags)
}

/// Length-weighted majority vote per segment.
fn majority(points: &[CentrelinePoint], tags: &[usize], hit: &[bool], segments: usize) -> Vec<bool> {
    let mut yes = vec![0.0; segments];
    let mut all = vec![0.0; segments];
    for ((p, &t), &h) in points.iter().zip(tags).zip(hit) {
        all[t] += p.length_mm;
        if h {
            yes[t] += p.length_mm;
        }
    }
    yes.iter().zip(&all).map(|(y, a)| *a > 0.0 && 2.0 * y >= *a).collect()
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 { a / b } else { f64::NAN }
}

/// Scores `predicted` (nodes of type [`KIND_NEW_VESSEL`] are its new vessels) against the
/// true `missing` segments and the whole true tree `truth`.
pub fn score_centreline(
    predicted: &VesselTree,
    missing: &[Segment],
    truth: &[Segment],
) -> (CentrelineScores, CentrelineMatch) {
    let segments = predicted.segments();
    let pred_points = centreline_points(&segments);
    let pred_positions: Vec<_> = pred_points.iter().map(|p| p.position_mm).collect();

    let (missing_points, missing_tags) = tagged_points(missing);
    let found: Vec<bool> =
        nearest_points(&missing_points.iter().map(|p| p.position_mm).collect::<Vec<_>>(), &pred_positions)
            .iter()
            .zip(&missing_points)
            .map(|((d, _), q)| *d <= q.radius_mm + RECALL_SLACK_MM)
            .collect();
    let missing_length: f64 = missing_points.iter().map(|p| p.length_mm).sum();
    let found_length: f64 = missing_points.iter().zip(&found).filter(|(_, f)| **f).map(|(p, _)| p.length_mm).sum();

    let new_segments: Vec<Segment> =
        segments.iter().copied().filter(|s| predicted.nodes[s.child].kind == KIND_NEW_VESSEL).collect();
    let (new_points, new_tags) = tagged_points(&new_segments);
    let truth_points = centreline_points(truth);
    let truth_positions: Vec<_> = truth_points.iter().map(|p| p.position_mm).collect();
    let nearest = nearest_points(&new_points.iter().map(|p| p.position_mm).collect::<Vec<_>>(), &truth_positions);
    let on_truth: Vec<bool> =
        nearest.iter().map(|&(d, i)| i != usize::MAX && d <= truth_points[i].radius_mm + RECALL_SLACK_MM).collect();
    let (mut new_length, mut true_length, mut abs_err, mut err) = (0.0, 0.0, 0.0, 0.0);
    for ((p, &(_, i)), &ok) in new_points.iter().zip(&nearest).zip(&on_truth) {
        new_length += p.length_mm;
        if ok {
            let e = p.radius_mm - truth_points[i].radius_mm;
            true_length += p.length_mm;
            abs_err += e.abs() * p.length_mm;
            err += e * p.length_mm;
        }
    }
    let scores = CentrelineScores {
        missing_length_mm: missing_length,
        recall: ratio(found_length, missing_length),
        new_length_mm: new_length,
        precision: ratio(true_length, new_length),
        radius_error_mm: ratio(abs_err, true_length),
        radius_bias_mm: ratio(err, true_length),
    };
    let mut new_true_length_mm = vec![0.0; new_segments.len()];
    for ((p, &t), _) in new_points.iter().zip(&new_tags).zip(&on_truth).filter(|(_, ok)| **ok) {
        new_true_length_mm[t] += p.length_mm;
    }
    let verdicts = CentrelineMatch {
        missing_found: majority(&missing_points, &missing_tags, &found, missing.len()),
        new_true: majority(&new_points, &new_tags, &on_truth, new_segments.len()),
        new_segments,
        new_true_length_mm,
    };
    (scores, verdicts)
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::data::tree::{KIND_PRIOR_VESSEL, TreeNode};

    fn seg(a: DVec3, b: DVec3, r: f64) -> Segment {
        Segment { child: 0, start_mm: a, end_mm: b, start_radius_mm: r, end_radius_mm: r }
    }

    /// A chain of nodes along `points` with one radius and type.
    fn chain(tree: &mut VesselTree, points: &[DVec3], r: f64, kind: i32, parent: Option<usize>) {
        let mut parent = parent;
        for &p in points {
            tree.nodes.push(TreeNode { id: 0, kind, position_mm: p, radius_mm: r, parent });
            parent = Some(tree.nodes.len() - 1);
        }
    }

    #[test]
    fn half_a_missing_vessel_and_one_false_branch() {
        let x = |v: f64| DVec3::new(v, 0.0, 0.0);
        // Truth: prior trunk x ∈ [0, 20] (r 1.7), missing vessel y ∈ [0, 20] at x = 10 (r 0.5).
        let prior = seg(x(0.0), x(20.0), 1.7);
        let missing = seg(DVec3::new(10.0, 0.0, 0.0), DVec3::new(10.0, 20.0, 0.0), 0.5);
        // Prediction: the trunk; the missing vessel up to y = 10, 0.3 mm off its axis and
        // 0.2 mm too wide; a false branch of 10 mm along −y.
        let mut tree = VesselTree::default();
        chain(&mut tree, &[x(0.0), x(10.0), x(20.0)], 2.0, KIND_PRIOR_VESSEL, None);
        let found: Vec<DVec3> = (0..=10).map(|k| DVec3::new(10.3, k as f64, 0.0)).collect();
        chain(&mut tree, &found, 0.7, KIND_NEW_VESSEL, Some(1));
        let false_branch: Vec<DVec3> = (1..=10).map(|k| DVec3::new(10.0, -(k as f64), 0.0)).collect();
        chain(&mut tree, &false_branch, 0.5, KIND_NEW_VESSEL, Some(1));
        let (s, m) = score_centreline(&tree, &[missing], &[prior, missing]);
        assert!((s.missing_length_mm - 20.0).abs() < 1e-9);
        // Found: y ≤ 10 plus what lies within 1 mm of the end point (10.3, 10).
        let expected = (10.0 + (1.0f64 - 0.09).sqrt()) / 20.0;
        assert!((s.recall - expected).abs() < 0.01, "recall {} vs {expected}", s.recall);
        // New: the found part (0.3 mm to its first node, then 10) and the false branch (10 mm),
        // whose first 2.2 mm lie within the trunk's radius + 0.5 mm.
        assert!((s.new_length_mm - 20.3).abs() < 1e-6, "{}", s.new_length_mm);
        let precision = (10.3 + 2.2) / 20.3;
        assert!((s.precision - precision).abs() < 0.01, "precision {} vs {precision}", s.precision);
        // Radius errors: 0.2 mm on the found part (bar its first 0.3 mm, nearer the trunk), 1.2 mm
        // on the false branch's true first 2.2 mm (measured against the trunk).
        let error = (10.0 * 0.2 + 2.2 * 1.2) / 12.5;
        assert!((s.radius_error_mm - error).abs() < 0.03, "radius error {} vs {error}", s.radius_error_mm);
        assert!(s.radius_bias_mm < 0.0, "the false branch is too thin for the trunk");
        assert_eq!(m.missing_found, vec![true]);
        assert_eq!(m.new_true, [vec![true; 11], vec![true, true], vec![false; 8]].concat());
    }
}

//! Splitting a tree into the part a CTA would show (the prior) and the part it misses, by
//! vessel diameter.

use serde::{Deserialize, Serialize};

use super::{Segment, VesselTree};
use crate::error::{CoreError, Result};

/// How to choose the diameter below which vessels are missing from the prior.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PriorThreshold {
    /// Keep segments whose diameter is at least this (mm); the paper uses 1.0, 1.5, 2.0.
    DiameterMm(f64),
    /// Drop the thinnest segments that make up this percentage of the centreline length
    /// (useful for trees such as BraVa whose vessels are mostly thin).
    LengthPercentile(f64),
}

impl PriorThreshold {
    /// The diameter threshold (mm) this resolves to on `tree`.
    pub fn diameter_mm(&self, tree: &VesselTree) -> Result<f64> {
        match *self {
            PriorThreshold::DiameterMm(d) if d.is_finite() && d >= 0.0 => Ok(d),
            PriorThreshold::DiameterMm(d) => Err(CoreError::invalid(format!("prior threshold {d} mm is not ≥ 0"))),
            PriorThreshold::LengthPercentile(p) if (0.0..=100.0).contains(&p) => {
                Ok(diameter_at_length_percentile(&tree.segments(), p))
            }
            PriorThreshold::LengthPercentile(p) => {
                Err(CoreError::invalid(format!("length percentile {p} is not in [0, 100]")))
            }
        }
    }
}

/// The smallest segment diameter `d` such that segments thinner than `d` hold at least `p`% of
/// the total centreline length (0 for an empty tree).
pub fn diameter_at_length_percentile(segments: &[Segment], p: f64) -> f64 {
    let mut by_d: Vec<(f64, f64)> = segments.iter().map(|s| (s.diameter_mm(), s.length_mm())).collect();
    by_d.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = by_d.iter().map(|s| s.1).sum();
    if total <= 0.0 {
        return 0.0;
    }
    let target = total * p / 100.0;
    let mut below = 0.0;
    for (d, len) in by_d {
        if below >= target {
            return d;
        }
        below += len;
    }
    f64::INFINITY
}

/// Segments of a tree split by a diameter threshold.
#[derive(Debug, Clone)]
pub struct PriorSplit {
    /// The threshold used (mm).
    pub threshold_mm: f64,
    /// Segments with diameter ≥ threshold (what the CTA shows).
    pub prior: Vec<Segment>,
    /// The others (what the CTA misses).
    pub missing: Vec<Segment>,
}

/// Splits the segments of `tree` at `threshold_mm`: a segment is in the prior iff its diameter
/// (twice its mean end radius) is at least the threshold.
pub fn split_by_diameter(tree: &VesselTree, threshold_mm: f64) -> PriorSplit {
    let (prior, missing) = tree.segments().into_iter().partition(|s| s.diameter_mm() >= threshold_mm);
    PriorSplit { threshold_mm, prior, missing }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::tree::swc::parse_swc;

    #[test]
    fn keeps_exactly_the_segments_at_or_above_the_threshold() {
        // Diameters (2 × mean radius): 4.0, 3.0, 2.0 (= threshold), 1.0.
        let t = parse_swc("1 1 0 0 0 2 -1\n2 1 10 0 0 2 1\n3 1 20 0 0 1 2\n4 1 30 0 0 1 3\n5 1 30 10 0 0.5 4\n5b")
            .map(|f| f.tree);
        let tree = t.unwrap();
        let split = split_by_diameter(&tree, 2.0);
        let kept: Vec<f64> = split.prior.iter().map(|s| s.diameter_mm()).collect();
        let dropped: Vec<f64> = split.missing.iter().map(|s| s.diameter_mm()).collect();
        assert_eq!(kept, vec![4.0, 3.0, 2.0]);
        assert_eq!(dropped, vec![1.5]);
        assert!(split_by_diameter(&tree, 10.0).prior.is_empty());
        assert!(split_by_diameter(&tree, 0.0).missing.is_empty());
    }

    #[test]
    fn length_percentile_threshold() {
        let tree = parse_swc("1 1 0 0 0 2 -1\n2 1 10 0 0 2 1\n3 1 20 0 0 1 2\n4 1 50 0 0 1 3\n").unwrap().tree;
        // Segments: d=4 (10 mm), d=3 (10 mm), d=2 (30 mm). 60% of 50 mm = 30 mm → threshold 3.
        assert_eq!(PriorThreshold::LengthPercentile(60.0).diameter_mm(&tree).unwrap(), 3.0);
        assert_eq!(PriorThreshold::LengthPercentile(0.0).diameter_mm(&tree).unwrap(), 2.0);
        assert!(PriorThreshold::LengthPercentile(120.0).diameter_mm(&tree).is_err());
    }
}

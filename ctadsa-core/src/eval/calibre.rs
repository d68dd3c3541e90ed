//! The missing vessels by calibre (`ctadsa diagnose`): for each band of true diameter, how much
//! of the missing centreline the completed surface found and how much the completed centreline
//! found, by the same criteria as the run's scores (a point within its radius +
//! [`RECALL_SLACK_MM`] of the surface, or of a predicted centreline point of any kind).
//!
//! The thinnest vessels are most of the missing length on BraVa trees and the hardest to place
//! from two views; a single recall hides that.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::data::tree::VesselTree;
use crate::eval::diagnose::{ClassifiedPoint, PointClass};
use crate::eval::metrics::nearest_distances;
use crate::eval::surface_metrics::{RECALL_SLACK_MM, centreline_points};

/// Upper edges (mm) of the diameter bands; the last band is open.
pub const DIAMETER_EDGES_MM: [f64; 3] = [0.8, 1.0, 1.2];

/// One band of true diameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CalibreBand {
    /// Diameters in `[from_mm, to_mm)`; `to_mm` is `None` for the open last band.
    pub from_mm: f64,
    pub to_mm: Option<f64>,
    /// Missing centreline length in the band (mm) and its share of all the missing length.
    pub length_mm: f64,
    pub share: f64,
    /// Fraction of the band's length the completed surface found.
    pub surface_recall: f64,
    /// Fraction the completed centreline found (`None` without a centreline).
    pub centreline_recall: Option<f64>,
}

/// The bands of [`DIAMETER_EDGES_MM`] over the `points` of [`crate::eval::diagnose::diagnose`]
/// (those without missing length left out);
/// `centreline` is the run's completed centreline (every node kind counts, as in the recall of
/// [`crate::eval::centreline_metrics::score_centreline`]).
pub fn by_calibre(points: &[ClassifiedPoint], centreline: Option<&VesselTree>) -> Vec<CalibreBand> {
    let to_centreline: Option<Vec<f64>> = centreline.map(|tree| {
        let predicted: Vec<DVec3> = centreline_points(&tree.segments()).iter().map(|p| p.position_mm).collect();
        let positions: Vec<DVec3> = points.iter().map(|p| DVec3::from_array(p.position_mm)).collect();
        nearest_distances(&positions, &predicted)
    });
    let total: f64 = points.iter().map(|p| p.length_mm).sum();
    let mut edges = vec![0.0];
    edges.extend(DIAMETER_EDGES_MM);
    edges
        .iter()
        .enumerate()
        .filter_map(|(b, &from_mm)| {
            let to_mm = edges.get(b + 1).copied();
            let (mut length, mut surface, mut traced) = (0.0, 0.0, 0.0);
            for (k, p) in points.iter().enumerate() {
                let diameter = 2.0 * p.radius_mm;
                if diameter < from_mm || to_mm.is_some_and(|t| diameter >= t) {
                    continue;
                }
                length += p.length_mm;
                if p.class == PointClass::Found {
                    surface += p.length_mm;
                }
                if to_centreline.as_ref().is_some_and(|d| d[k] <= p.radius_mm + RECALL_SLACK_MM) {
                    traced += p.length_mm;
                }
            }
            (length > 0.0).then(|| CalibreBand {
                from_mm,
                to_mm,
                length_mm: length,
                share: length / total,
                surface_recall: surface / length,
                centreline_recall: to_centreline.as_ref().map(|_| traced / length),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::tree::{KIND_NEW_VESSEL, TreeNode};

    fn point(x: f64, radius_mm: f64, class: PointClass) -> ClassifiedPoint {
        ClassifiedPoint {
            position_mm: [x, 0.0, 0.0],
            radius_mm,
            length_mm: 1.0,
            class,
            to_seed_mm: 0.0,
            to_surface_mm: 0.0,
            density_over_level: 1.0,
        }
    }

    #[test]
    fn bands_split_the_length_by_diameter_and_score_each_band_alone() {
        // Thin points at x = 0..4 (diameter 0.6 mm), thick ones at x = 10..12 (diameter 1.4 mm).
        let mut points: Vec<_> = (0..4).map(|i| point(i as f64, 0.3, PointClass::Found)).collect();
        points[3].class = PointClass::Faded;
        points.extend((10..12).map(|i| point(i as f64, 0.7, PointClass::BehindPrior)));
        // A centreline along the thin points' first two, 0.5 mm off the axis (within 0.3 + 0.5).
        let node = |x: f64, parent| TreeNode {
            id: 0,
            position_mm: DVec3::new(x, 0.5, 0.0),
            radius_mm: 0.3,
            kind: KIND_NEW_VESSEL,
            parent,
        };
        let tree = VesselTree { nodes: vec![node(-0.2, None), node(1.2, Some(0))] };
        let bands = by_calibre(&points, Some(&tree));
        // The two bands between hold no points and are left out.
        assert_eq!(bands.len(), 2);
        let (thin, thick) = (&bands[0], &bands[1]);
        assert_eq!((thin.from_mm, thin.to_mm), (0.0, Some(0.8)));
        assert_eq!((thick.from_mm, thick.to_mm), (1.2, None));
        assert!((thin.length_mm - 4.0).abs() < 1e-12 && (thick.length_mm - 2.0).abs() < 1e-12);
        assert!((thin.share - 4.0 / 6.0).abs() < 1e-12);
        assert!((thin.surface_recall - 0.75).abs() < 1e-12, "{}", thin.surface_recall);
        assert!((thin.centreline_recall.unwrap() - 0.5).abs() < 1e-12, "{:?}", thin.centreline_recall);
        assert_eq!(thick.surface_recall, 0.0);
        assert_eq!(thick.centreline_recall, Some(0.0));
        // Without a centreline the surface recall stands alone.
        assert!(by_calibre(&points, None).iter().all(|b| b.centreline_recall.is_none()));
    }
}

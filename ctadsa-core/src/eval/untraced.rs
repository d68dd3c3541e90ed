//! Where the completed centreline misses what the completed surface found (`ctadsa diagnose`):
//! the missing centreline the surface finds (a point within its radius + [`RECALL_SLACK_MM`] of
//! it) and the centreline does not (no centreline point that close), by what the nearest
//! centreline point is. The gap between the two recalls is mostly thin vessels; where it lies
//! says whether the graph's tracing or the density's shape loses them:
//! - *beside the prior*: the nearest centreline point is a prior vessel's, within
//!   [`NEAR_MM`]: a thin vessel running along a prior one, inside the prior path's cover;
//! - *beside a new branch*: a new branch's, within [`NEAR_MM`]: the branch runs off the
//!   vessel's axis (a wide or merged blob of density, a ghost traced instead of its neighbour);
//! - *no centreline near*: none within [`NEAR_MM`] (a part left out of the graph: a speck, a
//!   dropped branch, a pruned end).

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::data::tree::{KIND_PRIOR_VESSEL, VesselTree};
use crate::eval::centreline_metrics::tagged_points;
use crate::eval::diagnose::{ClassifiedPoint, PointClass};
use crate::eval::metrics::nearest_points;
use crate::eval::surface_metrics::RECALL_SLACK_MM;

/// How far (mm) the nearest centreline point may lie and still be the one the point is beside.
pub const NEAR_MM: f64 = 2.5;

/// Fractions of the missing centreline length that the surface finds and the centreline does
/// not, by where the nearest centreline point lies (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Untraced {
    pub beside_prior: f64,
    pub beside_new: f64,
    pub none_near: f64,
}

impl Untraced {
    /// The whole gap: surface recall less the part the centreline also finds.
    pub fn total(&self) -> f64 {
        self.beside_prior + self.beside_new + self.none_near
    }
}

/// The gap over the `points` of [`crate::eval::diagnose::diagnose`] and the run's completed
/// `centreline` (every node kind counts as found, as in the recall of
/// [`crate::eval::centreline_metrics::score_centreline`]).
pub fn untraced(points: &[ClassifiedPoint], centreline: &VesselTree) -> Untraced {
    let segments = centreline.segments();
    let (predicted, tags) = tagged_points(&segments);
    let predicted: Vec<DVec3> = predicted.iter().map(|p| p.position_mm).collect();
    let prior_kind = |k: usize| centreline.nodes[segments[tags[k]].child].kind == KIND_PRIOR_VESSEL;
    let positions: Vec<DVec3> = points.iter().map(|p| DVec3::from_array(p.position_mm)).collect();
    let nearest = nearest_points(&positions, &predicted);
    let total: f64 = points.iter().map(|p| p.length_mm).sum();
    let mut gap = Untraced { beside_prior: 0.0, beside_new: 0.0, none_near: 0.0 };
    if !(total > 0.0) {
        return gap;
    }
    for (p, &(distance, k)) in points.iter().zip(&nearest) {
        if p.class != PointClass::Found || distance <= p.radius_mm + RECALL_SLACK_MM {
            continue;
        }
        let share = p.length_mm / total;
        if distance > NEAR_MM {
            gap.none_near += share;
        } else if prior_kind(k) {
            gap.beside_prior += share;
        } else {
            gap.beside_new += share;
        }
    }
    gap
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::tree::{KIND_NEW_VESSEL, TreeNode};

    fn point(x: f64, class: PointClass) -> ClassifiedPoint {
        ClassifiedPoint {
            position_mm: [x, 0.0, 0.0],
            radius_mm: 0.3,
            length_mm: 1.0,
            class,
            to_seed_mm: 0.0,
            to_surface_mm: 0.0,
            density_over_level: 1.0,
        }
    }

    fn line(from: DVec3, to: DVec3, kind: i32, first: usize) -> [TreeNode; 2] {
        let node = |p: DVec3, parent| TreeNode { id: 0, position_mm: p, radius_mm: 0.5, kind, parent };
        [node(from, None), node(to, Some(first))]
    }

    /// Found points in four groups: on a new branch (traced), 1.5 mm from a prior vessel, 2 mm
    /// from a new branch, far from everything; a point the surface missed counts in no class.
    #[test]
    fn the_gap_is_split_by_the_nearest_centreline_point() {
        let mut points: Vec<_> =
            [0.5, 1.5, 10.5, 11.5, 20.5, 21.5, 22.5, 30.5, 31.5].map(|x| point(x, PointClass::Found)).into();
        points.push(point(0.5, PointClass::Faded));
        let mut nodes = Vec::new();
        nodes.extend(line(DVec3::new(0.0, 0.0, 0.0), DVec3::new(2.0, 0.0, 0.0), KIND_NEW_VESSEL, 0));
        nodes.extend(line(DVec3::new(10.0, 1.5, 0.0), DVec3::new(12.0, 1.5, 0.0), KIND_PRIOR_VESSEL, 2));
        nodes.extend(line(DVec3::new(20.0, 2.0, 0.0), DVec3::new(23.0, 2.0, 0.0), KIND_NEW_VESSEL, 4));
        let gap = untraced(&points, &VesselTree { nodes });
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        assert!(close(gap.beside_prior, 0.2), "{gap:?}");
        assert!(close(gap.beside_new, 0.3), "{gap:?}");
        assert!(close(gap.none_near, 0.2), "{gap:?}");
        assert!(close(gap.total(), 0.7));
        let empty = untraced(&points, &VesselTree::default());
        assert!(close(empty.none_near, 0.9), "no centreline: the whole surface recall");
    }
}

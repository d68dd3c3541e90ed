//! Topology scores of a completed vessel volume against the ground truth, as the vessel
//! segmentation field ranks methods (TopCoW, TopBrain): clDice and the Betti-0 error.
//!
//! - **clDice** (Shit et al., CVPR 2021): `2·Tprec·Tsens / (Tprec + Tsens)` with the topology
//!   precision `Tprec` = the share of the predicted skeleton inside the true volume and the
//!   topology sensitivity `Tsens` = the share of the true skeleton inside the predicted volume.
//!   The skeletons here are centreline graphs (the run's TEASAR centreline, the case's true
//!   tree), measured by length (points every [`STEP_MM`] along each segment) instead of by
//!   skeleton voxels: the same ratios in the limit of small voxels, without a thinning step.
//! - **Betti-0 error**: `|β₀(predicted) − β₀(true)|`, the difference of the numbers of
//!   26-connected components of the two volumes on one grid.
//!
//! `docs/METRICS.md` defines them beside the distances.

use serde::{Deserialize, Serialize};

use crate::data::mesh::TriMesh;
use crate::data::mesh::voxelize::voxelize_union;
use crate::data::tree::Segment;
use crate::data::volume::skeleton::{SkeletonParams, skeletonize};
use crate::data::volume::{BoxMm, Grid, Volume};
use crate::error::{CoreError, Result};

/// Spacing (mm) of the points along the skeletons.
pub const STEP_MM: f64 = 0.1;

/// Topology scores of one prediction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TopologyScores {
    /// clDice in [0, 1] (1: each skeleton lies wholly inside the other volume).
    pub cl_dice: f64,
    /// Share of the predicted skeleton's length inside the true volume.
    pub topology_precision: f64,
    /// Share of the true skeleton's length inside the predicted volume.
    pub topology_sensitivity: f64,
    /// 26-connected components of the predicted and the true volume.
    pub components: usize,
    pub true_components: usize,
    /// `|components − true_components|`.
    pub betti0_error: usize,
}

/// Number of 26-connected components of the set voxels.
pub fn components_26(solid: &Volume<u8>) -> usize {
    let grid = solid.grid;
    let mut reached = vec![false; solid.data.len()];
    let mut count = 0;
    for start in 0..solid.data.len() {
        if solid.data[start] == 0 || reached[start] {
            continue;
        }
        count += 1;
        reached[start] = true;
        grid.flood_fill_26(&mut reached, vec![start], |j| solid.data[j] != 0);
    }
    count
}

/// The share of the length of `segments` whose points (every [`STEP_MM`]) lie in `solid`; `NaN`
/// for no length.
pub fn share_inside(segments: &[Segment], solid: &Volume<u8>) -> f64 {
    let (mut inside, mut total) = (0.0, 0.0);
    for s in segments {
        let length = s.start_mm.distance(s.end_mm);
        let n = (length / STEP_MM).ceil().max(1.0) as usize;
        let piece = length / n as f64;
        for k in 0..n {
            let p = s.start_mm.lerp(s.end_mm, (k as f64 + 0.5) / n as f64);
            total += piece;
            if solid.is_set_at(p) {
                inside += piece;
            }
        }
    }
    if total > 0.0 { inside / total } else { f64::NAN }
}

/// clDice and the Betti-0 error of `predicted` against `truth` (volumes on one grid) with their
/// skeletons `predicted_skeleton` and `true_skeleton`.
pub fn topology_scores(
    predicted: &Volume<u8>,
    truth: &Volume<u8>,
    predicted_skeleton: &[Segment],
    true_skeleton: &[Segment],
) -> TopologyScores {
    let topology_precision = share_inside(predicted_skeleton, truth);
    let topology_sensitivity = share_inside(true_skeleton, predicted);
    let sum = topology_precision + topology_sensitivity;
    let cl_dice = if sum > 0.0 { 2.0 * topology_precision * topology_sensitivity / sum } else { 0.0 };
    let (components, true_components) = (components_26(predicted), components_26(truth));
    TopologyScores {
        cl_dice,
        topology_precision,
        topology_sensitivity,
        components,
        true_components,
        betti0_error: components.abs_diff(true_components),
    }
}

/// [`topology_scores`] of two surfaces (`ctadsa eval`): both voxelised on one grid of
/// `voxel_mm` covering them (1 mm margin; each connected component on its own, so that a
/// prior joined with new vessels is filled where they overlap), the predicted skeleton traced by TEASAR in its solid
/// (as a run's centreline, default settings), the true skeleton `true_tree`'s segments.
pub fn topology_of_surfaces(
    predicted: &TriMesh,
    truth: &TriMesh,
    true_tree: &[Segment],
    voxel_mm: f64,
) -> Result<TopologyScores> {
    let (lo_p, hi_p) = predicted.bounds_mm().ok_or_else(|| CoreError::invalid("the predicted surface is empty"))?;
    let (lo_t, hi_t) = truth.bounds_mm().ok_or_else(|| CoreError::invalid("the true surface is empty"))?;
    let (lo, hi) = (lo_p.min(lo_t) - 1.0, hi_p.max(hi_t) + 1.0);
    let grid = Grid::covering(&BoxMm { min_mm: lo.to_array(), max_mm: hi.to_array() }, voxel_mm)?;
    let (solid, true_solid) = (voxelize_union(predicted, grid), voxelize_union(truth, grid));
    let skeleton = skeletonize(&solid, &SkeletonParams::default()).segments();
    Ok(topology_scores(&solid, &true_solid, &skeleton, true_tree))
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::data::volume::Grid;
    use crate::data::volume::rasterize::rasterize_segments;

    fn tube(from: DVec3, to: DVec3) -> Segment {
        Segment { child: 0, start_mm: from, end_mm: to, start_radius_mm: 1.0, end_radius_mm: 1.0 }
    }

    fn grid() -> Grid {
        Grid { dims: [80, 30, 30], spacing_mm: [0.5; 3], origin_mm: [-20.0, -7.5, -7.5] }
    }

    fn solid(segments: &[Segment]) -> Volume<u8> {
        rasterize_segments(segments, grid(), 2).map(|v| (v > 0.5) as u8)
    }

    #[test]
    fn surfaces_are_scored_on_their_own_grid() {
        use crate::data::mesh::tubes::segment_tubes;
        let t = [tube(DVec3::new(-15.0, 0.0, 0.0), DVec3::new(15.0, 0.0, 0.0))];
        let mesh = segment_tubes(&t, 1.0, 16);
        let s = topology_of_surfaces(&mesh, &mesh, &t, 0.25).unwrap();
        assert!(s.cl_dice > 0.95 && s.betti0_error == 0, "{s:?}");
        // Two separate pieces of the tube against the whole one.
        let halves = [
            tube(DVec3::new(-15.0, 0.0, 0.0), DVec3::new(-3.0, 0.0, 0.0)),
            tube(DVec3::new(3.0, 0.0, 0.0), DVec3::new(15.0, 0.0, 0.0)),
        ];
        let s = topology_of_surfaces(&segment_tubes(&halves, 1.0, 16), &mesh, &t, 0.25).unwrap();
        assert_eq!((s.components, s.true_components, s.betti0_error), (2, 1, 1), "{s:?}");
        assert!(topology_of_surfaces(&TriMesh::default(), &mesh, &t, 0.25).is_err());
    }

    #[test]
    fn a_tube_against_itself_is_perfect() {
        let t = [tube(DVec3::new(-15.0, 0.0, 0.0), DVec3::new(15.0, 0.0, 0.0))];
        let v = solid(&t);
        let s = topology_scores(&v, &v, &t, &t);
        assert_eq!((s.cl_dice, s.components, s.true_components, s.betti0_error), (1.0, 1, 1, 0), "{s:?}");
    }

    #[test]
    fn a_tube_cut_in_two_has_betti0_error_one() {
        let whole = [tube(DVec3::new(-15.0, 0.0, 0.0), DVec3::new(15.0, 0.0, 0.0))];
        let cut = [
            tube(DVec3::new(-15.0, 0.0, 0.0), DVec3::new(-2.0, 0.0, 0.0)),
            tube(DVec3::new(2.0, 0.0, 0.0), DVec3::new(15.0, 0.0, 0.0)),
        ];
        let s = topology_scores(&solid(&cut), &solid(&whole), &cut, &whole);
        assert_eq!((s.components, s.true_components, s.betti0_error), (2, 1, 1), "{s:?}");
        assert_eq!(s.topology_precision, 1.0, "the cut tube's skeleton lies in the whole one");
        // The true skeleton misses the predicted volume over the 4 mm gap, less the two
        // radius-1 caps that reach into it: about 2 of 30 mm.
        assert!((s.topology_sensitivity - 28.0 / 30.0).abs() < 0.02, "{s:?}");
        assert!(s.cl_dice < 1.0 && s.cl_dice > 0.9, "{s:?}");
    }

    #[test]
    fn a_shifted_tube_scores_less_the_farther_it_moves() {
        let t = [tube(DVec3::new(-15.0, 0.0, 0.0), DVec3::new(15.0, 0.0, 0.0))];
        let v = solid(&t);
        let mut last = 1.0;
        for shift in [0.5, 1.5, 3.0] {
            let moved = [tube(DVec3::new(-15.0, shift, 0.0), DVec3::new(15.0, shift, 0.0))];
            let s = topology_scores(&solid(&moved), &v, &moved, &t);
            assert!(s.cl_dice <= last, "shift {shift}: {s:?}");
            assert_eq!(s.betti0_error, 0);
            last = s.cl_dice;
        }
        assert_eq!(last, 0.0, "3 mm away (radius 1 mm): the skeletons lie outside each other's tubes");
    }
}

//! Where a run's new centreline lies against the truth and the views (`ctadsa diagnose`): on a
//! true vessel, or off every true vessel and yet a *ghost* — its axis projects into every
//! view's vessel mask, so that the views cannot tell it from a vessel — near a true vessel or
//! farther away, or off some view's vessels (a piece the views do not support).
//!
//! With two views most of the false new centreline is of the ghost kind: no check of the
//! projections can reject it, only what the views do not show (arrival times, the tree's
//! connections, agreement between models) can.

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::data::masks::{Mask, pixel_of};
use crate::data::tree::{KIND_NEW_VESSEL, Segment, VesselTree};
use crate::eval::metrics::nearest_points;
use crate::eval::surface_metrics::{RECALL_SLACK_MM, centreline_points};

/// A ghost whose axis lies within this distance (mm) of a true vessel's wall is *near* it.
pub const NEAR_MM: f64 = 2.0;

/// Pixels by which each view's vessel mask is widened before the ghost test: an axis that
/// projects beside a vessel's edge by a pixel still lies on it.
pub const MASK_SLACK_PX: u32 = 1;

/// Shares of the new centreline length (they sum to 1 when there is new length).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct NewCentreline {
    /// Length of the new centreline (mm).
    pub length_mm: f64,
    /// Within radius + 0.5 mm of a true centreline point (the centreline precision criterion).
    pub on_vessel: f64,
    /// Off every true vessel, projecting into every view's vessel mask, within [`NEAR_MM`] of a
    /// true vessel's wall.
    pub ghost_near: f64,
    /// The same, farther from every true vessel.
    pub ghost_far: f64,
    /// Off every true vessel and outside some view's vessel mask (or detector).
    pub off_views: f64,
}

/// Classifies the new centreline of `predicted` (nodes of type [`KIND_NEW_VESSEL`]) against the
/// whole true centreline `truth` and the `views` with their vessel `masks` (one per view, as
/// large as its detector; widened by [`MASK_SLACK_PX`] here).
pub fn new_centreline(
    predicted: &VesselTree,
    truth: &[Segment],
    views: &[ConeBeamView],
    masks: &[Mask],
) -> NewCentreline {
    let new: Vec<Segment> =
        predicted.segments().into_iter().filter(|s| predicted.nodes[s.child].kind == KIND_NEW_VESSEL).collect();
    let points = centreline_points(&new);
    let truth_points = centreline_points(truth);
    let truth_positions: Vec<DVec3> = truth_points.iter().map(|p| p.position_mm).collect();
    let positions: Vec<DVec3> = points.iter().map(|p| p.position_mm).collect();
    let nearest = nearest_points(&positions, &truth_positions);
    let masks: Vec<Mask> = masks.iter().map(|m| m.dilated(MASK_SLACK_PX)).collect();
    let mut out = NewCentreline::default();
    for (p, &(d, i)) in points.iter().zip(&nearest) {
        let true_radius = truth_points.get(i).map_or(0.0, |t| t.radius_mm);
        let in_every_mask = views
            .iter()
            .zip(&masks)
            .all(|(v, m)| pixel_of(v, p.position_mm).is_some_and(|q| m.data.get(q) == Some(&true)));
        let share = if d <= true_radius + RECALL_SLACK_MM {
            &mut out.on_vessel
        } else if !in_every_mask {
            &mut out.off_views
        } else if d <= true_radius + NEAR_MM {
            &mut out.ghost_near
        } else {
            &mut out.ghost_far
        };
        *share += p.length_mm;
        out.length_mm += p.length_mm;
    }
    if out.length_mm > 0.0 {
        let l = out.length_mm;
        for f in [&mut out.on_vessel, &mut out.ghost_near, &mut out.ghost_far, &mut out.off_views] {
            *f /= l;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use ctadsa_render::TigreGeometry;

    use super::*;
    use crate::data::tree::{KIND_PRIOR_VESSEL, TreeNode};

    fn view(primary_deg: f64) -> ConeBeamView {
        ConeBeamView::from_tigre(&TigreGeometry { detector_px: [160, 160], ..TigreGeometry::reference(primary_deg) })
            .unwrap()
    }

    /// A vertical line at `(x, y)` from z = −10 to 10 mm.
    fn vertical(x: f64, y: f64) -> (DVec3, DVec3) {
        (DVec3::new(x, y, -10.0), DVec3::new(x, y, 10.0))
    }

    fn segment((a, b): (DVec3, DVec3)) -> Segment {
        Segment { child: 0, start_mm: a, end_mm: b, start_radius_mm: 0.5, end_radius_mm: 0.5 }
    }

    /// Each view's mask: the pixels the true axes project into, widened by 2 px (a vessel
    /// 0.5 mm in radius is about 3 px wide on this detector).
    fn masks(truth: &[Segment], views: &[ConeBeamView]) -> Vec<Mask> {
        views
            .iter()
            .map(|v| {
                let mut m =
                    Mask { width: v.width(), height: v.height(), data: vec![false; (v.width() * v.height()) as usize] };
                for p in centreline_points(truth) {
                    if let Some(q) = pixel_of(v, p.position_mm) {
                        m.data[q] = true;
                    }
                }
                m.dilated(2)
            })
            .collect()
    }

    #[test]
    fn new_pieces_on_a_vessel_near_and_far_ghosts_and_off_the_views() {
        // Lateral (rays along x) and AP (rays along y) views; three vertical true vessels. A point
        // (x, y) is seen at x by the AP view and at y by the lateral one, so (5, −3.5) lies on
        // V1 in AP and on V2 in the lateral view: a ghost 1.5 mm from V1; (5, 8) one of V1 and V3
        // far from all; (0, 0) lies on no vessel's projection.
        let views = [view(0.0), view(-90.0)];
        let truth: Vec<Segment> =
            [vertical(5.0, -5.0), vertical(-5.0, -3.5), vertical(-5.0, 8.0)].map(segment).to_vec();
        let masks = masks(&truth, &views);
        let mut tree = VesselTree::default();
        // A prior stub, then four new vertical pieces of 20 mm each.
        tree.nodes.push(TreeNode {
            id: 0,
            kind: KIND_PRIOR_VESSEL,
            position_mm: DVec3::ZERO,
            radius_mm: 1.0,
            parent: None,
        });
        for (x, y) in [(5.2, -5.0), (5.0, -3.5), (5.0, 8.0), (0.0, 0.0)] {
            let (a, b) = vertical(x, y);
            for k in 0..=20 {
                let parent = if k == 0 { None } else { Some(tree.nodes.len() - 1) };
                let position_mm = a.lerp(b, k as f64 / 20.0);
                tree.nodes.push(TreeNode { id: 0, kind: KIND_NEW_VESSEL, position_mm, radius_mm: 0.4, parent });
            }
        }
        let c = new_centreline(&tree, &truth, &views, &masks);
        assert!((c.length_mm - 80.0).abs() < 1e-6, "{}", c.length_mm);
        for (name, got) in [("on", c.on_vessel), ("near", c.ghost_near), ("far", c.ghost_far), ("off", c.off_views)] {
            assert!((got - 0.25).abs() < 0.01, "{name}: {got} ({c:?})");
        }
        // Without the views' support the ghosts fall off the views.
        let empty: Vec<Mask> = masks.iter().map(|m| Mask { data: vec![false; m.data.len()], ..m.clone() }).collect();
        let c = new_centreline(&tree, &truth, &views, &empty);
        assert!((c.on_vessel - 0.25).abs() < 0.01 && (c.off_views - 0.75).abs() < 0.01, "{c:?}");
    }
}

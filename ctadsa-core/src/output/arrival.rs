//! The contrast's arrival time as a check of new centreline branches seen in two views
//! ([`crate::method::arrival`] says why it tells vessels from ghosts).

use ctadsa_render::ConeBeamView;

use super::confidence::Branch;
use crate::data::case::images::Image;
use crate::data::tree::VesselTree;
use crate::method::arrival::{frames_agree, frames_seen};

/// Step (mm) between the points of a branch that are checked.
const SAMPLE_MM: f64 = 0.1;

/// For each new branch of `tree` in a run of two views: the share (0–1) of its length whose
/// projections into the two views lie on pixels (3 × 3 around each) filled in frames within
/// `tolerance_frames` of each other ([`frames_seen`] with `exit_px`, where `maps` hide the
/// prior's projection). `None` for prior branches, and for every branch unless there are exactly
/// two views (with three, the third view already rejects the ghosts).
pub fn arrival_agreement(
    tree: &VesselTree,
    branches: &[Branch],
    views: &[ConeBeamView],
    maps: &[Image],
    tolerance_frames: f32,
    exit_px: u32,
) -> Vec<Option<f64>> {
    branches
        .iter()
        .map(|b| {
            if !b.new || views.len() != 2 || maps.len() != 2 {
                return None;
            }
            let (mut agree, mut total) = (0.0, 0.0);
            for pair in b.nodes.windows(2) {
                let (a, z) = (tree.nodes[pair[0]].position_mm, tree.nodes[pair[1]].position_mm);
                let length = a.distance(z);
                let n = (length / SAMPLE_MM).ceil().max(1.0) as usize;
                for k in 0..n {
                    let p = a.lerp(z, (k as f64 + 0.5) / n as f64);
                    let (first, second) =
                        (frames_seen(&views[0], &maps[0], p, exit_px), frames_seen(&views[1], &maps[1], p, exit_px));
                    let same = frames_agree(&first, &second, tolerance_frames);
                    total += length / n as f64;
                    if same {
                        agree += length / n as f64;
                    }
                }
            }
            Some(if total > 0.0 { agree / total } else { 0.0 })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::case::images::{NO_ARRIVAL, bin_arrival};
    use crate::data::synth::arrival::{ArrivalSpec, arrival_map};
    use crate::data::tree::{KIND_NEW_VESSEL, TreeNode};
    use ctadsa_render::TigreGeometry;
    use glam::DVec3;

    fn node(id: i64, parent: Option<usize>, p: [f64; 3], kind: i32) -> TreeNode {
        TreeNode { id, kind, position_mm: DVec3::from(p), radius_mm: 0.3, parent }
    }

    fn new_branch(nodes: Vec<usize>) -> Branch {
        Branch {
            nodes,
            new: true,
            length_mm: 0.0,
            mean_radius_mm: 0.3,
            connected_to_prior: true,
            unique_support: vec![],
            confidence: 1.0,
        }
    }

    /// Two vertical vessels filled in opposite directions: A at x = y = 0 from its root at
    /// z = −20 mm, B at x = y = 20 mm from its root at z = +20 mm. AP (along y) sees A at x = 0,
    /// LAT (along x) sees B at y = 20, so the vertical ghost at (0, 20) lies under A in AP and
    /// under B in LAT: its two frames differ, while a stretch of A has A's frames in both views.
    /// Returns the truth, the two views, and a found tree of two new branches: the stretch of A
    /// and the ghost.
    fn vessel_and_ghost() -> (VesselTree, Vec<ConeBeamView>, VesselTree, [Branch; 2]) {
        let truth = VesselTree {
            nodes: vec![
                node(1, None, [0.0, 0.0, -20.0], 0),
                node(2, Some(0), [0.0, 0.0, 20.0], 0),
                node(3, None, [20.0, 20.0, 20.0], 0),
                node(4, Some(2), [20.0, 20.0, -20.0], 0),
            ],
        };
        let views: Vec<ConeBeamView> = [-90.0, 0.0]
            .map(|primary| {
                let mut g = TigreGeometry::reference(primary);
                g.detector_px = [128, 128];
                g.pixel_mm = [1.0, 1.0];
                ConeBeamView::from_tigre(&g).unwrap()
            })
            .into();
        let found = VesselTree {
            nodes: vec![
                node(1, None, [0.0, 0.0, -15.0], KIND_NEW_VESSEL),
                node(2, Some(0), [0.0, 0.0, -5.0], KIND_NEW_VESSEL),
                node(3, None, [0.0, 20.0, -15.0], KIND_NEW_VESSEL),
                node(4, Some(2), [0.0, 20.0, -5.0], KIND_NEW_VESSEL),
            ],
        };
        (truth, views, found, [new_branch(vec![0, 1]), new_branch(vec![2, 3])])
    }

    #[test]
    fn a_vessel_agrees_and_a_ghost_between_two_vessels_does_not() {
        let (truth, views, found, branches) = vessel_and_ghost();
        let spec = ArrivalSpec::ideal(10.0, 100.0);
        let maps: Vec<Image> = views.iter().enumerate().map(|(i, v)| arrival_map(&truth, v, i, &spec)).collect();
        let agreement = arrival_agreement(&found, &branches, &views, &maps, 0.0, 0);
        assert_eq!(agreement[0], Some(1.0), "the true vessel");
        assert_eq!(agreement[1], Some(0.0), "the ghost");
        // Three views: not checked.
        let three = [views[0], views[1], views[0]];
        assert!(arrival_agreement(&found, &branches, &three, &maps, 0.0, 0).iter().all(Option::is_none));
        // Binning keeps the earliest frame of each block.
        let map = Image { width: 2, height: 2, data: vec![NO_ARRIVAL, 3.0, 2.0, NO_ARRIVAL] };
        assert_eq!(bin_arrival(&map, 2).data, vec![2.0]);
        let empty = Image { width: 2, height: 2, data: vec![NO_ARRIVAL; 4] };
        assert_eq!(bin_arrival(&empty, 2).data, vec![NO_ARRIVAL]);
    }

    /// A biplane run images its planes alternately: with the lateral plane's frames half a frame
    /// late, the true vessel shows the same frame or the one before in LAT, and an exact frame
    /// test rejects part of it; read as the times its frames stand for (its offset known), the
    /// vessel agrees whole and the ghost mostly does not.
    #[test]
    fn a_plane_imaged_half_a_frame_late_agrees_once_its_offset_is_known() {
        use crate::method::arrival::arrival_times;
        let (truth, views, found, branches) = vessel_and_ghost();
        let spec = ArrivalSpec { interleave_frames: 0.5, ..ArrivalSpec::ideal(10.0, 100.0) };
        let frames: Vec<Image> = views.iter().enumerate().map(|(i, v)| arrival_map(&truth, v, i, &spec)).collect();
        let exact = arrival_agreement(&found, &branches, &views, &frames, 0.0, 0);
        let vessel_exact = exact[0].unwrap();
        assert!(vessel_exact < 0.9, "an exact frame test passes {vessel_exact:.2} of the true vessel");
        let times: Vec<Image> =
            frames.iter().enumerate().map(|(i, m)| arrival_times(m, spec.delay_frames(i))).collect();
        let timed = arrival_agreement(&found, &branches, &views, &times, 0.0, 0);
        assert_eq!(timed[0], Some(1.0), "the true vessel, its offset known");
        // The span a frame stands for is wider than the frame: where the ghost's two frames are
        // one apart, the spans touch the half frame and it agrees there.
        let ghost = timed[1].unwrap();
        assert!(ghost <= 0.25, "the ghost, its offset known, agrees over {ghost:.2}");
    }
}

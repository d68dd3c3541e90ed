//! Sub-voxel centring of centreline nodes. A skeleton traced on a voxel grid runs through voxel
//! centres, up to half a voxel diagonal off a thin vessel's axis; the extracted iso-surface is
//! finer than the grid. Each node moves, across its branch (perpendicular to the local tangent),
//! to the middle of the surface's chord through it along the direction of its nearest wall: for
//! a round vessel that line passes through the axis, so one step centres the node.

use glam::DVec3;
use rayon::prelude::*;

use crate::data::mesh::distance::SurfaceIndex;
use crate::data::tree::VesselTree;

/// Two steps: the second corrects what an oval cross-section leaves of the first.
const STEPS: usize = 2;

/// Below this share of the nearest wall's direction across the branch, the nearest wall is an
/// end (a tip or a cap) and the node stays.
const MIN_ACROSS: f64 = 0.5;

/// The unit tangent of the tree at node `i`: from its parent (or itself) to its first child
/// (or itself); `None` for a lone node.
fn tangent(tree: &VesselTree, children: &[Vec<usize>], i: usize) -> Option<DVec3> {
    let here = tree.nodes[i].position_mm;
    let back = tree.nodes[i].parent.map_or(here, |p| tree.nodes[p].position_mm);
    let ahead = children[i].first().map_or(here, |&c| tree.nodes[c].position_mm);
    (ahead - back).try_normalize()
}

/// Moves the nodes for which `movable` holds to the middle of `surface`'s chord through them
/// (see the module doc), each by at most `max_shift_mm` in all; a node whose chord is longer
/// than `max_chord_mm` (a junction, a blob), that a ray leaves without hitting the surface (it
/// lies outside), or whose nearest wall is an end, stays where it is.
pub fn centre_nodes(
    tree: &mut VesselTree,
    surface: &SurfaceIndex,
    movable: impl Fn(DVec3) -> bool + Sync,
    max_shift_mm: f64,
    max_chord_mm: f64,
) {
    let mut children = vec![Vec::new(); tree.nodes.len()];
    for (i, n) in tree.nodes.iter().enumerate() {
        if let Some(p) = n.parent {
            children[p].push(i);
        }
    }
    let tangents: Vec<Option<DVec3>> = (0..tree.nodes.len()).map(|i| tangent(tree, &children, i)).collect();
    let moved: Vec<DVec3> = tree
        .nodes
        .par_iter()
        .zip(&tangents)
        .map(|(n, t)| {
            let start = n.position_mm;
            let Some(t) = *t else { return start };
            if !movable(start) {
                return start;
            }
            let mut p = start;
            for _ in 0..STEPS {
                let Some(q) = surface.closest(p) else { break };
                let Some(away) = (p - q).try_normalize() else { break };
                let across = away - away.dot(t) * t;
                if across.length() < MIN_ACROSS {
                    break;
                }
                let dir = across.normalize();
                let (Some(ahead), Some(behind)) =
                    (surface.first_hit(p, dir, max_chord_mm), surface.first_hit(p, -dir, max_chord_mm))
                else {
                    break;
                };
                if ahead + behind > max_chord_mm {
                    break;
                }
                let candidate = p + 0.5 * (ahead - behind) * dir;
                let shift = candidate - start;
                p = if shift.length() > max_shift_mm {
                    start + shift * (max_shift_mm / shift.length())
                } else {
                    candidate
                };
            }
            p
        })
        .collect();
    for (n, p) in tree.nodes.iter_mut().zip(moved) {
        n.position_mm = p;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::mesh::marching::extract_isosurface;
    use crate::data::tree::{Segment, TreeNode};
    use crate::data::volume::rasterize::rasterize_segments;
    use crate::data::volume::{BoxMm, Grid};

    #[test]
    fn nodes_off_a_thin_vessels_axis_move_onto_it() {
        // A vessel of radius 0.5 mm along x, its axis between voxel centres of a 0.6 mm grid;
        // its iso-surface; a centreline of nodes on the nearest voxel centres.
        let axis = DVec3::new(0.0, 0.23, -0.17);
        let seg = Segment {
            child: 0,
            start_mm: axis + DVec3::new(-8.0, 0.0, 0.0),
            end_mm: axis + DVec3::new(8.0, 0.0, 0.0),
            start_radius_mm: 0.5,
            end_radius_mm: 0.5,
        };
        let grid = Grid::covering(&BoxMm { min_mm: [-10.0; 3], max_mm: [10.0; 3] }, 0.6).unwrap();
        let surface = extract_isosurface(&rasterize_segments(&[seg], grid, 4), 0.5);
        let snap = |v: f64, o: f64| ((v - o) / 0.6 - 0.5).round() * 0.6 + 0.5 * 0.6 + o;
        let nodes: Vec<TreeNode> = (0..20)
            .map(|i| {
                let x = -5.0 + 0.5 * i as f64;
                TreeNode {
                    id: i as i64,
                    kind: 4,
                    position_mm: DVec3::new(x, snap(axis.y, grid.origin_mm[1]), snap(axis.z, grid.origin_mm[2])),
                    radius_mm: 0.3,
                    parent: (i > 0).then(|| i - 1),
                }
            })
            .collect();
        let mut tree = VesselTree { nodes };
        let off = |t: &VesselTree| {
            t.nodes.iter().map(|n| ((n.position_mm - axis) * DVec3::new(0.0, 1.0, 1.0)).length()).sum::<f64>()
                / t.nodes.len() as f64
        };
        let before = off(&tree);
        let index = SurfaceIndex::new(&surface);
        centre_nodes(&mut tree, &index, |_| true, 0.6, 3.0);
        let after = off(&tree);
        eprintln!("mean distance to the axis: {before:.3} -> {after:.3} mm");
        assert!(before > 0.1, "the snapped nodes start off the axis ({before})");
        // Halved at least: what is left is the iso-surface's own offset on a 0.6 mm grid.
        assert!(after < 0.5 * before, "{before} -> {after}");
        // Along the vessel nothing moves.
        for (i, n) in tree.nodes.iter().enumerate() {
            assert!((n.position_mm.x - (-5.0 + 0.5 * i as f64)).abs() < 1e-9);
        }
        // A node that may not move stays.
        let mut fixed = tree.clone();
        let frozen: Vec<DVec3> = fixed.nodes.iter().map(|n| n.position_mm).collect();
        centre_nodes(&mut fixed, &index, |_| false, 0.6, 3.0);
        assert!(fixed.nodes.iter().zip(&frozen).all(|(n, p)| n.position_mm == *p));
    }
}

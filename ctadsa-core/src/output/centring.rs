//! Sub-voxel centring of centreline nodes. A skeleton traced on a voxel grid runs through voxel
//! centres, up to half a voxel diagonal off a thin vessel's axis; the extracted iso-surface is
//! finer than the grid. Each node moves, across its branch (perpendicular to the local tangent),
//! to the middle of the surface's chord through it along the direction of its nearest wall: for
//! a round vessel that line passes through the axis, so one step centres the node. Or, given the
//! density, each node moves onto the density's ridge across its branch ([`centre_on_ridge`]).

use glam::DVec3;
use rayon::prelude::*;

use crate::data::mesh::distance::SurfaceIndex;
use crate::data::tree::VesselTree;
use crate::data::volume::Volume;

/// Where a centreline's nodes are moved to, across their branch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Centring {
    /// They stay on the voxel centres the skeleton ran through.
    Off,
    /// The middle of the surface's chord ([`centre_nodes`]).
    Surface,
    /// The density's ridge ([`centre_on_ridge`]); where there is no density to follow, as
    /// [`Centring::Surface`].
    Ridge,
}

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
    move_across(tree, movable, max_shift_mm, |p, t| {
        let q = surface.closest(p)?;
        let away = (p - q).try_normalize()?;
        let across = away - away.dot(t) * t;
        if across.length() < MIN_ACROSS {
            return None;
        }
        let dir = across.normalize();
        let ahead = surface.first_hit(p, dir, max_chord_mm)?;
        let behind = surface.first_hit(p, -dir, max_chord_mm)?;
        (ahead + behind <= max_chord_mm).then(|| p + 0.5 * (ahead - behind) * dir)
    });
}

/// Moves each node of `tree` for which `movable` holds and that has a tangent by [`STEPS`]
/// steps of `step` (position, unit tangent → the next position, `None`: stay), each node by at
/// most `max_shift_mm` in all from where it started.
fn move_across(
    tree: &mut VesselTree,
    movable: impl Fn(DVec3) -> bool + Sync,
    max_shift_mm: f64,
    step: impl Fn(DVec3, DVec3) -> Option<DVec3> + Sync,
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
                let Some(candidate) = step(p, t) else { break };
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

/// Moves the nodes for which `movable` holds onto the ridge of `field` (a density) across their
/// branch: a Newton step on the quadratic through `field`'s values at the node and one voxel
/// either way along two directions perpendicular to the tangent, twice, each node by at most
/// `max_shift_mm` in all. Where the field has no maximum across the branch (not negative
/// definite there) the node stays. Where the surface merges a thin vessel with a fainter
/// neighbour, its middle lies between the two and the ridge on the vessel.
pub fn centre_on_ridge(
    tree: &mut VesselTree,
    field: &Volume<f32>,
    movable: impl Fn(DVec3) -> bool + Sync,
    max_shift_mm: f64,
) {
    let h = field.grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
    move_across(tree, movable, max_shift_mm, |p, t| {
        let e1 = t.any_orthonormal_vector();
        let e2 = t.cross(e1);
        let at = |a: f64, b: f64| field.trilinear_at(p + h * (a * e1 + b * e2));
        let c = at(0.0, 0.0);
        let (xp, xm, yp, ym) = (at(1.0, 0.0), at(-1.0, 0.0), at(0.0, 1.0), at(0.0, -1.0));
        let (gx, gy) = (0.5 * (xp - xm), 0.5 * (yp - ym));
        let (hxx, hyy) = (xp - 2.0 * c + xm, yp - 2.0 * c + ym);
        let hxy = 0.25 * (at(1.0, 1.0) - at(1.0, -1.0) - at(-1.0, 1.0) + at(-1.0, -1.0));
        let det = hxx * hyy - hxy * hxy;
        if !(hxx < 0.0 && det > 0.0) {
            return None;
        }
        // The Newton step -H⁻¹ g, in voxels.
        let sx = -(hyy * gx - hxy * gy) / det;
        let sy = -(-hxy * gx + hxx * gy) / det;
        Some(p + h * (sx * e1 + sy * e2))
    });
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

    /// A thin bright vessel beside a wider faint one 1.2 mm away: nodes on the pair's middle
    /// move onto the bright vessel's axis (the density's ridge), by at most the shift allowed;
    /// a node that may not move stays, and a field with no ridge across the branch moves nothing.
    #[test]
    fn nodes_move_onto_the_ridge_of_the_density_across_their_branch() {
        let grid = Grid::covering(&BoxMm { min_mm: [-6.0; 3], max_mm: [6.0; 3] }, 0.42).unwrap();
        let bright = DVec3::new(0.0, 0.13, -0.07);
        let field_of = |f: &dyn Fn(DVec3) -> f64| {
            let mut v = Volume::<f32>::zeros(grid);
            for i in 0..grid.dims[0] {
                for j in 0..grid.dims[1] {
                    for k in 0..grid.dims[2] {
                        let idx = grid.index(i, j, k);
                        v.data[idx] = f(grid.centre_mm(i, j, k)) as f32;
                    }
                }
            }
            v
        };
        let across = |p: DVec3, c: DVec3| (p - c) * DVec3::new(0.0, 1.0, 1.0);
        let glow = |p: DVec3, c: DVec3, peak: f64, sigma: f64| {
            peak * (-across(p, c).length_squared() / (2.0 * sigma * sigma)).exp()
        };
        let faint = bright + DVec3::new(0.0, 1.2, 0.0);
        let pair = field_of(&|p| glow(p, bright, 2.0, 0.35) + glow(p, faint, 0.8, 0.6));
        let line = |start: DVec3| VesselTree {
            nodes: (0..15)
                .map(|i| TreeNode {
                    id: i as i64,
                    kind: 4,
                    position_mm: start + DVec3::new(-3.5 + 0.5 * i as f64, 0.0, 0.0),
                    radius_mm: 0.3,
                    parent: (i > 0).then(|| i - 1),
                })
                .collect(),
        };
        let off = |t: &VesselTree| t.nodes.iter().map(|n| across(n.position_mm, bright).length()).sum::<f64>() / 15.0;
        let middle = bright + DVec3::new(0.0, 0.35, 0.1);
        let mut tree = line(middle);
        let before = off(&tree);
        centre_on_ridge(&mut tree, &pair, |_| true, 0.42);
        let after = off(&tree);
        eprintln!("mean distance to the bright axis: {before:.3} -> {after:.3} mm");
        assert!(after < 0.1 && before > 0.3, "{before} -> {after}");
        for (i, n) in tree.nodes.iter().enumerate() {
            assert!((n.position_mm.x - (-3.5 + 0.5 * i as f64)).abs() < 1e-9, "along the branch nothing moves");
        }
        // At most the shift allowed.
        let mut short = line(middle);
        centre_on_ridge(&mut short, &pair, |_| true, 0.1);
        assert!(
            short
                .nodes
                .iter()
                .all(|n| (n.position_mm - (middle + DVec3::new(n.position_mm.x - middle.x, 0.0, 0.0))).length()
                    <= 0.1 + 1e-9)
        );
        // Frozen nodes, and a field without a ridge (a plane slope), move nothing.
        let mut frozen = line(middle);
        centre_on_ridge(&mut frozen, &pair, |_| false, 0.42);
        assert_eq!(off(&frozen), before);
        let mut sloped = line(middle);
        centre_on_ridge(&mut sloped, &field_of(&|p| 1.0 + 0.1 * p.y), |_| true, 0.42);
        assert_eq!(off(&sloped), before);
    }
}

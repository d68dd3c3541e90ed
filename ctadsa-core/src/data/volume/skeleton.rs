//! Centrelines of a binary volume: TEASAR (Sato et al. 2000, as kimimaro runs it).
//!
//! Per connected component (26-connectivity) of the foreground:
//! 1. the boundary distance `dbf` of every voxel (exact EDT, mm);
//! 2. a root at the voxel geodesically farthest from the deepest voxel (an end of the tree);
//! 3. the shortest-path tree from the root over a penalty field that makes paths off the
//!    medial axis expensive: a step of length `ℓ` into voxel `v` costs
//!    `ℓ · (1 + PDRF_SCALE · (1 − a(v))^8)` with `a = dbf(v)/max dbf`; given a ridge field `r`
//!    (in [0, 1], e.g. a density relative to its level) and `ridge_weight` β,
//!    `a = (dbf/max dbf)^(1−β) · (r/max r)^β`, so that paths follow the field's ridges where
//!    the solid merges two of them;
//! 4. repeatedly, the not yet covered voxel geodesically farthest from the root is joined to the
//!    skeleton along that tree, and every voxel within `scale · dbf + const_mm` of the new path
//!    is covered — until nothing is left.
//!
//! Paths end where they meet the skeleton, so each component gives one tree. Nodes sit at voxel
//! centres; a node's radius is its boundary distance less half a voxel (the distance runs to the
//! nearest background voxel *centre*).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::DVec3;

use super::Volume;
use super::edt::squared_edt;
use crate::data::tree::graph::CentrelineGraph;
use crate::data::tree::{TreeNode, VesselTree};

/// Weight of the penalty field against path length (kimimaro's default).
const PDRF_SCALE: f64 = 100_000.0;

/// How much of the volume each traced path covers, and which components count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkeletonParams {
    /// Covered radius around a path voxel = `scale · dbf + const_mm`.
    pub scale: f64,
    pub const_mm: f64,
    /// Components with fewer voxels are left out.
    pub min_component_voxels: usize,
    /// Terminal branches shorter than this are removed (mm).
    pub min_branch_mm: f64,
    /// Rounds of Laplacian smoothing of the node positions along branches.
    pub smoothing: usize,
    /// β of the penalty field (module doc): how much the paths follow the ridge field rather
    /// than the medial axis, in [0, 1]; unused without a ridge field.
    pub ridge_weight: f64,
}

impl Default for SkeletonParams {
    fn default() -> Self {
        Self { scale: 1.5, const_mm: 1.0, min_component_voxels: 8, min_branch_mm: 1.0, smoothing: 2, ridge_weight: 0.0 }
    }
}

/// The 26 neighbour offsets.
fn offsets() -> Vec<[i64; 3]> {
    let mut o = Vec::with_capacity(26);
    for di in -1..=1 {
        for dj in -1..=1 {
            for dk in -1..=1 {
                if (di, dj, dk) != (0, 0, 0) {
                    o.push([di, dj, dk]);
                }
            }
        }
    }
    o
}

/// One connected component: its voxels (flat grid indices) and a map back from the grid.
struct Component<'a> {
    voxels: Vec<usize>,
    /// `local[g]` = position of grid voxel `g` in `voxels` (valid where `label[g] == id`).
    local: &'a [u32],
    label: &'a [u32],
    id: u32,
}

/// Neighbour walk on the grid restricted to one component.
struct Walker {
    dims: [usize; 3],
    offsets: Vec<[i64; 3]>,
    /// Step length (mm) of each offset.
    steps_mm: Vec<f64>,
    spacing_mm: [f64; 3],
}

impl Walker {
    fn new(dims: [usize; 3], spacing: [f64; 3]) -> Self {
        let offsets = offsets();
        let steps_mm = offsets
            .iter()
            .map(|o| DVec3::new(o[0] as f64 * spacing[0], o[1] as f64 * spacing[1], o[2] as f64 * spacing[2]).length())
            .collect();
        Self { dims, offsets, steps_mm, spacing_mm: spacing }
    }

    fn coords(&self, g: usize) -> [i64; 3] {
        let [_, ny, nz] = self.dims;
        [(g / (ny * nz)) as i64, ((g / nz) % ny) as i64, (g % nz) as i64]
    }

    fn flat(&self, c: [i64; 3]) -> Option<usize> {
        let d = self.dims;
        if (0..3).any(|a| c[a] < 0 || c[a] >= d[a] as i64) {
            return None;
        }
        Some((c[0] as usize * d[1] + c[1] as usize) * d[2] + c[2] as usize)
    }

    /// Calls `f(neighbour's local index, step length mm)` for every neighbour of local voxel
    /// `u` inside `comp`.
    fn each_neighbour(&self, comp: &Component, u: usize, mut f: impl FnMut(usize, f64)) {
        let c = self.coords(comp.voxels[u]);
        for (o, &step) in self.offsets.iter().zip(&self.steps_mm) {
            if let Some(g) = self.flat([c[0] + o[0], c[1] + o[1], c[2] + o[2]])
                && comp.label[g] == comp.id
            {
                f(comp.local[g] as usize, step);
            }
        }
    }
}

/// Shortest paths from `source` where entering voxel `v` over a step `ℓ` costs `ℓ · cost[v]`:
/// `(distance, parent)` per local voxel (`u32::MAX` = none).
fn dijkstra(walker: &Walker, comp: &Component, source: usize, cost: &[f64]) -> (Vec<f64>, Vec<u32>) {
    let n = comp.voxels.len();
    let mut dist = vec![f64::INFINITY; n];
    let mut parent = vec![u32::MAX; n];
    let mut heap = BinaryHeap::new();
    dist[source] = 0.0;
    // Distances are non-negative, so their bit patterns order as the values do.
    heap.push(Reverse((0u64, source)));
    while let Some(Reverse((d_bits, u))) = heap.pop() {
        let d = f64::from_bits(d_bits);
        if d > dist[u] {
            continue;
        }
        walker.each_neighbour(comp, u, |v, step| {
            let nd = d + step * cost[v];
            if nd < dist[v] {
                dist[v] = nd;
                parent[v] = u as u32;
                heap.push(Reverse((nd.to_bits(), v)));
            }
        });
    }
    (dist, parent)
}

/// Labels the 26-connected components of the foreground: `(label per voxel, voxels per
/// component)`; background is `u32::MAX`.
fn components(solid: &Volume<u8>, walker: &Walker) -> (Vec<u32>, Vec<u32>, Vec<Vec<usize>>) {
    let n = solid.data.len();
    let mut label = vec![u32::MAX; n];
    let mut local = vec![0u32; n];
    let mut comps = Vec::new();
    for start in 0..n {
        if solid.data[start] == 0 || label[start] != u32::MAX {
            continue;
        }
        let id = comps.len() as u32;
        let mut voxels = vec![start];
        label[start] = id;
        let mut head = 0;
        while head < voxels.len() {
            let c = walker.coords(voxels[head]);
            head += 1;
            for o in &walker.offsets {
                if let Some(g) = walker.flat([c[0] + o[0], c[1] + o[1], c[2] + o[2]])
                    && solid.data[g] != 0
                    && label[g] == u32::MAX
                {
                    label[g] = id;
                    local[g] = voxels.len() as u32;
                    voxels.push(g);
                }
            }
        }
        comps.push(voxels);
    }
    (label, local, comps)
}

/// Index of the largest finite value (the first among equals).
fn argmax(values: &[f64]) -> usize {
    let mut best = 0;
    for (i, &v) in values.iter().enumerate() {
        if v.is_finite() && (!values[best].is_finite() || v > values[best]) {
            best = i;
        }
    }
    best
}

/// The centreline forest of the foreground of `solid` (positions and radii in mm; node kinds 0):
/// traced, ends trimmed back to the medial axis, short spurs removed, smoothed, each component
/// rooted at its widest end.
pub fn skeletonize(solid: &Volume<u8>, params: &SkeletonParams) -> VesselTree {
    skeletonize_along(solid, None, params)
}

/// [`skeletonize`] with a ridge field: `ridge[g]` in [0, 1] per voxel of `solid`'s grid,
/// followed by the paths with `params.ridge_weight` (module doc). A field without one value
/// per voxel of `solid` is not used (debug builds panic).
pub fn skeletonize_along(solid: &Volume<u8>, ridge: Option<&[f32]>, params: &SkeletonParams) -> VesselTree {
    let min_h = solid.grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
    debug_assert!(ridge.is_none_or(|r| r.len() == solid.data.len()), "one ridge value per voxel");
    let ridge = ridge.filter(|r| params.ridge_weight > 0.0 && r.len() == solid.data.len());
    let mut graph = CentrelineGraph::from_tree(&trace(solid, ridge, params));
    graph.trim_ends(min_h, 0.5 * min_h);
    graph.prune_spurs(params.min_branch_mm);
    graph.smooth(params.smoothing);
    graph.into_tree()
}

/// The raw TEASAR forest (see the module documentation).
fn trace(solid: &Volume<u8>, ridge: Option<&[f32]>, params: &SkeletonParams) -> VesselTree {
    let grid = solid.grid;
    let walker = Walker::new(grid.dims, grid.spacing_mm);
    let min_h = grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
    // A voxel with no background voxel in the grid (a solid filling the box) takes its distance
    // to the grid's faces instead, so that boundary distances stay finite and covering ends.
    let extent2: f64 = (0..3).map(|a| (grid.dims[a] as f64 * grid.spacing_mm[a]).powi(2)).sum();
    let dbf_all: Vec<f64> = squared_edt(solid)
        .into_iter()
        .enumerate()
        .map(|(g, d2)| {
            if d2.is_finite() && d2 <= extent2 {
                return d2.sqrt();
            }
            let c = walker.coords(g);
            (0..3)
                .map(|a| ((c[a] + 1).min(grid.dims[a] as i64 - c[a]) as f64) * grid.spacing_mm[a])
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    let (label, local, comps) = components(solid, &walker);
    let mut tree = VesselTree::default();
    for (id, voxels) in comps.into_iter().enumerate() {
        if voxels.len() < params.min_component_voxels.max(1) {
            continue;
        }
        let comp = Component { voxels, local: &local, label: &label, id: id as u32 };
        trace_component(&comp, &walker, &dbf_all, ridge, params, min_h, solid, &mut tree);
    }
    tree
}

/// TEASAR on one component; appends its nodes to `tree`.
#[allow(clippy::too_many_arguments)]
fn trace_component(
    comp: &Component,
    walker: &Walker,
    dbf_all: &[f64],
    ridge: Option<&[f32]>,
    params: &SkeletonParams,
    min_h: f64,
    solid: &Volume<u8>,
    tree: &mut VesselTree,
) {
    let n = comp.voxels.len();
    let dbf: Vec<f64> = comp.voxels.iter().map(|&g| dbf_all[g].min(1e6)).collect();
    let max_dbf = dbf.iter().copied().fold(0.0, f64::max).max(1e-12);
    let unit = vec![1.0; n];
    let (from_deepest, _) = dijkstra(walker, comp, argmax(&dbf), &unit);
    let root = argmax(&from_deepest);
    let (daf, _) = dijkstra(walker, comp, root, &unit);
    let mut axis: Vec<f64> = dbf.iter().map(|&d| d / max_dbf).collect();
    if let Some(ridge) = ridge {
        let r: Vec<f64> = comp.voxels.iter().map(|&g| f64::from(ridge[g]).clamp(0.0, 1.0)).collect();
        let max_r = r.iter().copied().fold(0.0, f64::max).max(1e-12);
        let beta = params.ridge_weight.clamp(0.0, 1.0);
        for (a, r) in axis.iter_mut().zip(r) {
            *a = a.powf(1.0 - beta) * (r / max_r).powf(beta);
        }
    }
    let penalty: Vec<f64> = axis.iter().map(|&a| 1.0 + PDRF_SCALE * (1.0 - a).max(0.0).powi(8)).collect();
    let (_, parent) = dijkstra(walker, comp, root, &penalty);

    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| daf[b].total_cmp(&daf[a]).then(a.cmp(&b)));
    let mut covered = vec![false; n];
    // Local voxel → node index in `tree`.
    let mut node_of = vec![u32::MAX; n];
    let node_at = |v: usize, id: usize| {
        let c = walker.coords(comp.voxels[v]);
        TreeNode {
            id: id as i64 + 1,
            kind: 0,
            position_mm: solid.grid.centre_mm(c[0] as usize, c[1] as usize, c[2] as usize),
            radius_mm: (dbf[v] - 0.5 * min_h).max(0.5 * min_h),
            parent: None,
        }
    };
    node_of[root] = tree.nodes.len() as u32;
    tree.nodes.push(node_at(root, tree.nodes.len()));
    cover(comp, walker, &dbf, params, root, &mut covered);
    for &target in &order {
        if covered[target] || !daf[target].is_finite() {
            continue;
        }
        // Walk back towards the root until the skeleton is met.
        let mut path = Vec::new();
        let mut v = target;
        while node_of[v] == u32::MAX {
            path.push(v);
            let p = parent[v];
            if p == u32::MAX {
                break;
            }
            v = p as usize;
        }
        let mut attach = (node_of[v] != u32::MAX).then(|| node_of[v] as usize);
        for &u in path.iter().rev() {
            let idx = tree.nodes.len();
            node_of[u] = idx as u32;
            tree.nodes.push(TreeNode { parent: attach, ..node_at(u, idx) });
            attach = Some(idx);
            cover(comp, walker, &dbf, params, u, &mut covered);
        }
        covered[target] = true;
    }
}

/// Marks every voxel of the component within `scale · dbf(u) + const_mm` of voxel `u` covered.
fn cover(comp: &Component, walker: &Walker, dbf: &[f64], params: &SkeletonParams, u: usize, covered: &mut [bool]) {
    let radius = params.scale * dbf[u] + params.const_mm;
    let centre = walker.coords(comp.voxels[u]);
    let spacing = walker.spacing_mm;
    // At most the grid's extent: a radius that large covers every voxel anyway.
    let reach: Vec<i64> =
        spacing.iter().zip(walker.dims).map(|(h, n)| ((radius / h).floor() as i64).min(n as i64)).collect();
    for di in -reach[0]..=reach[0] {
        for dj in -reach[1]..=reach[1] {
            for dk in -reach[2]..=reach[2] {
                let d2 = (di as f64 * spacing[0]).powi(2)
                    + (dj as f64 * spacing[1]).powi(2)
                    + (dk as f64 * spacing[2]).powi(2);
                if d2 > radius * radius {
                    continue;
                }
                if let Some(g) = walker.flat([centre[0] + di, centre[1] + dj, centre[2] + dk])
                    && comp.label[g] == comp.id
                {
                    covered[comp.local[g] as usize] = true;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::tree::Segment;
    use crate::data::volume::rasterize::rasterize_segments;
    use crate::data::volume::{BoxMm, Grid};

    fn seg(a: DVec3, b: DVec3, r: f64) -> Segment {
        Segment { child: 0, start_mm: a, end_mm: b, start_radius_mm: r, end_radius_mm: r }
    }

    fn solid_of(segments: &[Segment], voxel_mm: f64) -> Volume<u8> {
        let bounds = BoxMm { min_mm: [-5.0, -25.0, -5.0], max_mm: [45.0, 25.0, 5.0] };
        let grid = Grid::covering(&bounds, voxel_mm).unwrap();
        rasterize_segments(segments, grid, 1).map(|v| (v > 0.5) as u8)
    }

    /// Distance (mm) from `p` to the nearest of `segments`' axes.
    fn axis_distance(segments: &[Segment], p: DVec3) -> f64 {
        segments
            .iter()
            .map(|s| {
                let ab = s.end_mm - s.start_mm;
                let t = ((p - s.start_mm).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
                (p - (s.start_mm + t * ab)).length()
            })
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn a_straight_tube_gives_one_centred_branch_with_its_radius() {
        let tube = [seg(DVec3::ZERO, DVec3::new(40.0, 0.0, 0.0), 2.0)];
        let tree = skeletonize(&solid_of(&tube, 0.25), &SkeletonParams::default());
        let roots = tree.nodes.iter().filter(|n| n.parent.is_none()).count();
        assert_eq!(roots, 1);
        let children: Vec<usize> =
            (0..tree.nodes.len()).map(|i| tree.nodes.iter().filter(|n| n.parent == Some(i)).count()).collect();
        assert!(children.iter().all(|&c| c <= 1), "one branch, no spurs: {children:?}");
        // It runs along the axis from end to end (the caps' centres, 40 mm apart).
        assert!((tree.total_length_mm() - 40.0).abs() < 1.0, "length {}", tree.total_length_mm());
        for n in &tree.nodes {
            assert!(axis_distance(&tube, n.position_mm) < 0.3, "off axis: {:?}", n.position_mm);
        }
        let mid: Vec<f64> =
            tree.nodes.iter().filter(|n| (5.0..35.0).contains(&n.position_mm.x)).map(|n| n.radius_mm).collect();
        let mean = mid.iter().sum::<f64>() / mid.len() as f64;
        // Radii from the boundary distance on a 0.25 mm grid: within a voxel.
        assert!((mean - 2.0).abs() < 0.25, "radius {mean}");
    }

    /// A solid with no background voxel (a prior filling the working box): boundary distances
    /// are taken to the grid's faces, and the trace ends (it ran for ever before).
    #[test]
    fn a_solid_filling_the_box_is_traced_in_finite_time() {
        let bounds = BoxMm { min_mm: [0.0; 3], max_mm: [12.0, 8.0, 6.0] };
        let grid = Grid::covering(&bounds, 0.5).unwrap();
        let solid = Volume { grid, index_to_world: grid.index_to_world(), data: vec![1u8; grid.len()] };
        let started = std::time::Instant::now();
        let tree = skeletonize(&solid, &SkeletonParams::default());
        assert!(!tree.nodes.is_empty(), "one tree for the block");
        assert!(started.elapsed().as_secs() < 30, "took {:?}", started.elapsed());
        for n in &tree.nodes {
            assert!(n.radius_mm.is_finite() && n.radius_mm <= 4.0, "radius {} within the block", n.radius_mm);
        }
    }

    #[test]
    fn a_y_gives_one_tree_with_three_ends() {
        let o = DVec3::new(20.0, 0.0, 0.0);
        let y = [
            seg(DVec3::ZERO, o, 1.5),
            seg(o, DVec3::new(40.0, 15.0, 0.0), 1.0),
            seg(o, DVec3::new(40.0, -15.0, 0.0), 1.0),
        ];
        let tree = skeletonize(&solid_of(&y, 0.3), &SkeletonParams::default());
        assert_eq!(tree.nodes.iter().filter(|n| n.parent.is_none()).count(), 1);
        let ends = (0..tree.nodes.len())
            .filter(|&i| {
                let children = tree.nodes.iter().filter(|n| n.parent == Some(i)).count();
                children + tree.nodes[i].parent.is_some() as usize == 1
            })
            .count();
        assert_eq!(ends, 3, "three ends");
        let truth: f64 = y.iter().map(Segment::length_mm).sum();
        assert!((tree.total_length_mm() - truth).abs() < 4.0, "{} vs {truth}", tree.total_length_mm());
        let worst = tree.nodes.iter().map(|n| axis_distance(&y, n.position_mm)).fold(0.0, f64::max);
        assert!(worst < 0.6, "a node {worst} mm off the axes");
    }

    /// A narrow bright vessel merged with a wider faint one 1.2 mm away into one solid: the
    /// medial axis runs along the wider one, the path along the bright one's ridge once it
    /// follows the ridge field.
    #[test]
    fn a_ridge_field_pulls_the_path_of_a_merged_pair_onto_the_brighter_vessel() {
        let bright = seg(DVec3::ZERO, DVec3::new(40.0, 0.0, 0.0), 0.7);
        let faint = seg(DVec3::new(0.0, 1.2, 0.0), DVec3::new(40.0, 1.2, 0.0), 1.0);
        let solid = solid_of(&[bright, faint], 0.2);
        let ridge: Vec<f32> = (0..solid.data.len())
            .map(|g| {
                let [_, ny, nz] = solid.grid.dims;
                let p = solid.grid.centre_mm(g / (ny * nz), (g / nz) % ny, g % nz);
                let glow =
                    |s: &Segment, peak: f64| peak * (-axis_distance(&[*s], p).powi(2) / (2.0 * 0.4f64.powi(2))).exp();
                glow(&bright, 1.0).max(glow(&faint, 0.4)) as f32
            })
            .collect();
        // Mean distance (mm) to the bright vessel's axis of the nodes along the pair's middle.
        let off_bright = |tree: &VesselTree| {
            let mid: Vec<f64> = tree
                .nodes
                .iter()
                .filter(|n| (8.0..32.0).contains(&n.position_mm.x))
                .map(|n| axis_distance(&[bright], n.position_mm))
                .collect();
            assert!(!mid.is_empty(), "a path along the pair");
            mid.iter().sum::<f64>() / mid.len() as f64
        };
        let medial = skeletonize(&solid, &SkeletonParams::default());
        let along =
            skeletonize_along(&solid, Some(&ridge), &SkeletonParams { ridge_weight: 1.0, ..Default::default() });
        let (medial_off, along_off) = (off_bright(&medial), off_bright(&along));
        assert!(medial_off > 0.8, "the medial axis runs along the wider one: {medial_off} mm off the bright one");
        // (voxel centres lie 0.14 mm off the axis at best)
        assert!(along_off < 0.4, "the ridge path runs on the bright one: {along_off} mm off");
        // Without a weight the field changes nothing.
        let unweighted = skeletonize_along(&solid, Some(&ridge), &SkeletonParams::default());
        assert_eq!(unweighted.nodes.len(), medial.nodes.len());
    }

    #[test]
    fn separate_components_give_separate_trees_and_specks_are_left_out() {
        let parts = [
            seg(DVec3::ZERO, DVec3::new(15.0, 0.0, 0.0), 1.0),
            seg(DVec3::new(25.0, 0.0, 0.0), DVec3::new(40.0, 0.0, 0.0), 1.0),
        ];
        let mut solid = solid_of(&parts, 0.3);
        let speck = solid.grid.index(2, 2, 2);
        solid.data[speck] = 1;
        let tree = skeletonize(&solid, &SkeletonParams::default());
        assert_eq!(tree.nodes.iter().filter(|n| n.parent.is_none()).count(), 2);
        assert!(tree.skeleton_free_of(solid.grid.centre_mm(2, 2, 2)));
        let empty = Volume::<u8>::zeros(solid.grid);
        assert!(skeletonize(&empty, &SkeletonParams::default()).nodes.is_empty());
    }

    impl VesselTree {
        fn skeleton_free_of(&self, p: DVec3) -> bool {
            self.nodes.iter().all(|n| (n.position_mm - p).length() > 1.0)
        }
    }
}

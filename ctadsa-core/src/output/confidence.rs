//! Which new vessels to trust: a confidence in [0, 1] for every branch of the completed
//! centreline, from how much of it the views show on their own.
//!
//! A vessel the views really show has, in the views that place it, pixels that nothing else in
//! the completed tree covers. A ghost — a branch put where the back-projections of two other
//! vessels cross, which two views cannot tell from a vessel — projects onto those two vessels in
//! each view: it has no pixel of its own. So every branch of the completed centreline (prior
//! branches included) is drawn into every view as its tube's footprint, and a branch's *unique
//! support* in a view is the share of its length (away from its junctions) whose projected axis
//! falls on a pixel no other branch covers. A branch is placed by two views: its view support is
//! the second-lowest unique support over the views (with 2 views the lower one, with 3 the
//! middle one), so that a vessel hidden in one of three views keeps its confidence. Short pieces
//! are the least reliable (a fragment a few voxels long fits the views by chance more easily
//! than a branch): the confidence is the view support × (1 − exp(−length / 4 mm)). With two
//! views, where any ghost that two vessels make can have pixels of its own when those vessels
//! were not found, a new branch whose tree never reaches the prior (it floats free, as ghosts do
//! and few vessels) has that halved ([`FLOATING_FACTOR`]). Prior branches have confidence 1.

use std::fmt::Write as _;
use std::path::Path;

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::data::mesh::TriMesh;
use crate::data::mesh::io::{read_ply_with, write_ply_with};
use crate::data::tree::{KIND_NEW_VESSEL, KIND_PRIOR_VESSEL, VesselTree};
use crate::error::{Result, write_file};
use crate::eval::metrics::nearest_points;

/// Bins of the confidence in `summary.json` and the pictures: `[k/BINS, (k+1)/BINS)`, the last
/// one closed.
pub const CONFIDENCE_BINS: usize = 5;

/// Step of the samples along a branch (mm).
const SAMPLE_MM: f64 = 0.25;

/// Length scale of the confidence's length factor `1 − exp(−length / LENGTH_SCALE_MM)` (mm):
/// of 0 (none), 2, 4 and 8 mm, 4 gave the top confidence bin ≥ 0.89 precision with both view
/// counts while keeping precision rising bin by bin (docs/RESULTS.md, "Which new vessels to
/// trust").
pub const LENGTH_SCALE_MM: f64 = 4.0;

/// Factor on the confidence of a new branch whose tree (connected component) holds no prior
/// node, in runs of at most [`FLOATING_MAX_VIEWS`] views. On the 8 BraVa trees (512² views,
/// 2 views) the new centreline ranked by confidence is then more precise in its top fifth on 8
/// of 8 trees (71 → 78 %); with 3 views, where the third view decides, it made some trees better
/// and as many worse (docs/RESULTS.md, "Which new vessels to trust").
pub const FLOATING_FACTOR: f64 = 0.5;

/// Runs of at most this many views apply [`FLOATING_FACTOR`].
pub const FLOATING_MAX_VIEWS: usize = 2;

/// One branch of the completed centreline: a chain of nodes from a root or junction to the next
/// junction or end ([`VesselTree::branches`]), cut where it passes from a prior vessel to a new
/// one, so that a new vessel grown from a prior vessel's end is a branch of its own.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Branch {
    /// Node indices, away from the root (the first one is shared with the parent branch).
    pub nodes: Vec<usize>,
    /// Whether it is new (its nodes after the first of type [`KIND_NEW_VESSEL`]).
    pub new: bool,
    /// Length (mm).
    pub length_mm: f64,
    /// Length-weighted mean radius (mm).
    pub mean_radius_mm: f64,
    /// Whether its tree (connected component) holds a prior node.
    pub connected_to_prior: bool,
    /// Per view: the share of its length whose projection no other branch covers.
    pub unique_support: Vec<f64>,
    /// In [0, 1]; 1 for prior branches.
    pub confidence: f64,
}

/// A point along a branch: position (mm), radius (mm), the length it stands for (mm), and
/// whether it lies near a junction (where the neighbouring branches' footprints overlap it).
struct Sample {
    position_mm: DVec3,
    radius_mm: f64,
    length_mm: f64,
    near_junction: bool,
}

fn samples(tree: &VesselTree, chain: &[usize], degree: &[usize]) -> Vec<Sample> {
    let node = |i: usize| &tree.nodes[i];
    let junctions: Vec<(DVec3, f64)> = [chain[0], chain[chain.len() - 1]]
        .into_iter()
        .filter(|&i| degree[i] >= 3)
        .map(|i| (node(i).position_mm, node(i).radius_mm))
        .collect();
    let mut out = Vec::new();
    for pair in chain.windows(2) {
        let (a, b) = (node(pair[0]), node(pair[1]));
        let len = a.position_mm.distance(b.position_mm);
        if !(len > 0.0) {
            continue;
        }
        let steps = (len / SAMPLE_MM).ceil().clamp(1.0, 1e6) as usize;
        for k in 0..steps {
            let t = (k as f64 + 0.5) / steps as f64;
            let position_mm = a.position_mm.lerp(b.position_mm, t);
            let radius_mm = a.radius_mm + (b.radius_mm - a.radius_mm) * t;
            let near_junction = junctions.iter().any(|&(j, rj)| position_mm.distance(j) < 2.0 * (rj + radius_mm));
            out.push(Sample { position_mm, radius_mm, length_mm: len / steps as f64, near_junction });
        }
    }
    out
}

/// Which branch covers each pixel of one view: the first one drawn, and whether another one
/// covers it too.
struct Coverage {
    width: i64,
    height: i64,
    first: Vec<u32>,
    shared: Vec<bool>,
}

impl Coverage {
    const NONE: u32 = u32::MAX;

    fn new(view: &ConeBeamView) -> Self {
        let n = view.width() as usize * view.height() as usize;
        Self {
            width: view.width() as i64,
            height: view.height() as i64,
            first: vec![Self::NONE; n],
            shared: vec![false; n],
        }
    }

    /// The pixel holding detector position `(u, v)`, if on the detector.
    fn pixel(&self, u: f64, v: f64) -> Option<usize> {
        let (i, j) = (u.floor(), v.floor());
        (i >= 0.0 && j >= 0.0 && (i as i64) < self.width && (j as i64) < self.height)
            .then(|| (j as i64 * self.width + i as i64) as usize)
    }

    /// Marks the disk of `radius_px` around `(u, v)` (at least the pixel holding it) as covered
    /// by `branch`.
    fn draw(&mut self, u: f64, v: f64, radius_px: f64, branch: u32) {
        let r = radius_px.clamp(0.5, 1e4);
        let (i0, i1) = (((u - r).floor() as i64).max(0), ((u + r).floor() as i64).min(self.width - 1));
        let (j0, j1) = (((v - r).floor() as i64).max(0), ((v + r).floor() as i64).min(self.height - 1));
        let centre = self.pixel(u, v);
        for j in j0..=j1 {
            for i in i0..=i1 {
                let (du, dv) = (i as f64 + 0.5 - u, j as f64 + 0.5 - v);
                let p = (j * self.width + i) as usize;
                if du * du + dv * dv <= r * r || Some(p) == centre {
                    self.mark(p, branch);
                }
            }
        }
    }

    fn mark(&mut self, p: usize, branch: u32) {
        if self.first[p] == Self::NONE {
            self.first[p] = branch;
        } else if self.first[p] != branch {
            self.shared[p] = true;
        }
    }

    fn owned_by(&self, p: usize, branch: u32) -> bool {
        self.first[p] == branch && !self.shared[p]
    }
}

/// `(u, v, radius in pixels)` of a sample in `view`, if in front of the source.
fn projected(view: &ConeBeamView, s: &Sample) -> Option<(f64, f64, f64)> {
    let uv = view.project(s.position_mm)?;
    let depth = view.to_camera(s.position_mm).z;
    let focal = view.intrinsics().focal_px;
    Some((uv.x, uv.y, s.radius_mm * focal[0].min(focal[1]) / depth))
}

/// The view support of `supports` (one per view): the second-lowest (the lowest with one view).
pub fn view_support(supports: &[f64]) -> f64 {
    let mut s = supports.to_vec();
    s.sort_by(f64::total_cmp);
    match s.len() {
        0 => 0.0,
        1 => s[0],
        n => s[n - 2],
    }
}

/// The branches of `tree` with their unique support in `views` and their confidence.
pub fn branch_confidence(tree: &VesselTree, views: &[ConeBeamView]) -> Vec<Branch> {
    let chains = kind_branches(tree);
    let children = tree.children();
    let degree: Vec<usize> =
        tree.nodes.iter().enumerate().map(|(i, n)| children[i].len() + n.parent.is_some() as usize).collect();
    let component_has_prior = prior_components(tree);
    let sampled: Vec<Vec<Sample>> = chains.iter().map(|c| samples(tree, c, &degree)).collect();
    let coverages: Vec<Coverage> = views
        .iter()
        .map(|view| {
            let mut coverage = Coverage::new(view);
            for (b, ss) in sampled.iter().enumerate() {
                for (u, v, r) in ss.iter().filter_map(|s| projected(view, s)) {
                    coverage.draw(u, v, r, b as u32);
                }
            }
            coverage
        })
        .collect();
    chains
        .into_iter()
        .zip(&sampled)
        .enumerate()
        .map(|(b, (nodes, ss))| {
            let length_mm: f64 = ss.iter().map(|s| s.length_mm).sum();
            let new = tree.nodes[nodes[1]].kind == KIND_NEW_VESSEL;
            let mean_radius_mm = if length_mm > 0.0 {
                ss.iter().map(|s| s.radius_mm * s.length_mm).sum::<f64>() / length_mm
            } else {
                tree.nodes[nodes[0]].radius_mm
            };
            // Away from the junctions, unless that leaves nothing.
            let away: Vec<&Sample> = ss.iter().filter(|s| !s.near_junction).collect();
            let counted: Vec<&Sample> = if away.is_empty() { ss.iter().collect() } else { away };
            let total: f64 = counted.iter().map(|s| s.length_mm).sum();
            let unique_support: Vec<f64> = views
                .iter()
                .zip(&coverages)
                .map(|(view, coverage)| {
                    let own: f64 = counted
                        .iter()
                        .filter(|s| {
                            projected(view, s)
                                .and_then(|(u, v, _)| coverage.pixel(u, v))
                                .is_some_and(|p| coverage.owned_by(p, b as u32))
                        })
                        .map(|s| s.length_mm)
                        .sum();
                    if total > 0.0 { own / total } else { 0.0 }
                })
                .collect();
            let connected_to_prior = component_has_prior[component_root(tree, nodes[0])];
            let floating = if !connected_to_prior && views.len() <= FLOATING_MAX_VIEWS { FLOATING_FACTOR } else { 1.0 };
            let confidence = if new {
                view_support(&unique_support) * (1.0 - (-length_mm / LENGTH_SCALE_MM).exp()) * floating
            } else {
                1.0
            };
            Branch { nodes, new, length_mm, mean_radius_mm, connected_to_prior, unique_support, confidence }
        })
        .collect()
}

/// [`VesselTree::branches`], each cut at the nodes after which the node type changes: every
/// chain's nodes after its first are all new or all not.
pub fn kind_branches(tree: &VesselTree) -> Vec<Vec<usize>> {
    let is_new = |i: usize| tree.nodes[i].kind == KIND_NEW_VESSEL;
    let mut out = Vec::new();
    for chain in tree.branches() {
        let mut start = 0;
        for k in 2..chain.len() {
            if is_new(chain[k]) != is_new(chain[k - 1]) {
                out.push(chain[start..k].to_vec());
                start = k - 1;
            }
        }
        out.push(chain[start..].to_vec());
    }
    out
}

fn component_root(tree: &VesselTree, mut i: usize) -> usize {
    while let Some(p) = tree.nodes[i].parent {
        i = p;
    }
    i
}

/// For every root: whether its tree holds a node of type [`KIND_PRIOR_VESSEL`].
fn prior_components(tree: &VesselTree) -> Vec<bool> {
    let mut has = vec![false; tree.nodes.len()];
    for (i, n) in tree.nodes.iter().enumerate() {
        if n.kind == KIND_PRIOR_VESSEL {
            has[component_root(tree, i)] = true;
        }
    }
    has
}

/// `tree` without the new branches whose confidence is below `min_confidence` (their nodes
/// other than the one they start from), and the kept nodes' `confidence`. A branch hanging from
/// a dropped one becomes a tree of its own.
pub fn without_doubtful_branches(
    tree: &VesselTree,
    branches: &[Branch],
    confidence: &[f64],
    min_confidence: f64,
) -> (VesselTree, Vec<f64>) {
    let drop: Vec<bool> = branches.iter().map(|b| b.new && b.confidence < min_confidence).collect();
    without_branches(tree, branches, &drop, confidence)
}

/// `tree` without the branches marked in `drop` (their nodes other than the one they start from,
/// prior nodes kept), and the kept nodes' `confidence`. A branch hanging from a dropped one
/// becomes a tree of its own.
pub fn without_branches(
    tree: &VesselTree,
    branches: &[Branch],
    drop: &[bool],
    confidence: &[f64],
) -> (VesselTree, Vec<f64>) {
    let mut keep = vec![true; tree.nodes.len()];
    for (b, _) in branches.iter().zip(drop).filter(|(_, d)| **d) {
        for &i in &b.nodes[1..] {
            keep[i] = tree.nodes[i].kind == KIND_PRIOR_VESSEL;
        }
    }
    let mut index = vec![usize::MAX; tree.nodes.len()];
    let mut out = VesselTree::default();
    let mut kept_confidence = Vec::new();
    for (i, n) in tree.nodes.iter().enumerate().filter(|(i, _)| keep[*i]) {
        index[i] = out.nodes.len();
        out.nodes.push(*n);
        kept_confidence.push(confidence[i]);
    }
    for n in &mut out.nodes {
        // Parents come before their children in a centreline tree, but not necessarily in any
        // tree: map after all kept nodes have their index.
        n.parent = n.parent.and_then(|p| (index[p] != usize::MAX).then_some(index[p]));
    }
    (out, kept_confidence)
}

/// `mesh` without the faces whose vertices' mean confidence is below `min_confidence`.
pub fn mesh_without_doubtful(mesh: &TriMesh, vertex_confidence: &[f64], min_confidence: f64) -> TriMesh {
    let faces = mesh
        .faces
        .iter()
        .filter(|f| f.iter().map(|&i| vertex_confidence[i as usize]).sum::<f64>() / 3.0 >= min_confidence)
        .copied()
        .collect();
    TriMesh { vertices: mesh.vertices.clone(), faces }.compacted()
}

/// Every vertex's confidence: that of the nearest node of `tree`.
pub fn vertex_confidence(mesh: &TriMesh, tree: &VesselTree, node_confidence: &[f64]) -> Vec<f64> {
    let nodes: Vec<DVec3> = tree.nodes.iter().map(|n| n.position_mm).collect();
    nearest_points(&mesh.vertices, &nodes)
        .iter()
        .map(|&(_, i)| node_confidence.get(i).copied().unwrap_or(1.0))
        .collect()
}

/// Every node's confidence: the confidence of the branch it ends or lies inside (1 for the
/// prior's); roots take that of their first branch.
pub fn node_confidence(tree: &VesselTree, branches: &[Branch]) -> Vec<f64> {
    let mut out = vec![f64::NAN; tree.nodes.len()];
    for b in branches {
        for &i in &b.nodes[1..] {
            out[i] = b.confidence;
        }
        if out[b.nodes[0]].is_nan() && tree.nodes[b.nodes[0]].parent.is_none() {
            out[b.nodes[0]] = b.confidence;
        }
    }
    out.iter().map(|c| if c.is_nan() { 1.0 } else { *c }).collect()
}

/// The new length (mm) and the part of it on a true vessel in one confidence bin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ConfidenceBin {
    pub from: f64,
    pub to: f64,
    pub new_length_mm: f64,
    /// `None` without a true tree.
    pub true_length_mm: Option<f64>,
    pub precision: Option<f64>,
}

/// The bin of `confidence`.
pub fn bin_of(confidence: f64) -> usize {
    ((confidence * CONFIDENCE_BINS as f64).floor() as usize).min(CONFIDENCE_BINS - 1)
}

/// The new length per confidence bin from `(confidence, length, true length)` of each new piece.
pub fn confidence_bins(pieces: impl Iterator<Item = (f64, f64, Option<f64>)>) -> Vec<ConfidenceBin> {
    let mut bins: Vec<ConfidenceBin> = (0..CONFIDENCE_BINS)
        .map(|k| ConfidenceBin {
            from: k as f64 / CONFIDENCE_BINS as f64,
            to: (k + 1) as f64 / CONFIDENCE_BINS as f64,
            new_length_mm: 0.0,
            true_length_mm: None,
            precision: None,
        })
        .collect();
    for (confidence, length, truth) in pieces {
        let bin = &mut bins[bin_of(confidence)];
        bin.new_length_mm += length;
        if let Some(t) = truth {
            *bin.true_length_mm.get_or_insert(0.0) += t;
        }
    }
    for b in &mut bins {
        b.precision = b.true_length_mm.filter(|_| b.new_length_mm > 0.0).map(|t| t / b.new_length_mm);
    }
    bins
}

/// `branches.csv`: one row per branch (lengths and radii in mm), with its arrival agreement
/// ([`crate::output::arrival::arrival_agreement`]; empty where not checked).
pub fn write_branches_csv(path: &Path, branches: &[Branch], views: usize, arrival: &[Option<f64>]) -> Result<()> {
    let mut s = String::from("branch,new,length_mm,mean_radius_mm,connected_to_prior,confidence");
    for v in 0..views {
        let _ = write!(s, ",unique_support_view{v}");
    }
    s.push_str(",arrival_agreement\n");
    for (k, b) in branches.iter().enumerate() {
        let _ = write!(
            s,
            "{k},{},{:.3},{:.3},{},{:.3}",
            b.new as u8, b.length_mm, b.mean_radius_mm, b.connected_to_prior as u8, b.confidence
        );
        for u in &b.unique_support {
            let _ = write!(s, ",{u:.3}");
        }
        match arrival.get(k).copied().flatten() {
            Some(a) => {
                let _ = writeln!(s, ",{a:.3}");
            }
            None => s.push_str(",\n"),
        }
    }
    write_file(path, s.as_bytes())
}

/// The completed mesh with each vertex's confidence: `mesh-confidence.ply`.
pub const MESH_CONFIDENCE: &str = "mesh-confidence.ply";

/// Writes `mesh` as binary PLY with a float `confidence` per vertex ([`vertex_confidence`]).
pub fn write_mesh_confidence(path: &Path, mesh: &TriMesh, vertex_confidence: &[f64]) -> Result<()> {
    let comment = "ctadsa completed mesh, world coordinates in mm; confidence of the nearest centreline branch (1 = prior vessel)";
    write_ply_with(path, mesh, &[("confidence", vertex_confidence)], comment)
}

/// Reads what [`write_mesh_confidence`] wrote: the mesh and each vertex's confidence. Errors
/// name the file.
pub fn read_mesh_confidence(path: &Path) -> Result<(TriMesh, Vec<f32>)> {
    let (mesh, confidence) = read_ply_with(path, "confidence")?;
    Ok((mesh, confidence.into_iter().map(|c| c as f32).collect()))
}

/// The faces of `mesh` in one mesh per confidence bin, by the mean of their vertices'
/// `vertex_confidence`.
pub fn faces_by_confidence(mesh: &TriMesh, vertex_confidence: &[f32]) -> Vec<TriMesh> {
    let mut bins = vec![TriMesh { vertices: mesh.vertices.clone(), faces: Vec::new() }; CONFIDENCE_BINS];
    for f in &mesh.faces {
        let c = f.iter().map(|&i| vertex_confidence.get(i as usize).copied().unwrap_or(1.0) as f64).sum::<f64>() / 3.0;
        bins[bin_of(c)].faces.push(*f);
    }
    bins.iter().map(TriMesh::compacted).collect()
}

/// Colour of a confidence: red (0) through yellow to green (1).
pub fn confidence_rgb(confidence: f64) -> [u8; 3] {
    let c = confidence.clamp(0.0, 1.0);
    if c < 0.5 {
        [220, (60.0 + 340.0 * c) as u8, 40]
    } else {
        [(220.0 - 380.0 * (c - 0.5)) as u8, 230 - (60.0 * (c - 0.5)) as u8, 40]
    }
}

#[cfg(test)]
mod tests {
    use ctadsa_render::TigreGeometry;

    use super::*;
    use crate::data::tree::TreeNode;

    fn view(primary_deg: f64) -> ConeBeamView {
        ConeBeamView::from_tigre(&TigreGeometry {
            dsd_mm: 700.0,
            dso_mm: 500.0,
            detector_px: [128, 128],
            pixel_mm: [1.0, 1.0],
            offset_mm: [0.0, 0.0],
            primary_deg,
            secondary_deg: 0.0,
        })
        .unwrap()
    }

    /// A straight chain of `kind` nodes from `a` to `b` (radius 0.5 mm), its root at `a`.
    fn chain(tree: &mut VesselTree, a: DVec3, b: DVec3, kind: i32) {
        let n = 20;
        let first = tree.nodes.len();
        for k in 0..=n {
            let parent = if k == 0 { None } else { Some(first + k - 1) };
            let position_mm = a.lerp(b, k as f64 / n as f64);
            tree.nodes.push(TreeNode { id: 0, kind, position_mm, radius_mm: 0.5, parent });
        }
    }

    #[test]
    fn a_ghost_where_two_vessels_cross_has_no_support_and_the_vessels_keep_theirs() {
        // Two views along x and along y (primary 0° and 90°); vessel X runs along z at
        // (0, 10), vessel Y along z at (10, 0). A ghost at (10, 10) lies on X's ray in one view
        // and on Y's in the other: it covers no pixel of its own in either.
        let views = [view(0.0), view(90.0)];
        let (lo, hi) = (-15.0, 15.0);
        let mut tree = VesselTree::default();
        chain(&mut tree, DVec3::new(0.0, 10.0, lo), DVec3::new(0.0, 10.0, hi), KIND_NEW_VESSEL);
        chain(&mut tree, DVec3::new(10.0, 0.0, lo), DVec3::new(10.0, 0.0, hi), KIND_NEW_VESSEL);
        chain(&mut tree, DVec3::new(10.0, 10.0, lo), DVec3::new(10.0, 10.0, hi), KIND_NEW_VESSEL);
        let branches = branch_confidence(&tree, &views);
        assert_eq!(branches.len(), 3);
        let ghost = &branches[2];
        assert!(ghost.confidence < 0.05, "ghost {ghost:?}");
        // X and Y lose the ghost's share in the view where it hides behind them, not the other.
        for b in &branches[..2] {
            assert!(b.unique_support.iter().any(|&u| u > 0.95), "{b:?}");
        }
        // Without the ghost both are fully their own in both views (and, floating free of any
        // prior with two views, keep half the confidence).
        tree.nodes.truncate(42);
        for b in branch_confidence(&tree, &views) {
            assert!(b.unique_support.iter().all(|&u| u > 0.95), "{b:?}");
            assert!(b.new && !b.connected_to_prior);
            assert!(b.confidence > 0.95 * FLOATING_FACTOR && b.confidence <= FLOATING_FACTOR, "{b:?}");
        }
    }

    #[test]
    fn with_two_views_a_branch_floating_free_of_the_prior_keeps_half_the_confidence() {
        // A new branch hanging from a prior trunk, and the same branch cut loose (no parent).
        let trunk_and_branch = |attached: bool| {
            let mut tree = VesselTree::default();
            chain(&mut tree, DVec3::new(0.0, 0.0, -10.0), DVec3::new(0.0, 0.0, 10.0), KIND_PRIOR_VESSEL);
            let first = tree.nodes.len();
            chain(&mut tree, DVec3::new(1.0, 1.0, 1.0), DVec3::new(9.0, 9.0, 9.0), KIND_NEW_VESSEL);
            tree.nodes[first].parent = attached.then_some(10);
            tree
        };
        let new_confidence = |tree: &VesselTree, views: &[ConeBeamView]| {
            let branches = branch_confidence(tree, views);
            let new: Vec<&Branch> = branches.iter().filter(|b| b.new).collect();
            assert_eq!(new.len(), 1);
            (new[0].confidence, new[0].connected_to_prior)
        };
        let two = [view(0.0), view(90.0)];
        let (attached, joined) = new_confidence(&trunk_and_branch(true), &two);
        let (loose, floating) = new_confidence(&trunk_and_branch(false), &two);
        assert!(joined && !floating);
        assert!(attached > 0.5, "{attached}");
        // The loose branch covers one more node's footprint of its own (its first is not shared
        // with the trunk): its support is at least the attached one's.
        assert!(loose <= FLOATING_FACTOR * 1.0 && loose >= FLOATING_FACTOR * attached * 0.95, "{loose} vs {attached}");
        // Three views: the third view decides, no factor.
        let three = [view(0.0), view(90.0), view(45.0)];
        let (attached3, _) = new_confidence(&trunk_and_branch(true), &three);
        let (loose3, _) = new_confidence(&trunk_and_branch(false), &three);
        assert!((loose3 - attached3).abs() < 0.1 * attached3, "{loose3} vs {attached3}");
    }

    #[test]
    fn prior_branches_are_trusted_and_nodes_take_their_branch_confidence() {
        let views = [view(0.0), view(90.0)];
        let mut tree = VesselTree::default();
        chain(&mut tree, DVec3::new(0.0, 0.0, -10.0), DVec3::new(0.0, 0.0, 10.0), KIND_PRIOR_VESSEL);
        // A new branch grown from the middle of the prior trunk (node 10, a junction).
        let first = tree.nodes.len();
        chain(&mut tree, DVec3::new(0.0, 0.0, 0.0), DVec3::new(8.0, 8.0, 8.0), KIND_NEW_VESSEL);
        tree.nodes[first].parent = Some(10);
        let branches = branch_confidence(&tree, &views);
        assert!(branches.iter().all(|b| b.connected_to_prior));
        let prior = branches.iter().find(|b| !b.new).unwrap();
        assert_eq!(prior.confidence, 1.0);
        let nodes = node_confidence(&tree, &branches);
        assert_eq!(nodes[0], 1.0);
        let new = branches.iter().find(|b| b.new).unwrap();
        assert_eq!(nodes[*new.nodes.last().unwrap()], new.confidence);
    }

    #[test]
    fn a_new_vessel_grown_from_a_prior_end_is_a_branch_of_its_own() {
        let mut tree = VesselTree::default();
        chain(&mut tree, DVec3::new(0.0, 0.0, -10.0), DVec3::new(0.0, 0.0, 0.0), KIND_PRIOR_VESSEL);
        let first = tree.nodes.len();
        chain(&mut tree, DVec3::new(0.0, 0.0, 0.25), DVec3::new(0.0, 0.0, 3.0), KIND_NEW_VESSEL);
        tree.nodes[first].parent = Some(first - 1);
        assert_eq!(tree.branches().len(), 1);
        let cut = kind_branches(&tree);
        assert_eq!(cut.len(), 2);
        assert_eq!(cut[1][0], first - 1, "the new branch starts from the prior's end");
        let branches = branch_confidence(&tree, &[view(0.0), view(90.0)]);
        assert!(!branches[0].new && branches[1].new);
        assert!(branches[1].confidence < 0.6, "a 3 mm piece: {}", branches[1].confidence);
        let nodes = node_confidence(&tree, &branches);
        assert_eq!(nodes[first - 1], 1.0);
        assert_eq!(nodes[tree.nodes.len() - 1], branches[1].confidence);
    }

    #[test]
    fn doubtful_branches_are_dropped_and_what_hangs_from_them_kept() {
        let views = [view(0.0), view(90.0)];
        let mut tree = VesselTree::default();
        chain(&mut tree, DVec3::new(0.0, 0.0, -10.0), DVec3::new(0.0, 0.0, 10.0), KIND_PRIOR_VESSEL);
        let first = tree.nodes.len();
        chain(&mut tree, DVec3::new(0.0, 0.0, 0.0), DVec3::new(8.0, 8.0, 8.0), KIND_NEW_VESSEL);
        tree.nodes[first].parent = Some(10);
        let branches = branch_confidence(&tree, &views);
        let confidence = node_confidence(&tree, &branches);
        let new = branches.iter().find(|b| b.new).unwrap().confidence;
        let (kept, c) = without_doubtful_branches(&tree, &branches, &confidence, new - 1e-9);
        assert_eq!(kept.nodes.len(), tree.nodes.len());
        let (kept, c2) = without_doubtful_branches(&tree, &branches, &confidence, new + 1e-9);
        assert_eq!(kept.nodes.len(), 21, "only the prior trunk is left");
        assert!(kept.nodes.iter().all(|n| n.kind == KIND_PRIOR_VESSEL) && c2.iter().all(|&x| x == 1.0));
        assert_eq!(c.len(), tree.nodes.len());
        assert!(kept.nodes[1..].iter().all(|n| n.parent.is_some()));
    }

    #[test]
    fn the_mesh_confidence_ply_reads_back() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let mesh = TriMesh {
            vertices: vec![DVec3::ZERO, DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, 5.0, 0.0)],
            faces: vec![[0, 1, 2]],
        };
        let mut tree = VesselTree::default();
        chain(&mut tree, DVec3::ZERO, DVec3::new(0.0, 5.0, 0.0), KIND_NEW_VESSEL);
        let conf: Vec<f64> = (0..tree.nodes.len()).map(|i| i as f64 / 20.0).collect();
        let path = dir.join(MESH_CONFIDENCE);
        write_mesh_confidence(&path, &mesh, &vertex_confidence(&mesh, &tree, &conf)).unwrap();
        let (back, c) = read_mesh_confidence(&path).unwrap();
        assert_eq!(back.faces, mesh.faces);
        assert_eq!(c, vec![0.0, 0.0, 1.0]);
        std::fs::write(&path, b"ply\nend_header\n").unwrap();
        assert!(read_mesh_confidence(&path).unwrap_err().to_string().contains(MESH_CONFIDENCE));
    }

    #[test]
    fn the_second_lowest_support_decides_and_bins_sum_lengths() {
        assert_eq!(view_support(&[0.2, 0.9]), 0.2);
        assert_eq!(view_support(&[0.0, 0.9, 0.8]), 0.8);
        assert_eq!(view_support(&[0.7]), 0.7);
        let bins = confidence_bins([(0.05, 2.0, Some(1.0)), (1.0, 3.0, Some(3.0)), (0.99, 1.0, Some(0.0))].into_iter());
        assert_eq!(bins[0].new_length_mm, 2.0);
        assert_eq!(bins[0].precision, Some(0.5));
        assert_eq!(bins[CONFIDENCE_BINS - 1].new_length_mm, 4.0);
        assert_eq!(bins[CONFIDENCE_BINS - 1].precision, Some(0.75));
        assert_eq!(bins[2].precision, None);
    }
}

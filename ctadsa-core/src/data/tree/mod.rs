//! Vessel trees: centrelines with radii (mm), as in SWC files.

pub mod gaussians;
pub mod graph;
pub mod prior;
pub mod procedural;
pub mod swc;
pub mod vtp;

use glam::DVec3;

/// SWC type of a centreline node on a vessel the prior (CTA) already had — the type BraVa's
/// trees use for every vessel.
pub const KIND_PRIOR_VESSEL: i32 = 3;
/// SWC type of a centreline node on a vessel the completion added.
pub const KIND_NEW_VESSEL: i32 = 4;

/// One centreline node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeNode {
    /// The node's id in its source (SWC id), kept for reporting.
    pub id: i64,
    /// SWC structure type (kept as read; 0 when unknown).
    pub kind: i32,
    /// Position (mm).
    pub position_mm: DVec3,
    /// Vessel radius at the node (mm).
    pub radius_mm: f64,
    /// Index of the parent node in [`VesselTree::nodes`], `None` for a root.
    pub parent: Option<usize>,
}

/// A forest of centreline trees. Every non-root node with its parent forms one segment,
/// a tube whose radius goes linearly from the parent's radius to the node's.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VesselTree {
    pub nodes: Vec<TreeNode>,
}

/// One segment: from the parent node to the child node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Index of the child node (the segment's identity).
    pub child: usize,
    pub start_mm: DVec3,
    pub end_mm: DVec3,
    pub start_radius_mm: f64,
    pub end_radius_mm: f64,
}

impl Segment {
    /// Length (mm).
    pub fn length_mm(&self) -> f64 {
        (self.end_mm - self.start_mm).length()
    }

    /// The segment's diameter: twice the mean of its end radii (mm).
    pub fn diameter_mm(&self) -> f64 {
        self.start_radius_mm + self.end_radius_mm
    }
}

impl VesselTree {
    /// All segments (one per non-root node), in node order.
    pub fn segments(&self) -> Vec<Segment> {
        self.nodes
            .iter()
            .enumerate()
            .filter_map(|(i, n)| {
                n.parent.map(|p| {
                    let pn = &self.nodes[p];
                    Segment {
                        child: i,
                        start_mm: pn.position_mm,
                        end_mm: n.position_mm,
                        start_radius_mm: pn.radius_mm,
                        end_radius_mm: n.radius_mm,
                    }
                })
            })
            .collect()
    }

    /// Axis-aligned bounding box of the tubes `(min, max)` (mm), or `None` for an empty tree.
    pub fn bounds_mm(&self) -> Option<(DVec3, DVec3)> {
        let mut it = self.nodes.iter();
        let first = it.next()?;
        let r = DVec3::splat(first.radius_mm);
        let init = (first.position_mm - r, first.position_mm + r);
        Some(it.fold(init, |(lo, hi), n| {
            let r = DVec3::splat(n.radius_mm);
            (lo.min(n.position_mm - r), hi.max(n.position_mm + r))
        }))
    }

    /// Translates the tree so that the centre of its bounding box is at the origin
    /// (the isocentre); returns the translation applied (mm).
    pub fn centre_on_isocentre(&mut self) -> DVec3 {
        let Some((lo, hi)) = self.bounds_mm() else {
            return DVec3::ZERO;
        };
        let shift = -(lo + hi) / 2.0;
        for n in &mut self.nodes {
            n.position_mm += shift;
        }
        shift
    }

    /// Applies a rigid transform `x ↦ R x + t` (R a rotation, t in mm).
    pub fn transform(&mut self, rotation: glam::DMat3, translation_mm: DVec3) {
        for n in &mut self.nodes {
            n.position_mm = rotation * n.position_mm + translation_mm;
        }
    }

    /// Total centreline length (mm).
    pub fn total_length_mm(&self) -> f64 {
        self.segments().iter().map(Segment::length_mm).sum()
    }
}

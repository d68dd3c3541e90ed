//! A procedural arterial tree, grown by a simplified constrained constructive optimisation
//! (CCO, Schreiner & Buxbaum 1993): terminals are added one at a time at random points of an
//! ellipsoidal perfusion domain, each farther than a shrinking minimum distance from the tree,
//! and joined to the segment that minimises the added branch length, at the centroid of the
//! segment's ends and the new terminal. Radii follow Murray's law with equal terminal flows:
//! `r = r_terminal · (terminals downstream)^(1/γ)`, γ = 3.
// Index loops over parallel arrays read more plainly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{TreeNode, VesselTree};
use crate::error::{CoreError, Result};

/// Parameters of the procedural tree.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProceduralTree {
    /// Random seed; the same seed gives the same tree.
    pub seed: u64,
    /// Number of terminal segments.
    pub terminals: usize,
    /// Semi-axes of the ellipsoidal domain (mm), centred on the origin.
    pub domain_mm: [f64; 3],
    /// Radius of the terminal segments (mm).
    pub terminal_radius_mm: f64,
    /// Murray's law exponent γ.
    pub murray_exponent: f64,
}

impl Default for ProceduralTree {
    fn default() -> Self {
        Self { seed: 1, terminals: 120, domain_mm: [32.0, 32.0, 26.0], terminal_radius_mm: 0.3, murray_exponent: 3.0 }
    }
}

fn point_segment_distance(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    (p - (a + t * ab)).length()
}

/// Most terminals a procedural tree may have: growth takes time quadratic in their number
/// (8,000 take about 17 s on one core) and more would fill the domain with vessel.
pub const MAX_TERMINALS: usize = 10_000;

impl ProceduralTree {
    /// Grows the tree. Fails only for invalid parameters.
    pub fn generate(&self) -> Result<VesselTree> {
        let [a, b, c] = self.domain_mm;
        if !((1..=MAX_TERMINALS).contains(&self.terminals) && a > 0.0 && b > 0.0 && c > 0.0) {
            return Err(CoreError::invalid(format!(
                "procedural tree needs 1 to {MAX_TERMINALS} terminals and positive domain semi-axes, got {} and {:?}",
                self.terminals, self.domain_mm
            )));
        }
        if !(self.terminal_radius_mm > 0.0 && self.murray_exponent >= 1.0) {
            return Err(CoreError::invalid("terminal radius must be > 0 and the Murray exponent ≥ 1"));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let sample = |rng: &mut ChaCha8Rng| loop {
            let p = DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
            if p.length_squared() <= 1.0 {
                return p * DVec3::new(a, b, c);
            }
        };
        // Nodes: positions and parents; segments are (parent → child) for non-roots.
        let inlet = DVec3::new(0.0, 0.0, -c);
        let mut pos = vec![inlet, DVec3::new(0.0, 0.0, -0.2 * c)];
        let mut parent: Vec<Option<usize>> = vec![None, Some(0)];
        let volume = 4.0 / 3.0 * std::f64::consts::PI * a * b * c;
        let mut tries_without_success = 0;
        let mut terminals = 1;
        while terminals < self.terminals {
            // The exclusion distance shrinks with the number of terminals already placed,
            // and relaxes further when candidates keep failing.
            let d_min = 0.6 * (volume / (terminals + 1) as f64).cbrt() * 0.9f64.powi(tries_without_success / 50);
            let x = sample(&mut rng);
            let mut best: Option<(f64, usize)> = None;
            let mut too_close = false;
            for child in 1..pos.len() {
                let Some(p) = parent[child] else { continue };
                let d = point_segment_distance(x, pos[p], pos[child]);
                if d < d_min {
                    too_close = true;
                    break;
                }
                let bif = (pos[p] + pos[child] + x) / 3.0;
                let added = (x - bif).length();
                if best.is_none_or(|(cost, _)| added < cost) {
                    best = Some((added, child));
                }
            }
            if too_close {
                tries_without_success += 1;
                continue;
            }
            tries_without_success = 0;
            let Some((_, child)) = best else { continue };
            let p = parent[child].expect("segment child has a parent");
            let bif = (pos[p] + pos[child] + x) / 3.0;
            let b_idx = pos.len();
            pos.push(bif);
            parent.push(Some(p));
            parent[child] = Some(b_idx);
            pos.push(x);
            parent.push(Some(b_idx));
            terminals += 1;
        }
        // Terminals downstream of each node (a node with no children is a terminal).
        let n = pos.len();
        let mut children = vec![0usize; n];
        for p in parent.iter().flatten() {
            children[*p] += 1;
        }
        let mut downstream = vec![0usize; n];
        // Nodes are appended after their parents except for re-parented children, so iterate
        // to a fixed point by walking each terminal up to the root.
        for i in 0..n {
            if children[i] == 0 {
                let mut cur = Some(i);
                while let Some(c) = cur {
                    downstream[c] += 1;
                    cur = parent[c];
                }
            }
        }
        let nodes = (0..n)
            .map(|i| {
                // The root's radius is that of its single outgoing segment.
                let flow = if parent[i].is_none() { downstream[i] } else { downstream[i].max(1) };
                TreeNode {
                    id: i as i64 + 1,
                    kind: 3,
                    position_mm: pos[i],
                    radius_mm: self.terminal_radius_mm * (flow as f64).powf(1.0 / self.murray_exponent),
                    parent: parent[i],
                }
            })
            .collect();
        Ok(VesselTree { nodes })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeded_murray_tree() {
        let params = ProceduralTree { terminals: 40, ..Default::default() };
        let a = params.generate().unwrap();
        let b = params.generate().unwrap();
        assert_eq!(a, b, "same seed, same tree");
        let c = ProceduralTree { seed: 2, ..params }.generate().unwrap();
        assert_ne!(a, c);
        let leaves = (0..a.nodes.len()).filter(|&i| !a.nodes.iter().any(|n| n.parent == Some(i))).count();
        assert_eq!(leaves, 40);
        // Murray: at a bifurcation r_parent³ = Σ r_child³ (equal terminal flows).
        for (i, n) in a.nodes.iter().enumerate() {
            let kids: Vec<&TreeNode> = a.nodes.iter().filter(|m| m.parent == Some(i)).collect();
            if kids.len() == 2 && n.parent.is_some() {
                let lhs = n.radius_mm.powi(3);
                let rhs: f64 = kids.iter().map(|k| k.radius_mm.powi(3)).sum();
                assert!((lhs - rhs).abs() < 1e-9 * lhs, "node {i}: {lhs} vs {rhs}");
            }
        }
        // Inside the domain (plus the inlet on its boundary).
        for n in &a.nodes {
            let q = n.position_mm / DVec3::from(params.domain_mm);
            assert!(q.length() <= 1.0 + 1e-9);
        }
    }
}

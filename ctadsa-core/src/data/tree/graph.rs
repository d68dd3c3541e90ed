//! Clean-up of traced centrelines as an undirected graph: ends trimmed back into the vessel,
//! short spurs removed, positions smoothed, then a tree again, rooted at the widest end of each
//! component (where a vessel enters the field of view, in a vessel tree).

use std::collections::VecDeque;

use super::{TreeNode, VesselTree};

/// A centreline forest with undirected edges; removed nodes stay in place until
/// [`CentrelineGraph::into_tree`].
#[derive(Debug, Clone)]
pub struct CentrelineGraph {
    pub nodes: Vec<TreeNode>,
    adjacency: Vec<Vec<usize>>,
    removed: Vec<bool>,
}

impl CentrelineGraph {
    /// The tree's parent links as undirected edges.
    pub fn from_tree(tree: &VesselTree) -> Self {
        let mut adjacency = vec![Vec::new(); tree.nodes.len()];
        for (i, n) in tree.nodes.iter().enumerate() {
            if let Some(p) = n.parent {
                adjacency[i].push(p);
                adjacency[p].push(i);
            }
        }
        Self { nodes: tree.nodes.clone(), adjacency, removed: vec![false; tree.nodes.len()] }
    }

    fn live_neighbours(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        self.adjacency[i].iter().copied().filter(|&j| !self.removed[j])
    }

    fn degree(&self, i: usize) -> usize {
        self.live_neighbours(i).count()
    }

    fn ends(&self) -> Vec<usize> {
        (0..self.nodes.len()).filter(|&i| !self.removed[i] && self.degree(i) == 1).collect()
    }

    /// The chain from end `e` inwards: `e`, its neighbour, … up to the first junction (included)
    /// or the other end.
    fn chain_from(&self, e: usize) -> Vec<usize> {
        let mut chain = vec![e];
        let mut prev = usize::MAX;
        let mut cur = e;
        loop {
            let next: Vec<usize> = self.live_neighbours(cur).filter(|&j| j != prev).collect();
            if next.len() != 1 {
                return chain;
            }
            prev = cur;
            cur = next[0];
            chain.push(cur);
            if self.degree(cur) != 2 {
                return chain;
            }
        }
    }

    /// Removes end nodes that lie inside the inscribed ball of a node farther in (grown by
    /// `grow_mm`, e.g. a voxel, for radii measured on a grid) while being thinner than it by
    /// more than `thinner_mm` (e.g. half a voxel): the part of a traced path
    /// that runs from the vessel's axis out to its wall at an end, which is not on the medial
    /// axis. Nodes on a tapering vessel are kept (their radius changes far slower).
    pub fn trim_ends(&mut self, grow_mm: f64, thinner_mm: f64) {
        let mut queue: VecDeque<usize> = self.ends().into();
        while let Some(e) = queue.pop_front() {
            if self.removed[e] || self.degree(e) != 1 {
                continue;
            }
            let chain = self.chain_from(e);
            let (p, r) = (self.nodes[e].position_mm, self.nodes[e].radius_mm);
            let inside = chain[1..].iter().any(|&j| {
                let rj = self.nodes[j].radius_mm;
                (self.nodes[j].position_mm - p).length() < rj + grow_mm && r < rj - thinner_mm
            });
            if inside && chain.len() > 2 {
                self.removed[e] = true;
                queue.push_back(chain[1]);
            }
        }
    }

    /// Removes terminal branches (end to junction) shorter than `min_mm`; a component that is
    /// one branch is kept.
    pub fn prune_spurs(&mut self, min_mm: f64) {
        for e in self.ends() {
            if self.removed[e] || self.degree(e) != 1 {
                continue;
            }
            let chain = self.chain_from(e);
            let last = *chain.last().unwrap_or(&e);
            if self.degree(last) < 3 {
                continue;
            }
            let length: f64 =
                chain.windows(2).map(|w| (self.nodes[w[0]].position_mm - self.nodes[w[1]].position_mm).length()).sum();
            if length < min_mm {
                for &j in &chain[..chain.len() - 1] {
                    self.removed[j] = true;
                }
            }
        }
    }

    /// `iterations` rounds of Laplacian smoothing (weight ½) of the positions of nodes on a
    /// branch (degree 2); ends and junctions stay.
    pub fn smooth(&mut self, iterations: usize) {
        for _ in 0..iterations {
            let moved: Vec<_> = (0..self.nodes.len())
                .map(|i| {
                    let p = self.nodes[i].position_mm;
                    if self.removed[i] || self.degree(i) != 2 {
                        return p;
                    }
                    let mean = self.live_neighbours(i).map(|j| self.nodes[j].position_mm).sum::<glam::DVec3>() / 2.0;
                    0.5 * p + 0.5 * mean
                })
                .collect();
            for (n, p) in self.nodes.iter_mut().zip(moved) {
                n.position_mm = p;
            }
        }
    }

    /// The remaining nodes as a forest: each component rooted at its widest end (its widest
    /// node when it has no end), parents by breadth-first search, ids renumbered from 1.
    pub fn into_tree(self) -> VesselTree {
        let n = self.nodes.len();
        let mut new_index = vec![usize::MAX; n];
        let mut out = VesselTree::default();
        let mut seen = vec![false; n];
        for start in 0..n {
            if self.removed[start] || seen[start] {
                continue;
            }
            // Collect the component, then pick its root.
            let mut comp = vec![start];
            seen[start] = true;
            let mut head = 0;
            while head < comp.len() {
                let u = comp[head];
                head += 1;
                for v in self.live_neighbours(u) {
                    if !seen[v] {
                        seen[v] = true;
                        comp.push(v);
                    }
                }
            }
            let widest = |candidates: &mut dyn Iterator<Item = usize>| {
                candidates.max_by(|&a, &b| self.nodes[a].radius_mm.total_cmp(&self.nodes[b].radius_mm).then(b.cmp(&a)))
            };
            let root = widest(&mut comp.iter().copied().filter(|&i| self.degree(i) <= 1))
                .or_else(|| widest(&mut comp.iter().copied()))
                .unwrap_or(start);
            let mut queue = VecDeque::from([root]);
            new_index[root] = out.nodes.len();
            out.nodes.push(TreeNode { parent: None, ..self.nodes[root] });
            while let Some(u) = queue.pop_front() {
                for v in self.live_neighbours(u) {
                    if new_index[v] == usize::MAX {
                        new_index[v] = out.nodes.len();
                        out.nodes.push(TreeNode { parent: Some(new_index[u]), ..self.nodes[v] });
                        queue.push_back(v);
                    }
                }
            }
        }
        for (i, node) in out.nodes.iter_mut().enumerate() {
            node.id = i as i64 + 1;
        }
        out
    }
}

impl VesselTree {
    /// Children of every node.
    pub fn children(&self) -> Vec<Vec<usize>> {
        let mut c = vec![Vec::new(); self.nodes.len()];
        for (i, n) in self.nodes.iter().enumerate() {
            if let Some(p) = n.parent {
                c[p].push(i);
            }
        }
        c
    }

    /// The tree cut into branches: node chains from a root or junction to the next junction or
    /// end (both included), each as node indices in order away from the root.
    pub fn branches(&self) -> Vec<Vec<usize>> {
        let children = self.children();
        let mut out = Vec::new();
        for (i, n) in self.nodes.iter().enumerate() {
            let starts_branches = n.parent.is_none() || children[i].len() != 1;
            if !starts_branches {
                continue;
            }
            for &c in &children[i] {
                let mut chain = vec![i, c];
                let mut cur = c;
                while children[cur].len() == 1 {
                    cur = children[cur][0];
                    chain.push(cur);
                }
                out.push(chain);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;

    fn node(x: f64, y: f64, r: f64, parent: Option<usize>) -> TreeNode {
        TreeNode { id: 0, kind: 0, position_mm: DVec3::new(x, y, 0.0), radius_mm: r, parent }
    }

    /// A trunk along x (radius 2) ending at x = 10 with a 2-node blunt-end tail up to the wall,
    /// a long side branch (radius 0.5) and a 0.6 mm spur.
    fn sample() -> VesselTree {
        let mut nodes = vec![node(0.0, 0.0, 1.9, None)];
        for k in 1..=10 {
            nodes.push(node(k as f64, 0.0, 2.0, Some(k - 1)));
        }
        nodes.push(node(10.4, 0.6, 0.5, Some(10))); // its ball inside node 10's
        nodes.push(node(10.6, 1.2, 0.3, Some(11))); // its ball inside node 10's
        for k in 1..=8 {
            let parent = if k == 1 { 5 } else { nodes.len() - 1 };
            nodes.push(node(5.0, k as f64, 0.5, Some(parent)));
        }
        let spur_parent = 3;
        nodes.push(node(3.0, -0.6, 0.3, Some(spur_parent)));
        VesselTree { nodes }
    }

    #[test]
    fn blunt_ends_are_trimmed_and_spurs_pruned() {
        let mut g = CentrelineGraph::from_tree(&sample());
        g.trim_ends(0.1, 0.1);
        g.prune_spurs(1.0);
        let t = g.into_tree();
        // The two tail nodes and the spur are gone; trunk (11) and side branch (8) stay.
        assert_eq!(t.nodes.len(), 19, "{:?}", t.nodes.iter().map(|n| n.position_mm).collect::<Vec<_>>());
        assert!(t.nodes.iter().all(|n| n.position_mm.y >= 0.0));
        // Rooted at the widest end: the trunk's end at x = 10 (radius 2).
        assert_eq!(t.nodes[0].position_mm, DVec3::new(10.0, 0.0, 0.0));
        assert_eq!(t.branches().len(), 3, "trunk in two pieces and the side branch");
        let total: f64 = t.total_length_mm();
        assert!((total - 18.0).abs() < 1e-9, "{total}");
    }

    #[test]
    fn smoothing_straightens_a_zigzag_and_keeps_the_ends() {
        let nodes: Vec<TreeNode> =
            (0..21usize).map(|k| node(k as f64, if k % 2 == 0 { 0.0 } else { 0.5 }, 1.0, k.checked_sub(1))).collect();
        let mut g = CentrelineGraph::from_tree(&VesselTree { nodes });
        g.smooth(5);
        let t = g.into_tree();
        let ends: Vec<DVec3> = [0, 20].iter().map(|&x| DVec3::new(x as f64, 0.0, 0.0)).collect();
        assert!(ends.iter().all(|e| t.nodes.iter().any(|n| n.position_mm == *e)));
        let spread = t.nodes[3..18].iter().map(|n| n.position_mm.y).fold(0.0f64, |a, y| a.max((y - 0.25).abs()));
        assert!(spread < 0.05, "zigzag left: {spread}");
    }
}

//! Prior-surface points binned into cells of a uniform grid, found through a hash table of the
//! occupied cells, and the k-nearest-neighbour search over it that the anchor op runs (this CPU
//! version is the GPU kernel's oracle; a test checks it against a brute-force search).
//!
//! The search visits shells of cells around the query's cell (Chebyshev distance 0, 1, 2, …).
//! After shell `s`, every point within `s · cell` of the query has been seen, so it stops once
//! the k-th nearest so far is that close — or, when nothing lies within the radius, once
//! `s · cell` reaches the radius (the query is not anchored) — or after [`MAX_SHELL`] shells
//! (far from a dense prior surface only; then the k nearest found so far are used).

use rayon::prelude::*;

/// Shells searched at most.
pub const MAX_SHELL: u32 = 16;

/// Floats per hash-table slot: cell `x, y, z` (−1: empty), first point, point count.
pub const SLOT: usize = 5;

/// The most neighbours per query the GPU kernel keeps (`loss.pa_k` above it is clamped).
pub const MAX_K: usize = 32;

/// The grid, laid out for the device: points sorted by cell, the occupied cells hashed.
#[derive(Debug, Clone)]
pub struct AnchorGrid {
    /// Lower corner of cell (0, 0, 0) (mm).
    pub origin: [f32; 3],
    /// Cell side (mm), at least the radius.
    pub cell_mm: f32,
    /// Points `[M · 3]` (mm), those of one cell contiguous.
    pub points: Vec<f32>,
    /// `[slots · SLOT]` (see [`SLOT`]); slots a power of two.
    pub table: Vec<f32>,
}

/// The slot a cell hashes to first (the kernel's own arithmetic: wrapping u32).
#[inline(always)]
pub fn hash_cell(c: [u32; 3], mask: u32) -> u32 {
    (c[0].wrapping_mul(73_856_093) ^ c[1].wrapping_mul(19_349_663) ^ c[2].wrapping_mul(83_492_791)) & mask
}

impl AnchorGrid {
    /// At most this many cells along an axis (cells widen beyond the radius for large extents,
    /// so that cell coordinates stay exact in f32).
    const MAX_DIM: f64 = 4096.0;

    /// The grid of `points` (mm) for anchoring within `radius_mm`.
    pub fn new(points: &[[f64; 3]], radius_mm: f64) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if points.is_empty() {
            lo = [0.0; 3];
            hi = [0.0; 3];
        }
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let cell_mm = (radius_mm * 1.001).max(extent / (Self::MAX_DIM - 4.0)).max(1e-6) as f32;
        // One cell of margin, so that no point sits in a cell with a negative coordinate.
        let origin = lo.map(|l| (l - cell_mm as f64) as f32);
        let cell_of = |p: &[f64; 3]| -> [u32; 3] {
            [0, 1, 2].map(|a| ((p[a] as f32 - origin[a]) / cell_mm).floor().max(0.0) as u32)
        };
        let mut keyed: Vec<([u32; 3], usize)> = points.iter().enumerate().map(|(i, p)| (cell_of(p), i)).collect();
        keyed.sort_unstable_by_key(|&(c, i)| (c[2], c[1], c[0], i));
        let mut cells: Vec<([u32; 3], usize, usize)> = Vec::new();
        for (k, &(c, _)) in keyed.iter().enumerate() {
            match cells.last_mut() {
                Some(last) if last.0 == c => last.2 += 1,
                _ => cells.push((c, k, 1)),
            }
        }
        let slots = (2 * cells.len()).next_power_of_two().max(2);
        let mask = (slots - 1) as u32;
        let mut table = vec![0.0f32; slots * SLOT];
        for s in 0..slots {
            table[s * SLOT] = -1.0;
        }
        for &(c, start, count) in &cells {
            let mut s = hash_cell(c, mask) as usize;
            while table[s * SLOT] >= 0.0 {
                s = (s + 1) & mask as usize;
            }
            table[s * SLOT..(s + 1) * SLOT].copy_from_slice(&[
                c[0] as f32,
                c[1] as f32,
                c[2] as f32,
                start as f32,
                count as f32,
            ]);
        }
        let points = keyed.iter().flat_map(|&(_, i)| points[i].map(|v| v as f32)).collect();
        Self { origin, cell_mm, points, table }
    }

    /// The grid as the search reads it.
    pub fn view(&self) -> GridView<'_> {
        GridView { origin: self.origin, cell_mm: self.cell_mm, points: &self.points, table: &self.table }
    }
}

/// A grid's arrays, wherever they are held (an [`AnchorGrid`], or host copies of its tensors).
#[derive(Debug, Clone, Copy)]
pub struct GridView<'a> {
    pub origin: [f32; 3],
    pub cell_mm: f32,
    pub points: &'a [f32],
    pub table: &'a [f32],
}

impl GridView<'_> {
    /// Hash-table slots.
    pub fn slots(&self) -> usize {
        self.table.len() / SLOT
    }

    /// `(first point, count)` of cell `c`, if occupied.
    fn lookup(&self, c: [u32; 3]) -> Option<(usize, usize)> {
        if self.slots() == 0 {
            return None;
        }
        let mask = (self.slots() - 1) as u32;
        let mut s = hash_cell(c, mask) as usize;
        loop {
            let slot = &self.table[s * SLOT..(s + 1) * SLOT];
            if slot[0] < 0.0 {
                return None;
            }
            if [slot[0], slot[1], slot[2]] == [c[0] as f32, c[1] as f32, c[2] as f32] {
                return Some((slot[3] as usize, slot[4] as usize));
            }
            s = (s + 1) & mask as usize;
        }
    }

    /// For each query `[m · 3]`: the mean of its `k` nearest points and 1 where its nearest
    /// point is within `radius_mm`, else the query itself and 0. Queries run in parallel
    /// (rayon); each one's answer does not depend on the others or on the thread count.
    pub fn targets(&self, queries: &[f32], k: usize, radius_mm: f32) -> (Vec<f32>, Vec<f32>) {
        let k = k.clamp(1, MAX_K);
        let r2 = radius_mm * radius_mm;
        let (targets, keep): (Vec<[f32; 3]>, Vec<f32>) = queries
            .par_chunks_exact(3)
            .with_min_len(64)
            .map(|q| {
                let q = [q[0], q[1], q[2]];
                let best = self.nearest(q, k, radius_mm);
                let best = best.points();
                if best.first().is_none_or(|&(d2, _)| d2 > r2) {
                    return (q, 0.0);
                }
                let mut m = [0.0f32; 3];
                for &(_, p) in best {
                    let p = p as usize;
                    for (sum, v) in m.iter_mut().zip(&self.points[3 * p..3 * p + 3]) {
                        *sum += v;
                    }
                }
                (m.map(|v| v / best.len() as f32), 1.0)
            })
            .unzip();
        (targets.into_flattened(), keep)
    }

    /// The `k` nearest points to `q` the shell search finds. A cell whose box lies farther than
    /// the k-th nearest found so far is skipped: none of its points could enter the list, then
    /// or later (the k-th distance only shrinks), so the answer is the one of visiting it.
    fn nearest(&self, q: [f32; 3], k: usize, radius_mm: f32) -> Nearest {
        let c = [0, 1, 2].map(|a| ((q[a] - self.origin[a]) / self.cell_mm).floor() as i64);
        let mut best = Nearest::new(k);
        for s in 0..=MAX_SHELL as i64 {
            for dz in -s..=s {
                for dy in -s..=s {
                    for dx in -s..=s {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != s {
                            continue;
                        }
                        let cell = [c[0] + dx, c[1] + dy, c[2] + dz];
                        if cell.iter().any(|&v| !(0..=u32::MAX as i64).contains(&v)) {
                            continue;
                        }
                        if best.is_full() && self.box_distance2(cell, q) > best.kth() {
                            continue;
                        }
                        let Some((start, count)) = self.lookup(cell.map(|v| v as u32)) else { continue };
                        for p in start..start + count {
                            let d = [0, 1, 2].map(|a| self.points[3 * p + a] - q[a]);
                            best.offer(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], p as u32);
                        }
                    }
                }
            }
            let bound = s as f32 * self.cell_mm;
            if best.is_full() && best.kth() <= bound * bound {
                break;
            }
            if bound >= radius_mm && best.points().first().is_none_or(|&(d2, _)| d2 > radius_mm * radius_mm) {
                break;
            }
        }
        best
    }

    /// A lower bound (mm²) of the squared distance from `q` to any point binned into `cell`:
    /// the distance to the cell's box, less a slack of 10⁻⁴ cell per axis for the rounding of
    /// the binning (a point at a cell's face may be binned into its neighbour).
    fn box_distance2(&self, cell: [i64; 3], q: [f32; 3]) -> f32 {
        let slack = 1e-4 * self.cell_mm;
        let mut d2 = 0.0;
        for a in 0..3 {
            let lo = self.origin[a] + cell[a] as f32 * self.cell_mm;
            let hi = lo + self.cell_mm;
            let d = ((lo - q[a]).max(q[a] - hi) - slack).max(0.0);
            d2 += d * d;
        }
        d2
    }
}

/// The `k` nearest points offered so far, nearest first (ties: the first offered first).
struct Nearest {
    k: usize,
    len: usize,
    found: [(f32, u32); MAX_K],
}

impl Nearest {
    fn new(k: usize) -> Self {
        Self { k: k.clamp(1, MAX_K), len: 0, found: [(0.0, 0); MAX_K] }
    }

    fn is_full(&self) -> bool {
        self.len == self.k
    }

    /// The k-th nearest squared distance (call when full).
    fn kth(&self) -> f32 {
        self.found[self.k - 1].0
    }

    fn points(&self) -> &[(f32, u32)] {
        &self.found[..self.len]
    }

    /// Keeps point `p` at squared distance `d2` if it is among the `k` nearest so far.
    fn offer(&mut self, d2: f32, p: u32) {
        if self.is_full() && d2 >= self.kth() {
            return;
        }
        let at = self.found[..self.len].partition_point(|&(b, _)| b <= d2);
        let end = if self.is_full() { self.k - 1 } else { self.len };
        self.found.copy_within(at..end, at + 1);
        self.found[at] = (d2, p);
        self.len = (self.len + 1).min(self.k);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use rand::{RngExt, SeedableRng};

    /// Points on two tubes (a prior surface's shape) and a sparse cloud.
    fn surface_points(seed: u64) -> Vec<DVec3> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut pts = Vec::new();
        for i in 0..6000 {
            let (t, a) = (rng.random_range(-10.0..10.0), rng.random_range(0.0..std::f64::consts::TAU));
            let r = if i % 2 == 0 { 1.0 } else { 0.6 };
            let p = if i % 2 == 0 {
                DVec3::new(t, r * a.cos(), r * a.sin())
            } else {
                DVec3::new(r * a.cos(), t, 3.0 + r * a.sin())
            };
            pts.push(p);
        }
        for _ in 0..200 {
            pts.push(DVec3::new(
                rng.random_range(-15.0..15.0),
                rng.random_range(-15.0..15.0),
                rng.random_range(-15.0..15.0),
            ));
        }
        pts
    }

    /// The brute-force answer for one centre: whether its nearest point is within `radius`,
    /// the mean of its `k` nearest (f64), and the distance to the k-th nearest.
    fn brute_force(pts: &[DVec3], q: DVec3, k: usize, radius: f64) -> (bool, DVec3, f64) {
        let mut d: Vec<(f64, DVec3)> = pts.iter().map(|p| (p.distance(q), *p)).collect();
        d.sort_by(|x, y| x.0.total_cmp(&y.0));
        let k = k.min(d.len());
        (d[0].0 <= radius, d[..k].iter().map(|x| x.1).sum::<DVec3>() / k as f64, d[k - 1].0)
    }

    /// The shell search finds what a brute-force search finds: the same anchored centres and
    /// the mean of the same k nearest points, for centres on, near and far from the surface.
    #[test]
    fn shell_search_matches_a_brute_force_search() {
        let pts = surface_points(3);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let queries: Vec<f32> = (0..3000)
            .flat_map(|i| {
                let base = pts[rng.random_range(0..pts.len())];
                let spread = [0.05, 0.4, 2.0][i % 3];
                let d =
                    DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
                (base + d * spread).to_array().map(|v| v as f32)
            })
            .collect();
        for (radius, k) in [(0.5, 8), (0.3, 1), (1.0, 20)] {
            let grid = AnchorGrid::new(&pts.iter().map(|p| p.to_array()).collect::<Vec<_>>(), radius);
            let (targets, keep) = grid.view().targets(&queries, k, radius as f32);
            let reach = MAX_SHELL as f64 * grid.cell_mm as f64;
            let (mut kept, mut compared) = (0, 0);
            for (i, q) in queries.chunks_exact(3).enumerate() {
                let q = DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64);
                let (near, mean, kth) = brute_force(&pts, q, k, radius);
                assert_eq!(keep[i] == 1.0, near, "radius {radius}, k {k}: centre {i} anchored?");
                if !near {
                    assert_eq!(
                        &targets[3 * i..3 * i + 3],
                        &queries[3 * i..3 * i + 3],
                        "a free centre is its own target"
                    );
                    continue;
                }
                kept += 1;
                // Exact where the k nearest lie within the shells searched (documented limit).
                if kth > reach {
                    continue;
                }
                compared += 1;
                let t = DVec3::new(targets[3 * i] as f64, targets[3 * i + 1] as f64, targets[3 * i + 2] as f64);
                assert!(t.distance(mean) < 1e-4, "centre {i}: target {t} vs {mean}");
            }
            assert!(kept > 500 && kept < 2900, "a mix of anchored and free centres: {kept}");
            assert!(compared > kept * 9 / 10, "{compared} of {kept} compared");
        }
    }

    #[test]
    fn targets_are_means_of_nearest_points() {
        let pts: Vec<[f64; 3]> = (0..10).map(|i| [i as f64, 0.0, 0.0]).collect();
        let grid = AnchorGrid::new(&pts, 0.5);
        let (targets, keep) = grid.view().targets(&[4.2, 0.3, 0.0, 4.5, 3.0, 0.0], 2, 0.5);
        assert_eq!(keep, vec![1.0, 0.0], "the second centre is 3 mm away");
        assert_eq!(&targets[..3], &[4.5, 0.0, 0.0], "the mean of points 4 and 5");
    }

    /// The list keeps the k smallest offers in order, the first of equal offers first.
    #[test]
    fn nearest_keeps_the_k_smallest_in_order() {
        let mut best = Nearest::new(3);
        for (d2, p) in [(5.0, 0), (1.0, 1), (3.0, 2), (1.0, 3), (4.0, 4), (0.5, 5), (3.0, 6)] {
            best.offer(d2, p);
        }
        assert_eq!(best.points(), &[(0.5, 5), (1.0, 1), (1.0, 3)]);
        assert!(best.is_full() && best.kth() == 1.0);
    }

    #[test]
    fn an_empty_grid_anchors_nothing() {
        let grid = AnchorGrid::new(&[], 0.5);
        let (targets, keep) = grid.view().targets(&[1.0, 2.0, 3.0], 8, 0.5);
        assert_eq!((targets, keep), (vec![1.0, 2.0, 3.0], vec![0.0]));
    }
}

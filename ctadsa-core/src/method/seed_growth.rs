//! Seeds grown from the prior, one depth per pixel: the back-projection's candidates kept in the
//! order a vessel tree reaches them.
//!
//! With two views every pixel of one view's vessel meets every vessel of the other view along
//! its epipolar line, so the back-projection holds, besides each true vessel, a "ghost" at every
//! crossing of two different vessels — most of its voxels. A pixel shows (mostly) one vessel,
//! though, at one depth, and a vessel tree is connected: growing from the prior through the
//! candidates in order of path length, the first voxel reached on a view's pixel ray *claims*
//! that ray, and a later voxel on it is kept only near the claim. A true vessel, reached along
//! its own length from its junction with the prior, claims its pixels before the ghosts that
//! cross it can, and the ghosts, which meet the tree only where they cross it, find their
//! pixels taken. With `init.occluded_views_support`, a view whose pixel the prior covers does not
//! claim: the growth carries the depth in from where every view shows the vessel.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};

use ctadsa_render::ConeBeamView;
use glam::DVec3;

use crate::data::masks::Mask;
use crate::data::masks::pixel_of;
use crate::data::volume::edt::squared_edt;
use crate::data::volume::{Grid, Volume};
use crate::method::init::Scored;

/// The `candidates` reached by growth from the `start` ones (`start(c)`: the path length (mm)
/// it starts with, `None`: not a start) through candidates on `grid` (26-connected steps of 1,
/// √2 and √3 voxels), within `reach_mm` of path. A candidate is kept when, for every view whose
/// residual `support` shows it, that view's pixel ray is unclaimed (it then claims it) or was
/// claimed within 1.5 voxels of it.
pub(crate) fn grow_with_claims(
    grid: &Grid,
    views: &[ConeBeamView],
    support: &[Mask],
    candidates: Vec<Scored>,
    start: impl Fn(&Scored) -> Option<f64>,
    reach_mm: f64,
) -> Vec<Scored> {
    let h = grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
    // Path length in 1/1000 voxel (integer heap keys).
    let unit = |voxels: f64| (voxels * 1000.0).round() as u64;
    let max_cost = unit(reach_mm / h);
    let tolerance_mm = 1.5 * h;
    let mut slot: HashMap<usize, usize> = HashMap::with_capacity(candidates.len());
    let mut cost: HashMap<usize, u64> = HashMap::new();
    let mut heap = BinaryHeap::new();
    for (k, s) in candidates.iter().enumerate() {
        let Some(i) = grid.index_at(s.1) else { continue };
        slot.insert(i, k);
        if let Some(c) = start(s).map(|mm| unit(mm / h)).filter(|&c| c <= max_cost) {
            cost.insert(i, c);
            heap.push(Reverse((c, i)));
        }
    }
    let mut claims: HashMap<(usize, usize), DVec3> = HashMap::new();
    let mut kept = vec![false; candidates.len()];
    let mut rays = Vec::with_capacity(views.len());
    let [nx, ny, nz] = grid.dims;
    while let Some(Reverse((c, i))) = heap.pop() {
        let k = slot[&i];
        if kept[k] || cost.get(&i).is_some_and(|&best| best < c) {
            continue;
        }
        let p = candidates[k].1;
        rays.clear();
        rays.extend(
            views
                .iter()
                .zip(support)
                .enumerate()
                .filter_map(|(vi, (v, m))| pixel_of(v, p).filter(|&px| m.data[px]).map(|px| (vi, px))),
        );
        if rays.iter().any(|ray| claims.get(ray).is_some_and(|q| q.distance(p) > tolerance_mm)) {
            continue;
        }
        for &ray in &rays {
            claims.entry(ray).or_insert(p);
        }
        kept[k] = true;
        let (x, y, z) = (i / (ny * nz), (i / nz) % ny, i % nz);
        for a in x.saturating_sub(1)..(x + 2).min(nx) {
            for b in y.saturating_sub(1)..(y + 2).min(ny) {
                for d in z.saturating_sub(1)..(z + 2).min(nz) {
                    let j = grid.index(a, b, d);
                    if slot.get(&j).is_none_or(|&kj| kept[kj]) {
                        continue;
                    }
                    let steps = (a != x) as u32 + (b != y) as u32 + (d != z) as u32;
                    let next = c + unit((steps as f64).sqrt());
                    if next <= max_cost && cost.get(&j).is_none_or(|&best| next < best) {
                        cost.insert(j, next);
                        heap.push(Reverse((next, j)));
                    }
                }
            }
        }
    }
    candidates.into_iter().zip(kept).filter_map(|(s, k)| k.then_some(s)).collect()
}

/// [`grow_with_claims`] from the candidates within `reach_mm` of `anchors` (non-zero voxels on
/// `grid`), nearest first.
pub(crate) fn grow_from(
    grid: &Grid,
    views: &[ConeBeamView],
    support: &[Mask],
    candidates: Vec<Scored>,
    anchors: &Volume<u8>,
    reach_mm: f64,
    grow_mm: f64,
) -> Vec<Scored> {
    let dist2 = squared_edt(&anchors.map(|v| u8::from(v == 0)));
    let start = |v: &Scored| anchors.grid.index_at(v.1).map(|i| dist2[i].sqrt()).filter(|&d| d <= reach_mm);
    grow_with_claims(grid, views, support, candidates, start, grow_mm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::volume::BoxMm;
    use crate::method::init::tests::scene;

    /// Voxels of `grid` along the polyline `points` (mm), one per voxel step.
    fn voxels_along(grid: &Grid, points: &[DVec3]) -> Vec<DVec3> {
        let h = grid.spacing_mm[0];
        let mut out: Vec<DVec3> = Vec::new();
        for w in points.windows(2) {
            let n = ((w[1] - w[0]).length() / (0.5 * h)).ceil() as usize;
            for k in 0..=n {
                let i = grid.index_at(w[0].lerp(w[1], k as f64 / n as f64)).unwrap();
                let (x, y, z) =
                    (i / (grid.dims[1] * grid.dims[2]), (i / grid.dims[2]) % grid.dims[1], i % grid.dims[2]);
                let c = grid.centre_mm(x, y, z);
                if out.last() != Some(&c) {
                    out.push(c);
                }
            }
        }
        out
    }

    /// A true vessel rising from the prior (z = 0) and a ghost on its rays in view 0 that meets it
    /// only where the two cross, halfway up: the growth from the prior claims the vessel's pixels
    /// first, and the ghost finds them taken; the plain connectivity keeps both.
    #[test]
    fn a_ghost_that_meets_the_tree_only_where_it_crosses_a_vessel_loses_its_pixels() {
        let (_, views, _, _) = scene();
        let views = &views[..2];
        let grid = Grid::covering(&BoxMm { min_mm: [-12.0; 3], max_mm: [12.0; 3] }, 0.4).unwrap();
        // View 0 looks along ±y (its pixels fix x and z), view 1 along ±x.
        let d0 = views[0].source_mm().normalize();
        assert!(d0.y.abs() > 0.99, "view 0 looks along y: {d0}");
        let vessel = voxels_along(&grid, &[DVec3::new(2.0, 0.0, 0.0), DVec3::new(2.0, 0.0, 10.0)]);
        // On the vessel's view-0 rays (same x, z), leaving it in y: crosses it at z = 5.
        let ghost: Vec<DVec3> = voxels_along(&grid, &[DVec3::new(2.0, -4.0, 0.5), DVec3::new(2.0, 4.0, 9.5)])
            .into_iter()
            .filter(|p| p.y.abs() > 0.3)
            .collect();
        let candidates: Vec<Scored> = vessel.iter().chain(&ghost).map(|&c| (1.0, c, true)).collect();
        let support: Vec<Mask> = views
            .iter()
            .map(|v| {
                let mut m =
                    Mask { width: v.width(), height: v.height(), data: vec![false; (v.width() * v.height()) as usize] };
                for s in &candidates {
                    m.data[pixel_of(v, s.1).unwrap()] = true;
                }
                m
            })
            .collect();
        let start = |s: &Scored| (s.1.z < 0.5).then_some(s.1.z);
        let kept = grow_with_claims(&grid, views, &support, candidates.clone(), start, 100.0);
        let on_vessel = kept.iter().filter(|s| s.1.x == vessel[0].x && s.1.y.abs() < 0.3).count();
        let ghost_far = kept.iter().filter(|s| s.1.y.abs() > 1.0).count();
        eprintln!("kept {} of {} vessel voxels, {} ghost voxels > 1 mm from it", on_vessel, vessel.len(), ghost_far);
        assert_eq!(on_vessel, vessel.len(), "the vessel keeps every voxel");
        assert_eq!(ghost_far, 0, "the ghost keeps nothing away from the crossing");
        // Without claims (no pixel ever taken: every view's support empty) the ghost is kept.
        let empty: Vec<Mask> = support.iter().map(|m| Mask { data: vec![false; m.data.len()], ..m.clone() }).collect();
        let all = grow_with_claims(&grid, views, &empty, candidates, start, 100.0);
        assert!(all.iter().filter(|s| s.1.y.abs() > 1.0).count() > 10, "connected through the crossing");
    }
}

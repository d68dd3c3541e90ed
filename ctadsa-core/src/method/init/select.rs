//! Which supported voxels become centres: the best-scored, spread apart, connected to the prior.

use glam::DVec3;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use super::Scored;
use crate::data::volume::Volume;

/// The centres (mm) of the `n` best-scored voxels (of side `voxel_mm`), at least `spacing_mm`
/// apart when it is > 0 ([`spread`]), each jittered uniformly inside its voxel.
pub(crate) fn best_centres(
    mut scored: Vec<Scored>,
    spacing_mm: f64,
    n: usize,
    voxel_mm: f64,
    rng: &mut ChaCha8Rng,
) -> Vec<DVec3> {
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    if spacing_mm > 0.0 {
        scored = spread(scored, spacing_mm, n);
    }
    scored.truncate(n);
    scored
        .into_iter()
        .map(|(_, c, _)| {
            c + DVec3::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5))
                * voxel_mm
        })
        .collect()
}

/// The first `n` of `sorted` (best first) that lie at least `spacing_mm` from every one taken
/// before them (greedy non-maximum suppression on a hashed grid of `spacing_mm` cells).
pub(crate) fn spread(sorted: Vec<Scored>, spacing_mm: f64, n: usize) -> Vec<Scored> {
    let cell = |p: DVec3| (p / spacing_mm).floor().as_ivec3();
    let mut taken: std::collections::HashMap<glam::IVec3, Vec<DVec3>> = std::collections::HashMap::new();
    let mut out = Vec::with_capacity(n.min(sorted.len()));
    for s in sorted {
        if out.len() == n {
            break;
        }
        let c = cell(s.1);
        let near = (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    taken
                        .get(&(c + glam::IVec3::new(dx, dy, dz)))
                        .is_some_and(|ps| ps.iter().any(|q| q.distance_squared(s.1) < spacing_mm * spacing_mm))
                })
            })
        });
        if !near {
            taken.entry(c).or_default().push(s.1);
            out.push(s);
        }
    }
    out
}

/// The scored voxels (centres on `prior`'s grid) whose 26-connected group of scored voxels holds
/// an anchor or comes within `reach_mm` of the prior solid (`reach_mm` = 0: anchors only).
pub(crate) fn connected_to_anchors(
    scored: Vec<Scored>,
    prior: &Volume<u8>,
    reach_mm: f64,
    is_anchor: impl Fn(&Scored) -> bool,
) -> Vec<Scored> {
    let grid = prior.grid;
    let index_of = |c: DVec3| grid.index_at(c);
    // Distance² (mm²) of every voxel outside the prior to the prior.
    let outside = prior.map(|v| u8::from(v == 0));
    let dist2 = crate::data::volume::edt::squared_edt(&outside);
    let mut supported = vec![false; grid.len()];
    let mut reached = vec![false; grid.len()];
    let mut stack = Vec::new();
    for s in &scored {
        if let Some(i) = index_of(s.1) {
            supported[i] = true;
            if !reached[i] && (is_anchor(s) || (reach_mm > 0.0 && dist2[i] <= reach_mm * reach_mm)) {
                reached[i] = true;
                stack.push(i);
            }
        }
    }
    // Flood fill from the anchors and the supported voxels within reach of the prior.
    grid.flood_fill_26(&mut reached, stack, |j| supported[j]);
    scored.into_iter().filter(|s| index_of(s.1).is_some_and(|i| reached[i])).collect()
}

//! From the trained density volume to the completed surface, with nothing but the inputs:
//! - the iso-level chosen so that the extracted volume, projected into every view, best matches
//!   the views' vessel masks (Dice), instead of a fixed fraction of a density percentile;
//! - the prior kept: the completed surface is the prior mesh joined with the new vessels of the
//!   extracted surface (its faces outside the prior and farther than a margin from it);
//! - optionally, only the pieces of the extracted surface that the density connects to the
//!   prior: a vessel tree is connected, while the ghosts of a few views float free;
//! - optionally, faint vessels at their own scale: a thin vessel's density peaks below the level
//!   the thick ones set, so the level is lowered locally (down to a second level from the
//!   views) where the density's local maximum is low, and stays where it is high.

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::data::case::images::Image;
use crate::data::masks::{Mask, vessel_masks};
use crate::data::mesh::TriMesh;
use crate::data::mesh::distance::SurfaceIndex;
use crate::data::mesh::voxelize::voxelize_mesh;
use crate::data::projector::project_volume_max;
use crate::data::volume::Volume;
use crate::data::volume::edt::squared_edt;
use crate::stats::percentile;

/// Candidate levels, as fractions of the 99.9th percentile of the positive densities.
pub const LEVEL_FRACTIONS: [f64; 12] = [0.01, 0.015, 0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2, 0.25, 0.35, 0.5];

/// One candidate level and how well its silhouettes match the vessel masks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LevelScore {
    /// Fraction of the 99.9th density percentile.
    pub fraction: f64,
    /// Density units.
    pub level: f64,
    /// Mean Dice over the views of silhouette and vessel mask.
    pub dice: f64,
}

/// The 99.9th percentile of the positive densities (1 when there is none).
pub fn density_scale(volume: &Volume<f32>) -> f64 {
    let pos: Vec<f64> = volume.data.iter().filter(|&&v| v > 0.0).map(|&v| v as f64).collect();
    if pos.is_empty() { 1.0 } else { percentile(&pos, 99.9) }
}

fn dice(a: &[bool], b: &[bool]) -> f64 {
    let (mut both, mut na, mut nb) = (0usize, 0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        both += (x && y) as usize;
        na += x as usize;
        nb += y as usize;
    }
    if na + nb == 0 { 1.0 } else { 2.0 * both as f64 / (na + nb) as f64 }
}

/// What the views see of the completed solid (`density ≥ level`, joined with `keep`, e.g. the
/// prior's voxels) at every level at once: per view and pixel, the highest density its ray
/// crosses (`+∞` where it crosses `keep`). A level's silhouette is `reach ≥ level`, so one
/// maximum-value projection replaces one projection per candidate level.
#[derive(Debug, Clone)]
pub struct LevelReach {
    /// [`density_scale`] of the volume (candidate levels are fractions of it).
    scale: f64,
    /// `[V][H·W]`, density units.
    reach: Vec<Vec<f32>>,
}

impl LevelReach {
    /// Projects `volume` (joined with `keep`) into `views`.
    pub fn new(volume: &Volume<f32>, views: &[ConeBeamView], keep: Option<&Volume<u8>>) -> Self {
        let joined = Volume {
            grid: volume.grid,
            index_to_world: volume.index_to_world,
            data: volume
                .data
                .iter()
                .enumerate()
                .map(|(i, &d)| if keep.is_some_and(|k| k.data[i] != 0) { f32::INFINITY } else { d })
                .collect(),
        };
        Self { scale: density_scale(volume), reach: project_volume_max(&joined, views) }
    }

    /// One score per candidate level ([`LEVEL_FRACTIONS`], in order): the mean over the views of
    /// the Dice of the level's silhouette and the vessel mask at `mask_threshold`.
    pub fn scores(&self, images: &[Image], mask_threshold: f64) -> Vec<LevelScore> {
        let masks: Vec<Mask> = vessel_masks(images, mask_threshold);
        LEVEL_FRACTIONS
            .iter()
            .map(|&fraction| {
                let level = fraction * self.scale;
                let dice = self
                    .reach
                    .iter()
                    .zip(&masks)
                    .map(|(r, m)| dice(&r.iter().map(|&v| v as f64 >= level).collect::<Vec<_>>(), &m.data))
                    .sum::<f64>()
                    / masks.len().max(1) as f64;
                LevelScore { fraction, level, dice }
            })
            .collect()
    }
}

/// `density ≥ level`, joined with `keep` (e.g. the prior's voxels) where given.
pub fn completed_solid(volume: &Volume<f32>, level: f64, keep: Option<&Volume<u8>>) -> Volume<u8> {
    Volume {
        grid: volume.grid,
        index_to_world: volume.index_to_world,
        data: volume
            .data
            .iter()
            .enumerate()
            .map(|(i, &d)| (d as f64 >= level || keep.is_some_and(|k| k.data[i] != 0)) as u8)
            .collect(),
    }
}

/// The best-scoring level (the lowest fraction among equals).
pub fn best_level(scores: &[LevelScore]) -> Option<LevelScore> {
    scores.iter().copied().fold(None, |best: Option<LevelScore>, s| match best {
        Some(b) if b.dice >= s.dice => Some(b),
        _ => Some(s),
    })
}

/// The prior mesh joined with the faces of `extracted` that lie outside the prior's solid
/// (voxelised on `volume`'s grid) and farther than `margin_mm` from its surface: the prior
/// vessels exactly as the CTA gave them, plus the new ones.
pub fn join_prior(extracted: &TriMesh, prior: &TriMesh, solid: &Volume<u8>, margin_mm: f64) -> TriMesh {
    let index = SurfaceIndex::new(prior);
    let centroids: Vec<DVec3> = extracted
        .faces
        .iter()
        .map(|f| f.iter().map(|&i| extracted.vertices[i as usize]).sum::<DVec3>() / 3.0)
        .collect();
    let dist = index.distances(&centroids);
    let mut new = extracted.clone();
    new.faces = extracted
        .faces
        .iter()
        .zip(centroids.iter().zip(&dist))
        .filter(|(_, (c, d))| **d > margin_mm && !solid.is_set_at(**c))
        .map(|(f, _)| *f)
        .collect();
    let mut out = prior.clone();
    out.append(&new.compacted());
    out
}

/// The prior's solid voxels on `volume`'s grid.
pub fn prior_solid(prior: &TriMesh, volume: &Volume<f32>) -> Volume<u8> {
    voxelize_mesh(prior, volume.grid)
}

/// Voxels with `density ≥ level` that a 26-connected path of such voxels links to a voxel of
/// `solid` (the prior) that also has `density ≥ level`.
pub fn connected_to_solid(volume: &Volume<f32>, level: f64, solid: &Volume<u8>) -> Vec<bool> {
    let grid = volume.grid;
    let above = |i: usize| volume.data[i] as f64 >= level;
    let mut reached = vec![false; grid.len()];
    let seeds: Vec<usize> = (0..grid.len()).filter(|&i| solid.data[i] != 0 && above(i)).collect();
    for &i in &seeds {
        reached[i] = true;
    }
    grid.flood_fill_26(&mut reached, seeds, above);
    reached
}

/// `above` (voxels at or above the surface's level) joined with the voxels of `density ≥
/// low_level` that lie within `reach` voxels (a cube of that half-width) of an `above` voxel
/// and that a 26-connected path of such voxels links to one: the faint density between the
/// pieces of a vessel that the level cuts into beads (hysteresis thresholding, bounded). With
/// `keep_clear = (voxels, r)`, no voxel within `r` voxels of `voxels` (the prior) is added.
pub fn bridged_solid(
    density: &Volume<f32>,
    above: &Volume<u8>,
    low_level: f64,
    reach: usize,
    keep_clear: Option<(&Volume<u8>, usize)>,
) -> Volume<u8> {
    let grid = density.grid;
    let near_of =
        |v: &Volume<u8>, r: usize| max_filter(&v.data.iter().map(|&a| a as f32).collect::<Vec<_>>(), grid.dims, r);
    let near = near_of(above, reach);
    let blocked = keep_clear.map(|(v, r)| near_of(v, r));
    let candidate =
        |i: usize| near[i] > 0.0 && density.data[i] as f64 >= low_level && blocked.as_ref().is_none_or(|b| b[i] == 0.0);
    let mut reached: Vec<bool> = above.data.iter().map(|&a| a != 0).collect();
    let seeds: Vec<usize> = (0..grid.len()).filter(|&i| reached[i]).collect();
    grid.flood_fill_26(&mut reached, seeds, candidate);
    Volume { grid, index_to_world: above.index_to_world, data: reached.iter().map(|&r| r as u8).collect() }
}

/// Whether the voxel containing `p`, or one of its 26 neighbours, is set in `voxels`.
fn near_set(volume: &Volume<f32>, voxels: &[bool], p: DVec3) -> bool {
    let g = volume.grid;
    let ijk = [0, 1, 2].map(|a| ((p[a] - g.origin_mm[a]) / g.spacing_mm[a]).floor() as i64);
    (-1..=1).any(|dx| {
        (-1..=1).any(|dy| {
            (-1..=1).any(|dz| {
                let q = [ijk[0] + dx, ijk[1] + dy, ijk[2] + dz];
                q.iter().zip(g.dims).all(|(&t, d)| t >= 0 && (t as usize) < d)
                    && voxels[g.index(q[0] as usize, q[1] as usize, q[2] as usize)]
            })
        })
    })
}

/// The connected components of `extracted` that the density links to the prior: those with at
/// least half of their vertices next to a voxel of [`connected_to_solid`] at `level`. Returns
/// the kept surface and the number of components dropped.
pub fn keep_connected_to_prior(
    extracted: &TriMesh,
    volume: &Volume<f32>,
    level: f64,
    solid: &Volume<u8>,
) -> (TriMesh, usize) {
    let reached = connected_to_solid(volume, level, solid);
    let mut kept = TriMesh::default();
    let mut dropped = 0;
    for part in extracted.components() {
        let near = part.vertices.iter().filter(|&&v| near_set(volume, &reached, v)).count();
        if 2 * near >= part.vertices.len() {
            kept.append(&part);
        } else {
            dropped += 1;
        }
    }
    (kept, dropped)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::mesh::marching::extract_isosurface;
    use crate::data::volume::Grid;

    /// A 40 × 12 × 12 grid of 1 mm: the prior (x < 6) with a vessel running on to x = 16, a
    /// floating blob at x = 26..30, and between them a faint bridge of density `bridge`.
    fn scene(bridge: f32) -> (Volume<f32>, Volume<u8>) {
        let grid = Grid { dims: [40, 12, 12], spacing_mm: [1.0; 3], origin_mm: [0.0; 3] };
        let mut density = Volume::<f32>::zeros(grid);
        let mut solid = Volume::<u8>::zeros(grid);
        for x in 0..40 {
            for y in 4..8 {
                for z in 4..8 {
                    let i = grid.index(x, y, z);
                    density.data[i] = match x {
                        0..16 => 1.0,
                        16..26 if (5..7).contains(&y) && (5..7).contains(&z) => bridge,
                        26..30 => 1.0,
                        _ => 0.0,
                    };
                    solid.data[i] = u8::from(x < 6);
                }
            }
        }
        (density, solid)
    }

    #[test]
    fn pieces_the_density_links_to_the_prior_are_kept_and_floating_ones_dropped() {
        let (density, solid) = scene(0.0);
        let mesh = extract_isosurface(&density, 0.5);
        assert_eq!(mesh.components().len(), 2, "the prior's vessel and the floating blob");
        let (kept, dropped) = keep_connected_to_prior(&mesh, &density, 0.05, &solid);
        assert_eq!(dropped, 1);
        let (_, hi) = kept.bounds_mm().unwrap();
        assert!(hi.x < 20.0, "the kept piece is the vessel on the prior, up to x = {}", hi.x);
        // A faint bridge links the blob at a path level below the bridge's density, not above.
        let (density, solid) = scene(0.1);
        let mesh = extract_isosurface(&density, 0.5);
        assert_eq!(keep_connected_to_prior(&mesh, &density, 0.05, &solid).1, 0);
        assert_eq!(keep_connected_to_prior(&mesh, &density, 0.2, &solid).1, 1);
    }

    /// The slow, obvious score of each level: its solid voxelised, projected exactly (line
    /// integrals), the pixels with a positive integral compared with the mask.
    fn score_levels_one_projection_each(
        volume: &Volume<f32>,
        views: &[ConeBeamView],
        images: &[Image],
        mask_threshold: f64,
        keep: Option<&Volume<u8>>,
    ) -> Vec<LevelScore> {
        let masks: Vec<Mask> = vessel_masks(images, mask_threshold);
        let scale = density_scale(volume);
        LEVEL_FRACTIONS
            .iter()
            .map(|&fraction| {
                let level = fraction * scale;
                let solid = completed_solid(volume, level, keep).map(f32::from);
                let sil = crate::data::projector::project_volume(&solid, views);
                let dice = sil
                    .iter()
                    .zip(&masks)
                    .map(|(s, m)| dice(&s.iter().map(|&v| v > 0.0).collect::<Vec<_>>(), &m.data))
                    .sum::<f64>()
                    / masks.len() as f64;
                LevelScore { fraction, level, dice }
            })
            .collect()
    }

    #[test]
    fn one_maximum_projection_scores_every_level_as_one_projection_each() {
        use ctadsa_render::TigreGeometry;
        // Densities spread over three decades, so that every candidate level cuts a different
        // solid; the views see the 40 mm scene on 56 × 56 px of 1 mm.
        use rand::{RngExt, SeedableRng};
        let (mut density, solid) = scene(0.3);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12345);
        for (i, d) in density.data.iter_mut().enumerate() {
            if *d > 0.0 || i % 7 == 0 {
                *d = 10f32.powf(-3.0 * rng.random_range(0.0f32..1.0));
            }
        }
        let views: Vec<ConeBeamView> = [0.0, 90.0, 35.0]
            .iter()
            .map(|&deg| {
                let g = TigreGeometry {
                    detector_px: [56, 56],
                    pixel_mm: [1.0, 1.0],
                    offset_mm: [-20.0 * 1.4, 6.0 * 1.4],
                    ..TigreGeometry::reference(deg)
                };
                ConeBeamView::from_tigre(&g).unwrap()
            })
            .collect();
        // Masks from the density's own projection, so that the Dice varies across the levels.
        let images: Vec<Image> = crate::data::projector::project_volume(&density, &views)
            .into_iter()
            .map(|data| Image { width: 56, height: 56, data })
            .collect();
        for keep in [None, Some(&solid)] {
            let fast = LevelReach::new(&density, &views, keep).scores(&images, 0.1);
            let slow = score_levels_one_projection_each(&density, &views, &images, 0.1, keep);
            assert_eq!(fast, slow, "keep: {}", keep.is_some());
            let dice: Vec<f64> = fast.iter().map(|s| s.dice).collect();
            assert!(dice.iter().any(|&d| d != dice[0]), "the levels differ: {dice:?}");
        }
    }
}

/// Lowers the level of `field` (the density over its local level, cut at 1) to `near_level`
/// (density units) at the voxels within `within_mm` of the `prior` solid (on the field's grid):
/// there the field becomes at least `density / near_level`. Beside the prior the density
/// draws the roots of the vessels that leave it; farther out, a lower level grows more ghosts
/// than vessels.
fn lower_level_near_prior(
    field: &mut Volume<f32>,
    density: &Volume<f32>,
    prior: &Volume<u8>,
    near_level: f64,
    within_mm: f64,
) {
    let to_prior2 = squared_edt(&prior.map(|v| u8::from(v == 0)));
    let near_level = near_level as f32;
    for ((f, &d), &d2) in field.data.iter_mut().zip(&density.data).zip(&to_prior2) {
        if d2 <= within_mm * within_mm {
            *f = f.max(d / near_level);
        }
    }
}

/// What a surface is cut from, and at which level: `density` at `level`, or — with the faint
/// vessels' field (`faint`, [`faint_level_field`]) or a lower level beside the prior (`near`:
/// the prior's solid on the density's grid, the lower level, the distance in mm;
/// `lower_level_near_prior`, applied only where it is lower than `level`) — the density over
/// its local level, at 1. The surface and the centreline's finer solid are cut alike.
pub fn level_field(
    density: &Volume<f32>,
    level: f64,
    faint: Option<Volume<f32>>,
    near: Option<(&Volume<u8>, f64, f64)>,
) -> (Option<Volume<f32>>, f64) {
    let mut field = faint;
    if let Some((prior, near_level, within_mm)) = near.filter(|&(_, l, _)| l < level) {
        let f = field.get_or_insert_with(|| {
            let level = level as f32;
            Volume {
                grid: density.grid,
                index_to_world: density.index_to_world,
                data: density.data.iter().map(|&d| d / level).collect(),
            }
        });
        lower_level_near_prior(f, density, prior, near_level, within_mm);
    }
    let cut_level = if field.is_some() { 1.0 } else { level };
    (field, cut_level)
}

/// The density divided by a local level, to extract at 1: the local level is `fraction` × the
/// density's maximum within `radius` voxels (a cube), clamped to `[low, level]`. Around thick
/// vessels (local maximum ≥ `level / fraction`) this is the plain level; a faint vessel alone
/// is cut at `fraction` of its own peak, never below `low`. `low` and `level` are density
/// units, `0 < low ≤ level`.
pub fn faint_level_field(volume: &Volume<f32>, level: f64, low: f64, fraction: f64, radius: usize) -> Volume<f32> {
    let local_max = max_filter(&volume.data, volume.grid.dims, radius);
    let (low, level) = (low.min(level) as f32, level as f32);
    let data = volume.data.iter().zip(&local_max).map(|(&d, &m)| d / (fraction as f32 * m).clamp(low, level)).collect();
    Volume { grid: volume.grid, index_to_world: volume.index_to_world, data }
}

/// The maximum over a cube of half-width `radius` voxels (separable, one axis at a time);
/// `data` is indexed `(i · ny + j) · nz + k` for `dims = [nx, ny, nz]`. Along y and x the
/// maximum is taken over whole contiguous rows / planes at once (vectorised, in parallel).
fn max_filter(data: &[f32], dims: [usize; 3], radius: usize) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    if data.is_empty() || nx * ny * nz != data.len() {
        return data.to_vec();
    }
    let window = |at: usize, n: usize| at.saturating_sub(radius)..=(at + radius).min(n - 1);
    // Along z, within each contiguous line.
    let mut along_z = vec![0.0f32; data.len()];
    along_z.par_chunks_mut(nz).zip(data.par_chunks(nz)).for_each(|(out, line)| {
        for (k, o) in out.iter_mut().enumerate() {
            *o = line[window(k, nz)].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        }
    });
    // Along y then x: each output row (plane) is the element-wise maximum of its neighbours.
    let rows_max = |src: &[f32], len: usize, n: usize| {
        let mut out = vec![f32::NEG_INFINITY; src.len()];
        out.par_chunks_mut(len).enumerate().for_each(|(row, o)| {
            let (outer, at) = (row / n, row % n);
            for near in window(at, n) {
                let start = (outer * n + near) * len;
                for (v, &s) in o.iter_mut().zip(&src[start..start + len]) {
                    *v = v.max(s);
                }
            }
        });
        out
    };
    let along_y = rows_max(&along_z, nz, ny);
    rows_max(&along_y, ny * nz, nx)
}

#[cfg(test)]
mod faint_tests {
    use super::*;
    use crate::data::volume::Grid;

    fn volume(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> f32) -> Volume<f32> {
        let grid = Grid { dims, spacing_mm: [1.0; 3], origin_mm: [0.0; 3] };
        let mut data = vec![0.0f32; dims[0] * dims[1] * dims[2]];
        for i in 0..dims[0] {
            for j in 0..dims[1] {
                for k in 0..dims[2] {
                    data[grid.index(i, j, k)] = f(i, j, k);
                }
            }
        }
        Volume { grid, index_to_world: grid.index_to_world(), data }
    }

    #[test]
    fn max_filter_equals_the_brute_force_cube_maximum() {
        let dims = [7, 5, 6];
        let v = volume(dims, |i, j, k| ((i * 31 + j * 17 + k * 7) % 11) as f32);
        for r in [0, 1, 2, 9] {
            let filtered = max_filter(&v.data, dims, r);
            for i in 0..dims[0] {
                for j in 0..dims[1] {
                    for k in 0..dims[2] {
                        let mut m = f32::NEG_INFINITY;
                        for a in i.saturating_sub(r)..=(i + r).min(dims[0] - 1) {
                            for b in j.saturating_sub(r)..=(j + r).min(dims[1] - 1) {
                                for c in k.saturating_sub(r)..=(k + r).min(dims[2] - 1) {
                                    m = m.max(v.data[v.grid.index(a, b, c)]);
                                }
                            }
                        }
                        assert_eq!(filtered[v.grid.index(i, j, k)], m, "voxel {i} {j} {k}, radius {r}");
                    }
                }
            }
        }
    }

    /// A faint vessel (density 0.6, level 1) leaving a prior (the voxels with x < 3, 1 mm
    /// voxels) is cut at the lower level 0.5 up to 2 mm from the prior and at 1 beyond.
    #[test]
    fn the_level_is_lowered_only_near_the_prior() {
        let dims = [12, 5, 5];
        let density = volume(dims, |_, j, k| if j == 2 && k == 2 { 0.6 } else { 0.0 });
        let prior = Volume {
            grid: density.grid,
            index_to_world: density.index_to_world,
            data: volume(dims, |i, _, _| if i < 3 { 1.0 } else { 0.0 }).data.iter().map(|&v| v as u8).collect(),
        };
        let mut field = density.clone();
        lower_level_near_prior(&mut field, &density, &prior, 0.5, 2.0);
        let on_axis: Vec<bool> = (0..dims[0]).map(|i| field.data[density.grid.index(i, 2, 2)] >= 1.0).collect();
        // x = 0..2 is the prior itself, 3 and 4 lie 1 and 2 mm from it.
        assert_eq!(on_axis, [[true; 5].as_slice(), &[false; 7]].concat(), "cut at 0.5 within 2 mm only");
        assert!(field.data.iter().zip(&density.data).all(|(f, d)| f >= d), "never raises the level");
    }

    /// Without a faint field or a lower level beside the prior the density is cut at the
    /// level; with the near-prior level alone (no faint field), the field is cut at 1 and
    /// draws the same solid as the density at the level away from the prior, and at the lower
    /// level beside it; a near-prior level above the level changes nothing.
    #[test]
    fn the_level_field_cuts_like_the_level_away_from_the_prior() {
        let dims = [12, 5, 5];
        let density = volume(dims, |i, j, k| if j == 2 && k == 2 { 0.35 + 0.1 * i as f32 } else { 0.05 * k as f32 });
        let prior = Volume {
            grid: density.grid,
            index_to_world: density.index_to_world,
            data: volume(dims, |i, _, _| if i < 2 { 1.0 } else { 0.0 }).data.iter().map(|&v| v as u8).collect(),
        };
        let (none, at) = level_field(&density, 0.8, None, None);
        assert!(none.is_none() && at == 0.8);
        let (above, at) = level_field(&density, 0.8, None, Some((&prior, 0.9, 2.0)));
        assert!(above.is_none() && at == 0.8, "a higher near level changes nothing");
        let (field, at) = level_field(&density, 0.8, None, Some((&prior, 0.4, 2.0)));
        let field = field.expect("a field where the near level is lower");
        assert_eq!(at, 1.0);
        let to_prior2 = squared_edt(&prior.map(|v| u8::from(v == 0)));
        for ((&f, &d), &d2) in field.data.iter().zip(&density.data).zip(&to_prior2) {
            let cut = if d2 <= 4.0 { 0.4 } else { 0.8 };
            assert_eq!(f >= 1.0, d >= cut, "density {d} at {d2} mm² from the prior");
        }
    }

    /// Two beads of a vessel (density 1) with a faint gap between them (0.6) are joined at a
    /// low level of 0.5 when the gap is within reach, not when it is fainter than the low level
    /// or out of reach; faint density touching nothing above the level stays out; nothing is
    /// added within the clearance of the prior.
    #[test]
    fn bridges_join_beads_through_faint_gaps_within_reach() {
        // Along x: bead at 2..=4, gap 5..=7 at 0.6, bead 8..=10; a lone faint blob at x = 14.
        let profile = |gap: f32| {
            volume([17, 3, 3], move |i, j, k| match (i, j == 1 && k == 1) {
                (2..=4 | 8..=10, true) => 1.0,
                (5..=7, true) => gap,
                (14, true) => 0.6,
                _ => 0.0,
            })
        };
        let set = |v: &Volume<u8>, i: usize| v.data[v.grid.index(i, 1, 1)] != 0;
        let density = profile(0.6);
        let above = completed_solid(&density, 0.9, None);
        assert!(!set(&above, 6) && set(&above, 4) && set(&above, 8), "the level cuts the vessel into two beads");
        let bridged = bridged_solid(&density, &above, 0.5, 2, None);
        assert!((2..=10).all(|i| set(&bridged, i)), "the gap is bridged");
        assert!(!set(&bridged, 14), "a faint blob linked to no bead stays out");
        assert!(bridged.data.iter().zip(&above.data).all(|(&b, &a)| b >= a), "every voxel above the level stays");
        assert!(!set(&bridged_solid(&density, &above, 0.5, 1, None), 6), "the middle of the gap is out of reach");
        assert!(!set(&bridged_solid(&profile(0.4), &above, 0.5, 2, None), 6), "a gap below the low level stays open");
        // With the voxels at x ≥ 6 kept clear of (within one voxel of a "prior" at x = 7), only
        // x = 5 is added.
        let prior = completed_solid(&volume([17, 3, 3], |i, _, _| (i == 7) as u8 as f32), 0.5, None);
        let clear = bridged_solid(&density, &above, 0.5, 2, Some((&prior, 1)));
        assert!(set(&clear, 5) && !set(&clear, 6) && !set(&clear, 7), "no bridge next to the prior");
        assert!(set(&clear, 8), "the solid itself is kept next to the prior");
    }

    /// A thick vessel (peak 1) keeps the plain level; a faint one (peak 0.2, below the level
    /// 0.3) is extracted around its own peak; a faint blob below `low` stays out.
    #[test]
    fn faint_vessels_are_cut_at_their_own_scale_and_thick_ones_at_the_level() {
        let profile = |d: f32, peak: f32| peak * (-d * d / 2.0).exp();
        let v = volume([40, 9, 9], |i, j, k| {
            let d = ((j as f32 - 4.0).powi(2) + (k as f32 - 4.0).powi(2)).sqrt();
            match i {
                0..=9 => profile(d, 1.0),
                20..=29 => profile(d, 0.2),
                _ => profile(d, 0.04),
            }
        });
        let f = faint_level_field(&v, 0.3, 0.05, 0.5, 2);
        let inside = |i: usize, j: usize| f.data[f.grid.index(i, j, 4)] >= 1.0;
        // Thick: the plain level 0.3 (profile ≥ 0.3 out to d ≈ 1.55: voxels 3..=5 in j).
        assert!(inside(5, 4) && inside(5, 5) && !inside(5, 6));
        // Faint: half its own peak (0.1 out to d ≈ 1.18): its axis and the next voxel.
        assert!(inside(25, 4) && inside(25, 5) && !inside(25, 6));
        // Below `low` everywhere: nothing.
        assert!((32..40).all(|i| !inside(i, 4)));
        // With the plain level the faint vessel is not there at all.
        assert!(v.data[v.grid.index(25, 4, 4)] < 0.3);
    }
}

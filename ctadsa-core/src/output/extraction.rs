//! From the trained density volume to the completed surface, with nothing but the inputs:
//! - the iso-level chosen so that the extracted volume, projected into every view, best matches
//!   the views' vessel masks (Dice), instead of a fixed fraction of a density percentile;
//! - the prior kept: the completed surface is the prior mesh joined with the new vessels of the
//!   extracted surface (its faces outside the prior and farther than a margin from it).

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::data::case::images::Image;
use crate::data::masks::{Mask, vessel_mask};
use crate::data::mesh::TriMesh;
use crate::data::mesh::distance::SurfaceIndex;
use crate::data::mesh::voxelize::voxelize_mesh;
use crate::data::projector::project_volume;
use crate::data::volume::Volume;
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

/// Scores every candidate level: the solid `density ≥ level` (joined with `keep`, e.g. the
/// prior's voxels, when given) is projected into the views and compared with their vessel masks
/// (`mask_threshold` as the N2 seeds). Returns one score per candidate level, in order.
pub fn score_levels(
    volume: &Volume<f32>,
    views: &[ConeBeamView],
    images: &[Image],
    mask_threshold: f64,
    keep: Option<&Volume<u8>>,
) -> Vec<LevelScore> {
    let masks: Vec<Mask> = images.iter().map(|i| vessel_mask(i, mask_threshold)).collect();
    let scale = density_scale(volume);
    LEVEL_FRACTIONS
        .iter()
        .map(|&fraction| {
            let level = fraction * scale;
            let solid = completed_solid(volume, level, keep).map(f32::from);
            let sil = project_volume(&solid, views);
            let dice = sil
                .iter()
                .zip(&masks)
                .map(|(s, m)| dice(&s.iter().map(|&v| v > 0.0).collect::<Vec<_>>(), &m.data))
                .sum::<f64>()
                / masks.len().max(1) as f64;
            LevelScore { fraction, level, dice }
        })
        .collect()
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

//! The completed surface: the density's iso-surface at the level from the views, islands
//! dropped, joined with the prior.

use std::borrow::Cow;
use std::path::Path;

use super::density::mc_level;
use crate::data::mesh::TriMesh;
use crate::data::mesh::io::write_mesh;
use crate::data::mesh::marching::extract_isosurface;
use crate::data::volume::Volume;
use crate::error::Result;
use crate::method::train::Trainer;
use crate::output::extraction::{
    LevelReach, LevelScore, best_level, faint_level_field, join_prior, keep_connected_to_prior, level_field,
    prior_solid,
};

/// The completed surface and how it was extracted.
pub(super) struct CompletedSurface {
    pub(super) mesh: TriMesh,
    /// Iso-level (density units).
    pub(super) level: f64,
    pub(super) level_scores: Vec<LevelScore>,
    pub(super) faint_level: Option<f64>,
    /// The level beside the prior (`output.near_prior_mask_threshold`), where it is lower.
    pub(super) near_prior_level: Option<f64>,
    /// What was cut at `field_level` (the density, or with faint vessels or the near-prior
    /// level the density over the local level, at 1).
    pub(super) field: Option<Volume<f32>>,
    pub(super) field_level: f64,
    pub(super) islands_dropped: usize,
    /// The extracted iso-surface (islands dropped) before the prior is joined.
    pub(super) extracted: TriMesh,
    /// The prior's voxels on the density grid, where the prior is kept.
    pub(super) kept_prior: Option<Volume<u8>>,
}

/// The iso-surface of the density at the level from the views (or the configured one), small
/// islands dropped, joined with the prior when it is kept; writes `mesh.*` (and the
/// intermediate `mesh-raw.*` / `mesh-extracted.*`).
pub(super) fn extract_completed_surface(
    dir: &Path,
    trainer: &Trainer,
    volume: &Volume<f32>,
    prior: Option<&TriMesh>,
) -> Result<CompletedSurface> {
    let out = &trainer.cfg().output;
    let solid = prior.filter(|_| out.keep_prior).map(|p| prior_solid(p, volume));
    let views = trainer.views().views();
    // What the views see of the solid at every candidate level: one projection for the level,
    // the faint level and (with the prior kept) the near-prior level.
    let reach = out.level_from_views.then(|| LevelReach::new(volume, views, solid.as_ref()));
    let level_scores = match &reach {
        Some(reach) => {
            reach.scores(trainer.images(), out.level_mask_threshold_for(views.len(), trainer.cfg().init.mask_threshold))
        }
        None => Vec::new(),
    };
    let level = match best_level(&level_scores) {
        Some(best) => best.level,
        None => mc_level(volume, out.mc_level, out.mc_relative),
    };
    let faint = reach.as_ref().filter(|_| out.faint_mask_threshold > 0.0).map(|reach| {
        let scores = reach.scores(trainer.images(), out.faint_mask_threshold);
        let low = best_level(&scores).map_or(level, |b| b.level.min(level));
        let radius = (out.faint_radius_mm / volume.grid.spacing_mm[0]).round() as usize;
        (low, faint_level_field(volume, level, low, out.faint_fraction, radius))
    });
    let (faint_level, faint_field) = faint.map_or((None, None), |(low, field)| (Some(low), Some(field)));
    // Beside the prior, the lower level of `output.near_prior_mask_threshold`.
    let near_solid = (out.near_prior_mask_threshold > 0.0 && out.level_from_views)
        .then(|| solid.as_ref().map(Cow::Borrowed).or_else(|| prior.map(|p| Cow::Owned(prior_solid(p, volume)))))
        .flatten();
    let near_prior_level = near_solid
        .as_ref()
        .and_then(|s| {
            let scores = match (s, &reach) {
                (Cow::Borrowed(_), Some(reach)) => reach.scores(trainer.images(), out.near_prior_mask_threshold),
                _ => LevelReach::new(volume, views, Some(&**s)).scores(trainer.images(), out.near_prior_mask_threshold),
            };
            best_level(&scores)
        })
        .map(|b| b.level)
        .filter(|&l| l < level);
    let near = near_solid.as_deref().zip(near_prior_level).map(|(s, l)| (s, l, out.near_prior_mm));
    let (field, field_level) = level_field(volume, level, faint_field, near);
    let cut = field.as_ref().unwrap_or(volume);
    let raw_mesh = extract_isosurface(cut, field_level as f32);
    let (extracted, islands_dropped) = if out.min_island_mm2 > 0.0 {
        let (kept, dropped) = raw_mesh.without_islands_below(out.min_island_mm2);
        write_mesh(&dir.join(format!("mesh-raw.{}", out.mesh_format)), &raw_mesh)?;
        (kept, dropped)
    } else {
        (raw_mesh, 0)
    };
    let (extracted, islands_dropped) = match prior {
        Some(p) if out.connected_level_fraction > 0.0 => {
            let voxelised;
            let s = match &solid {
                Some(s) => s,
                None => {
                    voxelised = prior_solid(p, volume);
                    &voxelised
                }
            };
            let (kept, dropped) =
                keep_connected_to_prior(&extracted, cut, out.connected_level_fraction * field_level, s);
            (kept, islands_dropped + dropped)
        }
        _ => (extracted, islands_dropped),
    };
    let mesh = match (prior, &solid) {
        (Some(p), Some(s)) => {
            write_mesh(&dir.join(format!("mesh-extracted.{}", out.mesh_format)), &extracted)?;
            join_prior(&extracted, p, s, out.keep_prior_mm)
        }
        _ => extracted.clone(),
    };
    write_mesh(&dir.join(format!("mesh.{}", out.mesh_format)), &mesh)?;
    Ok(CompletedSurface {
        mesh,
        level,
        level_scores,
        faint_level,
        near_prior_level,
        field,
        field_level,
        islands_dropped,
        extracted,
        kept_prior: solid,
    })
}

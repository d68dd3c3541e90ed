//! Initial Gaussians from what a user has — the DSA images, their geometry and the prior mesh:
//!
//! - N1: centres sampled area-uniformly on the prior surface;
//! - N2: the residual back-projection. Per view, vessel mask minus the dilated projection of the
//!   (solid) prior; each voxel of a back-projection grid is looked up in every view's residual
//!   and kept when supported in all views (intersection) and outside the prior; the N2 voxels
//!   with the largest geometric-mean residual intensity become centres (jittered inside the voxel).
//!   With `init.subtract_prior` the prior's projection is subtracted instead of masked: each
//!   view's image minus the prior mesh's chord lengths at a fitted contrast per mm, so a vessel
//!   behind the prior in one view still shows there.
//!   Variants: union instead of intersection, uniform random, masks instead of residuals, and
//!   (`init.grow_claims_mm`) the supported voxels grown from the prior one depth per pixel
//!   (`crate::method::seed_growth`).
//! - with `init.track_max_views`, the points of the vessels tracked from the prior through both
//!   views' residuals besides (`crate::method::tracking`).
//! - with two views and the case's arrival maps (`init.arrival_seeds`,
//!   `init.arrival_track_starts`), the image seeds and the tracks' starts only where both views
//!   fill at once (`crate::method::arrival`: the ghosts where two vessels cross fill at two times).
//! - isotropic scales from the mean squared distance to the k nearest other centres, identity
//!   rotations.

mod arrival_checks;
mod back_projection;
mod gaussians;
mod residual;
mod select;
#[cfg(test)]
pub(crate) mod tests;

use std::borrow::Cow;

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::config::{InitConfig, SeedMode};
use crate::data::case::images::Image;
use crate::data::masks::{Mask, prior_solid};
use crate::data::mesh::TriMesh;
use crate::data::mesh::sample::sample_surface;
use crate::data::vessel_evidence::VesselEvidence;
use crate::data::volume::{BoxMm, Grid};
use crate::error::{CoreError, Result};
use crate::method::model::{GaussianInit, ScaleBounds};
use crate::method::seed_growth::grow_from;
use crate::method::tracking::{FillsAtOnce, Residuals, TrackSettings, track_from_prior};

use arrival_checks::fills_at_once;
pub(crate) use arrival_checks::{arrival_pair, arriving};
pub(crate) use back_projection::{Scored, back_project};
pub(crate) use gaussians::isotropic_gaussians;
pub use gaussians::knn_scales;
use residual::{PriorRemoval, Residual, ResidualViews};
pub(crate) use select::{best_centres, connected_to_anchors};

/// The N2 centres for `mode`.
#[allow(clippy::too_many_arguments)]
pub fn n2_seeds(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    images: &[Image],
    prior: Option<&TriMesh>,
    bounds: &BoxMm,
    voxel_mm: f64,
    seed: u64,
    arrival: Option<&[Image]>,
) -> Result<Vec<DVec3>> {
    let n2 = cfg.n2_for(views.len());
    // With `n2 = 0` the tracked seeds alone (the prior-only member's, `run.member_tracks_max_views`).
    let tracking = views.len() <= cfg.track_max_views;
    if (n2 == 0 && !tracking) || cfg.n2_mode == SeedMode::None {
        return Ok(Vec::new());
    }
    let h = if cfg.n2_voxel_mm > 0.0 { cfg.n2_voxel_mm } else { voxel_mm };
    let grid = Grid::covering(bounds, h)?;
    let solid = prior.map(|p| prior_solid(p, grid));
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4e32);
    if cfg.n2_mode == SeedMode::Uniform {
        let mut out = Vec::with_capacity(n2);
        let mut tries = 0usize;
        while out.len() < n2 && tries < 1000 * n2 {
            tries += 1;
            let p = DVec3::new(
                rng.random_range(bounds.min_mm[0]..bounds.max_mm[0]),
                rng.random_range(bounds.min_mm[1]..bounds.max_mm[1]),
                rng.random_range(bounds.min_mm[2]..bounds.max_mm[2]),
            );
            let inside_prior = solid.as_ref().is_some_and(|s| {
                let ijk = [0, 1, 2].map(|a| ((p[a] - grid.origin_mm[a]) / h).floor() as usize);
                ijk.iter().zip(grid.dims).all(|(&i, d)| i < d) && s.get(ijk[0], ijk[1], ijk[2]) != 0
            });
            if !inside_prior {
                out.push(p);
            }
        }
        return Ok(out);
    }
    // What the views show of their vessels (pooled along them where noisy): everything below
    // reads these, their levels and masks.
    let evidence: Vec<VesselEvidence> = VesselEvidence::of_views(images);
    let levels: Vec<f64> = evidence.iter().map(|e| e.level(cfg.mask_threshold)).collect();
    let masks: Vec<Mask> = evidence.iter().map(|e| e.mask(cfg.mask_threshold)).collect();
    let shown_images: Cow<'_, [Image]> = if evidence.iter().any(VesselEvidence::pooled) {
        Cow::Owned(evidence.into_iter().map(|e| e.image.into_owned()).collect())
    } else {
        Cow::Borrowed(images)
    };
    let images = shown_images.as_ref();
    let intersect = cfg.n2_mode != SeedMode::ResidualUnion;
    let exclude = if cfg.n2_mode == SeedMode::AllViewsIntersect { None } else { solid.as_ref() };
    let shown = ResidualViews {
        cfg,
        views,
        images,
        prior,
        solid: solid.as_ref(),
        masks: &masks,
        levels: &levels,
        grid: &grid,
        exclude,
        intersect,
    };
    let seeds_removal = PriorRemoval { fit: cfg.fit_prior_projection, dilation_px: cfg.prior_dilation_px };
    // The image seeds' residual; none without image seeds (the tracked seeds alone).
    let seeding = if n2 > 0 { Some(shown.residual(seeds_removal)?) } else { None };
    // Tracked from the prior (before the growth or the connectivity filter thins the starts).
    let tracked = match exclude {
        Some(s) if intersect && tracking => {
            let track_removal = PriorRemoval {
                fit: cfg.track_fit_prior_projection.unwrap_or(seeds_removal.fit),
                dilation_px: cfg.track_prior_dilation_px.unwrap_or(seeds_removal.dilation_px),
            };
            // The tracker reads the image seeds' residual unless it removes the prior its own way.
            let own;
            let read = match &seeding {
                Some(r) if track_removal == seeds_removal => r,
                _ => {
                    own = shown.residual(track_removal)?;
                    &own
                }
            };
            let res = Residuals { views, images: &read.values, levels: &levels };
            // With `init.arrival_track_starts`, tracks start only where both views fill at once;
            // with `init.arrival_track_claims`, a claim whose point fills at two times gives way
            // to a point that fills at once, and the tracks, going farther, get their own rounds.
            let maps = arrival_pair(cfg, views, arrival);
            let together = maps.filter(|_| cfg.arrival_track_claims).map(|maps| fills_at_once(cfg, views, maps));
            let claims_checked = together.is_some();
            let settings = TrackSettings {
                start_mm: cfg.track_start_mm,
                level: cfg.track_level,
                turn_cost: cfg.track_turn_cost,
                brightness_cost: cfg.track_brightness_cost,
                claimed_run_mm: cfg.track_claimed_run_mm,
                max_points: cfg.track_max_points_for(claims_checked),
                rounds: cfg.track_rounds_for(claims_checked),
            };
            let starts: Cow<'_, [Scored]> = match maps {
                Some(maps) if cfg.arrival_track_starts => {
                    Cow::Owned(arriving(cfg, views, maps, read.scored.par_iter().copied()))
                }
                _ => Cow::Borrowed(&read.scored),
            };
            track_from_prior(&res, &starts, s, settings, together.as_ref().map(|f| f as FillsAtOnce))
        }
        _ => Vec::new(),
    };
    let Some(Residual { support, occluded, mut scored, .. }) = seeding else {
        return Ok(tracked);
    };
    if let Some(maps) = arrival_pair(cfg, views, arrival).filter(|_| cfg.arrival_seeds) {
        scored = arriving(cfg, views, maps, scored);
    }
    // Not for the mask-only mode, which ignores the prior by design.
    let (mut spacing_mm, mut n) = (cfg.seed_spacing_mm_for(views.len()), n2);
    if let Some(s) = exclude {
        let to_prior = cfg.connected_to_prior_mm > 0.0 && views.len() <= cfg.connected_max_views;
        if to_prior && cfg.grow_claims_mm > 0.0 {
            scored = grow_from(&grid, views, &support, scored, s, cfg.connected_to_prior_mm, cfg.grow_claims_mm);
            (spacing_mm, n) = (cfg.grow_claims_spacing_mm, cfg.grow_claims_n2);
        } else if to_prior {
            scored = connected_to_anchors(scored, s, cfg.connected_to_prior_mm, |_| false);
        } else if occluded.is_some() && cfg.occluded_connected {
            // A voxel that a view passed only because the prior hides it must belong to a group
            // that holds a voxel every view supports with residual, or that reaches the prior.
            scored = connected_to_anchors(scored, s, cfg.connected_to_prior_mm, |&(_, _, full)| full);
        }
    }
    let mut centres = best_centres(scored, spacing_mm, n, h, &mut rng);
    centres.extend(tracked);
    Ok(centres)
}

/// The initial Gaussians and what went into them.
#[derive(Debug, Clone)]
pub struct Initialisation {
    pub gaussians: GaussianInit,
    /// How many came from the prior (first) and from the images (after).
    pub n1: usize,
    pub n2: usize,
}

/// N1 + N2 centres with kNN isotropic scales and identity rotations.
#[allow(clippy::too_many_arguments)]
pub fn initialise(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    images: &[Image],
    prior: Option<&TriMesh>,
    bounds: &BoxMm,
    voxel_mm: f64,
    scale_bounds: ScaleBounds,
    seed: u64,
    arrival: Option<&[Image]>,
) -> Result<Initialisation> {
    let mut centres: Vec<DVec3> = Vec::new();
    let use_prior = cfg.n2_mode != SeedMode::AllViewsIntersect;
    if cfg.n1 > 0 && use_prior {
        let p = prior.ok_or_else(|| CoreError::invalid("init.n1 > 0 needs a prior mesh (or set init.n1 = 0)"))?;
        centres.extend(sample_surface(p, cfg.n1, seed));
    }
    let n1 = centres.len();
    centres.extend(n2_seeds(cfg, views, images, prior.filter(|_| use_prior), bounds, voxel_mm, seed, arrival)?);
    let n2 = centres.len() - n1;
    if centres.is_empty() {
        return Err(CoreError::invalid("initialisation produced no Gaussian (empty prior and no image support)"));
    }
    let scales = knn_scales(&centres, cfg.knn, voxel_mm);
    Ok(Initialisation { gaussians: isotropic_gaussians(&centres, &scales, scale_bounds), n1, n2 })
}

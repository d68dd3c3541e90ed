//! What each view shows beside the prior: the support masks and images the back-projection reads,
//! with the prior's projection masked (dilated) or subtracted at a fitted contrast.

use std::borrow::Cow;

use ctadsa_render::ConeBeamView;

use super::{Scored, back_project};
use crate::config::{InitConfig, SeedMode};
use crate::data::case::images::Image;
use crate::data::masks::{Mask, above, contrast_per_mm, max_filtered, minus_solid, silhouettes};
use crate::data::mesh::TriMesh;
use crate::data::projector::matched::{BLUR_SIGMAS_PX, OFFSETS_MM, fit_mesh_projection};
use crate::data::projector::mesh::mesh_chords;
use crate::data::volume::{Grid, Volume};
use crate::error::{CoreError, Result};

/// How each view's image is rid of the prior before the back-projection
/// (`init.fit_prior_projection`, `init.prior_dilation_px`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct PriorRemoval {
    pub(super) fit: bool,
    pub(super) dilation_px: u32,
}

/// What the views show beside the prior: per view the support mask and the image that scores the
/// voxels, (`init.occluded_views_support`, intersect modes) the masks where the prior hides a
/// vessel, and the back-projection's supported voxels.
pub(super) struct Residual<'a> {
    pub(super) support: Vec<Mask>,
    pub(super) values: Cow<'a, [Image]>,
    pub(super) occluded: Option<Vec<Mask>>,
    pub(super) scored: Vec<Scored>,
}

/// The inputs from which [`Residual`]s are taken (one per [`PriorRemoval`]).
pub(super) struct ResidualViews<'a> {
    pub(super) cfg: &'a InitConfig,
    pub(super) views: &'a [ConeBeamView],
    pub(super) images: &'a [Image],
    pub(super) prior: Option<&'a TriMesh>,
    /// The prior's solid on the back-projection grid.
    pub(super) solid: Option<&'a Volume<u8>>,
    /// Each view's vessel mask and vessel level (contrast × mm).
    pub(super) masks: &'a [Mask],
    pub(super) levels: &'a [f64],
    /// The back-projection's grid, the solid its voxels must lie outside, and whether every view
    /// must support a voxel.
    pub(super) grid: &'a Grid,
    pub(super) exclude: Option<&'a Volume<u8>>,
    pub(super) intersect: bool,
}

impl<'a> ResidualViews<'a> {
    /// The residual with the prior removed as `removal` says, back-projected.
    pub(super) fn residual(&self, removal: PriorRemoval) -> Result<Residual<'a>> {
        let mut r = self.shown(removal)?;
        r.occluded = r.occluded.filter(|_| self.intersect);
        r.scored = back_project(
            self.grid,
            self.views,
            &r.support,
            r.occluded.as_deref(),
            &r.values,
            self.exclude,
            self.intersect,
        );
        Ok(r)
    }

    /// The residual before its back-projection (`scored` empty).
    fn shown(&self, removal: PriorRemoval) -> Result<Residual<'a>> {
        let (cfg, views, images) = (self.cfg, self.views, self.images);
        let mut values: Cow<'a, [Image]> = Cow::Borrowed(images);
        if cfg.n2_mode == SeedMode::AllViewsIntersect {
            let support = self.masks.iter().map(|m| m.dilated(cfg.residual_dilation_px)).collect();
            return Ok(Residual { support, values, occluded: None, scored: Vec::new() });
        }
        let Some(s) = self.solid else {
            return Err(CoreError::invalid(format!("init.n2_mode {:?} needs a prior mesh", cfg.n2_mode)));
        };
        let subtracted = self.prior.filter(|_| cfg.subtract_prior);
        let occluded_support = cfg.occluded_views_support && views.len() >= cfg.occluded_min_views;
        // The prior's dilated silhouettes, where something reads them.
        let prior_sil: Vec<Mask> = if subtracted.is_none() || occluded_support {
            silhouettes(s, views).iter().map(|p| p.dilated(removal.dilation_px)).collect()
        } else {
            Vec::new()
        };
        let occluded = occluded_support.then(|| {
            self.masks.iter().zip(&prior_sil).map(|(m, p)| m.dilated(cfg.residual_dilation_px).and(p)).collect()
        });
        let mut support = Vec::with_capacity(views.len());
        for (vi, m) in self.masks.iter().enumerate() {
            let shown = match subtracted {
                // The prior's projection subtracted instead of masked: a pixel shows residual
                // where the image exceeds the prior's chord (the longest within the dilation:
                // the grey-level analogue of dilating its silhouette) at the fitted contrast per
                // mm, and what is left scores the voxels.
                Some(mesh) => {
                    let (chords, contrast) = if removal.fit {
                        let fit = fit_mesh_projection(&images[vi], mesh, &views[vi], &OFFSETS_MM, &BLUR_SIGMAS_PX)?;
                        (fit.chords, fit.contrast_per_mm)
                    } else {
                        let sharp = mesh_chords(mesh, &views[vi])?;
                        let contrast = contrast_per_mm(&images[vi], &sharp);
                        (sharp, contrast)
                    };
                    let longest = max_filtered(&chords, m.width as usize, removal.dilation_px);
                    let rest = minus_solid(&images[vi], &longest, contrast);
                    let shown = above(&rest, self.levels[vi]);
                    values.to_mut()[vi] = rest;
                    shown
                }
                None => m.minus(&prior_sil[vi]),
            };
            support.push(shown.dilated(cfg.residual_dilation_px));
        }
        Ok(Residual { support, values, occluded, scored: Vec::new() })
    }
}

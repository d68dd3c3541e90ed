//! The completed centreline: the solid it is traced in (on the density's grid or a finer one),
//! traced, written and scored, with the topology scores.

use std::path::Path;

use super::density::{RunModels, completion_density_on};
use super::surface::CompletedSurface;
use crate::config::OutputConfig;
use crate::data::case::images::Image;
use crate::data::mesh::TriMesh;
use crate::data::mesh::marching::extract_isosurface;
use crate::data::volume::skeleton::SkeletonParams;
use crate::data::volume::{Grid, Volume};
use crate::error::Result;
use crate::eval::score::CaseTruth;
use crate::eval::topology::{TopologyScores, topology_scores};
use crate::output::centreline::{ArrivalCheck, CentrelineSummary, SolidPart, completed_centreline, write_centreline};
use crate::output::centring::Centring;
use crate::output::confidence::{MESH_CONFIDENCE, vertex_confidence, write_mesh_confidence};
use crate::output::extraction::{bridged_solid, completed_solid, faint_level_field, level_field, prior_solid};
use ctadsa_render::ConeBeamView;

/// The solid the centreline is traced in (`output.centreline_voxel_mm`): the voxels of the
/// completion's density at or above the surface's level, their iso-surface and the prior's
/// voxels, on the density volume's grid or on a finer one.
pub(super) struct TracedSolid<'a> {
    pub(super) above_level: Volume<u8>,
    /// The iso-surface on the finer grid; `None` on the density volume's grid, where it is the
    /// extracted surface.
    pub(super) surface: Option<TriMesh>,
    /// The prior mesh and its voxels on this grid.
    pub(super) prior: Option<&'a TriMesh>,
    pub(super) prior_voxels: Option<Volume<u8>>,
    /// With `output.centreline_bridge_fraction` (`…_two_views`): the extracted solid and the
    /// faint voxels between its beads ([`bridged_solid`]).
    pub(super) bridges: Option<Volume<u8>>,
    /// With `output.centreline_ridge_weight` (`…_arrival`): the density over the level it was
    /// cut at, on this grid.
    pub(super) relative: Option<Volume<f32>>,
}

/// The [`TracedSolid`] of a run: on the density volume's grid, or with
/// `output.centreline_voxel_mm` finer than its voxel, the completion's density voxelised again
/// at that size and cut the way the surface was (the same level, the faint vessels' local
/// level at the same radius in mm, and the near-prior level within the same distance). The
/// settings and the working box are `own`'s; with `others` (an ensemble) the density is theirs too.
pub(super) fn traced_solid<'a>(
    own: &RunModels,
    others: &[RunModels],
    volume: &Volume<f32>,
    surface: &CompletedSurface,
    prior: Option<&'a TriMesh>,
) -> Result<TracedSolid<'a>> {
    let trainer = &own.model;
    let out = &trainer.cfg().output;
    let voxel = out.centreline_voxel_mm;
    let bridge_fraction = out.centreline_bridge_fraction_for(trainer.views().views().len());
    let bridges = |density: &Volume<f32>, above: &Volume<u8>, prior_voxels: Option<&Volume<u8>>| {
        (bridge_fraction > 0.0).then(|| {
            let voxels = |mm: f64| (mm / density.grid.spacing_mm[0]).round() as usize;
            let clear = (out.centreline_bridge_prior_clearance_mm > 0.0)
                .then_some(prior_voxels)
                .flatten()
                .map(|p| (p, voxels(out.centreline_bridge_prior_clearance_mm)));
            bridged_solid(density, above, bridge_fraction * surface.level, voxels(out.centreline_bridge_mm), clear)
        })
    };
    let relative =
        |cut: &Volume<f32>, level: f64| out.centreline_follows_ridges().then(|| cut.map(|d| d / level as f32));
    if voxel <= 0.0 || voxel >= volume.grid.spacing_mm[0] {
        let cut = surface.field.as_ref().unwrap_or(volume);
        let above_level = completed_solid(cut, surface.field_level, None);
        let prior_voxels = surface.kept_prior.clone().or_else(|| prior.map(|p| prior_solid(p, volume)));
        let bridges = bridges(volume, &above_level, prior_voxels.as_ref());
        let relative = relative(cut, surface.field_level);
        return Ok(TracedSolid { above_level, surface: None, prior, prior_voxels, bridges, relative });
    }
    let grid = Grid::covering(trainer.working_box(), voxel)?;
    let density = completion_density_on(grid, own, others)?;
    let faint = surface.faint_level.map(|low| {
        let radius = (out.faint_radius_mm / voxel).round() as usize;
        faint_level_field(&density, surface.level, low, out.faint_fraction, radius)
    });
    let prior_voxels = prior.map(|p| prior_solid(p, &density));
    let near = prior_voxels.as_ref().zip(surface.near_prior_level).map(|(p, l)| (p, l, out.near_prior_mm));
    let (field, cut_level) = level_field(&density, surface.level, faint, near);
    let cut = field.as_ref().unwrap_or(&density);
    let above_level = completed_solid(cut, cut_level, None);
    let fine_surface = extract_isosurface(cut, cut_level as f32);
    let bridges = bridges(&density, &above_level, prior_voxels.as_ref());
    let relative = relative(cut, cut_level);
    Ok(TracedSolid { above_level, surface: Some(fine_surface), prior, prior_voxels, bridges, relative })
}

/// The centreline of the completed solid ([`TracedSolid`]), written and scored
/// ([`write_centreline`]; `arrival_maps`: the run's views', when the case has them); the
/// topology scores on the density volume's grid.
#[allow(clippy::too_many_arguments)]
pub(super) fn write_centreline_of(
    dir: &Path,
    volume: &Volume<f32>,
    surface: &CompletedSurface,
    traced: &TracedSolid,
    out: &OutputConfig,
    views: &[ConeBeamView],
    arrival_maps: Option<&[Image]>,
    truth: Option<&CaseTruth>,
) -> Result<(CentrelineSummary, Option<TopologyScores>, Vec<f64>)> {
    let prior = traced.prior;
    let prior_part = prior.zip(traced.prior_voxels.as_ref()).map(|(surface, voxels)| SolidPart { voxels, surface });
    let extracted =
        SolidPart { voxels: &traced.above_level, surface: traced.surface.as_ref().unwrap_or(&surface.extracted) };
    let working_voxel = volume.grid.spacing_mm[0];
    let traced_voxel = traced.above_level.grid.spacing_mm[0];
    let defaults = SkeletonParams::default();
    // The smallest component kept holds the same volume on either grid.
    let min_component_voxels =
        (defaults.min_component_voxels as f64 * (working_voxel / traced_voxel).powi(3)).round() as usize;
    // With three views or more the third view already rejects the ghosts.
    let checked = out.arrival_min_agreement > 0.0 && views.len() == 2;
    let arrival = arrival_maps.filter(|_| checked).map(|maps| ArrivalCheck {
        maps,
        tolerance_frames: out.arrival_tolerance_frames,
        min_agreement: out.arrival_min_agreement,
        exit_px: out.arrival_prior_exit_px.unwrap_or(0),
    });
    let params = SkeletonParams {
        scale: out.centreline_scale,
        const_mm: out.centreline_const_mm_for(views.len(), arrival.is_some()),
        min_branch_mm: out.centreline_min_branch_mm,
        min_component_voxels,
        ridge_weight: out.centreline_ridge_weight_for(views.len(), arrival.is_some()),
        ..defaults
    };
    let tree = completed_centreline(
        extracted,
        prior_part,
        surface.kept_prior.is_some(),
        &params,
        match (out.centreline_centring, out.centreline_ridge_centring) {
            (false, _) => Centring::Off,
            (true, false) => Centring::Surface,
            (true, true) => Centring::Ridge,
        },
        working_voxel,
        traced.bridges.as_ref(),
        traced.relative.as_ref(),
    );
    // The completed volume (inside the extracted surface, islands dropped as in the mesh, and the
    // prior's voxels where it is kept) against the voxels inside the true surface, both on the
    // density's grid (vessels thinner than its voxels break up alike in both), with the two
    // centrelines as skeletons.
    let topology = truth.and_then(|t| t.centreline.as_deref().map(|skeleton| (t, skeleton))).map(|(t, skeleton)| {
        let mut completed = crate::data::mesh::voxelize::voxelize_mesh(&surface.extracted, volume.grid);
        let working_prior = match (&surface.kept_prior, prior) {
            (Some(kept), _) => Some(kept.clone()),
            (None, Some(p)) if traced.surface.is_some() => Some(prior_solid(p, volume)),
            (None, _) => traced.prior_voxels.clone(),
        };
        if let Some(prior) = working_prior {
            for (c, &p) in completed.data.iter_mut().zip(&prior.data) {
                *c |= p;
            }
        }
        let true_solid = crate::data::mesh::voxelize::voxelize_mesh(&t.complete, volume.grid);
        topology_scores(&completed, &true_solid, &tree.segments(), skeleton)
    });
    let truth = truth.and_then(|t| t.missing_centreline.as_deref().zip(t.centreline.as_deref()));
    let (summary, confidence) = write_centreline(dir, &tree, views, truth, out.min_confidence, arrival)?;
    let at_vertices = vertex_confidence(&surface.mesh, &tree, &confidence);
    write_mesh_confidence(&dir.join(MESH_CONFIDENCE), &surface.mesh, &at_vertices)?;
    Ok((summary, topology, at_vertices))
}

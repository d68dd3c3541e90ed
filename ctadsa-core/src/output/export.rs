//! Everything a completion run writes: density volume (NIfTI), completed mesh, Gaussians (PLY),
//! renders beside targets with their difference (PNG), loss curve (PNG + CSV), the config used,
//! and metrics (JSON) when the case has ground truth.

use std::borrow::Cow;
use std::path::Path;

use burn::module::Module;
use glam::DVec3;
use serde::Serialize;

use crate::config::OutputConfig;
use crate::data::case::images::{Image, write_rgb_or_grey};
use crate::data::case::{Case, ViewGeometry};
use crate::data::mesh::TriMesh;
use crate::data::mesh::io::{write_mesh, write_point_ply};
use crate::data::mesh::marching::extract_isosurface;
use crate::data::mesh::render_png::{Coloured, OrbitView, standard_views, write_mesh_png};
use crate::data::mesh::split::split_by_distance;
use crate::data::projector::correction::{PoseCorrection, PoseError, corrected_view, pose_errors};
use crate::data::volume::nifti_io::write_nifti;
use crate::data::volume::skeleton::SkeletonParams;
use crate::data::volume::{Grid, Volume};
use crate::error::{Result, to_json, write_file};
use crate::eval::metrics::RegionScores;
use crate::eval::score::{CaseTruth, EvalOptions};
use crate::eval::surface_metrics::Coverage;
use crate::eval::topology::{TopologyScores, topology_scores};
use crate::method::arrival::{prior_hidden_maps, run_arrival_maps};
use crate::method::field_health::DensitySpread;
use crate::method::train::{StepLog, Trainer};
use crate::method::training_time::TrainingTime;
use crate::output::centreline::{ArrivalCheck, CentrelineSummary, SolidPart, completed_centreline, write_centreline};
use crate::output::centring::Centring;
use crate::output::confidence::{MESH_CONFIDENCE, mesh_without_doubtful, vertex_confidence, write_mesh_confidence};
use crate::output::extraction::{
    LevelReach, LevelScore, best_level, bridged_solid, completed_solid, density_scale, faint_level_field, join_prior,
    keep_connected_to_prior, level_field, prior_solid,
};
use crate::output::plot::{PALETTE, Series, line_plot};
use ctadsa_ops::readback::host_vec;
use ctadsa_render::ConeBeamView;

/// Numbers of a finished run.
#[derive(Debug, Clone, Serialize)]
pub struct RunSummary {
    /// The case folder the run used (as given).
    pub case_dir: String,
    /// The case's [`Case::fingerprint`](crate::data::case::Case::fingerprint) (name and a hash
    /// of its `case.json`).
    pub case_fingerprint: String,
    pub iterations: usize,
    pub gaussians: usize,
    pub n1: usize,
    pub n2: usize,
    /// Iso-level of the extracted surface (density units) and the triangle count.
    pub mc_level: f64,
    /// With `output.level_from_views`: every candidate level and its silhouette Dice.
    pub level_scores: Vec<LevelScore>,
    /// With `output.faint_mask_threshold`: the lower level the faint vessels may go down to
    /// (density units).
    pub faint_level: Option<f64>,
    pub mesh_triangles: usize,
    /// Connected components dropped as floaters (`output.min_island_mm2`) or as not linked
    /// to the prior (`output.connected_level_fraction`).
    pub islands_dropped: usize,
    pub final_loss: f64,
    /// The field's densities at the Gaussians' centres; a constant field has collapsed
    /// ([`crate::method::field_health`]).
    pub field_densities: Option<DensitySpread>,
    pub field_constant: bool,
    /// The training time from the run's step log (across resumes; [`TrainingTime`]).
    pub training_time: Option<TrainingTime>,
    /// The prior-only member whose density was averaged in (`run.prior_only_member`).
    pub prior_only_member: Option<MemberSummary>,
    /// The further image-seeded members averaged in (`run.member_seeds`), in that order.
    pub seed_members: Vec<MemberSummary>,
    /// Scores of the completed surface (exact distances, `docs/METRICS.md`) when the case has
    /// ground truth.
    pub metrics: Option<RegionScores>,
    /// Missing-vessel recall and false surface of the completed surface.
    pub coverage: Option<Coverage>,
    /// The completed surface in the paper's convention (vertex point sets).
    pub paper_metrics: Option<RegionScores>,
    /// The same scores for the prior alone (what the run started from), for comparison.
    pub prior_metrics: Option<RegionScores>,
    pub prior_coverage: Option<Coverage>,
    /// The completed centreline (`centreline.swc` / `.vtp`) and its scores against the true tree.
    pub centreline: CentrelineSummary,
    /// clDice and the Betti-0 error of the completed volume against the true one
    /// ([`crate::eval::topology`]), when the case has a true tree.
    pub topology: Option<TopologyScores>,
    /// With pose refinement on a case whose true view corrections are known: how far each
    /// refined view is from the truth.
    pub pose_errors: Option<Vec<PoseError>>,
}

/// A member of a run (`run.prior_only_member`, `run.member_seeds`).
#[derive(Debug, Clone, Serialize)]
pub struct MemberSummary {
    /// Its `run.seed`.
    pub seed: u64,
    pub gaussians: usize,
    pub final_loss: f64,
    /// Its training time (the run's own is [`RunSummary::training_time`]).
    pub training_time: Option<TrainingTime>,
}

impl MemberSummary {
    fn of(member: &Trainer) -> Self {
        Self {
            seed: member.cfg().run.seed,
            gaussians: member.model().len(),
            final_loss: member.history().last().map_or(f64::NAN, |s| s.loss),
            training_time: TrainingTime::of(member.history()),
        }
    }
}

/// The density field on a grid over the working box.
pub fn density_volume(trainer: &Trainer) -> Result<Volume<f32>> {
    let voxel = if trainer.cfg().output.voxel_mm > 0.0 { trainer.cfg().output.voxel_mm } else { trainer.voxel_mm() };
    density_on(trainer, Grid::covering(trainer.working_box(), voxel)?)
}

/// The density field of `trainer`'s Gaussians on `grid`.
fn density_on(trainer: &Trainer, grid: Grid) -> Result<Volume<f32>> {
    let m = trainer.model().valid();
    let vol = ctadsa_render::voxelize(&m.gaussians(), &grid.to_render_grid()?, trainer.settings())?;
    Ok(Volume { grid, index_to_world: grid.index_to_world(), data: host_vec(vol) })
}

/// The density of the run: the mean of the image-seeded models' densities (the run's and its
/// `seed_members'`, `run.member_seeds`) on the run's grid, and with a prior-only `member`
/// (`run.prior_only_member`) the mean of that and the member's.
pub fn completion_density(
    trainer: &Trainer,
    seed_members: &[Trainer],
    member: Option<&Trainer>,
) -> Result<Volume<f32>> {
    completion_density_on(density_volume(trainer)?, seed_members, member)
}

/// [`completion_density`] with the run's own density (on the grid it is to have) given.
fn completion_density_on(
    mut volume: Volume<f32>,
    seed_members: &[Trainer],
    member: Option<&Trainer>,
) -> Result<Volume<f32>> {
    let mut seeded = vec![];
    for m in seed_members {
        seeded.push(density_on(m, volume.grid)?.data);
    }
    mean_into(&mut volume.data, &seeded);
    if let Some(member) = member {
        mean_into(&mut volume.data, &[density_on(member, volume.grid)?.data]);
    }
    Ok(volume)
}

/// `acc` becomes the voxel-wise mean of itself and `others` (each as long as `acc`).
fn mean_into(acc: &mut [f32], others: &[Vec<f32>]) {
    if others.is_empty() {
        return;
    }
    let n = (others.len() + 1) as f32;
    for (i, d) in acc.iter_mut().enumerate() {
        *d = (*d + others.iter().map(|o| o[i]).sum::<f32>()) / n;
    }
}

/// The iso-level: relative to the 99.9th percentile of the positive densities, or absolute.
pub fn mc_level(volume: &Volume<f32>, level: f64, relative: bool) -> f64 {
    if relative { level * density_scale(volume) } else { level }
}

/// `[target | render | |difference|]` of every view, one PNG per view, magnified by an integer
/// factor (nearest neighbour) so that each panel is at least 256 pixels wide.
fn write_renders(dir: &Path, case: &Case, trainer: &Trainer, renders: &[Vec<f32>]) -> Result<()> {
    let names: Vec<String> = if trainer.cfg().run.views.is_empty() {
        case.file.views.iter().map(|v| v.name.clone()).collect()
    } else {
        trainer.cfg().run.views.iter().map(|&i| case.file.views[i].name.clone()).collect()
    };
    for ((name, target), render) in names.iter().zip(trainer.images()).zip(renders) {
        let (w, h) = (target.width as usize, target.height as usize);
        let max = target.max().max(render.iter().copied().fold(0.0, f32::max)).max(1e-12);
        let mut rgb = vec![255u8; 3 * w * 3 * h];
        let stride = 3 * w;
        for r in 0..h {
            for c in 0..w {
                let t = target.data[r * w + c] / max;
                let p = render[r * w + c] / max;
                let d = p - t;
                let grey = |v: f32| (255.0 * (1.0 - v.clamp(0.0, 1.0))).round() as u8;
                let px = |k: usize, col: [u8; 3], rgb: &mut Vec<u8>| {
                    let i = 3 * (r * stride + k * w + c);
                    rgb[i..i + 3].copy_from_slice(&col);
                };
                px(0, [grey(t); 3], &mut rgb);
                px(1, [grey(p); 3], &mut rgb);
                // Difference: red where the render is too bright, blue where too dark.
                let m = (255.0 * (1.0 - (d.abs() * 2.0).clamp(0.0, 1.0))).round() as u8;
                px(2, if d > 0.0 { [255, m, m] } else { [m, m, 255] }, &mut rgb);
            }
        }
        // Small detectors are enlarged to ≈ 256 px wide, never past 4,096 px tall (a 1 × 65,536
        // detector would otherwise ask for a 38 GB picture).
        let f = (256 / w.max(1)).min(4096 / h.max(1)).max(1);
        let (big_w, big_h) = (3 * w * f, h * f);
        let mut big = vec![0u8; 3 * big_w * big_h];
        for y in 0..big_h {
            for x in 0..big_w {
                let (i, j) = (3 * (y * big_w + x), 3 * ((y / f) * stride + x / f));
                big[i..i + 3].copy_from_slice(&rgb[j..j + 3]);
            }
        }
        write_rgb_or_grey(&dir.join(format!("renders/{name}.png")), big_w as u32, big_h as u32, big, 3)?;
    }
    Ok(())
}

/// With pose refinement: writes `poses.json` (the corrections and the refined geometry of every
/// view of the run, as world-to-camera matrices at the case's detector) and, when the case knows
/// the true corrections, returns how far the refined views are from them.
fn write_poses(dir: &Path, case: &Case, trainer: &Trainer, prior: Option<&TriMesh>) -> Result<Option<Vec<PoseError>>> {
    let Some(learned) = trainer.pose_corrections() else {
        return Ok(None);
    };
    let indices: Vec<usize> = if trainer.cfg().run.views.is_empty() {
        (0..case.views.len()).collect()
    } else {
        trainer.cfg().run.views.clone()
    };
    let nominal: Vec<(usize, ConeBeamView)> = indices.iter().map(|&i| (i, case.views.views()[i])).collect();
    let mut entries = Vec::new();
    for ((i, view), c) in nominal.iter().zip(&learned) {
        let refined = corrected_view(view, c)?;
        let intr = refined.intrinsics();
        let m = refined.world_to_camera().transpose().to_cols_array_2d();
        entries.push(serde_json::json!({
            "view": i,
            "name": case.file.views[*i].name,
            "rotation_deg": [c[0].to_degrees(), c[1].to_degrees(), c[2].to_degrees()],
            "translation_mm": [c[3], c[4], c[5]],
            "geometry": ViewGeometry::Matrix {
                world_to_camera: m,
                focal_px: intr.focal_px,
                principal_px: intr.principal_px,
                detector_px: [refined.width(), refined.height()],
            },
        }));
    }
    let poses_path = dir.join("poses.json");
    let text = to_json(
        &serde_json::json!({
            "convention": "view v sees world point x where the nominal view sees R(ω) x + t (rotation about the isocentre, then translation); geometry = the refined view",
            "views": entries,
        }),
        &poses_path,
    )?;
    write_file(&poses_path, text.as_bytes())?;
    let truth = case.file.ground_truth.as_ref().and_then(|g| g.view_corrections.as_ref());
    let Some(truth) = truth else {
        return Ok(None);
    };
    let truth: Vec<PoseCorrection> = indices.iter().map(|&i| truth.get(i).copied().unwrap_or([0.0; 6])).collect();
    let points: Vec<DVec3> = match prior {
        Some(p) if !p.vertices.is_empty() => {
            p.vertices.iter().step_by((p.vertices.len() / 2000).max(1)).copied().collect()
        }
        _ => vec![DVec3::ZERO],
    };
    Ok(Some(pose_errors(&nominal, &learned, &truth, &points)?))
}

/// Writes the outputs of a run into `dir`; with members (`seed_members`, a prior-only `member`)
/// the density, the surface and what comes from them are of the mean density
/// ([`completion_density`]), the Gaussians and the renders the run's own.
pub fn write_outputs(
    dir: &Path,
    case: &Case,
    trainer: &Trainer,
    seed_members: &[Trainer],
    member: Option<&Trainer>,
) -> Result<RunSummary> {
    let cfg = trainer.cfg();
    write_file(&dir.join("config.toml"), cfg.to_toml().as_bytes())?;
    let gaussians = write_gaussians(dir, trainer)?;
    let volume = completion_density(trainer, seed_members, member)?;
    write_nifti(&dir.join("density.nii.gz"), &volume, "ctadsa density (per mm)")?;
    let prior = case.prior_mesh()?;
    let surface = extract_completed_surface(dir, trainer, &volume, prior.as_ref())?;
    let truth = CaseTruth::load(case)?;
    let traced = traced_solid(trainer, seed_members, member, &volume, &surface, prior.as_ref())?;
    let arrival_maps = match cfg.output.arrival_prior_exit_px {
        Some(_) => prior_hidden_maps(case, cfg)?,
        None => run_arrival_maps(case, cfg)?,
    };
    let (centreline, topology, vertex_confidence) = write_centreline_of(
        dir,
        &volume,
        &surface,
        &traced,
        &cfg.output,
        trainer.views().views(),
        arrival_maps.as_deref(),
        truth.as_ref(),
    )?;
    let trusted;
    let mesh = if cfg.output.min_confidence > 0.0 {
        trusted = mesh_without_doubtful(&surface.mesh, &vertex_confidence, cfg.output.min_confidence);
        write_mesh(&dir.join(format!("mesh.{}", cfg.output.mesh_format)), &trusted)?;
        &trusted
    } else {
        &surface.mesh
    };
    let renders = trainer.render_all()?;
    write_renders(dir, case, trainer, &renders)?;
    write_loss(dir, trainer.history())?;
    write_mesh_pictures(dir, mesh, prior.as_ref())?;
    // Metrics.
    let options = EvalOptions { samples: cfg.output.metric_samples, ..EvalOptions::default() };
    let scored = truth.as_ref().map(|t| t.evaluate(mesh, &options));
    let prior_scored = match (&truth, &prior) {
        (Some(t), Some(p)) => Some(t.evaluate(p, &options)),
        _ => None,
    };
    let pose_errors = write_poses(dir, case, trainer, prior.as_ref())?;
    let spread = trainer.density_spread();
    let summary = RunSummary {
        case_dir: case.dir.display().to_string(),
        case_fingerprint: case.fingerprint(),
        iterations: trainer.iteration(),
        gaussians,
        n1: trainer.seed_counts().0,
        n2: trainer.seed_counts().1,
        mc_level: surface.level,
        level_scores: surface.level_scores,
        faint_level: surface.faint_level,
        mesh_triangles: mesh.faces.len(),
        islands_dropped: surface.islands_dropped,
        final_loss: trainer.history().last().map_or(f64::NAN, |s| s.loss),
        field_densities: spread,
        field_constant: spread.is_some_and(|s| s.is_constant()),
        training_time: TrainingTime::of(trainer.history()),
        prior_only_member: member.map(MemberSummary::of),
        seed_members: seed_members.iter().map(MemberSummary::of).collect(),
        metrics: scored.as_ref().map(|r| r.scores),
        coverage: scored.as_ref().map(|r| r.coverage),
        paper_metrics: scored.as_ref().map(|r| r.paper),
        prior_metrics: prior_scored.as_ref().map(|r| r.scores),
        prior_coverage: prior_scored.as_ref().map(|r| r.coverage),
        centreline,
        topology,
        pose_errors,
    };
    let summary_path = dir.join("summary.json");
    write_file(&summary_path, to_json(&summary, &summary_path)?.as_bytes())?;
    Ok(summary)
}

/// `gaussians.ply`: centres and scales (mm), quaternions, densities. Returns the count.
fn write_gaussians(dir: &Path, trainer: &Trainer) -> Result<usize> {
    let (means, scales, rotations, densities) = trainer.host_gaussians();
    let rows: Vec<Vec<f32>> = (0..densities.len())
        .map(|i| {
            let mut r = means[3 * i..3 * i + 3].to_vec();
            r.extend_from_slice(&scales[3 * i..3 * i + 3]);
            r.extend_from_slice(&rotations[4 * i..4 * i + 4]);
            r.push(densities[i]);
            r
        })
        .collect();
    write_point_ply(
        &dir.join("gaussians.ply"),
        &["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "density"],
        &rows,
        "ctadsa Gaussians: centres and scales in mm, quaternion w x y z, density per mm",
    )?;
    Ok(densities.len())
}

/// The completed surface and how it was extracted.
struct CompletedSurface {
    mesh: TriMesh,
    /// Iso-level (density units).
    level: f64,
    level_scores: Vec<LevelScore>,
    faint_level: Option<f64>,
    /// The level beside the prior (`output.near_prior_mask_threshold`), where it is lower.
    near_prior_level: Option<f64>,
    /// What was cut at `field_level` (the density, or with faint vessels or the near-prior
    /// level the density over the local level, at 1).
    field: Option<Volume<f32>>,
    field_level: f64,
    islands_dropped: usize,
    /// The extracted iso-surface (islands dropped) before the prior is joined.
    extracted: TriMesh,
    /// The prior's voxels on the density grid, where the prior is kept.
    kept_prior: Option<Volume<u8>>,
}

/// The iso-surface of the density at the level from the views (or the configured one), small
/// islands dropped, joined with the prior when it is kept; writes `mesh.*` (and the
/// intermediate `mesh-raw.*` / `mesh-extracted.*`).
fn extract_completed_surface(
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

/// The solid the centreline is traced in (`output.centreline_voxel_mm`): the voxels of the
/// completion's density at or above the surface's level, their iso-surface and the prior's
/// voxels, on the density volume's grid or on a finer one.
struct TracedSolid<'a> {
    above_level: Volume<u8>,
    /// The iso-surface on the finer grid; `None` on the density volume's grid, where it is the
    /// extracted surface.
    surface: Option<TriMesh>,
    /// The prior mesh and its voxels on this grid.
    prior: Option<&'a TriMesh>,
    prior_voxels: Option<Volume<u8>>,
    /// With `output.centreline_bridge_fraction` (`…_two_views`): the extracted solid and the
    /// faint voxels between its beads ([`bridged_solid`]).
    bridges: Option<Volume<u8>>,
    /// With `output.centreline_ridge_weight` (`…_arrival`): the density over the level it was
    /// cut at, on this grid.
    relative: Option<Volume<f32>>,
}

/// The [`TracedSolid`] of a run: on the density volume's grid, or with
/// `output.centreline_voxel_mm` finer than its voxel, the completion's density voxelised again
/// at that size and cut the way the surface was (the same level, the faint vessels' local
/// level at the same radius in mm, and the near-prior level within the same distance).
fn traced_solid<'a>(
    trainer: &Trainer,
    seed_members: &[Trainer],
    member: Option<&Trainer>,
    volume: &Volume<f32>,
    surface: &CompletedSurface,
    prior: Option<&'a TriMesh>,
) -> Result<TracedSolid<'a>> {
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
    let density = completion_density_on(density_on(trainer, grid)?, seed_members, member)?;
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
fn write_centreline_of(
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

/// `loss.csv` and `loss.png` (log scale; a term is drawn where it is positive).
fn write_loss(dir: &Path, history: &[StepLog]) -> Result<()> {
    let mut csv = String::from("iteration,loss,l1,ssim,fn_loss,pa_loss,gaussians\n");
    for s in history {
        csv.push_str(&format!(
            "{},{},{},{},{},{},{}\n",
            s.iteration, s.loss, s.l1, s.ssim, s.fn_loss, s.pa_loss, s.gaussians
        ));
    }
    write_file(&dir.join("loss.csv"), csv.as_bytes())?;
    // Terms that are never positive (switched off) are left out.
    let pick = |f: fn(&StepLog) -> f64| {
        history.iter().map(|s| (s.iteration as f64, f(s))).filter(|p| p.1 > 0.0).collect::<Vec<_>>()
    };
    let series: Vec<Series> = [
        Series { name: "TOTAL".into(), points: pick(|s| s.loss), rgb: PALETTE[5] },
        Series { name: "L1".into(), points: pick(|s| s.l1), rgb: PALETTE[0] },
        Series { name: "1-SSIM".into(), points: pick(|s| 1.0 - s.ssim), rgb: PALETTE[1] },
        Series { name: "FN".into(), points: pick(|s| s.fn_loss), rgb: PALETTE[2] },
        Series { name: "PA".into(), points: pick(|s| s.pa_loss), rgb: PALETTE[3] },
    ]
    .into_iter()
    .filter(|s| !s.points.is_empty())
    .collect();
    line_plot(&dir.join("loss.png"), "TRAINING LOSS", "ITERATION", "LOSS (LOG)", &series, true)
}

/// `mesh.png` (completed mesh blue, prior red) and, with a prior, `mesh-completion.png` as the
/// paper's Fig. 4: the completed surface where the prior had vessels in red, the new vessels in
/// blue, from four directions.
fn write_mesh_pictures(dir: &Path, mesh: &TriMesh, prior: Option<&TriMesh>) -> Result<()> {
    let mut parts = vec![Coloured { mesh, rgb: [60, 120, 220] }];
    if let Some(p) = prior {
        parts.push(Coloured { mesh: p, rgb: [210, 60, 50] });
    }
    write_mesh_png(&dir.join("mesh.png"), &parts, &standard_views(360))?;
    if let Some(p) = prior {
        let (old, new) = split_by_distance(mesh, p, 1.0);
        let mut views = standard_views(320);
        views.push(OrbitView { azimuth_deg: 0.0, elevation_deg: 89.0, width: 320, height: 320 });
        write_mesh_png(
            &dir.join("mesh-completion.png"),
            &[Coloured { mesh: &old, rgb: [210, 60, 50] }, Coloured { mesh: &new, rgb: [60, 120, 220] }],
            &views,
        )?;
    }
    Ok(())
}
